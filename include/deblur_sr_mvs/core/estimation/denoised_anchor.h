// Denoised anchor for the last image pass (issue 12, "the image update must
// not amplify noise"; BENCHMARKS.md "Denoised anchor in the last image pass
// (branch noise7)").
//
// The restored I_t carries its own frame's noise, amplified by the
// deconvolution and the 2x super-resolution in the directions the capture
// operators hardly constrain (high frequencies along the blur), where only
// the TV term holds it back; a heavier TV weight removes detail faster than
// noise ("The TV weight cannot buy the amplification back"). A plug-and-play
// (half-quadratic splitting) step replaces the prior there by a denoiser:
// z_t = NLM(I_t) (OpenCV's non-local means, cv::fastNlMeansDenoising), then
// I_t is re-solved from its current value in the multi-frame data pass with
// the proximity term (weight / 2) ||I_t - z_t||^2 added to eq:imgUpdate's
// terms. Where the data terms are strong (what the frames observe) I_t
// follows them, detail included; where they are weak (the amplified noise)
// it follows the denoised z_t. A final NLM on the output instead removed
// detail with the noise (BENCHMARKS.md "Temporal fusion", -0.4 dB at h 5).
//
// Everything follows the input noise sigma_in, the window's noise estimate
// (EstimateNoiseSigma) less the estimator's floor on noise-free frames:
//   sigma_in  = sqrt(max(0, sigma_est^2 - noise_floor^2)),
//   sigma_amp = amplification x sigma_in   (the noise I_t carries),
//   h         = h_scale x sigma_amp        (NLM filter strength),
//   weight    = weight_scale x lambda_s x sigma_r / sigma_amp^2,
//               sigma_r = sqrt(model_error_sigma^2 + sigma_in^2),
// the last the Gaussian prior N(z_t, sigma_amp^2) in the units of the L1
// data terms (lambda_s |r| ~ lambda_s sigma_r r^2 / (2 sigma_r^2) for
// residuals of scale sigma_r). Below min_noise (sigma_in, hence on
// noise-free frames, whose estimates read 0.46-0.85 gray levels) there is
// no anchor: the images are those of before, bit for bit.
#pragma once

#include <opencv2/core.hpp>

namespace deblur_sr_mvs {

// The denoiser that gives the anchor z_t.
enum class AnchorDenoiser {
  kNonLocalMeans,   // single-image NLM of I_t (DenoisedAnchor), h as below
  kTemporalFusion,  // FuseRestoredImages of the window's I_s (independent noise draws)
};

struct DenoisedAnchorOptions {
  // Off: no anchor (the output images of before, bit for bit). Off by
  // default: on Dolls and Aloe, lateral and hand-held, sigma 1-4, every
  // variant measured lost PSNR against the pass without it (BENCHMARKS.md
  // "Denoised anchor in the last image pass (branch noise7)").
  bool enabled = false;
  AnchorDenoiser denoiser = AnchorDenoiser::kTemporalFusion;
  // Intensity units ([0, 1]). The estimate's floor on noise-free frames:
  // 0.46-0.85 gray levels measured (8-bit rounding and scene detail,
  // BENCHMARKS.md "Noise-aware image weight"); 0.9 lies above all of them.
  double noise_floor = 0.9 / 255.0;
  // No anchor while sigma_in is below this (intensity units).
  double min_noise = 0.25 / 255.0;
  // The added error of the restored images over the input noise, measured
  // 2.0-3.2 at sigma 2 before the fusion (BENCHMARKS.md "Noise amplification",
  // "Multi-frame evidence"): 3, the lateral paths' value.
  double amplification = 3.0;
  // NLM h over sigma_amp (OpenCV's weight exp(-d^2 / h^2), d^2 the patch
  // mean squared difference: two patches of the same content differing by
  // noise of sigma_amp get exp(-2 sigma_amp^2 / h^2), 0.14 at h_scale 1).
  double h_scale = 1.0;
  // Scale of the proximity weight against the rule above.
  double weight_scale = 1.0;
  // OpenCV's NLM patch and search window (odd, px; its defaults).
  int template_px = 7;
  int search_px = 21;
  // kTemporalFusion: the neighbours fused (EstimatorOptions::fusion's h and
  // patch).
  int fusion_radius = 2;
  void Check() const;  // throws InputError naming the bad value
};

// The anchor of one window: sigma_in and what follows from it (all
// intensity units); active false: no anchor.
struct DenoisedAnchorSettings {
  bool active = false;
  double input_noise = 0.0;
  double amplified_noise = 0.0;
  double h = 0.0;
  double weight = 0.0;
};

// The settings for a window whose noise estimate is `estimated_noise` (the
// floor is taken off) with the data terms' weight lambda_s and model error
// model_error_sigma (EstimatorOptions).
DenoisedAnchorSettings AnchorSettings(const DenoisedAnchorOptions& options, double estimated_noise,
                                      double lambda_s, double model_error_sigma);

// z = image + (NLM(q) - q) / 255 with q = image x 255 rounded to 8 bits
// (cv::fastNlMeansDenoising, filter strength h in intensity units, 1-4
// channels of CV_32F): the filter's correction on the float image, so that
// what it leaves alone keeps its float value. A new Mat.
cv::Mat DenoisedAnchor(const cv::Mat& image, double h, const DenoisedAnchorOptions& options);

}  // namespace deblur_sr_mvs
