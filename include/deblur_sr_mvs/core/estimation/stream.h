// Streaming joint estimation (docs/ros_interface.md), ROS-free so that it is unit
// tested without a master: frames arrive one at a time, are cut into windows
// of `window_size` frames that overlap by `window_overlap`, and each window is
// estimated (Algorithm 1) starting from the previous window's poses, so that
// the trajectory and its monocular scale are continuous across windows.
#pragma once

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <map>
#include <mutex>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <opencv2/core.hpp>

#include "deblur_sr_mvs/core/estimation/estimator.h"
#include "deblur_sr_mvs/core/geometry/camera.h"
#include "deblur_sr_mvs/core/geometry/pose_prior.h"
#include "deblur_sr_mvs/core/geometry/se3.h"
#include "deblur_sr_mvs/core/geometry/sim3.h"

namespace deblur_sr_mvs {

struct StreamOptions {
  int window_size = 6;  // frames per window (>= 3)
  // Frames shared by consecutive windows (>= 2: two shared cameras fix the
  // relative scale of the next window; < window_size so that windows advance).
  int window_overlap = 2;
  int max_pending_windows = 2;  // windows waiting for the worker; the oldest is dropped beyond
  void Check() const;           // throws InputError naming the bad value
};

// One incoming frame.
struct StreamFrame {
  uint64_t id = 0;         // arrival number, strictly increasing
  int64_t stamp_ns = 0;    // the caller's stamp (e.g. the message header), returned untouched
  double stamp_close = 0;  // shutter close time t_c (s), as FrameRecord::stamp
  double exposure = 0;     // t_c - t_o (s)
  double readout_time =
      0;          // rolling shutter (EstimatorInput::readout_time), s; the window takes its last frame's
  cv::Mat image;  // float in [0, 1], 1 or 3 channels (BGR)
  // Its pose in a pose prior's frame at stamp_close, when there is one
  // (EstimatorInput::T_prior_cam; the node: tf pose_prior_frame).
  std::optional<SE3> T_prior_cam;
};
using StreamWindow = std::vector<StreamFrame>;

// Cuts the frame stream into overlapping windows. Not thread-safe.
class FrameWindower {
 public:
  explicit FrameWindower(const StreamOptions& options);
  // Adds a frame; returns the windows it completes (none or one, more only
  // right after SetOptions shrank the window).
  std::vector<StreamWindow> Add(StreamFrame frame);
  // New window size / overlap, from the next window on (frames kept).
  void SetOptions(const StreamOptions& options);
  void Reset();  // forget buffered frames
  size_t buffered() const { return buffer_.size(); }

 private:
  StreamOptions options_;
  std::deque<StreamFrame> buffer_;
};

// Thread-safe bounded FIFO (the pending windows): Push drops the oldest
// entries beyond the capacity and counts them; Pop blocks until an entry
// arrives or Stop() is called.
template <typename T>
class DropOldestQueue {
 public:
  explicit DropOldestQueue(int capacity) : capacity_(capacity < 1 ? 1 : capacity) {}
  // Returns how many entries this push dropped (ignored after Stop()).
  int Push(T value) {
    int dropped = 0;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (stopped_) return 0;
      queue_.push_back(std::move(value));
      while (queue_.size() > static_cast<size_t>(capacity_)) {
        queue_.pop_front();
        ++dropped;
      }
      dropped_ += dropped;
    }
    ready_.notify_one();
    return dropped;
  }
  // False once stopped (then *value is untouched).
  bool Pop(T* value) {
    std::unique_lock<std::mutex> lock(mutex_);
    ready_.wait(lock, [this] { return stopped_ || !queue_.empty(); });
    if (stopped_) return false;
    *value = std::move(queue_.front());
    queue_.pop_front();
    return true;
  }
  void Stop() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      stopped_ = true;
      queue_.clear();
    }
    ready_.notify_all();
  }
  void SetCapacity(int capacity) {  // applies from the next push
    std::lock_guard<std::mutex> lock(mutex_);
    capacity_ = capacity < 1 ? 1 : capacity;
  }
  size_t size() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return queue_.size();
  }
  uint64_t dropped() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return dropped_;
  }

 private:
  mutable std::mutex mutex_;
  std::condition_variable ready_;
  std::deque<T> queue_;
  int capacity_;
  uint64_t dropped_ = 0;
  bool stopped_ = false;
};
using PendingWindowQueue = DropOldestQueue<StreamWindow>;

