// The exposure estimated from the blur itself (issue 12, part 2: `--exposure
// auto`, the node's `exposure_time: auto`): one fraction f of the frame
// interval per window.
//
// Over an exposure e = f x interval a pixel moves along its blur path by f
// times its image motion between two frames, v(x) (eq:interpolatingP), so
// the blurred frame is (locally) the sharp one averaged along a segment of
// length L = f |v(x)|. Its derivative along the motion is then the
// difference of two copies of the sharp image, L apart:
// dB(x) = (S(x) - S(x - L u)) / L, whose correlation with dB(x - L u) is
// strongly negative (-Var(dS) / L^2 against ~0 at other lags, once the
// frame is high-passed so that dS is nearly white). The search
// runs over f the normalised correlation of dB(x) with dB(x - f v(x)),
// summed over the window's frames, and takes its minimum (a grid, then a
// parabola through the best point and its neighbours).
//
// v(x) comes from the initialisation (InitializeStructure: LR depth and the
// poses of every frame; without parallax the orientations of
// EstimateRotationOnlyMotion, depth at infinity): the tracks follow the blur
// centroids, so the relative motion of two frames hardly depends on the
// exposure the initialisation assumes. Minimising instead the data residual
// of a short image update (eq:imgUpdate) over f does not work: with L1 and
// TV, a shorter exposure is always fitted by a blurrier latent image (Dolls,
// ratio 0.5: the residual grows monotonically from f = 0.05 to 1).
#pragma once

#include <atomic>
#include <string>
#include <utility>
#include <vector>

#include "deblur_sr_mvs/core/estimation/estimator.h"

namespace deblur_sr_mvs {

struct ExposureEstimationOptions {
  // Search interval of f, the exposure as a fraction of each frame's
  // interval (stamp_t - stamp_{t-1}; the first frame takes the next one).
  double min_fraction = 0.05;
  double max_fraction = 1.0;
  double fraction_step = 0.01;  // the grid's spacing, refined by a parabola
  // Fraction of the interval the initialisation assumes (only its move of
  // the poses to shutter close and its blur-aware matching use it).
  double initial_fraction = 0.5;
  // Pixels moving less than this between two frames (LR px) carry no
  // measurable blur length and are left out.
  double min_motion_px = 2.0;
  // The derivatives are those of the frame less its Gaussian blur of this
  // sigma (LR px): a whitened signal puts the dip at the blur length.
  double highpass_sigma_px = 1.0;
  void Check() const;  // throws InputError naming the bad field
};

struct ExposureEstimate {
  // false: no pixel moved enough, or the correlation has no negative dip
  // (no measurable blur): fraction is then initial_fraction.
  bool measured = false;
  double fraction = 0.0;                // of the frame interval
  double seconds = 0.0;                 // fraction x the median frame interval
  std::vector<double> frame_exposures;  // per frame: fraction x its interval (s)
  // (fraction, normalised correlation) of the grid, in increasing fraction.
  std::vector<std::pair<double, double>> correlation;
  double elapsed_seconds = 0.0;  // wall time (initialisation included)
  std::string summary;           // one line: the estimate, the dip, the time
};

// Each frame's interval (stamp_t - stamp_{t-1}; frame 0: stamp_1 - stamp_0);
// throws InputError unless there are >= 2 frames with increasing stamps.
std::vector<double> FrameIntervals(const std::vector<FrameRecord>& frames);

// `frames` with exposure_t = fraction x interval_t.
std::vector<FrameRecord> WithExposureFraction(const std::vector<FrameRecord>& frames, double fraction);

// The search of the header on LR frames (float [0, 1], 1 or 3 channels) of
// `camera_lr`, given each frame's LR depth (CV_32FC1, NaN/0 unknown; empty:
// depth at infinity, a rotation) and its pose at shutter close. With a
// rolling shutter (`readout_time` > 0, docs/file_formats.md#rolling-shutter)
// each row's motion is taken over the interval that ends when that row
// closes (its delay readout_time x y / H after row 0), and the lag is
// mapped into the frame's own rows, which see the moving image later the
// lower they are: a lag d of the image at row 0's time is J^-1 d in the
// frame, J = [[1, -s_x], [0, 1 - s_y]], s = the image motion per row time
// (the row's motion per interval x readout_time / interval / H).
ExposureEstimate EstimateExposureFromMotion(
    const std::vector<cv::Mat>& images_lr, const PinholeCamera& camera_lr,
    const std::vector<FrameRecord>& frames, const std::vector<cv::Mat>& depth_lr,
    const std::vector<SE3>& T_world_cam, const ExposureEstimationOptions& options, double readout_time = 0.0);

// The exposure of the window `input` (its frames' exposures are ignored):
// the initialisation with `estimator_options.initializer`, then
// EstimateExposureFromMotion. Throws InputError on unusable input,
// InitializationError when the frames cannot be initialised, and
// EstimationCancelled once *cancel (optional) is raised.
ExposureEstimate EstimateExposure(const EstimatorInput& input, const EstimatorOptions& estimator_options,
                                  const ExposureEstimationOptions& options,
                                  const std::atomic<bool>* cancel = nullptr);

}  // namespace deblur_sr_mvs
