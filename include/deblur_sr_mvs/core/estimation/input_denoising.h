// Denoising the input frames before the estimate (issue 12, "the image
// update must not amplify noise"; BENCHMARKS.md "Denoised anchor in the last
// image pass (branch noise7)", input denoising).
//
// The self-consistency term (eq:IPterm) makes I_t reproduce its own frame's
// noise, which the deblurring then amplifies; removing the noise from the
// LR frames first, where it is white and of a known level, keeps it out.
// Each frame B_t is filtered with OpenCV's multi-frame non-local means
// (cv::fastNlMeansDenoisingMulti) over the frames within temporal_radius of
// t (fewer at the window's ends: OpenCV centres the window), so that its
// patches are averaged with the same scene's patches in the neighbouring
// frames (independent noise draws) as well as its own. A single-frame
// filter removed blur-shaped detail with the noise (BENCHMARKS.md "Denoising
// the inputs first", -0.25 dB at sigma 2 with h 2).
//
// h follows the input noise sigma_in, the noise estimate (EstimateNoiseSigma,
// or EstimatorOptions::noise_sigma when given) less the estimator's floor
// on noise-free frames:
//   sigma_in = sqrt(max(0, sigma_est^2 - noise_floor^2)),  h = h_scale x sigma_in,
// OpenCV's weight exp(-d^2 / h^2) (d^2 the patch mean squared difference):
// two patches of the same content get exp(-2 sigma_in^2 / h^2), 0.14 at
// h_scale 1, a patch that differs by more than the noise far less. Below
// min_noise (so on noise-free frames, whose estimates read 0.46-0.85 gray
// levels) the frames are not touched: the estimate is that of before, bit
// for bit. The estimate then runs on the filtered frames: their own noise
// estimate (the residual noise) sets the TV weight and the multi-frame
// pass's threshold (EstimatorOptions::noise_sigma when given is kept).
#pragma once

#include <vector>

#include <opencv2/core.hpp>

namespace deblur_sr_mvs {

struct InputDenoisingOptions {
  // Off: the frames as given.
  bool enabled = false;
  // Intensity units ([0, 1]): the estimate's floor on noise-free frames
  // (0.46-0.85 gray levels measured, BENCHMARKS.md "Noise-aware image
  // weight"; 0.9 lies above all of them) and the least sigma_in filtered.
  double noise_floor = 0.9 / 255.0;
  double min_noise = 0.25 / 255.0;
  double h_scale = 1.0;     // h over sigma_in
  int temporal_radius = 1;  // frames on either side (the multi-frame pass's radius)
  int template_px = 7;      // OpenCV's NLM patch and search window (odd, px)
  int search_px = 21;
  void Check() const;  // throws InputError naming the bad value
};

// h (intensity units) for frames whose noise estimate is `estimated_noise`;
// 0: leave them as they are.
double InputDenoisingStrength(const InputDenoisingOptions& options, double estimated_noise);

// The frames (CV_32F, 1-4 channels, one size, [0, 1]) each filtered with
// the others within temporal_radius at strength h > 0 (intensity units):
// B_t + (NLM(q)_t - q_t) / 255, q the frames rounded to 8 bits (the filter's
// correction on the float frames; frames read from 8-bit files come back
// exactly where it does nothing). New Mats.
std::vector<cv::Mat> DenoiseInputFrames(const std::vector<cv::Mat>& images, double h,
                                        const InputDenoisingOptions& options);

// image + (filtered - quantised) / 255: the correction of an 8-bit filter
// (quantised = image x 255 rounded, filtered = its output) applied to the
// float image, so that what the filter leaves alone keeps its float value.
// A new Mat; used by DenoiseInputFrames and DenoisedAnchor.
cv::Mat WithFilterCorrection(const cv::Mat& image, const cv::Mat& quantised, const cv::Mat& filtered);

}  // namespace deblur_sr_mvs
