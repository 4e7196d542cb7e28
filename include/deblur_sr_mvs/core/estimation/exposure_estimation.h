// The exposure estimated from the blur itself (issue 12, part 2: `--exposure
// auto`, the node's `exposure_time: auto`): one fraction of the frame
// interval per window, found by a 1-D search that minimises the data
// residual of a short image update (eq:imgUpdate) over the exposure.
//
// The initialisation runs once, with an assumed fraction: its tracks follow
// the blur centroids (mid-exposure poses), so a probe with another exposure
// moves every pose at shutter close along the same path by half the change
// of the exposure (eq:interpolatingP) and keeps the depth maps. Each probe
// is then the estimator's own image phase (images only, depth and poses
// held) with fewer virtual cameras and reweightings; its residual
// sum_t (lambda_s |Psi_t I_t - B_t| + sum_{s in N(t)} |Psi_s I_t - B_s|) is
// the smallest where the exposure the operators assume explains the blur
// of every frame.
#pragma once

#include <atomic>
#include <string>
#include <utility>
#include <vector>

#include "deblur_sr_mvs/core/estimation/estimator.h"

namespace deblur_sr_mvs {

struct ExposureEstimationOptions {
  // Search interval of the exposure, as fractions of each frame's interval
  // (stamp_t - stamp_{t-1}; the first frame takes the next interval).
  double min_fraction = 0.05;
  double max_fraction = 1.0;
  // Fraction of the interval the initialisation assumes (its tracks see the
  // blur centroids whatever the exposure; only the poses moved to shutter
  // close and the blur-aware matching use it).
  double initial_fraction = 0.5;
  // Evenly spaced probes over [min_fraction, max_fraction] (both ends
  // included), then golden-section steps in the bracket of the best one.
  int grid_points = 6;
  int refine_steps = 5;
  // The probes' image update: virtual cameras per exposure (M of
  // eq:blurOperator) and the IRLS/CG budget of eq:imgUpdate.
  int samples = 20;
  int irls_iterations = 2;
  int cg_iterations = 10;
  void Check() const;  // throws InputError naming the bad field
};

struct ExposureEstimate {
  double fraction = 0.0;                 // of the frame interval
  double seconds = 0.0;                  // fraction x the median frame interval
  std::vector<double> frame_exposures;   // per frame: fraction x its interval (s)
  std::vector<std::pair<double, double>> probes;  // (fraction, residual), in probe order
  double elapsed_seconds = 0.0;          // wall time of the estimation
  std::string summary;                   // one line: the estimate, probes, time
};

// Each frame's interval (stamp_t - stamp_{t-1}; frame 0: stamp_1 - stamp_0);
// throws InputError unless there are >= 2 frames with increasing stamps.
std::vector<double> FrameIntervals(const std::vector<FrameRecord>& frames);

// `frames` with exposure_t = fraction x interval_t.
std::vector<FrameRecord> WithExposureFraction(const std::vector<FrameRecord>& frames, double fraction);

// The exposure of the window `input` (its frames' exposures are ignored).
// `estimator_options` gives the estimator's settings (scale, lambda_s,
// N(t), the initialisation); the probes lower the samples and the image
// update's budget to `options`'. Throws InputError on unusable input,
// InitializationError when the frames cannot be initialised, and
// EstimationCancelled once *cancel (optional) is raised.
ExposureEstimate EstimateExposure(const EstimatorInput& input, const EstimatorOptions& estimator_options,
                                  const ExposureEstimationOptions& options,
                                  const std::atomic<bool>* cancel = nullptr);

}  // namespace deblur_sr_mvs
