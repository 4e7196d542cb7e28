#include "deblur_sr_mvs/core/geometry/warp.h"

#include <cmath>
#include <limits>
#include <vector>

#include "deblur_sr_mvs/core/common/errors.h"

namespace deblur_sr_mvs {

PixelTransfer::PixelTransfer(const PinholeCamera& camera, const SE3& T_target_source) {
  const Eigen::Matrix3d k = camera.K();
  const Eigen::Matrix3d k_inv = k.inverse();
  homography = k * T_target_source.rotation() * k_inv;
  translation = k * T_target_source.translation();
}

PixelTransferF::PixelTransferF(const PixelTransfer& transfer) {
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) h[3 * r + c] = static_cast<float>(transfer.homography(r, c));
    t[r] = static_cast<float>(transfer.translation(r));
  }
}

void ReprojectDepth(const PinholeCamera& camera, const cv::Mat& depth_source, const SE3& T_target_source,
                    bool fill_from_source, cv::Mat* depth_target) {
  if (depth_source.type() != CV_32FC1 || depth_source.cols != camera.width ||
      depth_source.rows != camera.height) {
    throw InputError("ReprojectDepth: depth map must be CV_32FC1 of the camera size");
  }
  constexpr float kEmpty = std::numeric_limits<float>::infinity();
  depth_target->create(depth_source.size(), CV_32FC1);
  depth_target->setTo(kEmpty);
  const PixelTransferF transfer{PixelTransfer(camera, T_target_source)};
  const int width = camera.width;
  const int height = camera.height;
  float* zbuffer = depth_target->ptr<float>();
  // Per row, first the warp of every pixel (PixelTransferF::WarpUnchecked,
  // which vectorises), then the checks and the z-buffer scatter.
  std::vector<float> row_u(width), row_v(width), row_z(width);
  for (int y = 0; y < height; ++y) {
    const float* __restrict depth_row = depth_source.ptr<float>(y);
    float base[3];
    transfer.RowBase(static_cast<float>(y), base);
    float* __restrict out_u = row_u.data();
    float* __restrict out_v = row_v.data();
    float* __restrict out_z = row_z.data();
    for (int x = 0; x < width; ++x) {
      transfer.WarpUnchecked(base, static_cast<float>(x), depth_row[x], &out_u[x], &out_v[x], &out_z[x]);
    }
    for (int x = 0; x < width; ++x) {
      if (!ValidDepth(depth_row[x]) || !(row_z[x] > 1e-9f)) continue;
      // Nearest target pixel; the z-buffer keeps the closest surface. The
      // unsigned compare rejects negative and too large indices at once.
      const int tx = static_cast<int>(std::floor(row_u[x] + 0.5f));
      const int ty = static_cast<int>(std::floor(row_v[x] + 0.5f));
      if (static_cast<unsigned>(tx) >= static_cast<unsigned>(width) ||
          static_cast<unsigned>(ty) >= static_cast<unsigned>(height)) {
        continue;
      }
      float& slot = zbuffer[ty * width + tx];
      if (row_z[x] < slot) slot = row_z[x];
    }
  }
  const float missing = std::numeric_limits<float>::quiet_NaN();
  for (int y = 0; y < height; ++y) {
    float* out = depth_target->ptr<float>(y);
    const float* in = depth_source.ptr<float>(y);
    for (int x = 0; x < width; ++x) {
      if (out[x] == kEmpty) out[x] = fill_from_source ? in[x] : missing;
    }
  }
}

cv::Mat WarpCoordinates(const PinholeCamera& camera, const cv::Mat& depth_source,
                        const SE3& T_target_source) {
  if (depth_source.type() != CV_32FC1 || depth_source.cols != camera.width ||
      depth_source.rows != camera.height) {
    throw InputError("WarpCoordinates: depth map must be CV_32FC1 of the camera size");
  }
  const float nan = std::numeric_limits<float>::quiet_NaN();
  cv::Mat coordinates(depth_source.size(), CV_32FC2, cv::Scalar(nan, nan));
  const PixelTransfer transfer(camera, T_target_source);
  for (int y = 0; y < camera.height; ++y) {
    const float* depth_row = depth_source.ptr<float>(y);
    cv::Vec2f* out = coordinates.ptr<cv::Vec2f>(y);
    for (int x = 0; x < camera.width; ++x) {
      if (!ValidDepth(depth_row[x])) continue;
      Eigen::Vector2d target;
      if (transfer.Warp(x, y, depth_row[x], &target)) {
        out[x] = cv::Vec2f(static_cast<float>(target.x()), static_cast<float>(target.y()));
      }
    }
  }
  return coordinates;
}

}  // namespace deblur_sr_mvs
