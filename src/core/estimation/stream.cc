#include "deblur_sr_mvs/core/estimation/stream.h"

#include <algorithm>
#include <cmath>
#include <utility>

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
  Sim3 similarity;
  similarity.scale = target_length / source_length;
  similarity.rotation = target[0].rotation() * source[0].rotation().transpose();
  similarity.translation =
      target[0].translation() - similarity.scale * similarity.rotation * source[0].translation();
  return similarity;
}

SE3 TransformPose(const Sim3& similarity, const SE3& T_world_cam) {
  return SE3(similarity.rotation * T_world_cam.rotation(),
             similarity.scale * (similarity.rotation * T_world_cam.translation()) + similarity.translation);
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

// ------------------------------------------------------------ StreamEstimator

StreamEstimator::StreamEstimator(const EstimatorOptions& options) : estimator_(options) {}

void StreamEstimator::SetOptions(const EstimatorOptions& options) {
  estimator_ = Estimator(options);
  estimator_.SetCancelFlag(cancel_);
}

void StreamEstimator::SetCancelFlag(const std::atomic<bool>* flag) {
  cancel_ = flag;
  estimator_.SetCancelFlag(flag);
}

void StreamEstimator::Reset() {
  last_poses_.clear();
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
  return input;
}

}  // namespace

WindowEstimate StreamEstimator::Process(const StreamWindow& window, const PinholeCamera& camera_lr,
                                        const ProgressCallback& progress) {
  if (window.size() < 2) throw InputError("stream: a window needs at least 2 frames");
  WindowEstimate estimate;
  const EstimatorInput input = WindowInput(window, camera_lr, &estimate);
  if (!ContinueTrajectory(input, SharedPreviousPoses(window), progress, &estimate)) {
    StartSegment(input, progress, &estimate);
  }
  Remember(window, &estimate);
  return estimate;
}

std::vector<SE3> StreamEstimator::SharedPreviousPoses(const StreamWindow& window) const {
  std::vector<SE3> shared_previous;
  for (const StreamFrame& frame : window) {
    const auto found = last_poses_.find(frame.id);
    if (found == last_poses_.end()) break;
    shared_previous.push_back(found->second);
  }
  return shared_previous;
}

bool StreamEstimator::ContinueTrajectory(const EstimatorInput& input, const std::vector<SE3>& shared_previous,
                                         const ProgressCallback& progress, WindowEstimate* estimate) const {
  const int num_shared = static_cast<int>(shared_previous.size());
  if (!(num_shared >= 2 && PathLength(shared_previous) > 1e-12)) return false;
  const EstimatorOptions& options = estimator_.options();
  const double start = NowMs();
  InitializerOptions init_options = options.initializer;
  init_options.num_threads = options.num_threads;
  InitialStructure initial = InitializeStructure(input.images, input.camera, input.frames, init_options);
  std::vector<SE3> shared_initial(initial.T_world_cam.begin(), initial.T_world_cam.begin() + num_shared);
  if (!(PathLength(shared_initial) > 1e-12)) return false;
  // Initial structure of this window in the stream's world and scale; the
  // shared cameras start exactly where the previous window left them.
  const Sim3 to_stream = AlignPoseSequence(shared_initial, shared_previous);
  std::vector<SE3> poses;
  for (size_t i = 0; i < input.images.size(); ++i) {
    poses.push_back(static_cast<int>(i) < num_shared ? shared_previous[i]
                                                     : TransformPose(to_stream, initial.T_world_cam[i]));
  }
  std::vector<cv::Mat> depth_lr;
  for (const cv::Mat& depth : initial.depth_lr) depth_lr.push_back(depth * to_stream.scale);
  const std::vector<cv::Mat> depth_hr = UpsampleInitialDepth(depth_lr, options.scale);
  const double init_seconds = (NowMs() - start) / 1000.0;
  // The shared cameras stay where the previous window put them.
  EstimatorOptions held = options;
  held.fixed_leading_poses = num_shared;
  Estimator estimator(held);
  estimator.SetCancelFlag(cancel_);
  EstimatorResult& result = estimate->result;
  result = estimator.RunFromStructure(input, depth_hr, poses, progress);
  result.timings.insert(result.timings.begin(), StageTiming{"initialization", init_seconds});
  result.initializer_summary = initial.summary;
  // The estimator returns its own gauge (first camera, unit baseline):
  // carry the result back onto the previous window's shared cameras
  // (exact, since they were held).
  std::vector<SE3> shared_result(result.T_world_cam.begin(), result.T_world_cam.begin() + num_shared);
  const Sim3 back = AlignPoseSequence(shared_result, shared_previous);
  for (SE3& pose : result.T_world_cam) pose = TransformPose(back, pose);
  for (cv::Mat& depth : result.depth) depth *= back.scale;
  estimate->continued = true;
  estimate->note = "continued from the previous window through " + std::to_string(num_shared) +
                   " shared frames (scale factor " + std::to_string(back.scale) + ")";
  return true;
}

void StreamEstimator::StartSegment(const EstimatorInput& input, const ProgressCallback& progress,
                                   WindowEstimate* estimate) {
  estimate->result = estimator_.Run(input, progress);
  estimate->continued = false;
  estimate->note = last_poses_.empty()
                       ? "new trajectory: world = first camera, first two cameras 1 unit apart"
                       : "new trajectory segment (no usable overlap with the previous window): "
                         "world = this window's first camera, first two cameras 1 unit apart";
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
  for (size_t i = 0; i < window.size(); ++i) last_poses_[window[i].id] = estimate->result.T_world_cam[i];
  last_returned_id_ = std::max(has_returned_ ? last_returned_id_ : 0, window.back().id);
  has_returned_ = true;
}

}  // namespace deblur_sr_mvs
