#include "deblur_sr_mvs/core/estimation/frame_structure.h"

#include <algorithm>
#include <cmath>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/geometry/warp.h"

namespace deblur_sr_mvs {

CaptureGeometry MakeCaptureGeometry(const std::vector<FrameStructure>& frames, const PinholeCamera& camera_hr,
                                    int t, int source) {
  const int n = static_cast<int>(frames.size());
  if (n < 2 || t < 0 || t >= n || source < 0 || source >= n) {
    throw InputError("MakeCaptureGeometry: needs >= 2 frames and valid indices");
  }
  const int neighbour = t > 0 ? t - 1 : t + 1;
  CaptureGeometry geometry;
  geometry.camera_hr = camera_hr;
  geometry.depth_hr = frames[t].depth_hr;
  geometry.T_world_cam = frames[t].T_world_cam;
  geometry.T_world_neighbour = frames[neighbour].T_world_cam;
  geometry.stamp = frames[t].stamp;
  geometry.neighbour_stamp = frames[neighbour].stamp;
  geometry.exposure = frames[t].exposure;
  geometry.readout_time = frames[t].readout_time;
  if (source != t) geometry.T_world_source = frames[source].T_world_cam;
  return geometry;
}

cv::Mat RollingShutterLookup(const std::vector<FrameStructure>& frames, const PinholeCamera& camera_hr, int t,
                             int scale) {
  const CaptureGeometry geometry = MakeCaptureGeometry(frames, camera_hr, t, t);
  const int lr_rows = camera_hr.height / scale;
  // T_row_t per LR row: the camera that reads row y out against P_t.
  const SE3 T_world_t = geometry.T_world_cam;
  const double frame_gap = geometry.stamp - geometry.neighbour_stamp;
  std::vector<PixelTransfer> transfers;
  transfers.reserve(lr_rows);
  for (int y = 0; y < lr_rows; ++y) {
    const double alpha =
        (geometry.stamp + RowDelay(geometry, y, lr_rows) - geometry.neighbour_stamp) / frame_gap;
    const SE3 T_world_row = InterpolatePose(geometry.T_world_neighbour, T_world_t, alpha);
    transfers.emplace_back(camera_hr, T_world_row.Inverse() * T_world_t);
  }
  cv::Mat lookup(camera_hr.height, camera_hr.width, CV_32FC2);
  const cv::Mat& depth = frames[t].depth_hr;
#pragma omp parallel for schedule(static)
  for (int y = 0; y < camera_hr.height; ++y) {
    const float* depth_row = depth.ptr<float>(y);
    cv::Vec2f* out = lookup.ptr<cv::Vec2f>(y);
    for (int x = 0; x < camera_hr.width; ++x) {
      Eigen::Vector2d seen(x, y);
      for (int step = 0; step < 2 && ValidDepth(depth_row[x]); ++step) {
        const int row = std::clamp(static_cast<int>(std::floor(seen.y() / scale)), 0, lr_rows - 1);
        Eigen::Vector2d warped;
        if (transfers[row].Warp(x, y, depth_row[x], &warped)) seen = warped;
      }
      out[x] = cv::Vec2f(static_cast<float>(seen.x()), static_cast<float>(seen.y()));
    }
  }
  return lookup;
}

std::vector<int> Neighbours(int t, int num_frames, int radius) {
  std::vector<int> result;
  for (int s = t - radius; s <= t + radius; ++s) {
    if (s != t && s >= 0 && s < num_frames) result.push_back(s);
  }
  return result;
}

}  // namespace deblur_sr_mvs
