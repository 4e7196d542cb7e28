#include "deblur_sr_mvs/core/estimation/multi_frame_data.h"

#include <opencv2/imgproc.hpp>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/common/options_check.h"

namespace deblur_sr_mvs {

void MultiFrameDataOptions::Check() const {
  CheckAtLeast("multi_frame_weight", relative_weight, 0.0);
  CheckInRange("multi_frame_data: radius", radius, 1, 10);
  CheckAbove("multi_frame_data: agreement_scale", agreement_scale, 0.0);
  CheckAtLeast("multi_frame_data: patch_px", patch_px, 1);
  if (patch_px % 2 == 0) throw InputError("multi_frame_data: patch_px must be odd");
  CheckAtLeast("multi_frame_data: irls_iterations", irls_iterations, 1);
  CheckAtLeast("multi_frame_data: cg_iterations", cg_iterations, 1);
}

cv::Mat MultiFrameAgreementMask(const cv::Mat& predicted, const cv::Mat& observation, const cv::Mat& visible,
                                double threshold, int patch_px) {
  if (predicted.size() != observation.size() || predicted.type() != observation.type() ||
      predicted.depth() != CV_32F || (!visible.empty() && visible.size() != predicted.size())) {
    throw InputError("multi_frame_data: prediction, observation and mask differ in size or type");
  }
  cv::Mat squared, mean;
  cv::subtract(predicted, observation, squared);
  cv::multiply(squared, squared, squared);
  const int channels = squared.channels();
  if (channels > 1) {
    cv::Mat ones(1, channels, CV_32F, cv::Scalar(1.0 / channels));
    cv::transform(squared, mean, ones);
  } else {
    mean = squared;
  }
  cv::boxFilter(mean, mean, -1, cv::Size(patch_px, patch_px), cv::Point(-1, -1), true, cv::BORDER_REFLECT);
  cv::Mat mask = mean <= static_cast<float>(threshold * threshold);
  if (!visible.empty()) {
    cv::Mat seen = visible != 0;
    cv::bitwise_and(mask, seen, mask);
  }
  return mask;
}

}  // namespace deblur_sr_mvs
