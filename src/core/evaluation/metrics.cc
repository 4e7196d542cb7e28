#include "deblur_sr_mvs/core/evaluation/metrics.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/common/options_check.h"
#include "deblur_sr_mvs/core/common/text.h"
#include "deblur_sr_mvs/core/geometry/sim3.h"

namespace deblur_sr_mvs {
namespace {

// Depth maps may come as float or double; evaluate both in double.
cv::Mat ToDouble(const cv::Mat& image) {
  cv::Mat converted;
  image.convertTo(converted, CV_MAKETYPE(CV_64F, image.channels()));
  return converted;
}

}  // namespace

double Psnr(const cv::Mat& estimate, const cv::Mat& reference, double peak, const cv::Mat& mask) {
  if (estimate.empty() || reference.empty()) throw InputError("PSNR: empty image");
  if (estimate.size() != reference.size() || estimate.type() != reference.type()) {
    throw InputError("PSNR: estimate (" + SizeText(estimate.size()) + ", type " +
                     std::to_string(estimate.type()) + ") and reference (" + SizeText(reference.size()) +
                     ", type " + std::to_string(reference.type()) + ") differ in size or type");
  }
  if (!(peak > 0.0) || !std::isfinite(peak)) throw InputError("PSNR: peak must be positive");
  const bool masked = !mask.empty();
  if (masked && (mask.type() != CV_8UC1 || mask.size() != estimate.size())) {
    throw InputError("PSNR: mask must be 8UC1 of size " + SizeText(estimate.size()));
  }
  const cv::Mat a = ToDouble(estimate);
  const cv::Mat b = ToDouble(reference);
  const int channels = estimate.channels();
  const int row_values = estimate.cols * channels;
  double sum = 0.0;
  long long count = 0;
  for (int y = 0; y < a.rows; ++y) {
    const double* pa = a.ptr<double>(y);
    const double* pb = b.ptr<double>(y);
    const unsigned char* pm = masked ? mask.ptr<unsigned char>(y) : nullptr;
    for (int i = 0; i < row_values; ++i) {
      if (pm != nullptr && pm[i / channels] == 0) continue;
      const double d = pa[i] - pb[i];
      sum += d * d;
      ++count;
    }
  }
  if (count == 0) throw InputError("PSNR: the mask selects no pixels");
  const double mse = sum / static_cast<double>(count);
  if (mse == 0.0) return std::numeric_limits<double>::infinity();
  return 10.0 * std::log10(peak * peak / mse);
}

cv::Rect CentreCrop(const cv::Size& size, double fraction) {
  CheckAbove("crop fraction", fraction, 0.0);
  CheckInRange("crop fraction", fraction, 0.0, 1.0);
  const int width = std::clamp(static_cast<int>(std::lround(fraction * size.width)), 0, size.width);
  const int height = std::clamp(static_cast<int>(std::lround(fraction * size.height)), 0, size.height);
  return cv::Rect((size.width - width) / 2, (size.height - height) / 2, width, height);
}

void DepthMetricOptions::Check() const {
  // In (0, 1].
  CheckAbove("crop_fraction", crop_fraction, 0.0);
  CheckInRange("crop_fraction", crop_fraction, 0.0, 1.0);
}

DepthErrors EvaluateDepth(const cv::Mat& estimate, const cv::Mat& ground_truth,
                          const DepthMetricOptions& options) {
  options.Check();
  if (estimate.empty() || ground_truth.empty()) throw InputError("depth metrics: empty depth map");
  if (estimate.channels() != 1 || ground_truth.channels() != 1) {
    throw InputError("depth metrics: depth maps must be single-channel");
  }
  if (estimate.size() != ground_truth.size()) {
    throw InputError("depth metrics: estimate is " + SizeText(estimate.size()) + " but ground truth is " +
                     SizeText(ground_truth.size()));
  }
  const cv::Rect crop = CentreCrop(estimate.size(), options.crop_fraction);
  const cv::Mat est = ToDouble(estimate(crop));
  const cv::Mat gt = ToDouble(ground_truth(crop));

  // Valid pixels (both finite and > 0) gathered once, as (est, gt) pairs.
  std::vector<double> est_values;
  std::vector<double> gt_values;
  est_values.reserve(crop.area());
  gt_values.reserve(crop.area());
  for (int y = 0; y < est.rows; ++y) {
    const double* pe = est.ptr<double>(y);
    const double* pg = gt.ptr<double>(y);
    for (int x = 0; x < est.cols; ++x) {
      if (std::isfinite(pe[x]) && std::isfinite(pg[x]) && pe[x] > 0.0 && pg[x] > 0.0) {
        est_values.push_back(pe[x]);
        gt_values.push_back(pg[x]);
      }
    }
  }
  const std::size_t n = est_values.size();
  if (n == 0) {
    throw InputError(
        "depth metrics: no pixel has a finite, positive depth in both the estimate "
        "and the ground truth (inside the " +
        SizeText(crop.size()) + " centre crop)");
  }

  DepthErrors errors;
  errors.num_pixels = static_cast<int>(n);
  if (options.align_scale) {
    // Monocular depth is up to scale: s = median(gt / est), robust to outliers.
    std::vector<double> ratios(n);
    for (std::size_t i = 0; i < n; ++i) ratios[i] = gt_values[i] / est_values[i];
    const std::size_t mid = n / 2;
    std::nth_element(ratios.begin(), ratios.begin() + mid, ratios.end());
    double median = ratios[mid];
    if (n % 2 == 0) {
      median = 0.5 * (median + *std::max_element(ratios.begin(), ratios.begin() + mid));
    }
    errors.scale = median;
  }
  double relative_sum = 0.0;
  double squared_sum = 0.0;
  double peak = 0.0;
  for (std::size_t i = 0; i < n; ++i) {
    const double difference = errors.scale * est_values[i] - gt_values[i];
    relative_sum += std::abs(difference) / gt_values[i];
    squared_sum += difference * difference;
    peak = std::max(peak, gt_values[i]);
  }
  errors.relative_error = relative_sum / static_cast<double>(n);
  const double mse = squared_sum / static_cast<double>(n);
  errors.psnr_db =
      mse == 0.0 ? std::numeric_limits<double>::infinity() : 10.0 * std::log10(peak * peak / mse);
  return errors;
}

double AbsoluteTrajectoryRmse(const std::vector<Eigen::Vector3d>& estimate,
                              const std::vector<Eigen::Vector3d>& ground_truth, Sim3* alignment) {
  CheckCorrespondingPoints(estimate, ground_truth, "ATE");
  const Sim3 sim3 = UmeyamaAlignment(estimate, ground_truth, /*with_scale=*/true);
  double squared_sum = 0.0;
  for (std::size_t i = 0; i < estimate.size(); ++i) {
    const Eigen::Vector3d aligned = TransformPoint(sim3, estimate[i]);
    squared_sum += (ground_truth[i] - aligned).squaredNorm();
  }
  if (alignment != nullptr) *alignment = sim3;
  return std::sqrt(squared_sum / static_cast<double>(estimate.size()));
}

}  // namespace deblur_sr_mvs
