// Evaluation metrics of the paper's tables (Sec. experimentalResults).
#pragma once

#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "deblur_sr_mvs/core/geometry/sim3.h"

namespace deblur_sr_mvs {

// PSNR in dB of `estimate` against `reference` (same size and type, any
// channel count), computed in double: 10 log10(peak^2 / MSE) over the pixels
// where `mask` (CV_8UC1, optional) is non-zero. Infinity when MSE is 0.
double Psnr(const cv::Mat& estimate, const cv::Mat& reference, double peak, const cv::Mat& mask = cv::Mat());

// The centred rectangle covering `fraction` of the width and height.
cv::Rect CentreCrop(const cv::Size& size, double fraction);

struct DepthMetricOptions {
  double crop_fraction = 1.0;  // 0.7 reproduces the paper's centre crop
  bool align_scale = true;     // monocular depth: align by the median of gt/est
  void Check() const;
};

struct DepthErrors {
  double psnr_db = 0.0;         // peak = max ground-truth depth over the evaluated pixels
  double relative_error = 0.0;  // mean |s est - gt| / gt
  double scale = 1.0;           // s applied to the estimate
  int num_pixels = 0;           // pixels evaluated (both finite and > 0, inside the crop)
};

DepthErrors EvaluateDepth(const cv::Mat& estimate, const cv::Mat& ground_truth,
                          const DepthMetricOptions& options);

// ATE RMSE (m, in the ground-truth frame) of camera positions after Sim(3)
// alignment of the estimate onto the ground truth.
// Same preconditions as UmeyamaAlignment.
double AbsoluteTrajectoryRmse(const std::vector<Eigen::Vector3d>& estimate,
                              const std::vector<Eigen::Vector3d>& ground_truth, Sim3* alignment = nullptr);

}  // namespace deblur_sr_mvs
