#include "deblur_sr_mvs/core/geometry/visibility.h"

#include <cmath>
#include <limits>

#include <opencv2/imgproc.hpp>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/common/options_check.h"
#include "deblur_sr_mvs/core/geometry/warp.h"

namespace deblur_sr_mvs {

void VisibilityOptions::Check() const {
  CheckInInterval("visibility: depth_tolerance", depth_tolerance, 0.0, 1.0, Interval::kLeftClosed);
  CheckInInterval("visibility: source_depth_margin", source_depth_margin, 0.0, 1.0, Interval::kLeftClosed);
}

cv::Mat ComputeVisibility(const PinholeCamera& camera, const cv::Mat& depth_t, const SE3& T_s_t,
                          const VisibilityOptions& options, const cv::Mat* depth_s) {
  options.Check();
  if (depth_t.type() != CV_32FC1 || depth_t.cols != camera.width || depth_t.rows != camera.height) {
    throw InputError("visibility: depth must be CV_32FC1 of the camera size");
  }
  const bool source_test = options.source_depth_margin > 0.0 && depth_s != nullptr;
  if (source_test && (depth_s->type() != CV_32FC1 || depth_s->size() != depth_t.size())) {
    throw InputError("visibility: source depth must be CV_32FC1 of the camera size");
  }
  const float behind_source = static_cast<float>(1.0 + options.source_depth_margin);
  const int width = camera.width;
  const int height = camera.height;
  const PixelTransfer transfer(camera, T_s_t);
  // Target cell of every pixel (or -1) and its depth seen from s.
  cv::Mat cell(depth_t.size(), CV_32SC1, cv::Scalar(-1));
  cv::Mat depth_in_s(depth_t.size(), CV_32FC1);
  cv::Mat nearest(depth_t.size(), CV_32FC1, cv::Scalar(std::numeric_limits<float>::infinity()));
  for (int y = 0; y < height; ++y) {
    const float* d = depth_t.ptr<float>(y);
    int* c = cell.ptr<int>(y);
    float* z = depth_in_s.ptr<float>(y);
    for (int x = 0; x < width; ++x) {
      if (!ValidDepth(d[x])) continue;
      Eigen::Vector2d p;
      double target_depth;
      if (!transfer.Warp(x, y, d[x], &p, &target_depth)) continue;
      const int tx = static_cast<int>(std::floor(p.x() + 0.5));
      const int ty = static_cast<int>(std::floor(p.y() + 0.5));
      if (tx < 0 || ty < 0 || tx >= width || ty >= height) continue;
      c[x] = ty * width + tx;
      z[x] = static_cast<float>(target_depth);
      float& slot = nearest.ptr<float>(ty)[tx];
      if (z[x] < slot) slot = z[x];
      // Behind the surface that s sees there: occluded in s (the z-buffer
      // above still counts x as a possible occluder of t's other pixels).
      if (source_test) {
        const float seen = depth_s->ptr<float>(ty)[tx];
        if (ValidDepth(seen) && z[x] > seen * behind_source) c[x] = -1;
      }
    }
  }
  cv::Mat visible(depth_t.size(), CV_8UC1, cv::Scalar(0));
  const float* nearest_data = nearest.ptr<float>();
  const float tolerance = static_cast<float>(1.0 + options.depth_tolerance);
  for (int y = 0; y < height; ++y) {
    const int* c = cell.ptr<int>(y);
    const float* z = depth_in_s.ptr<float>(y);
    uchar* out = visible.ptr<uchar>(y);
    for (int x = 0; x < width; ++x) {
      if (c[x] >= 0 && z[x] <= nearest_data[c[x]] * tolerance) out[x] = 255;
    }
  }
  return visible;
}

cv::Mat DownscaleMaskAll(const cv::Mat& mask_hr, int scale) {
  if (mask_hr.type() != CV_8UC1 || scale < 1 || mask_hr.cols % scale != 0 || mask_hr.rows % scale != 0) {
    throw InputError("DownscaleMaskAll: mask must be CV_8UC1 with a size divisible by scale");
  }
  cv::Mat mask_lr(mask_hr.rows / scale, mask_hr.cols / scale, CV_8UC1);
  for (int y = 0; y < mask_lr.rows; ++y) {
    for (int x = 0; x < mask_lr.cols; ++x) {
      uchar all = 255;
      for (int dy = 0; dy < scale; ++dy) {
        const uchar* row = mask_hr.ptr<uchar>(y * scale + dy) + x * scale;
        for (int dx = 0; dx < scale; ++dx) all = row[dx] ? all : 0;
      }
      mask_lr.at<uchar>(y, x) = all;
    }
  }
  return mask_lr;
}

void EdgeWeightOptions::Check() const {
  CheckAbove("edge weight: sigma", sigma, 0.0);
  CheckAbove("edge weight: exponent", exponent, 0.0);
}

cv::Mat EdgeWeight(const cv::Mat& image, const EdgeWeightOptions& options) {
  options.Check();
  if (image.depth() != CV_32F || (image.channels() != 1 && image.channels() != 3)) {
    throw InputError("edge weight: image must be float with 1 or 3 channels");
  }
  cv::Mat gray;
  if (image.channels() == 3) {
    cv::transform(image, gray, cv::Matx13f(1.0f / 3, 1.0f / 3, 1.0f / 3));
  } else {
    gray = image;
  }
  cv::Mat weight(image.size(), CV_32FC1);
  for (int y = 0; y < gray.rows; ++y) {
    const float* row = gray.ptr<float>(y);
    const float* next = gray.ptr<float>(std::min(y + 1, gray.rows - 1));
    float* out = weight.ptr<float>(y);
    for (int x = 0; x < gray.cols; ++x) {
      const float gx = row[std::min(x + 1, gray.cols - 1)] - row[x];
      const float gy = next[x] - row[x];
      const double magnitude = std::sqrt(static_cast<double>(gx) * gx + gy * gy);
      out[x] = static_cast<float>(std::exp(-std::pow(magnitude / options.sigma, options.exponent)));
    }
  }
  return weight;
}

}  // namespace deblur_sr_mvs
