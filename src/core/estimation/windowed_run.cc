#include "deblur_sr_mvs/core/estimation/windowed_run.h"

#include <algorithm>
#include <sstream>
#include <string>
#include <utility>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/common/options_check.h"
#include "deblur_sr_mvs/core/common/runtime.h"
#include "deblur_sr_mvs/core/estimation/initializer.h"
#include "deblur_sr_mvs/core/geometry/pose_prior.h"

namespace deblur_sr_mvs {

void WindowedRunOptions::Check() const {
  CheckAbove("tie_position_sigma", tie_position_sigma, 0.0);
  CheckAtLeast("tie_rotation_sigma_deg", tie_rotation_sigma_deg, 0.0);
  if (window_size == 0) return;
  StreamOptions stream;
  stream.window_size = window_size;
  stream.window_overlap = window_overlap;
  stream.Check();
}

std::vector<FrameRange> WindowRanges(int num_frames, const WindowedRunOptions& options) {
  options.Check();
  if (num_frames < 1) return {};
  if (options.window_size == 0 || num_frames <= options.window_size) return {{0, num_frames - 1}};
  // The fewest windows of at most window_size frames that cover the
  // sequence with window_overlap shared between neighbours, made as even as
  // the frame count allows (no short last window that repeats most of the
  // one before it): k windows of `size` frames advancing by size - overlap;
  // the last one ends on the last frame and may share a little more.
  const int overlap = options.window_overlap;
  const int count =
      (num_frames - overlap + options.window_size - overlap - 1) / (options.window_size - overlap);
  const int size = (num_frames + (count - 1) * overlap + count - 1) / count;
  std::vector<FrameRange> ranges;
  for (int k = 0; k + 1 < count; ++k)
    ranges.push_back({k * (size - overlap), k * (size - overlap) + size - 1});
  ranges.push_back({num_frames - size, num_frames - 1});
  return ranges;
}

EstimatorInput WindowInputOf(const EstimatorInput& input, const FrameRange& range) {
  EstimatorInput window;
  window.camera = input.camera;
  window.readout_time = input.readout_time;
  window.images.assign(input.images.begin() + range.first, input.images.begin() + range.last + 1);
  window.frames.assign(input.frames.begin() + range.first, input.frames.begin() + range.last + 1);
  if (!input.T_prior_cam.empty()) {
    window.T_prior_cam.assign(input.T_prior_cam.begin() + range.first,
                              input.T_prior_cam.begin() + range.last + 1);
  }
  return window;
}

namespace {

std::string FramesText(const FrameRange& range) {
  return "frames " + std::to_string(range.first) + "-" + std::to_string(range.last);
}

// A window's input as the stream takes it (ids = sequence indices).
StreamWindow StreamFramesOf(const EstimatorInput& window_input, const FrameRange& range) {
  StreamWindow window;
  for (size_t i = 0; i < window_input.images.size(); ++i) {
    StreamFrame frame;
    frame.id = static_cast<uint64_t>(range.first + i);
    frame.stamp_ns = static_cast<int64_t>(range.first + i);
    frame.stamp_close = window_input.frames[i].stamp;
    frame.exposure = window_input.frames[i].exposure;
    frame.readout_time = window_input.readout_time;
    frame.image = window_input.images[i];
    if (i < window_input.T_prior_cam.size()) frame.T_prior_cam = window_input.T_prior_cam[i];
    window.push_back(std::move(frame));
  }
  return window;
}

// Sets frame t of `result` (appended when t is the next frame) from frame i
// of `window`, its gain relative to the window's first frame times
// `gain_of_first`.
void SetFrame(const EstimatorResult& window, size_t i, size_t t, double gain_of_first,
              EstimatorResult* result) {
  const cv::Mat& solver_depth = i < window.solver_depth.size() ? window.solver_depth[i] : window.depth[i];
  const double gain = window.frame_gains.empty() ? 1.0 : gain_of_first * window.frame_gains[i];
  if (t == result->latent.size()) {
    result->latent.push_back(window.latent[i]);
    result->depth.push_back(window.depth[i]);
    result->solver_depth.push_back(solver_depth);
    result->T_world_cam.push_back(window.T_world_cam[i]);
    if (!window.frame_gains.empty()) result->frame_gains.push_back(gain);
    return;
  }
  result->latent[t] = window.latent[i];
  result->depth[t] = window.depth[i];
  result->solver_depth[t] = solver_depth;
  result->T_world_cam[t] = window.T_world_cam[i];
  if (t < result->frame_gains.size()) result->frame_gains[t] = gain;
}

// Takes window `estimate`'s frames from window index `take_from` on into
// `result` (replacing those an earlier window gave), and its bookkeeping
// (timings, energies, notes, work) for all of it.
void Append(const WindowEstimate& estimate, const FrameRange& range, int take_from, EstimatorResult* result) {
  const EstimatorResult& window = estimate.result;
  const bool chain_gains =
      !window.frame_gains.empty() && static_cast<int>(result->frame_gains.size()) > range.first;
  const double gain_of_first =
      chain_gains ? result->frame_gains[range.first] / window.frame_gains.front() : 1.0;
  for (size_t i = take_from; i < window.latent.size(); ++i)
    SetFrame(window, i, range.first + i, gain_of_first, result);
  for (const StageTiming& timing : window.timings) AddStageSeconds(timing.stage, timing.seconds, &result->timings);
  result->energies.insert(result->energies.end(), window.energies.begin(), window.energies.end());
  const std::string prefix = FramesText(range) + ": ";
  for (const std::string& note : window.notes) result->notes.push_back(prefix + note);
  result->initializer_summary += "window " + FramesText(range) + ":\n" + window.initializer_summary + "\n";
  result->depth_observable = result->depth_observable || window.depth_observable;
  result->operators_reused += window.operators_reused;
  result->image_work += window.image_work;
}

// With WindowedRunOptions::tie_to_sequence_trajectory: the whole
// sequence's trajectory (InitializeTrajectory) as every window's pose prior,
// in `tied` and `tied_options`; returns a note for the result ("" when the
// tie is off).
std::string TieToSequenceTrajectory(const EstimatorInput& input, const EstimatorOptions& options,
                                    const WindowedRunOptions& windowing, EstimatorInput* tied,
                                    EstimatorOptions* tied_options) {
  if (!windowing.tie_to_sequence_trajectory) return "";
  if (HasAnyPriorPose(input.T_prior_cam)) return "windows tied by the input's pose prior";
  InitialTrajectory trajectory;
  try {
    trajectory = InitializeTrajectory(input.images, input.camera, input.frames, options.initializer,
                                      input.readout_time);
  } catch (const InitializationError& error) {
    return std::string("windows not tied: the whole sequence's trajectory could not be initialised (") +
           error.what() + ")";
  }
  tied->T_prior_cam.assign(trajectory.T_world_cam.begin(), trajectory.T_world_cam.end());
  tied_options->initializer.pose_prior_position_sigma = windowing.tie_position_sigma;
  tied_options->initializer.pose_prior_rotation_sigma_deg = windowing.tie_rotation_sigma_deg;
  // The trajectory is far more precise than its sigma (the stitched cameras
  // lie about 0.0005 median depths from it in the test): a spread of one
  // sigma fixes a window's scale to it (the metric prior's default, 0.02,
  // is meant for centimetres of noise), so that a slow start is tied too.
  tied_options->initializer.pose_prior.min_prior_extent = windowing.tie_position_sigma;
  std::ostringstream note;
  note << "windows tied to the whole sequence's trajectory (its tracks in one bundle adjustment) as a pose "
          "prior of sigma "
       << windowing.tie_position_sigma << " median depths, " << windowing.tie_rotation_sigma_deg << " deg";
  return note.str();
}

}  // namespace

EstimatorResult EstimateInWindows(const EstimatorInput& input, const EstimatorOptions& options,
                                  const WindowedRunOptions& windowing, const ProgressCallback& progress,
                                  std::vector<WindowRecord>* windows, const WindowPreparation& prepare) {
  const int num_frames = static_cast<int>(input.images.size());
  if (static_cast<int>(input.frames.size()) != num_frames) {
    throw InputError("EstimateInWindows: one frame record per image needed");
  }
  const std::vector<FrameRange> ranges = WindowRanges(num_frames, windowing);
  if (windows) windows->clear();
  if (ranges.size() <= 1) {
    EstimatorInput prepared = input;
    if (prepare && !ranges.empty()) prepare(0, &prepared);
    EstimatorResult result = Estimator(options).Run(prepared, progress);
    if (windows && !ranges.empty()) {
      windows->push_back({ranges.front(), 0, false, "one window of every frame", result.energies,
                          result.initializer_summary, result.notes});
    }
    return result;
  }
  EstimatorResult result;
  result.depth_observable = false;
  EstimatorInput tied = input;
  EstimatorOptions tied_options = options;
  const double tie_begin = NowMs();
  const std::string tie_note = TieToSequenceTrajectory(input, options, windowing, &tied, &tied_options);
  if (!tie_note.empty()) {
    AddStageSeconds("sequence trajectory", (NowMs() - tie_begin) / 1000.0, &result.timings);
    result.notes.push_back(tie_note);
  }
  StreamEstimator stream(tied_options);
  stream.SetWindowOverlap(windowing.window_overlap);
  double noise_sigma_sum = 0.0, lambda_i_sum = 0.0;
  for (size_t w = 0; w < ranges.size(); ++w) {
    const FrameRange& range = ranges[w];
    ProgressCallback window_progress;
    if (progress) {
      window_progress = [&progress, w, &ranges, &range](double fraction, const std::string& what) {
        progress((w + fraction) / ranges.size(), FramesText(range) + ": " + what);
      };
    }
    WindowEstimate estimate;
    try {
      EstimatorInput window_input = WindowInputOf(tied, range);
      if (prepare) prepare(static_cast<int>(w), &window_input);
      estimate = stream.Process(StreamFramesOf(window_input, range), input.camera, window_progress);
    } catch (const InitializationError& error) {
      throw InitializationError(FramesText(range) + ": " + error.what());
    }
    if (w == 0) {
      result.camera_hr = estimate.result.camera_hr;
      result.input_denoising_h = estimate.result.input_denoising_h;
    }
    // Of the frames two windows share, the earlier window gives out the
    // first half, the later one the rest: each from the window in which it
    // has neighbours on both sides (a window's last frame is matched from
    // one side only: in the test its depth rel. error is 0.052 from the
    // earlier window, 0.035 from the later). A shared frame keeps its pose
    // and restored image in the later window (held); its depth is
    // estimated again. A window that could not continue the trajectory (a
    // new segment, in its own world and scale) or has no depth (no
    // parallax) gives only the frames no earlier window gave.
    const int shared = w == 0 ? 0 : ranges[w - 1].last - range.first + 1;
    const int take_from = estimate.continued && estimate.result.depth_observable ? (shared + 1) / 2 : shared;
    Append(estimate, range, take_from, &result);
    noise_sigma_sum += estimate.result.noise_sigma;
    lambda_i_sum += estimate.result.image_lambda_i;
    if (windows) {
      windows->push_back({range, range.first + take_from, estimate.continued, estimate.note,
                          estimate.result.energies, estimate.result.initializer_summary,
                          estimate.result.notes});
    }
  }
  // Gains chain through the shared frames; a window without them (its
  // frames' gains could not be read) leaves no gain for the sequence.
  if (result.frame_gains.size() != result.latent.size()) result.frame_gains.clear();
  result.noise_sigma = noise_sigma_sum / ranges.size();
  result.image_lambda_i = lambda_i_sum / ranges.size();
  return result;
}

}  // namespace deblur_sr_mvs
