// A long sequence estimated offline in overlapping windows, as the node
// streams it (StreamEstimator): memory and time grow with the window, not
// with the sequence, so a clip of hundreds of frames runs where one window
// of all its frames would not fit in memory. Unlike the node, which
// publishes a frame with the first window that estimates it, a frame that
// two windows share is taken from the window where it has neighbours on
// both sides (EstimateInWindows).
#pragma once

#include <functional>
#include <string>
#include <vector>

#include "deblur_sr_mvs/core/estimation/estimator.h"
#include "deblur_sr_mvs/core/estimation/stream.h"

namespace deblur_sr_mvs {

// How a sequence is cut into windows.
struct WindowedRunOptions {
  // Frames per window; a sequence of at most this many frames is one window
  // (Estimator::Run on all of it). 0: always one window.
  int window_size = 0;
  // Frames shared by consecutive windows (StreamOptions::window_overlap);
  // the last window ends at the last frame and may share more.
  int window_overlap = 2;
  // Ties the windows to one trajectory of the whole sequence
  // (InitializeTrajectory: the tracks of every frame in one bundle
  // adjustment), given to every window as a pose prior
  // (EstimatorInput::T_prior_cam): windows that only share a few frames
  // otherwise let their poses drift apart along the chain (ATE 2.1x that of
  // one window on a 60-frame hand-held clip in windows of 22, 0.96x with the
  // tie: BENCHMARKS.md "Long sequences in windows"). Not used with a pose
  // prior of the input's own, nor when the whole sequence cannot be
  // initialised (the result's notes say so).
  bool tie_to_sequence_trajectory = true;
  // The tie's standard deviations, as InitializerOptions'
  // pose_prior_position_sigma (per axis, in the trajectory's units: median
  // point depths) and pose_prior_rotation_sigma_deg (0: the orientations
  // only align it).
  double tie_position_sigma = 0.01;
  double tie_rotation_sigma_deg = 0.1;
  void Check() const;  // throws InputError naming the bad value
};

// The frame ranges [first, last] of the windows of a sequence of
// `num_frames` frames: the fewest windows of at most window_size frames
// that cover it with window_overlap frames shared by neighbours, all of one
// size (the last ends on the last frame and may share more). One window of
// every frame when window_size is 0 or not below num_frames.
struct FrameRange {
  int first = 0;
  int last = 0;
};
std::vector<FrameRange> WindowRanges(int num_frames, const WindowedRunOptions& options);

// The frames `range` of `input` as an input of their own (camera, readout
// time and pose priors as `input`'s).
EstimatorInput WindowInputOf(const EstimatorInput& input, const FrameRange& range);

// Called with each window's index and input before the window is estimated:
// the caller may set its frames' exposures and its readout time (e.g.
// measured on those frames, as the node does per window).
using WindowPreparation = std::function<void(int window, EstimatorInput* window_input)>;

// What one window of a windowed run did (for report.json).
struct WindowRecord {
  FrameRange frames;
  int first_output = 0;  // sequence index of the first frame whose outputs come from this window
  bool continued = false;
  std::string note;  // WindowEstimate::note
  std::vector<EnergyRecord> energies;
  std::string initializer_summary;
  std::vector<std::string> notes;
};

// Estimates `input` window after window with a StreamEstimator of
// `options`, and returns one EstimatorResult for all frames: each frame's
// latent image, depth, solver depth and pose from one window (of the frames
// two windows share, the first half from the earlier and the rest from the
// later window, where each has neighbours on both sides; the later window
// holds their poses and restored images, so only their depth differs),
// poses and depths in the first window's world and scale (
// docs/file_formats.md#monocular-scale), stage timings summed over the
// windows, energies and notes of every window in order (after the tie's
// note: WindowedRunOptions::tie_to_sequence_trajectory), frame gains chained
// across windows relative to the first frame. `windows` (optional) gets one
// record per window; `prepare` (optional) sees each window's input first.
// With one window this is Estimator::Run. Throws as the
// Estimator does (InitializationError names the window's frames).
EstimatorResult EstimateInWindows(const EstimatorInput& input, const EstimatorOptions& options,
                                  const WindowedRunOptions& windowing, const ProgressCallback& progress,
                                  std::vector<WindowRecord>* windows = nullptr,
                                  const WindowPreparation& prepare = nullptr);

}  // namespace deblur_sr_mvs