// target ~= similarity applied to source: the transform that maps the
// `source` camera poses onto `target` (same frames, >= 2 of them). Rotation
// and translation come from the first pair; the scale is the ratio of the
// path lengths, which must be > 0 in both (else InputError: no parallax).
Sim3 AlignPoseSequence(const std::vector<SE3>& source, const std::vector<SE3>& target);
// The similarity with the given scale that puts camera `source` on `target`.
Sim3 AnchorAt(const SE3& source, const SE3& target, double scale);

// The estimate of one window, in the stream's world frame.
struct WindowEstimate {
  std::vector<uint64_t> ids;       // frame ids, window order
  std::vector<int64_t> stamps_ns;  // their caller stamps
  EstimatorResult result;          // poses/depths in the stream's world and scale
  // Index of the first frame not returned by an earlier window (the frames
  // before it were estimated, and given out, with the previous window).
  int first_new = 0;
  // False when this window starts a new trajectory segment (the first
  // window, after Reset(), or when the overlap could not be used): its first
  // camera is then the world origin and its median scene depth 1 unit
  // (docs/file_formats.md#monocular-scale).
  bool continued = false;
  // Leading frames (shared with the previous window) whose latent images
  // were taken from the previous window and held, not restored again
  // (EstimatorOptions::held_leading_latents); their depth maps started from
  // the previous window's.
  int warm_started = 0;
  std::string note;  // how the window was tied to the previous one
};

// The estimator options of the node's windows (the ROS glue adds its time
// cap): the library's defaults, with the published depth re-swept and made
// consistent across neighbouring frames as estimate_sequence refines its
// output (the library leaves both off: DepthSweepOptions::on_output and
// DepthConsistencyOptions::radius say why). StreamEstimator refines only the
// copies it publishes; the next window starts from the solver's depth.
EstimatorOptions StreamDefaultEstimatorOptions();

// Why an estimate must not be published, or "" when it may: a pose or a
// latent pixel that is not finite, or a pose jump (a camera step larger than
// max_step_ratio times the window's median step, or any step while the
// median is zero).
std::string ProblemWithEstimate(const EstimatorResult& result, double max_step_ratio);

// Runs the estimator window after window and ties the windows together.
// Not thread-safe (one worker thread owns it).
class StreamEstimator {
 public:
  explicit StreamEstimator(const EstimatorOptions& options);
  // New estimator options from the next window on.
  void SetOptions(const EstimatorOptions& options);
  // The window estimator's options: the caller's, except that the solver's
  // depth is not re-swept inside the iterations
  // (depth_sweep.before_last_structure_updates 0).
  const EstimatorOptions& options() const { return estimator_.options(); }
  void SetCancelFlag(const std::atomic<bool>* flag);
  // Frames the next window shares with this one (StreamOptions::
  // window_overlap): a continued window hands the capture operators among
  // them to the next one, which uses those whose structure did not change
  // instead of building them (EstimatorOptions::carried_frames). 0: none.
  // Default: StreamOptions' default (2), the least overlap a stream has, so
  // those frames are shared whatever the overlap. A frame's blur path runs
  // through its neighbours on both sides, so an overlap of 2 shares no
  // operator (the next window's first frame, and this window's last, change
  // their paths); 3 or more share those of the shared frames inside both.
  void SetWindowOverlap(int frames);

  // Estimates `window` (frames of `camera_lr`'s size, increasing stamps).
  // Throws InputError / InitializationError / EstimationCancelled as the
  // Estimator does; the stream state is then unchanged.
  WindowEstimate Process(const StreamWindow& window, const PinholeCamera& camera_lr,
                         const ProgressCallback& progress = nullptr);
  // The next window starts a new trajectory segment (e.g. the clock jumped back).
  void Reset();

