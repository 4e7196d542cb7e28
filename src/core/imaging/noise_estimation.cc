#include "deblur_sr_mvs/core/imaging/noise_estimation.h"

#include <algorithm>
#include <cmath>

#include <opencv2/imgproc.hpp>

namespace deblur_sr_mvs {
namespace {

// Standard deviation of Immerkaer's mask response to unit white noise:
// sqrt(sum of the squared coefficients) = sqrt(1+4+1+4+16+4+1+4+1).
constexpr double kMaskNoiseGain = 6.0;

double Median(std::vector<float>* values) {
  if (values->empty()) return 0.0;
  const auto middle = values->begin() + values->size() / 2;
  std::nth_element(values->begin(), middle, values->end());
  return *middle;
}

// The `quantile` of non-negative values on a grid (the mask response of a
// quantised image), as for grouped data: classes [(k - 1/2) step,
// (k + 1/2) step), interpolated linearly within the class holding it. The
// plain quantile jumps by whole grid steps, which at 1-2 gray levels of
// noise is 25 % of the estimate.
double GroupedQuantile(std::vector<float>* values, double quantile, double step) {
  if (values->empty()) return 0.0;
  const size_t rank = std::min(values->size() - 1, size_t(quantile * values->size()));
  std::nth_element(values->begin(), values->begin() + rank, values->end());
  const double value = (*values)[rank];
  const double lower = std::max(0.0, (std::round(value / step) - 0.5) * step);
  const double upper = lower + (lower > 0.0 ? step : 0.5 * step);
  size_t below = 0, inside = 0;
  for (float v : *values) {
    if (v < lower) {
      ++below;
    } else if (v < upper) {
      ++inside;
    }
  }
  if (inside == 0) return value;
  const double wanted = quantile * values->size();
  return lower + (upper - lower) * std::clamp((wanted - below) / inside, 0.0, 1.0);
}

// erf^-1 by Newton's method on std::erf (x in [0, 1)).
double ErfInverse(double x) {
  double y = 0.0;
  for (int i = 0; i < 50; ++i)
    y -= (std::erf(y) - x) / (2.0 / std::sqrt(3.14159265358979323846) * std::exp(-y * y));
  return y;
}

}  // namespace

double EstimateNoiseSigma(const cv::Mat& image, double quantization_step, double quantile) {
  if (image.rows < 3 || image.cols < 3) return 0.0;
  cv::Mat image32;
  image.convertTo(image32, CV_MAKETYPE(CV_32F, image.channels()));
  const cv::Mat mask = (cv::Mat_<float>(3, 3) << 1, -2, 1, -2, 4, -2, 1, -2, 1);
  cv::Mat response;
  cv::filter2D(image32, response, CV_32F, mask);
  // Interior only: the border rows and columns see a reflected neighbourhood.
  const cv::Mat interior = response(cv::Rect(1, 1, image.cols - 2, image.rows - 2));
  std::vector<float> magnitudes;
  magnitudes.reserve(interior.total() * interior.channels());
  for (int y = 0; y < interior.rows; ++y) {
    const float* row = interior.ptr<float>(y);
    for (int i = 0; i < interior.cols * interior.channels(); ++i) magnitudes.push_back(std::abs(row[i]));
  }
  // The quantile of |x| for x ~ N(0, 1): Phi^-1((1 + quantile) / 2).
  const double half_normal_quantile = std::sqrt(2.0) * ErfInverse(quantile);
  // Classes of 6 quantisation steps (the mask's noise gain; one step of the
  // estimate): they smooth the few values that low noise gives.
  return GroupedQuantile(&magnitudes, quantile, kMaskNoiseGain * quantization_step) /
         (kMaskNoiseGain * half_normal_quantile);
}

double EstimateNoiseSigma(const std::vector<cv::Mat>& images, double quantization_step, double quantile) {
  std::vector<float> sigmas;
  sigmas.reserve(images.size());
  for (const cv::Mat& image : images)
    sigmas.push_back(float(EstimateNoiseSigma(image, quantization_step, quantile)));
  return Median(&sigmas);
}

double NoiseAboveFloor(double estimated_noise, double floor) {
  const double estimate = std::max(estimated_noise, 0.0);
  const double excess = estimate * estimate - floor * floor;
  return excess > 0.0 ? std::sqrt(excess) : 0.0;
}

}  // namespace deblur_sr_mvs
