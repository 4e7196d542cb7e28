#include "deblur_sr_mvs/core/estimation/input_denoising.h"

#include <algorithm>
#include <cmath>

#include <opencv2/photo.hpp>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/common/options_check.h"
#include "deblur_sr_mvs/core/imaging/noise_estimation.h"

namespace deblur_sr_mvs {

void InputDenoisingOptions::Check() const {
  CheckInRange("input_denoising: noise_floor", noise_floor, 0.0, 1.0);
  CheckInRange("input_denoising: min_noise", min_noise, 0.0, 1.0);
  CheckAbove("input_denoising: h_scale", h_scale, 0.0);
  CheckInRange("input_denoising: temporal_radius", temporal_radius, 0, 10);
  CheckAtLeast("input_denoising: template_px", template_px, 1);
  CheckAtLeast("input_denoising: search_px", search_px, 1);
  if (template_px % 2 == 0 || search_px % 2 == 0) {
    throw InputError("input_denoising: template_px and search_px must be odd");
  }
}

cv::Mat WithFilterCorrection(const cv::Mat& image, const cv::Mat& quantised, const cv::Mat& filtered) {
  cv::Mat correction, corrected;
  cv::subtract(filtered, quantised, correction, cv::noArray(), CV_32F);
  cv::scaleAdd(correction, 1.0 / 255.0, image, corrected);
  return corrected;
}

double InputDenoisingStrength(const InputDenoisingOptions& options, double estimated_noise) {
  const double input_noise = NoiseAboveFloor(estimated_noise, options.noise_floor);
  if (!options.enabled || input_noise <= 0.0 || input_noise < options.min_noise) return 0.0;
  return options.h_scale * input_noise;
}

std::vector<cv::Mat> DenoiseInputFrames(const std::vector<cv::Mat>& images, double h,
                                        const InputDenoisingOptions& options) {
  CheckAbove("input_denoising: h", h, 0.0);
  std::vector<cv::Mat> quantised(images.size());
  for (size_t t = 0; t < images.size(); ++t) {
    if (images[t].empty() || images[t].depth() != CV_32F || images[t].channels() > 4 ||
        images[t].size() != images[0].size() || images[t].type() != images[0].type()) {
      throw InputError("input_denoising: the frames must be float images of 1 to 4 channels and one size");
    }
    images[t].convertTo(quantised[t], CV_8U, 255.0);
  }
  const int frames = static_cast<int>(images.size());
  std::vector<cv::Mat> denoised(images.size());
  for (int t = 0; t < frames; ++t) {
    const int radius = std::min(options.temporal_radius, std::min(t, frames - 1 - t));
    cv::Mat filtered;
    cv::fastNlMeansDenoisingMulti(quantised, filtered, t, 2 * radius + 1, static_cast<float>(h * 255.0),
                                  options.template_px, options.search_px);
    denoised[t] = WithFilterCorrection(images[t], quantised[t], filtered);
  }
  return denoised;
}

}  // namespace deblur_sr_mvs
