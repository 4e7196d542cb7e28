#include "deblur_sr_mvs/core/estimation/stream.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

#include <opencv2/imgproc.hpp>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/common/options_check.h"
#include "deblur_sr_mvs/core/common/runtime.h"
#include "deblur_sr_mvs/core/estimation/initializer.h"

namespace deblur_sr_mvs {

void StreamOptions::Check() const {
  CheckInRange("window_size", window_size, 3, 64);
  CheckInRange("window_overlap", window_overlap, 2, window_size - 1);
  CheckInRange("max_pending_windows", max_pending_windows, 1, 100);
}

// ------------------------------------------------------------- FrameWindower

FrameWindower::FrameWindower(const StreamOptions& options) {
  SetOptions(options);
}

void FrameWindower::SetOptions(const StreamOptions& options) {
  options.Check();
  options_ = options;
}

void FrameWindower::Reset() {
  buffer_.clear();
}

std::vector<StreamWindow> FrameWindower::Add(StreamFrame frame) {
  buffer_.push_back(std::move(frame));
  std::vector<StreamWindow> windows;
  const size_t size = static_cast<size_t>(options_.window_size);
  const size_t advance = size - static_cast<size_t>(options_.window_overlap);
  while (buffer_.size() >= size) {
    windows.emplace_back(buffer_.begin(), buffer_.begin() + size);
    buffer_.erase(buffer_.begin(), buffer_.begin() + advance);
  }
  return windows;
}

// ------------------------------------------------------------------ alignment

namespace {

double PathLength(const std::vector<SE3>& poses) {
  double length = 0.0;
  for (size_t i = 1; i < poses.size(); ++i) {
    length += (poses[i].translation() - poses[i - 1].translation()).norm();
  }
  return length;
}

}  // namespace

Sim3 AlignPoseSequence(const std::vector<SE3>& source, const std::vector<SE3>& target) {
  if (source.size() != target.size() || source.size() < 2) {
    throw InputError("pose alignment needs the same >= 2 cameras in both sequences");
  }
  const double source_length = PathLength(source);
  const double target_length = PathLength(target);
  if (!(source_length > 1e-12) || !(target_length > 1e-12) || !std::isfinite(source_length) ||
      !std::isfinite(target_length)) {
    throw InputError("pose alignment: the shared cameras do not move (no parallax to carry the scale)");
  }
  return AnchorAt(source[0], target[0], target_length / source_length);
}

Sim3 AnchorAt(const SE3& source, const SE3& target, double scale) {
  Sim3 similarity;
  similarity.scale = scale;
  similarity.rotation = target.rotation() * source.rotation().transpose();
  similarity.translation = target.translation() - scale * (similarity.rotation * source.translation());
  return similarity;
}

std::string ProblemWithEstimate(const EstimatorResult& result, double max_step_ratio) {
  for (const SE3& pose : result.T_world_cam) {
    if (!pose.translation().allFinite() || !pose.rotation().allFinite()) return "a pose is not finite";
  }
  for (const cv::Mat& latent : result.latent) {
    if (!cv::checkRange(latent, true, nullptr, -1e30, 1e30)) return "a restored image is not finite";
  }
  std::vector<double> steps;
  for (size_t i = 1; i < result.T_world_cam.size(); ++i) {
    steps.push_back((result.T_world_cam[i].translation() - result.T_world_cam[i - 1].translation()).norm());
  }
  if (steps.empty()) return "";
  std::vector<double> sorted = steps;
  std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
  const double median = sorted[sorted.size() / 2];
  const double largest = *std::max_element(steps.begin(), steps.end());
  if (largest > max_step_ratio * median || (median == 0.0 && largest > 0.0)) {
    return "pose jump: a camera step of " + std::to_string(largest) + " against a median step of " +
           std::to_string(median);
  }
  return "";
}

EstimatorOptions StreamDefaultEstimatorOptions() {
  EstimatorOptions options;
  options.depth_sweep.on_output = true;
  options.depth_consistency.radius = 2;
  return options;
}

// ------------------------------------------------------------ StreamEstimator

namespace {

// The stream's estimator options: the solver's depth is not re-swept inside
// the iterations (EstimatorOptions::depth_sweep.before_last_structure_updates:
// not over held leading latents). The output's refinements run as the
// caller asks; the next window starts from the solver's own depth
// (EstimatorResult::solver_depth).
EstimatorOptions WithoutSweepInIterations(EstimatorOptions options) {
  options.depth_sweep.before_last_structure_updates = 0;
  return options;
}

}  // namespace

StreamEstimator::StreamEstimator(const EstimatorOptions& options)
    : estimator_(WithoutSweepInIterations(options)),
      prior_history_(options.initializer.pose_prior) {}

void StreamEstimator::SetOptions(const EstimatorOptions& options) {
  estimator_ = Estimator(WithoutSweepInIterations(options));
  estimator_.SetCancelFlag(cancel_);
  last_operators_.clear();
}

void StreamEstimator::SetWindowOverlap(int frames) {
  if (frames < 0) throw InputError("stream: the window overlap must be >= 0, got " + std::to_string(frames));
  window_overlap_ = frames;
}

void StreamEstimator::SetCancelFlag(const std::atomic<bool>* flag) {
  cancel_ = flag;
  estimator_.SetCancelFlag(flag);
}

void StreamEstimator::Reset() {
  last_poses_.clear();
  last_depths_.clear();
  last_latents_.clear();
  last_operators_.clear();
  prior_history_.Reset();
  reference_median_depth_ = 0.0;
  last_rotation_only_ = false;
  has_returned_ = false;
}

namespace {

// The estimator's input for `window`; fills the ids and stamps of `estimate`.
EstimatorInput WindowInput(const StreamWindow& window, const PinholeCamera& camera_lr,
                           WindowEstimate* estimate) {
  EstimatorInput input;
  input.camera = camera_lr;
  for (size_t i = 0; i < window.size(); ++i) {
    const StreamFrame& frame = window[i];
    if (i > 0 && frame.id <= window[i - 1].id) throw InputError("stream: frame ids must increase");
    input.images.push_back(frame.image);
    input.frames.push_back(FrameRecord{static_cast<int>(i), frame.stamp_close, frame.exposure});
    estimate->ids.push_back(frame.id);
    estimate->stamps_ns.push_back(frame.stamp_ns);
  }
  if (!window.empty()) input.readout_time = window.back().readout_time;
  const bool any_prior = std::any_of(window.begin(), window.end(),
                                     [](const StreamFrame& frame) { return frame.T_prior_cam.has_value(); });
  if (any_prior) {
    for (const StreamFrame& frame : window) input.T_prior_cam.push_back(frame.T_prior_cam);
  }
  return input;
}

}  // namespace

WindowEstimate StreamEstimator::Process(const StreamWindow& window, const PinholeCamera& camera_lr,
                                        const ProgressCallback& progress) {
  if (window.size() < 2) throw InputError("stream: a window needs at least 2 frames");
  WindowEstimate estimate;
  EstimatorInput input = WindowInput(window, camera_lr, &estimate);
  const SharedFrames shared = SharedWithPrevious(window);
  if (!shared.poses.empty() && !input.T_prior_cam.empty()) {
    const PriorAlignment stream_alignment = prior_history_.Fit();
    if (stream_alignment.valid) input.world_to_prior = stream_alignment.estimate_to_prior;
  }
  if (!ContinueTrajectory(input, shared, progress, &estimate)) {
    input.world_to_prior.reset();
    StartSegment(input, progress, &estimate);
  }
  Remember(window, &estimate);
  return estimate;
}

StreamEstimator::SharedFrames StreamEstimator::SharedWithPrevious(const StreamWindow& window) const {
  SharedFrames shared;
  for (const StreamFrame& frame : window) {
    const auto found = last_poses_.find(frame.id);
    if (found == last_poses_.end()) break;
    shared.poses.push_back(found->second);
    const auto depth = last_depths_.find(frame.id);
    shared.depths.push_back(depth == last_depths_.end() ? cv::Mat() : depth->second);
    const auto latent = last_latents_.find(frame.id);
    shared.latents.push_back(latent == last_latents_.end() ? cv::Mat() : latent->second);
  }
  shared.from_rotation_only = last_rotation_only_;
  return shared;
}

namespace {

// Median over the shared frames' pixels of previous depth / initial depth:
// the scale of the initial structure in the stream's units (0 when no pixel
// has both).
double DepthRatio(const std::vector<cv::Mat>& previous_hr, const std::vector<cv::Mat>& initial_lr) {
  std::vector<float> ratios;
  for (size_t i = 0; i < previous_hr.size() && i < initial_lr.size(); ++i) {
    if (previous_hr[i].empty()) continue;
    cv::Mat previous;
    cv::resize(previous_hr[i], previous, initial_lr[i].size(), 0, 0, cv::INTER_NEAREST);
    for (int y = 0; y < previous.rows; ++y) {
      const float* p = previous.ptr<float>(y);
      const float* q = initial_lr[i].ptr<float>(y);
      for (int x = 0; x < previous.cols; ++x) {
        if (p[x] > 0.0f && q[x] > 0.0f && std::isfinite(p[x]) && std::isfinite(q[x])) {
          ratios.push_back(p[x] / q[x]);
        }
      }
    }
  }
  if (ratios.empty()) return 0.0;
  const auto middle = ratios.begin() + ratios.size() / 2;
  std::nth_element(ratios.begin(), middle, ratios.end());
  return *middle;
}

// Levenberg-Marquardt damping of the pose update (relative to its diagonal)
// in a continued window. A sideways camera can trade translation for
// rotation (the image motion differs only through the scene's depth
// variation): that direction of the pose system is nearly singular. With the
// shared poses held, the previous window's poses and depths and this
// window's initialisation disagree slightly, and the pose update's
// Gauss-Newton steps at the default damping (1e-4) slid the new frames far
// along it: the first new frame moved a third of a frame step towards the
// last held one with a 0.35 degree rotation, each window, and the stream's
// scale drifted by 10 % in two windows (Dolls, windows of 4 sharing 2).
// 0.01 keeps every step within 3 %. A window that starts a trajectory keeps
// the default: in single 8-frame windows 0.01 cost hand-held poses 14-29 % in
// ATE (image and depth unchanged).
constexpr double kContinuedPoseDamping = 0.01;

// What the window's note says of the shared frames' held latent images.
std::string WarmStartNote(int held_frames) {
  if (held_frames == 0) return "";
  return "; " + std::to_string(held_frames) + " shared frames kept the previous window's restored images";
}

// True when every map is present and of `size` with `channels` channels
// (an option change, e.g. of the scale, leaves maps of another size).
bool AllOfSize(const std::vector<cv::Mat>& maps, const cv::Size& size, int channels) {
  for (const cv::Mat& map : maps) {
    if (map.empty() || map.size() != size || map.channels() != channels) return false;
  }
  return true;
}

// A continued window's own budget (EstimatorOptions::continued_*), where set.
void ApplyContinuedBudget(EstimatorOptions* options) {
  if (options->continued_joint_irls_iterations > 0) {
    options->structure.joint_irls_iterations = options->continued_joint_irls_iterations;
  }
  if (options->continued_joint_cg_iterations > 0) {
    options->structure.joint_cg_iterations = options->continued_joint_cg_iterations;
  }
  if (options->continued_pose_iterations > 0) options->structure.pose_iterations = options->continued_pose_iterations;
  if (options->continued_max_iterations >= 0) options->max_iterations = options->continued_max_iterations;
  if (options->continued_recentred_depth_passes > 0) {
    options->recentred_depth_passes = options->continued_recentred_depth_passes;
  }
}

}  // namespace

StreamEstimator::StreamTie StreamEstimator::TieToStream(const InitialStructure& initial,
                                                        const SharedFrames& shared,
                                                        const PinholeCamera& camera_lr) const {
  const std::vector<SE3>& shared_previous = shared.poses;
  const int num_shared = static_cast<int>(shared_previous.size());
  const std::vector<SE3> shared_initial(initial.T_world_cam.begin(),
                                        initial.T_world_cam.begin() + num_shared);
  const double previous_path = PathLength(shared_previous);
  // Parallax (LR px at the median depth) of the shared cameras' motion: from
  // kMinSharedParallaxPx on, their path carries the scale.
  const double shared_parallax_px = reference_median_depth_ > 0.0
                                        ? camera_lr.fx * previous_path / reference_median_depth_
                                        : std::numeric_limits<double>::infinity();
  StreamTie tie;
  // The shared frames' depth maps, dense, fix the scale best: the path of
  // two shared cameras is one baseline of the initialiser's poses, whose
  // error put each new window's scale 2-5 % off in the stream tests.
  const double depth_scale = DepthRatio(shared.depths, initial.depth_lr);
  if (depth_scale > 0.0) {
    tie.initial_to_stream = AnchorAt(shared_initial.back(), shared_previous.back(), depth_scale);
    tie.how = "through the last shared frame, scale from the shared frames' depth";
  } else if (!shared.from_rotation_only && num_shared >= 2 && previous_path > 1e-12 &&
             PathLength(shared_initial) > 1e-12 && shared_parallax_px >= kMinSharedParallaxPx) {
    tie.initial_to_stream = AlignPoseSequence(shared_initial, shared_previous);
    tie.how = "through " + std::to_string(num_shared) + " shared frames (no shared depth)";
  } else {
    // The new cameras follow the last shared one.
    const double median = MedianDepth(initial.depth_lr);
    const double scale =
        median > 0.0 ? (reference_median_depth_ > 0.0 ? reference_median_depth_ : 1.0) / median : 1.0;
    tie.initial_to_stream = AnchorAt(shared_initial.back(), shared_previous.back(), scale);
    tie.how = "through the last shared frame, scale from the median depth of the last window with depth";
  }
  return tie;
}

bool StreamEstimator::ContinueTrajectory(const EstimatorInput& input, const SharedFrames& shared,
                                         const ProgressCallback& progress, WindowEstimate* estimate) const {
  const std::vector<SE3>& shared_previous = shared.poses;
  const int num_shared = static_cast<int>(shared_previous.size());
  if (num_shared < 1) return false;
  const EstimatorOptions& options = estimator_.options();
  const double start = NowMs();
  InitializerOptions init_options = options.initializer;
  init_options.num_threads = options.num_threads;
  InitialStructure initial;
  try {
    initial = InitializeStructure(input.images, input.camera, input.frames, init_options, input.readout_time,
                                  input.T_prior_cam);
  } catch (const NoParallaxError& no_parallax) {
    ContinueRotationOnly(input, shared, no_parallax.what(), progress, estimate);
    return true;
  }
  // Initial structure of this window in the stream's world and scale; the
  // held cameras start exactly where the previous window left them.
  const StreamTie tie = TieToStream(initial, shared, input.camera);
  std::vector<SE3> poses;
  for (size_t i = 0; i < input.images.size(); ++i) {
    poses.push_back(static_cast<int>(i) < num_shared
                        ? shared_previous[i]
                        : TransformPose(tie.initial_to_stream, initial.T_world_cam[i]));
  }
  std::vector<cv::Mat> depth_lr;
  for (const cv::Mat& depth : initial.depth_lr) depth_lr.push_back(depth * tie.initial_to_stream.scale);
  std::vector<cv::Mat> depth_hr = UpsampleInitialDepth(depth_lr, options.scale);
  // The held cameras stay where the previous window put them; the result
  // stays in the stream's world and scale.
  EstimatorOptions held = options;
  held.fixed_leading_poses = num_shared;
  held.keep_input_gauge = true;
  held.structure.pose_damping = std::max(held.structure.pose_damping, kContinuedPoseDamping);
  ApplyContinuedBudget(&held);
  // Operators of the previous window whose structure did not change are
  // used as they are; this window's are handed to the next.
  held.carried_frames = window_overlap_;
  // Warm start: the shared frames keep the previous window's latent images
  // (held) and start from its depth maps (already in the stream's world and
  // scale, as their poses).
  EstimatorInput warm_input = input;
  warm_input.carried_operators = last_operators_;
  // No feature tracks (EstimatorOptions::track_pose_weight): the gate opened
  // where the dense poses were the better ones (29 clips: ATE +2 to +5 %).
  // The prior's terms through the window's own Sim(3), not the stream's fit:
  // that fit failed on a clip whose window was taken for rotation-only and
  // misses issue 11's criterion on the node's test (BENCHMARKS.md "Tracks in
  // continued windows, measured again", "The stream's prior fit in continued
  // windows"). A stream's first window has its tracks.
  warm_input.tracks.clear();
  warm_input.world_to_prior.reset();
  const cv::Size hr_size(input.camera.width * options.scale, input.camera.height * options.scale);
  if (AllOfSize(shared.latents, hr_size, input.images[0].channels())) {
    warm_input.initial_latents = shared.latents;
    held.held_leading_latents = num_shared;
  }
  if (AllOfSize(shared.depths, hr_size, 1)) {
    for (int i = 0; i < num_shared; ++i) depth_hr[i] = shared.depths[i];
  }
  const double init_seconds = (NowMs() - start) / 1000.0;
  Estimator estimator(held);
  estimator.SetCancelFlag(cancel_);
  EstimatorResult& result = estimate->result;
  result = estimator.RunFromStructure(warm_input, depth_hr, poses, progress);
  result.timings.insert(result.timings.begin(), StageTiming{"initialization", init_seconds});
  result.initializer_summary = initial.summary;
  estimate->continued = true;
  estimate->warm_started = held.held_leading_latents;
  estimate->note = "continued from the previous window " + tie.how + " (scale factor " +
                   std::to_string(tie.initial_to_stream.scale) + ")" +
                   WarmStartNote(held.held_leading_latents);
  return true;
}

void StreamEstimator::ContinueRotationOnly(const EstimatorInput& input, const SharedFrames& shared,
                                           const std::string& why, const ProgressCallback& progress,
                                           WindowEstimate* estimate) const {
  const std::vector<SE3>& shared_previous = shared.poses;
  const double start = NowMs();
  InitializerOptions init_options = estimator_.options().initializer;
  init_options.num_threads = estimator_.options().num_threads;
  const RotationOnlyMotion motion =
      EstimateRotationOnlyMotion(input.images, input.camera, input.frames, init_options);
  // Orientations anchored at the first shared camera; every camera keeps
  // the last shared camera's translation.
  const Eigen::Matrix3d R_stream_motion = shared_previous[0].rotation() * motion.R_world_cam[0].transpose();
  std::vector<SE3> poses;
  for (const Eigen::Matrix3d& R_world_cam : motion.R_world_cam) {
    poses.emplace_back(R_stream_motion * R_world_cam, shared_previous.back().translation());
  }
  const double init_seconds = (NowMs() - start) / 1000.0;
  // The shared frames' latent images stay as the previous window left them.
  EstimatorOptions options = estimator_.options();
  EstimatorInput warm_input = input;
  const cv::Size hr_size(input.camera.width * options.scale, input.camera.height * options.scale);
  if (AllOfSize(shared.latents, hr_size, input.images[0].channels())) {
    warm_input.initial_latents = shared.latents;
    options.held_leading_latents = static_cast<int>(shared.latents.size());
  }
  EstimatorResult& result = estimate->result;
  Estimator estimator(options);
  estimator.SetCancelFlag(cancel_);
  result = estimator.RunRotationOnly(warm_input, poses, progress);
  result.timings.insert(result.timings.begin(), StageTiming{"initialization", init_seconds});
  result.initializer_summary = why + "\n" + motion.summary;
  estimate->continued = true;
  estimate->warm_started = options.held_leading_latents;
  estimate->note = "rotation-only window, continued from the previous window's cameras" +
                   WarmStartNote(options.held_leading_latents);
  if (PlaceOnPrior(input, shared_previous, &result.T_world_cam)) {
    estimate->note += "; camera positions from the pose prior";
  }
}

bool StreamEstimator::PlaceOnPrior(const EstimatorInput& input, const std::vector<SE3>& shared_previous,
                                   std::vector<SE3>* T_world_cam) {
  if (!input.world_to_prior || input.T_prior_cam.size() != T_world_cam->size()) return false;
  for (size_t i = shared_previous.size(); i < T_world_cam->size(); ++i) {
    if (!input.T_prior_cam[i]) return false;
  }
  const Sim3& world_to_prior = *input.world_to_prior;
  for (size_t i = 0; i < T_world_cam->size(); ++i) {
    const Eigen::Vector3d centre =
        i < shared_previous.size()
            ? shared_previous[i].translation()
            : InverseTransformPoint(world_to_prior, input.T_prior_cam[i]->translation());
    (*T_world_cam)[i] = SE3((*T_world_cam)[i].rotation(), centre);
  }
  return true;
}

void StreamEstimator::StartSegment(const EstimatorInput& input, const ProgressCallback& progress,
                                   WindowEstimate* estimate) {
  estimate->result = estimator_.Run(input, progress);
  estimate->continued = false;
  const std::string gauge = estimate->result.depth_observable
                                ? "world = first camera, median scene depth 1 unit"
                                : "world = first camera (rotation only: depth not observable)";
  estimate->note = last_poses_.empty() ? "new trajectory: " + gauge
                                       : "new trajectory segment (no usable overlap with the previous "
                                         "window): " +
                                             gauge;
}

void StreamEstimator::Remember(const StreamWindow& window, WindowEstimate* estimate) {
  estimate->first_new = 0;
  if (has_returned_) {
    while (estimate->first_new < static_cast<int>(window.size()) &&
           window[estimate->first_new].id <= last_returned_id_) {
      ++estimate->first_new;
    }
  }
  last_poses_.clear();
  last_depths_.clear();
  last_latents_.clear();
  // The solver's depth (the published one may be refined): the next window
  // starts from it, and the operators handed on were built with it.
  const EstimatorResult& result = estimate->result;
  const std::vector<cv::Mat>& solver_depth =
      result.solver_depth.size() == result.depth.size() ? result.solver_depth : result.depth;
  last_operators_ = std::move(estimate->result.carried_operators);
  estimate->result.carried_operators.clear();
  if (!estimate->continued) prior_history_.Reset();  // a new world
  for (size_t i = 0; i < window.size(); ++i) {
    last_poses_[window[i].id] = estimate->result.T_world_cam[i];
    last_latents_[window[i].id] = estimate->result.latent[i];
    if (estimate->result.depth_observable) last_depths_[window[i].id] = solver_depth[i];
    if (window[i].T_prior_cam) {
      prior_history_.Add(window[i].id, estimate->result.T_world_cam[i], *window[i].T_prior_cam);
    }
  }
  if (estimate->result.depth_observable) {
    const double median = MedianDepth(solver_depth);
    if (median > 0.0) reference_median_depth_ = median;
  }
  last_rotation_only_ = !estimate->result.depth_observable;
  last_returned_id_ = std::max(has_returned_ ? last_returned_id_ : 0, window.back().id);
  has_returned_ = true;
}

}  // namespace deblur_sr_mvs
