#include "deblur_sr_mvs/core/estimation/denoised_anchor.h"

#include <algorithm>
#include <cmath>

#include <opencv2/photo.hpp>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/common/options_check.h"
#include "deblur_sr_mvs/core/estimation/input_denoising.h"
#include "deblur_sr_mvs/core/imaging/noise_estimation.h"

namespace deblur_sr_mvs {

void DenoisedAnchorOptions::Check() const {
  CheckInRange("denoised_anchor: noise_floor", noise_floor, 0.0, 1.0);
  CheckInRange("denoised_anchor: min_noise", min_noise, 0.0, 1.0);
  CheckAbove("denoised_anchor: amplification", amplification, 0.0);
  CheckAbove("denoised_anchor: h_scale", h_scale, 0.0);
  CheckAbove("denoised_anchor: weight_scale", weight_scale, 0.0);
  CheckAtLeast("denoised_anchor: template_px", template_px, 1);
  CheckAtLeast("denoised_anchor: search_px", search_px, 1);
  CheckInRange("denoised_anchor: fusion_radius", fusion_radius, 1, 10);
  if (template_px % 2 == 0 || search_px % 2 == 0) {
    throw InputError("denoised_anchor: template_px and search_px must be odd");
  }
}

DenoisedAnchorSettings AnchorSettings(const DenoisedAnchorOptions& options, double estimated_noise,
                                      double lambda_s, double model_error_sigma) {
  DenoisedAnchorSettings settings;
  settings.input_noise = NoiseAboveFloor(estimated_noise, options.noise_floor);
  settings.active =
      options.enabled && settings.input_noise > 0.0 && settings.input_noise >= options.min_noise;
  if (!settings.active) return settings;
  settings.amplified_noise = options.amplification * settings.input_noise;
  settings.h = options.h_scale * settings.amplified_noise;
  const double residual_scale = std::hypot(model_error_sigma, settings.input_noise);
  settings.weight = options.weight_scale * lambda_s * residual_scale /
                    (settings.amplified_noise * settings.amplified_noise);
  return settings;
}

cv::Mat DenoisedAnchor(const cv::Mat& image, double h, const DenoisedAnchorOptions& options) {
  if (image.depth() != CV_32F || image.channels() > 4 || image.empty()) {
    throw InputError("denoised_anchor: the image must be a non-empty float image of 1 to 4 channels");
  }
  CheckAbove("denoised_anchor: h", h, 0.0);
  cv::Mat quantised, filtered;
  image.convertTo(quantised, CV_8U, 255.0);
  cv::fastNlMeansDenoising(quantised, filtered, static_cast<float>(h * 255.0), options.template_px,
                           options.search_px);
  return WithFilterCorrection(image, quantised, filtered);
}

}  // namespace deblur_sr_mvs