 private:
  // What the previous window gave the leading frames of `window`, as many as
  // the two windows share: poses, depths (empty where not observable) and
  // latent images.
  struct SharedFrames {
    std::vector<SE3> poses;
    std::vector<cv::Mat> depths;
    std::vector<cv::Mat> latents;
    // The previous window had no parallax: its orientations are a
    // rotation-only fit and its centres held or a prior's (PlaceOnPrior),
    // so their path does not carry the scale.
    bool from_rotation_only = false;
  };
  SharedFrames SharedWithPrevious(const StreamWindow& window) const;
  // How this window's initial structure is carried into the stream's world
  // and scale; the estimator holds every shared camera where the previous
  // window put it. Where the shared frames have depth, the similarity that
  // puts the last shared camera on its previous pose, with the scale from
  // those depths against the initial ones (the median ratio over their
  // pixels). Else, when the shared cameras' path carries
  // kMinSharedParallaxPx of parallax (and does not come from a rotation-only
  // window: SharedFrames::from_rotation_only), the similarity of AlignPoseSequence
  // (scale from the path); else the last shared camera's similarity with the
  // scale from the last known median depth.
  struct StreamTie {
    Sim3 initial_to_stream;
    std::string how;  // for the window's note
  };
  static constexpr double kMinSharedParallaxPx = 1.0;
  StreamTie TieToStream(const InitialStructure& initial, const SharedFrames& shared,
                        const PinholeCamera& camera_lr) const;
  // Estimates the window from the previous one: its initial structure is
  // carried into the stream's world and scale (TieToStream). The shared
  // frames keep the previous window's latent images (held: each image is
  // restored once) and start from its depth maps, where those have this
  // window's HR size; only the new frames start from the initialisation. A
  // window without parallax goes to ContinueRotationOnly. False (estimate
  // untouched) when no frame is shared.
  bool ContinueTrajectory(const EstimatorInput& input, const SharedFrames& shared,
                          const ProgressCallback& progress, WindowEstimate* estimate) const;
  // A window without parallax after a previous one: orientations from the
  // rotation-only motion anchored at the first shared camera, the last
  // shared camera's translation held (or the pose prior's centres:
  // PlaceOnPrior), depth NaN (Estimator::RunRotationOnly);
  // the shared frames' latent images are held as the previous window left them.
  void ContinueRotationOnly(const EstimatorInput& input, const SharedFrames& shared, const std::string& why,
                            const ProgressCallback& progress, WindowEstimate* estimate) const;
  // A rotation-only window with a pose prior fitted to the stream
  // (EstimatorInput::world_to_prior) and a prior pose for each new frame:
  // the new cameras take their centres from the prior, carried into the
  // stream's world, the shared ones keep the previous window's, so that a
  // camera that barely translates over a window still follows the prior's
  // path (the restored images do not depend on the centres: depth at
  // infinity). False (poses untouched) otherwise: every camera keeps one
  // translation.
  static bool PlaceOnPrior(const EstimatorInput& input, const std::vector<SE3>& shared_previous,
                           std::vector<SE3>* T_world_cam);
  // Estimates the window on its own: a new trajectory segment.
  void StartSegment(const EstimatorInput& input, const ProgressCallback& progress, WindowEstimate* estimate);
  // Marks the frames already returned and keeps this window's poses.
  void Remember(const StreamWindow& window, WindowEstimate* estimate);

  Estimator estimator_;
  const std::atomic<bool>* cancel_ = nullptr;
  std::map<uint64_t, SE3> last_poses_;        // the previous window's poses, by frame id
  std::map<uint64_t, cv::Mat> last_depths_;   // its depths (HR), when observable
  std::map<uint64_t, cv::Mat> last_latents_;  // its latent images (HR)
  CarriedOperators last_operators_;           // its operators among the frames the next window shares
  // The frames of this trajectory segment with a pose prior, as estimated:
  // a rotation-only window places its new cameras on the prior by this fit
  // (EstimatorInput::world_to_prior, PlaceOnPrior); a continued window with
  // depth fits its own (ContinueTrajectory). Its options are those of the
  // constructor's initializer.pose_prior.
  PosePriorAligner prior_history_;
  int window_overlap_ = StreamOptions().window_overlap;
  // Median depth of the last window with observable depth (stream units; 0
  // before the first).
  double reference_median_depth_ = 0.0;
  bool last_rotation_only_ = false;  // the previous window had no parallax
  uint64_t last_returned_id_ = 0;
  bool has_returned_ = false;
};

}  // namespace deblur_sr_mvs
