#include "deblur_sr_mvs/core/estimation/estimator.h"

#include <omp.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstring>
#include <exception>
#include <limits>
#include <list>
#include <map>
#include <memory>
#include <mutex>

#include <opencv2/imgproc.hpp>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/common/options_check.h"
#include "deblur_sr_mvs/core/common/runtime.h"
#include "deblur_sr_mvs/core/estimation/frame_structure.h"
#include "deblur_sr_mvs/core/geometry/pose_prior.h"
#include "deblur_sr_mvs/core/imaging/image_ops.h"
#include "deblur_sr_mvs/core/imaging/noise_estimation.h"

namespace deblur_sr_mvs {

void AddStageSeconds(const std::string& stage, double seconds, std::vector<StageTiming>* timings) {
  for (StageTiming& timing : *timings) {
    if (timing.stage == stage) {
      timing.seconds += seconds;
      return;
    }
  }
  timings->push_back({stage, seconds});
}

namespace {

// Accumulates wall time per named stage, in first-seen order.
class Timer {
 public:
  void Add(const std::string& stage, double seconds) {
    std::lock_guard<std::mutex> lock(mutex_);
    AddStageSeconds(stage, seconds, &timings_);
  }
  // Adds the wall time since start_ms (a NowMs() value).
  void AddSince(const std::string& stage, double start_ms) { Add(stage, (NowMs() - start_ms) / 1000.0); }
  const std::vector<StageTiming>& timings() const { return timings_; }

 private:
  std::mutex mutex_;
  std::vector<StageTiming> timings_;
};

double SumAbsMasked(const cv::Mat& a, const cv::Mat& b, const cv::Mat& mask) {
  const int channels = a.channels();
  double sum = 0.0;
  for (int y = 0; y < a.rows; ++y) {
    const float* pa = a.ptr<float>(y);
    const float* pb = b.ptr<float>(y);
    const uchar* m = mask.empty() ? nullptr : mask.ptr<uchar>(y);
    for (int x = 0; x < a.cols; ++x) {
      if (m != nullptr && m[x] == 0) continue;
      for (int c = 0; c < channels; ++c) sum += std::abs(pa[x * channels + c] - pb[x * channels + c]);
    }
  }
  return sum;
}

// Edge-weighted isotropic TV of c * rho (eq:regularizingTerm, depth part).
double DepthTv(const cv::Mat& inverse_depth, const cv::Mat& edge_weight, double parallax_scale) {
  double sum = 0.0;
  const int w = inverse_depth.cols, h = inverse_depth.rows;
  for (int y = 0; y < h; ++y) {
    const float* row = inverse_depth.ptr<float>(y);
    const float* next = inverse_depth.ptr<float>(std::min(y + 1, h - 1));
    const float* g = edge_weight.ptr<float>(y);
    for (int x = 0; x < w; ++x) {
      const double gx = row[std::min(x + 1, w - 1)] - row[x];
      const double gy = next[x] - row[x];
      sum += g[x] * parallax_scale * std::sqrt(gx * gx + gy * gy);
    }
  }
  return sum;
}

// Fills NaN / non-positive depth by the nearest valid values (row then
// column sweeps) so every pixel has a usable inverse depth.
cv::Mat InverseDepthFromDepth(const cv::Mat& depth) {
  cv::Mat rho(depth.size(), CV_32FC1);
  cv::Mat invalid(depth.size(), CV_8UC1, cv::Scalar(0));
  std::vector<float> valid_values;
  for (int y = 0; y < depth.rows; ++y) {
    for (int x = 0; x < depth.cols; ++x) {
      const float d = depth.at<float>(y, x);
      if (d > 0.0f && std::isfinite(d)) {
        rho.at<float>(y, x) = 1.0f / d;
        valid_values.push_back(1.0f / d);
      } else {
        rho.at<float>(y, x) = 0.0f;
        invalid.at<uchar>(y, x) = 255;
      }
    }
  }
  if (valid_values.empty()) throw InputError("estimator: a depth map has no valid pixel");
  if (cv::countNonZero(invalid) > 0) {
    // Smallest inverse depth (background) nearby fills holes: occlusion holes
    // are background more often than foreground.
    cv::Mat filled = rho.clone();
    cv::Mat mask = invalid.clone();
    for (int pass = 0; pass < 64 && cv::countNonZero(mask) > 0; ++pass) {
      cv::Mat next_mask = mask.clone();
      for (int y = 0; y < rho.rows; ++y) {
        for (int x = 0; x < rho.cols; ++x) {
          if (!mask.at<uchar>(y, x)) continue;
          float best = 0.0f;
          const int dx[4] = {1, -1, 0, 0}, dy[4] = {0, 0, 1, -1};
          for (int k = 0; k < 4; ++k) {
            const int nx = x + dx[k], ny = y + dy[k];
            if (nx < 0 || ny < 0 || nx >= rho.cols || ny >= rho.rows || mask.at<uchar>(ny, nx)) continue;
            const float v = filled.at<float>(ny, nx);
            if (best == 0.0f || v < best) best = v;
          }
          if (best > 0.0f) {
            filled.at<float>(y, x) = best;
            next_mask.at<uchar>(y, x) = 0;
          }
        }
      }
      mask = next_mask;
    }
    std::nth_element(valid_values.begin(), valid_values.begin() + valid_values.size() / 2,
                     valid_values.end());
    filled.setTo(valid_values[valid_values.size() / 2], mask);
    rho = filled;
  }
  return rho;
}

std::vector<cv::Mat> CloneAll(const std::vector<cv::Mat>& images) {
  std::vector<cv::Mat> copies;
  copies.reserve(images.size());
  for (const cv::Mat& image : images) copies.push_back(image.clone());
  return copies;
}

// Same size, type and bytes (NaN payloads included).
bool SameBits(const cv::Mat& a, const cv::Mat& b) {
  if (a.size() != b.size() || a.type() != b.type() || !a.isContinuous() || !b.isContinuous()) return false;
  return std::memcmp(a.data, b.data, a.total() * a.elemSize()) == 0;
}

cv::Mat DepthFromInverse(const cv::Mat& rho) {
  cv::Mat depth(rho.size(), CV_32FC1);
  for (int y = 0; y < rho.rows; ++y) {
    for (int x = 0; x < rho.cols; ++x) {
      const float r = rho.at<float>(y, x);
      depth.at<float>(y, x) = r > 0.0f ? 1.0f / r : std::numeric_limits<float>::quiet_NaN();
    }
  }
  return depth;
}

// Pixels of frame t (HR CV_8UC1) that frame s sees: Omega_{t,s} of eq:occSet,
// with `source_depth` also the test against D_s
// (VisibilityOptions::source_depth_margin, when it is on).
cv::Mat VisibleFromSource(const PinholeCamera& camera_hr, const std::vector<FrameStructure>& frames, int t,
                          int s, const VisibilityOptions& options, bool source_depth = true) {
  const SE3 T_s_t = frames[s].T_world_cam.Inverse() * frames[t].T_world_cam;
  return ComputeVisibility(camera_hr, frames[t].depth_hr, T_s_t, options,
                           source_depth ? &frames[s].depth_hr : nullptr);
}

// Operators Psi_t[src] and their visibility masks, rebuilt only when the
// structure they depend on (D_t, P_t, the poses of t's blur path, P_src) changed, or
// taken from the previous window of a stream when they were built there from
// the same structure. The virtual depths D_tau of frame t depend on D_t, P_t
// and the poses of its blur path only: they are computed once per structure, shared by
// the operators of every source, and dropped once each source's operator at
// that structure is there. Memory is bounded: the least recently used
// operators go first.
class OperatorCache {
 public:
  using Entry = MaskedOperator;

  // One builder (scratch buffers) per thread: Get may be called from the
  // threads of a parallel loop over frames, each building its own operators.
  // sources_per_frame[t]: how many sources frame t's operators sample.
  OperatorCache(const CaptureOperatorOptions& options, int threads, const PinholeCamera& camera_hr,
                const VisibilityOptions& visibility, size_t max_bytes, size_t max_depth_bytes,
                const std::vector<int>& sources_per_frame, const CarriedOperators& carried)
      : options_(options),
        camera_hr_(camera_hr),
        visibility_(visibility),
        max_bytes_(max_bytes),
        max_depth_bytes_(max_depth_bytes),
        sources_per_frame_(sources_per_frame),
        frame_depths_(sources_per_frame.size()),
        carried_(carried) {
    for (int i = 0; i < threads; ++i) builders_.emplace_back(options);
  }

  // Callers hold the returned pointer while they use the operator: eviction
  // only drops the cache's reference.
  std::shared_ptr<const Entry> Get(const std::vector<FrameStructure>& frames,
                                   const std::vector<long>& depth_version,
                                   const std::vector<long>& pose_version, int t, int source, Timer* timer) {
    const std::vector<long> depth_versions = Versions(depth_version, pose_version, t, t);
    const std::vector<long> versions = Versions(depth_version, pose_version, t, source);
    const auto key = std::make_pair(t, source);
    {
      std::lock_guard<std::mutex> lock(mutex_);
      auto it = entries_.find(key);
      if (it != entries_.end() && it->second.versions == versions) {
        Touch(key);
        return it->second.entry;
      }
    }
    const double start = NowMs();
    const CaptureGeometry geometry = MakeCaptureGeometry(frames, camera_hr_, t, source);
    std::shared_ptr<const Entry> entry = TakeCarried(geometry);
    if (entry == nullptr) {
      entry = Build(frames, geometry, t, source, depth_versions);
      timer->AddSince("operator builds (thread seconds)", start);
    }
    CountSource(t, source, depth_versions);
    std::lock_guard<std::mutex> lock(mutex_);
    auto it = entries_.find(key);
    if (it != entries_.end()) {
      bytes_ -= Bytes(*it->second.entry);
      it->second = Slot{entry, versions};
    } else {
      entries_[key] = Slot{entry, versions};
    }
    bytes_ += Bytes(*entry);
    Touch(key);
    Evict(key);
    return entry;
  }

  // The operators at the current structure whose geometry the next window,
  // which starts at frame `first`, can share: all of CaptureGeometryFrames
  // among frames >= first, and not the last frame (its blur path gains the
  // frame after it there). The next window uses those it finds equal.
  CarriedOperators Carry(const std::vector<FrameStructure>& frames, const std::vector<long>& depth_version,
                         const std::vector<long>& pose_version, int first) {
    CarriedOperators carried;
    std::lock_guard<std::mutex> lock(mutex_);
    const int num_frames = static_cast<int>(frames.size());
    for (const auto& [key, slot] : entries_) {
      const auto [t, source] = key;
      const std::vector<int> fixing = CaptureGeometryFrames(t, source, num_frames);
      if (t == num_frames - 1 || *std::min_element(fixing.begin(), fixing.end()) < first) continue;
      if (slot.versions != Versions(depth_version, pose_version, t, source)) continue;
      carried.push_back(
          {MakeCaptureGeometry(frames, camera_hr_, t, source), options_, visibility_, slot.entry});
    }
    return carried;
  }

  // Drops the operators offered by the previous window that were not used
  // (once the window's first structure has all its operators).
  void ForgetCarried() {
    std::lock_guard<std::mutex> lock(mutex_);
    carried_.clear();
  }
  int reused() const { return reused_; }

 private:
  struct Slot {
    std::shared_ptr<const Entry> entry;
    std::vector<long> versions;
  };

  // The versions of what fixes Psi_t[source]: D_t and the poses of
  // CaptureGeometryFrames (P_t, t's blur path, P_source). Source t: those of
  // frame t's virtual depths.
  static std::vector<long> Versions(const std::vector<long>& depth_version, const std::vector<long>& pose_version,
                                    int t, int source) {
    std::vector<long> versions = {depth_version[t]};
    for (int frame : CaptureGeometryFrames(t, source, static_cast<int>(pose_version.size()))) {
      versions.push_back(pose_version[frame]);
    }
    return versions;
  }

  // Psi_t[source] and its mask, built on the calling thread.
  std::shared_ptr<const Entry> Build(const std::vector<FrameStructure>& frames,
                                     const CaptureGeometry& geometry, int t, int source,
                                     const std::vector<long>& depth_versions) {
    const std::shared_ptr<const VirtualDepths> depths = SharedDepths(frames, t, depth_versions);
    auto entry = std::make_shared<Entry>();
    const size_t thread = std::min<size_t>(omp_get_thread_num(), builders_.size() - 1);
    builders_[thread].Build(geometry, *depths, &entry->op);
    const cv::Size lr = entry->op.lr_size();
    entry->mask = cv::Mat(lr, CV_8UC1);
    const std::vector<float>& coverage = entry->op.coverage();
    for (int i = 0; i < lr.area(); ++i) entry->mask.ptr<uchar>()[i] = coverage[i] >= 1.0f ? 255 : 0;
    if (source != t) {
      // D_t's own occlusion test only: the cache's versions do not follow
      // D_source (VisibilityOptions::source_depth_margin is for the HR pairs).
      const cv::Mat visible = DownscaleMaskAll(
          VisibleFromSource(camera_hr_, frames, t, source, visibility_, /*source_depth=*/false),
          camera_hr_.width / lr.width);
      cv::bitwise_and(entry->mask, visible, entry->mask);
    }
    return entry;
  }

  // The previous window's operator built from `geometry` with these options,
  // if it handed one on (each is taken once: the cache keeps it then).
  std::shared_ptr<const Entry> TakeCarried(const CaptureGeometry& geometry) {
    std::lock_guard<std::mutex> lock(mutex_);
    for (auto it = carried_.begin(); it != carried_.end(); ++it) {
      if (SameOperatorModel(it->options, options_) &&
          it->visibility.depth_tolerance == visibility_.depth_tolerance &&
          SameCaptureGeometry(it->geometry, geometry)) {
        std::shared_ptr<const Entry> entry = it->entry;
        carried_.erase(it);
        ++reused_;
        return entry;
      }
    }
    return nullptr;
  }

  // The virtual depths of frame t at `versions` (Versions of source t).
  struct FrameDepths {
    std::mutex compute;  // one computation per frame at a time
    std::vector<long> versions;
    std::shared_ptr<const VirtualDepths> depths;
    std::vector<int> sources;  // whose operators are there at `versions`
    long last_use = 0;
  };

  // Notes that frame t's operator of `source` at `versions` is there; once
  // every source's is, the frame's virtual depths are no longer needed (an
  // operator evicted later recomputes them).
  void CountSource(int t, int source, const std::vector<long>& versions) {
    FrameDepths& slot = frame_depths_[t];
    std::lock_guard<std::mutex> lock(depths_mutex_);
    if (slot.versions != versions) {
      slot.versions = versions;
      slot.sources.clear();
      if (slot.depths != nullptr) ReleaseDepths(&slot);
    }
    if (std::find(slot.sources.begin(), slot.sources.end(), source) == slot.sources.end())
      slot.sources.push_back(source);
    if (static_cast<int>(slot.sources.size()) >= sources_per_frame_[t] && slot.depths != nullptr)
      ReleaseDepths(&slot);
  }

  void ReleaseDepths(FrameDepths* slot) {
    depth_bytes_ -= slot->depths->Bytes();
    slot->depths.reset();
  }

  // The virtual depths of frame t, computed on the calling thread unless
  // they are stored at `versions`; the least recently used frames' depths
  // are dropped beyond max_depth_bytes_ (their holders keep them alive).
  std::shared_ptr<const VirtualDepths> SharedDepths(const std::vector<FrameStructure>& frames, int t,
                                                    const std::vector<long>& versions) {
    FrameDepths& slot = frame_depths_[t];
    std::lock_guard<std::mutex> compute_lock(slot.compute);
    {
      std::lock_guard<std::mutex> lock(depths_mutex_);
      slot.last_use = ++depth_clock_;
      if (slot.depths != nullptr && slot.versions == versions) return slot.depths;
    }
    auto depths = std::make_shared<VirtualDepths>();
    depths->Compute(MakeCaptureGeometry(frames, camera_hr_, t, t), options_);
    std::lock_guard<std::mutex> lock(depths_mutex_);
    if (slot.depths != nullptr) ReleaseDepths(&slot);
    if (slot.versions != versions) {
      slot.versions = versions;
      slot.sources.clear();
    }
    slot.depths = depths;
    depth_bytes_ += depths->Bytes();
    while (depth_bytes_ > max_depth_bytes_) {
      FrameDepths* oldest = nullptr;
      for (FrameDepths& other : frame_depths_) {
        if (&other != &slot && other.depths != nullptr &&
            (oldest == nullptr || other.last_use < oldest->last_use))
          oldest = &other;
      }
      if (oldest == nullptr) break;
      ReleaseDepths(oldest);
    }
    return depths;
  }

  // What an entry holds: the operator's row runs, the coverage and the mask.
  static size_t Bytes(const Entry& e) {
    return e.op.matrix().Bytes() + e.op.coverage().size() * sizeof(float) + e.mask.total();
  }
  void Touch(const std::pair<int, int>& key) {
    order_.remove(key);
    order_.push_back(key);
  }
  void Evict(const std::pair<int, int>& keep) {
    while (bytes_ > max_bytes_ && order_.size() > 1) {
      const auto victim = order_.front();
      if (victim == keep) break;
      order_.pop_front();
      auto it = entries_.find(victim);
      if (it != entries_.end()) {
        bytes_ -= Bytes(*it->second.entry);
        entries_.erase(it);
      }
    }
  }

  CaptureOperatorOptions options_;
  std::vector<CaptureOperatorBuilder> builders_;
  std::mutex mutex_;  // guards entries_, order_, bytes_, carried_, reused_
  PinholeCamera camera_hr_;
  VisibilityOptions visibility_;
  size_t max_bytes_;
  size_t bytes_ = 0;
  size_t max_depth_bytes_;
  size_t depth_bytes_ = 0;
  long depth_clock_ = 0;
  std::vector<int> sources_per_frame_;
  std::mutex depths_mutex_;  // guards the slots' versions, sources, depths and last_use
  std::vector<FrameDepths> frame_depths_;
  std::map<std::pair<int, int>, Slot> entries_;
  std::list<std::pair<int, int>> order_;
  CarriedOperators carried_;
  int reused_ = 0;
};

// Operator options of the estimator's capture operators (eq:blurOperator).
CaptureOperatorOptions EstimatorOperatorOptions(const EstimatorOptions& options) {
  CaptureOperatorOptions op_options;
  op_options.samples = options.samples;
  op_options.adaptive_samples = options.adaptive_samples;
  op_options.scale = options.scale;
  // The estimator parallelises over frames (no barriers inside a frame's
  // work, which matters when the cores are shared); every operator runs on
  // the thread that uses it.
  op_options.num_threads = 1;
  op_options.transposed_copy = false;  // half the memory, same speed on one thread
  return op_options;
}

// I_t where the image update starts: the warm start of `input`, else the
// bicubic up-sampling of B_t.
cv::Mat InitialLatent(const EstimatorInput& input, int t, const cv::Mat& bicubic) {
  if (static_cast<size_t>(t) >= input.initial_latents.size() || input.initial_latents[t].empty()) {
    return bicubic.clone();
  }
  const cv::Mat& latent = input.initial_latents[t];
  if (latent.size() != bicubic.size() || latent.type() != bicubic.type()) {
    throw InputError("estimator: an initial latent image differs from the HR frames in size or type");
  }
  return latent.clone();
}

// The pose prior of a window (EstimatorInput::T_prior_cam) as terms of the
// structure update (EstimatorOptions::pose_prior_in_iterations), in the
// world of T_world_cam, carried there by the inverse of the similarity of
// that world to the prior: the caller's (EstimatorInput::world_to_prior),
// with the frames whose aligned position lies within the initialiser's
// outlier distance of the prior's, or else the robust Sim(3) of T_world_cam
// to the prior (AlignToPrior with the initialiser's options) with the frames
// it keeps. The sigmas are the initialiser's, the position sigma divided by
// the similarity's scale. None when the options leave it out or the
// alignment fails; `note` says which.
PosePriorTerms WindowPosePrior(const EstimatorOptions& options, const EstimatorInput& input,
                               const std::vector<SE3>& T_world_cam, std::string* note) {
  PosePriorTerms terms;
  const InitializerOptions& init = options.initializer;
  if (input.T_prior_cam.empty() || !options.pose_prior_in_iterations || !options.update_structure ||
      !(init.pose_prior_position_sigma > 0.0)) {
    return terms;
  }
  std::vector<int> frame_of;
  std::vector<SE3> estimated, prior;
  for (size_t t = 0; t < input.T_prior_cam.size() && t < T_world_cam.size(); ++t) {
    if (!input.T_prior_cam[t]) continue;
    frame_of.push_back(static_cast<int>(t));
    estimated.push_back(T_world_cam[t]);
    prior.push_back(*input.T_prior_cam[t]);
  }
  Sim3 to_prior;
  std::vector<int> kept;  // indices into estimated / prior
  std::string how;
  if (input.world_to_prior) {
    to_prior = *input.world_to_prior;
    for (size_t i = 0; i < estimated.size(); ++i) {
      const Eigen::Vector3d aligned = TransformPose(to_prior, estimated[i]).translation();
      if ((aligned - prior[i].translation()).norm() <= init.pose_prior.outlier_distance) {
        kept.push_back(static_cast<int>(i));
      }
    }
    how = "through the stream's alignment, scale " + std::to_string(to_prior.scale);
  } else {
    const PriorAlignment alignment = AlignToPrior(estimated, prior, init.pose_prior);
    if (!alignment.valid) {
      *note = "pose prior: not in the structure update (" + alignment.note + ")";
      return terms;
    }
    to_prior = alignment.estimate_to_prior;
    kept = alignment.inlier_frames;
    how = alignment.note;
  }
  const Eigen::Matrix3d R_world_prior = to_prior.rotation.transpose();
  terms.centre_world.assign(T_world_cam.size(), std::nullopt);
  terms.R_world_cam.assign(T_world_cam.size(), Eigen::Matrix3d::Identity());
  for (int i : kept) {
    const int t = frame_of[i];
    terms.centre_world[t] = InverseTransformPoint(to_prior, prior[i].translation());
    terms.R_world_cam[t] = R_world_prior * prior[i].rotation();
  }
  terms.position_sigma = init.pose_prior_position_sigma / to_prior.scale;
  terms.rotation_sigma = init.pose_prior_rotation_sigma_deg * M_PI / 180.0;
  terms.weight = options.pose_prior_weight;
  *note = "pose prior in the structure update: " + std::to_string(kept.size()) + " of " +
          std::to_string(estimated.size()) + " frames (" + how + ")";
  return terms;
}

// The tracks' pose terms of a window (EstimatorOptions::track_pose_weight):
// none in baseline mode, with the weight 0, or without tracks. Their
// mid-exposure offsets and gate are set by RefreshTrackTerms.
TrackPoseTerms WindowTrackTerms(const EstimatorOptions& options, const EstimatorInput& input, bool joint) {
  TrackPoseTerms terms;
  if (!joint || !(options.track_pose_weight > 0.0)) return terms;
  const int num_frames = static_cast<int>(input.images.size());
  for (FeatureTrack track : input.tracks) {
    if (track.first_frame < 0 || track.first_frame >= num_frames) continue;
    track.points.resize(std::min<size_t>(track.points.size(), num_frames - track.first_frame));
    if (track.points.size() >= 2) terms.tracks.push_back(std::move(track));
  }
  terms.camera = input.camera;
  terms.weight = options.track_pose_weight;
  terms.sigma_px = options.track_pose_sigma_px;
  terms.gate_start = options.track_pose_gate_start;
  terms.gate_width = options.track_pose_gate_width;
  terms.T_cam_seen.resize(terms.tracks.size());
  for (size_t i = 0; i < terms.tracks.size(); ++i) terms.T_cam_seen[i].resize(terms.tracks[i].points.size());
  return terms;
}

// Algorithm 1 (alg:optimization) on one window from a given structure. The
// object holds the window's state: observations B_t, latent images I_t, the
// frame structures (D_t, P_t), inverse depths, edge weights g_t, the
// neighbour lists N(t) and the operator cache. Its phases are the image
// update (eq:imgUpdate), the structure update (eq:taylorExpansion,
// eq:updateVariables) and accept/undo of an iteration.
class WindowSolver {
 public:
  // Inputs must have been checked (CheckWindowCounts, CheckWindowValues);
  // the depth maps are checked here, frame by frame.
  WindowSolver(const EstimatorOptions& options, int threads, const EstimatorInput& input,
               const std::vector<cv::Mat>& depth_hr, const std::vector<SE3>& T_world_cam,
               const std::atomic<bool>* cancel, const ProgressCallback& progress);

  // Runs the iterations the options ask for and returns the result in the
  // output gauge.
  EstimatorResult Solve();

 private:
  using HeldOperators = std::vector<std::shared_ptr<const OperatorCache::Entry>>;
  // The state an iteration may have to undo.
  struct Snapshot {
    std::vector<cv::Mat> latents, inverse_depth, edge_weight;
    std::vector<SE3> T_world_cam;
  };

  // ---- The three schedules.
  void RunJoint();
  bool TryJointIteration(int iteration, bool sweep, double* accepted);
  void RunBaseline();
  void RunImagesOnly();

  // ---- Phases.
  void ImagePhase(int iteration);
  void StructurePhase(int iteration, bool isolated);
  ImageUpdateOptions PhaseCounts(int iteration) const;
  void UpdateLatent(int t, const ImageUpdateOptions& phase_options);
  void UpdateEdgeWeight(int t);
  void RefineAllDepthEdges();
  bool SweepsSolverDepths(int iteration) const;
  void SweepSolverDepths();
  std::vector<cv::Mat> SweptInverseDepths(int first_frame = 0);
  // The first frame whose output depth is refined: a stream's held leading
  // frames were given out, refined, with the previous window.
  int FirstRefinedOutput() const { return options_.held_leading_latents; }
  // The first frame whose depth the re-centred passes update
  // (EstimatorOptions::recentred_passes_on_held_frames).
  int FirstRecentredFrame() const {
    return options_.recentred_passes_on_held_frames ? 0 : options_.held_leading_latents;
  }
  bool RefineOutputDepthEdges() const;
  std::vector<cv::Mat> OutputDepths();
  std::vector<cv::Mat> ConsistentOutputDepths(const std::vector<cv::Mat>& depths);
  void UpdateFrameDepth(int t, int iteration, bool isolated, const std::vector<SE3>& poses,
                        const StructureUpdateOptions& structure_options, bool recentred_inputs = false);
  void UpdateAllPoses(int iteration, bool isolated, const std::vector<SE3>& poses,
                      const StructureUpdateOptions& structure_options);
  void RefreshTrackTerms();
  void UpdateDepthsAndPosesJointly(int iteration, bool isolated,
                                   const StructureUpdateOptions& structure_options);
  std::vector<BlurPoseTerm> BlurPoseTerms(const StructureUpdateOptions& structure_options);
  void AppendPairs(int t, const std::vector<int>& sources, bool with_inputs, bool weigh_inputs,
                   std::vector<PairMatching>* pairs, HeldOperators* held, bool recentred_inputs = false);
  float InputPairWeight(double blur_difference) const;
  void DropRestoredPairsOfEqualBlur(int t, std::vector<PairMatching>* pairs) const;
  double BlurDifference(const CaptureGeometry& geometry_t, int s) const;
  SelfConsistencyLinearization SelfConsistencyOf(int t);
  void SetInverseDepth(int t, const cv::Mat& inverse_depth);
  void SetPoses(const std::vector<SE3>& T_world_cam);
  void SetPose(int t, const SE3& T_world_cam);

  // ---- Energy (eq:energyFunction).
  double FrameEnergy(int t, EnergyRecord* parts);
  EnergyRecord TotalEnergy(int iteration, const std::string& stage);
  cv::Mat BaselineMask(int t, int s, const cv::Mat& valid) const;
  double ParallaxScale() const;

  // ---- Accept / undo.
  Snapshot TakeSnapshot() const;
  void Undo(int iteration, const Snapshot& snapshot, bool stop = true);

  // ---- Guards and bookkeeping.
  bool OutOfTime(int iterations_done);
  void RequireFiniteEnergy(const char* where) const;
  void ThrowIfCancelled() const;
  void Report(double within, const std::string& what);
  std::shared_ptr<const OperatorCache::Entry> Operator(int t, int source);
  template <typename Body>
  void ForEachFrame(const Body& body);
  template <typename Body>
  void ForEachTask(int count, const Body& body);
  EstimatorResult GaugedResult();
  void RefineOutputDepthsDuringFramePass(std::vector<cv::Mat>* depths);
  std::vector<cv::Mat> OutputLatents(const std::vector<cv::Mat>& depths);
  void UpdateLatentFromFrames(int t, bool raised);
  void FuseBetweenUpdates();

  bool blurred_matching() const {
    return joint_ && options_.structure_matching == StructureMatching::kBlurred;
  }
  bool input_matching() const {
    return joint_ && options_.structure_matching == StructureMatching::kRestoredAndInput;
  }
  bool cross_blurred_inputs() const { return input_matching() && options_.cross_blurred_inputs; }
  int PoseRadius() const {
    return blurred_matching() ? options_.neighbour_radius
                              : std::max(options_.neighbour_radius, options_.pose_neighbour_radius);
  }
  void BuildCrossBlurredInputs();
  bool RecentredDepthPass() const {
    return input_matching() && options_.depth_input_pairs && options_.recentred_depth_pass &&
           !cross_blurred_inputs();
  }
  void BuildRecentredInputs();

  const EstimatorOptions& options_;
  const std::atomic<bool>* cancel_;
  const ProgressCallback& progress_;
  const int num_frames_;
  const int scale_;
  const bool joint_;
  const int threads_;
  const PinholeCamera camera_hr_;
  const int total_steps_;  // progress: the first image phase and two phases per iteration
  int steps_done_ = 0;
  double run_start_ms_ = 0.0;
  Timer timer_;
  EstimatorResult result_;

  std::vector<cv::Mat> observations_;  // B_t (LR, continuous)
  std::vector<cv::Mat> bicubic_;       // B_t up-sampled (HR)
  // cross_blurred_[a][b - a + PoseRadius()]: B_a up-sampled and blurred by
  // b's blur (EstimatorOptions::cross_blurred_inputs), for |a - b| within
  // the pose radius; rebuilt at every structure update.
  std::vector<std::vector<cv::Mat>> cross_blurred_;
  // B_t up-sampled and re-centred on the shutter close, and where that holds
  // (RecentreOnShutterClose); filled for the re-centred depth pass only.
  std::vector<cv::Mat> recentred_inputs_, recentred_valid_;
  std::vector<cv::Mat> latents_;        // I_t (HR)
  std::vector<FrameStructure> frames_;  // D_t, P_t, stamps, exposures
  std::vector<cv::Mat> inverse_depth_;  // rho_t = 1 / D_t (HR, holes filled)
  std::vector<cv::Mat> edge_weight_;    // g_t of eq:regularizingTerm
  // Bumped on every change of D_t / P_t: the operator cache rebuilds what
  // depends on them.
  std::vector<long> depth_version_, pose_version_;
  std::vector<std::vector<int>> neighbours_;  // N(t)
  PosePriorTerms pose_prior_;                 // empty: none (WindowPosePrior)
  DenoisedAnchorSettings anchor_;             // the last pass's anchor (AnchorSettings)
  std::vector<cv::Mat> anchor_images_;        // z_t of AnchorDenoiser::kTemporalFusion
  std::unique_ptr<OperatorCache> cache_;
  std::mutex work_mutex_;  // result_.image_work, summed by the frames' threads
};

// Runs body(t) for every frame on `threads_` threads; the first exception
// thrown by any frame is rethrown here (exceptions must not leave an
// OpenMP region).
template <typename Body>
void WindowSolver::ForEachFrame(const Body& body) {
  ForEachTask(num_frames_, body);
}

// Runs body(task) for task = 0 .. count - 1 on `threads_` threads, in that
// order of start (dynamic schedule); exceptions as ForEachFrame.
template <typename Body>
void WindowSolver::ForEachTask(int count, const Body& body) {
  const int threads = threads_;
  std::exception_ptr error;
  std::mutex error_mutex;
#pragma omp parallel for schedule(dynamic, 1) num_threads(threads)
  for (int task = 0; task < count; ++task) {
    try {
      ThrowIfCancelled();
      body(task);
    } catch (...) {
      std::lock_guard<std::mutex> lock(error_mutex);
      if (!error) error = std::current_exception();
    }
  }
  if (error) std::rethrow_exception(error);
}

WindowSolver::WindowSolver(const EstimatorOptions& options, int threads, const EstimatorInput& input,
                           const std::vector<cv::Mat>& depth_hr, const std::vector<SE3>& T_world_cam,
                           const std::atomic<bool>* cancel, const ProgressCallback& progress)
    : options_(options),
      cancel_(cancel),
      progress_(progress),
      num_frames_(static_cast<int>(input.images.size())),
      scale_(options.scale),
      joint_(options.mode == EstimatorMode::kJoint),
      threads_(threads),
      camera_hr_(input.camera.Upscaled(options.scale)),
      total_steps_(std::max(1, 2 * options.max_iterations + 1)),
      observations_(num_frames_),
      bicubic_(num_frames_),
      latents_(num_frames_),
      frames_(num_frames_),
      inverse_depth_(num_frames_),
      edge_weight_(num_frames_),
      depth_version_(num_frames_, 0),
      pose_version_(num_frames_, 0),
      neighbours_(num_frames_) {
  result_.camera_hr = camera_hr_;
  for (int t = 0; t < num_frames_; ++t) {
    observations_[t] = input.images[t].isContinuous() ? input.images[t] : input.images[t].clone();
    bicubic_[t] = UpsampleBicubic(observations_[t], scale_);
    latents_[t] = InitialLatent(input, t, bicubic_[t]);
    frames_[t].stamp = input.frames[t].stamp;
    frames_[t].exposure = input.frames[t].exposure;
    frames_[t].readout_time = input.readout_time;
    frames_[t].T_world_cam = T_world_cam[t];
    if (depth_hr[t].type() != CV_32FC1 ||
        depth_hr[t].size() != cv::Size(camera_hr_.width, camera_hr_.height)) {
      throw InputError("estimator: depth maps must be CV_32FC1 of the HR size");
    }
    inverse_depth_[t] = InverseDepthFromDepth(depth_hr[t]);
    frames_[t].depth_hr = DepthFromInverse(inverse_depth_[t]);
    UpdateEdgeWeight(t);
  }
  std::string prior_note;
  pose_prior_ = WindowPosePrior(options_, input, T_world_cam, &prior_note);
  pose_prior_.tracks = WindowTrackTerms(options_, input, joint_);
  anchor_ = AnchorSettings(options_.denoised_anchor, options_.noise_sigma, options_.lambda_s,
                           options_.model_error_sigma);
  if (!prior_note.empty()) result_.notes.push_back(prior_note);
  omp_set_max_active_levels(1);
  std::vector<int> sources_per_frame(num_frames_);
  for (int t = 0; t < num_frames_; ++t) {
    neighbours_[t] = Neighbours(t, num_frames_, options_.neighbour_radius);
    sources_per_frame[t] = static_cast<int>(neighbours_[t].size()) + 1;  // N(t) and t itself
  }
  // Every operator of a 10-frame 640x480 window (30 operators of ~21 MiB)
  // fits; larger windows evict the least recently used ones and rebuild them,
  // which keeps the peak memory bounded.
  // The virtual depths of 4 frames at M = 50 and 640x480 (a frame's
  // operators are built close together in time, so sharing needs few).
  cache_ = std::make_unique<OperatorCache>(EstimatorOperatorOptions(options_), threads_, camera_hr_,
                                           options_.visibility, size_t(3) << 29, size_t(1) << 28,
                                           sources_per_frame, input.carried_operators);
}

// The main loop of Algorithm 1 (alg:optimization) after the initialisation
// (done by the caller): max_iter times the image phase and the structure
// phase, on the schedule the mode asks for.
EstimatorResult WindowSolver::Solve() {
  run_start_ms_ = NowMs();
  result_.energies.push_back(TotalEnergy(0, "initialization"));
  cache_->ForgetCarried();  // every operator of the initial structure is there
  RequireFiniteEnergy("at the initial structure");
  if (!joint_) {
    RunBaseline();
  } else if (!options_.update_structure) {
    RunImagesOnly();
  } else if (options_.max_iterations > 0) {
    RunJoint();
  }
  if (progress_) progress_(1.0, "done");
  return GaugedResult();
}

// Algorithm 1: image update, then max_iter times structure update followed
// by the image update that judges it (the last one gives the output images
// that match the final structure). A structure update whose following image
// update does not lower the energy is undone, with the images, and the
// iterations stop: the recorded energy after each kept iteration never
// increases. An iteration that started from the re-swept depth
// (DepthSweepOptions::before_last_structure_updates) and raised the energy
// is undone and run again from the solver's own depth.
void WindowSolver::RunJoint() {
  ImagePhase(1);
  RequireFiniteEnergy("after the first image update");
  double accepted = result_.energies.back().total;
  for (int iteration = 1; iteration <= options_.max_iterations; ++iteration) {
    if (OutOfTime(iteration - 1)) break;
    const Snapshot before = TakeSnapshot();
    const bool sweep = SweepsSolverDepths(iteration);
    if (TryJointIteration(iteration, sweep, &accepted)) continue;
    if (sweep) {
      Undo(iteration, before, /*stop=*/false);
      if (TryJointIteration(iteration, /*sweep=*/false, &accepted)) continue;
    }
    Undo(iteration, before);
    break;
  }
}

// One iteration of RunJoint: (the re-sweep of the solver's depth,) the
// structure update and the image update that judges it; true (and
// *accepted updated) when the energy did not rise above *accepted.
bool WindowSolver::TryJointIteration(int iteration, bool sweep, double* accepted) {
  FuseBetweenUpdates();
  if (sweep) SweepSolverDepths();
  StructurePhase(iteration, /*isolated=*/false);
  ImagePhase(iteration + 1);
  if (!(result_.energies.back().total <= *accepted)) return false;
  *accepted = result_.energies.back().total;
  return true;
}

// Baseline: the images stay the bicubic inputs; only the structure moves.
void WindowSolver::RunBaseline() {
  for (int iteration = 1; iteration <= options_.max_iterations && options_.update_structure; ++iteration) {
    if (OutOfTime(iteration - 1)) break;
    StructurePhase(iteration, /*isolated=*/true);
  }
}

// Images only: depth and poses stay as given.
void WindowSolver::RunImagesOnly() {
  for (int iteration = 1; iteration <= options_.max_iterations; ++iteration) {
    if (OutOfTime(iteration - 1)) break;
    ImagePhase(iteration);
  }
}

// ---- Phase 1: latent images (eq:imgUpdate), one frame at a time.
void WindowSolver::ImagePhase(int iteration) {
  const double begin = NowMs();
  ForEachFrame([this, iteration](int t) {
    if (omp_get_thread_num() == 0) {
      Report(double(t) / num_frames_,
             "iteration " + std::to_string(iteration) + ": image " + std::to_string(t));
    }
    if (t < options_.held_leading_latents) return;  // I_t stays as given
    UpdateLatent(t, PhaseCounts(iteration));
    UpdateEdgeWeight(t);
  });
  ++steps_done_;
  timer_.AddSince("image update (incl. operator builds)", begin);
  result_.energies.push_back(TotalEnergy(iteration, "image"));
}

// The counts of image phase `iteration` (1 = the first, from the initial
// latents). The phases between the first and the last refine the restored
// images with fewer steps; the last gives the output images: after
// refinement phases it runs the final counts, right after the first phase
// (one iteration) the full ones, as a phase that is both first and last.
ImageUpdateOptions WindowSolver::PhaseCounts(int iteration) const {
  const int last = options_.update_structure ? options_.max_iterations + 1 : options_.max_iterations;
  ImageUpdateOptions counts = options_.image;
  if (iteration == last) {
    if (last > 2) {
      counts.irls_iterations = counts.final_irls_iterations;
      counts.cg_iterations = counts.final_cg_iterations;
    }
  } else if (iteration == 1) {
    counts.irls_iterations = counts.first_irls_iterations;
  } else {
    counts.irls_iterations = counts.refine_irls_iterations;
    counts.cg_iterations = counts.refine_cg_iterations;
  }
  return counts;
}

// I_t from the matching terms of its neighbours (Psi_s applied to I_t
// against B_s) and its own self-consistency term (eq:IPterm), with the
// counts of the phase (PhaseCounts).
void WindowSolver::UpdateLatent(int t, const ImageUpdateOptions& phase_options) {
  std::vector<LinearL1Term> terms;
  HeldOperators held;
  for (int s : neighbours_[t]) {
    held.push_back(Operator(s, t));
    terms.push_back({&held.back()->op, &observations_[s], held.back()->mask, 1.0});
  }
  held.push_back(Operator(t, t));
  terms.push_back({&held.back()->op, &observations_[t], cv::Mat(), options_.lambda_s});
  ImageUpdateOptions image_options = phase_options;
  image_options.num_threads = 1;
  const double solve_begin = NowMs();
  const ImageUpdateStats stats = UpdateImage(terms, image_options, &latents_[t]);
  timer_.AddSince("image solves (thread seconds)", solve_begin);
  std::lock_guard<std::mutex> lock(work_mutex_);
  result_.image_work += stats;
}

// g_t of eq:regularizingTerm follows the edges of the current I_t.
void WindowSolver::UpdateEdgeWeight(int t) {
  edge_weight_[t] = EdgeWeight(latents_[t], options_.structure.edge_weight);
}

// ---- Phase 2: depths and poses (eq:taylorExpansion, eq:updateVariables).
// With `isolated` (baseline: the images are fixed) each depth map and the
// pose update is kept only if it lowers the energy on its own. In joint
// mode the latent images were fitted to the old structure, so a step
// towards the true structure can raise the energy until the images follow:
// RunJoint judges the structure update after the next image update.
void WindowSolver::StructurePhase(int iteration, bool isolated) {
  const double begin = NowMs();
  StructureUpdateOptions structure_options = options_.structure;
  structure_options.num_threads = threads_;
  if (cross_blurred_inputs()) BuildCrossBlurredInputs();
  if (options_.depth_edges.before_structure_update) RefineAllDepthEdges();
  if (structure_options.joint_depth_pose_step && options_.update_poses) {
    UpdateDepthsAndPosesJointly(iteration, isolated, structure_options);
  } else {
    std::vector<SE3> poses(num_frames_);
    for (int t = 0; t < num_frames_; ++t) poses[t] = frames_[t].T_world_cam;
    ForEachFrame([this, iteration, isolated, &poses, &structure_options](int t) {
      UpdateFrameDepth(t, iteration, isolated, poses, structure_options);
    });
  }
  std::vector<SE3> poses(num_frames_);
  for (int t = 0; t < num_frames_; ++t) poses[t] = frames_[t].T_world_cam;
  if (options_.update_poses) UpdateAllPoses(iteration, isolated, poses, structure_options);
  // The last structure update ends with depth updates on the input pairs
  // re-centred on the shutter close (EstimatorOptions::recentred_depth_pass,
  // recentred_depth_passes times), of the frames from FirstRecentredFrame.
  if (RecentredDepthPass() && iteration == options_.max_iterations) {
    for (int t = 0; t < num_frames_; ++t) poses[t] = frames_[t].T_world_cam;
    StructureUpdateOptions pass_options = structure_options;
    pass_options.depth_cg_iterations = options_.recentred_depth_cg_iterations;
    pass_options.depth_cg_tolerance = options_.recentred_depth_cg_tolerance;
    pass_options.depth_preconditioner = options_.recentred_depth_preconditioner;
    for (int pass = 0; pass < options_.recentred_depth_passes; ++pass) {
      BuildRecentredInputs();
      ForEachFrame([this, iteration, isolated, &poses, &pass_options](int t) {
        if (t < FirstRecentredFrame()) return;
        UpdateFrameDepth(t, iteration, isolated, poses, pass_options, /*recentred_inputs=*/true);
      });
    }
    recentred_inputs_.clear();
    recentred_valid_.clear();
  }
  ++steps_done_;
  timer_.AddSince("structure update", begin);
  result_.energies.push_back(TotalEnergy(iteration, "structure"));
}

// Whether the output depth goes through the edge-aware weighted median
// (EstimatorOptions::depth_edges), on the result's copy: the solver's state,
// its energy and the operators stay those of the estimated D_t, which the
// result also keeps (EstimatorResult::solver_depth: what a stream's next
// window starts from, and what the operators it hands on were built with).
// A weighted median commutes with the monotone depth = 1 / inverse depth, so
// the depth is filtered directly.
bool WindowSolver::RefineOutputDepthEdges() const {
  return options_.depth_edges.radius_px > 0 && options_.depth_edges.on_output;
}

// The output D_t: the solver's, or in joint mode with the re-sweep
// (EstimatorOptions::depth_sweep) copies re-swept against the neighbours'
// restored images at the current poses (the solver's own stay in
// EstimatorResult::solver_depth).
std::vector<cv::Mat> WindowSolver::OutputDepths() {
  std::vector<cv::Mat> depths(num_frames_);
  for (int t = 0; t < num_frames_; ++t) depths[t] = frames_[t].depth_hr;
  if (!joint_ || !options_.depth_sweep.on_output) return depths;
  const int first = FirstRefinedOutput();
  const std::vector<cv::Mat> swept = SweptInverseDepths(first);
  for (int t = first; t < num_frames_; ++t) depths[t] = DepthFromInverse(swept[t]);
  return depths;
}

// Copies of every solver D_t (inverse depth) re-swept against the
// neighbours' current latent images at the current poses
// (SweepInverseDepth, EstimatorOptions::depth_sweep); those of the frames
// before `first_frame` are copied as they are.
std::vector<cv::Mat> WindowSolver::SweptInverseDepths(int first_frame) {
  const double begin = NowMs();
  std::vector<SE3> poses(num_frames_);
  for (int t = 0; t < num_frames_; ++t) poses[t] = frames_[t].T_world_cam;
  std::vector<cv::Mat> swept(num_frames_);
  ForEachFrame([this, &poses, &swept, first_frame](int t) {
    swept[t] = inverse_depth_[t].clone();
    if (t < first_frame) return;
    const std::vector<int> sources = Neighbours(t, num_frames_, options_.depth_sweep.neighbour_radius);
    SweepInverseDepth(latents_, camera_hr_, poses, t, sources, options_.depth_sweep, &swept[t]);
  });
  timer_.AddSince("depth re-sweep", begin);
  return swept;
}

// DepthSweepOptions::before_last_structure_updates: whether the solver's own
// D_t is re-swept before structure update `iteration` (one of the last ones
// of max_iterations), so that the structure update continues from it
// (RunJoint judges the iteration by the energy after the next image
// update). Not in a window that hands operators on, nor over held leading
// latents (a stream's).
bool WindowSolver::SweepsSolverDepths(int iteration) const {
  const int last = options_.depth_sweep.before_last_structure_updates;
  return last > 0 && iteration > options_.max_iterations - last && options_.carried_frames == 0 &&
         options_.held_leading_latents == 0;
}

// Every solver D_t replaced by its re-swept copy (SweptInverseDepths),
// through the depth-edge median where that is on (DepthEdgeOptions).
void WindowSolver::SweepSolverDepths() {
  std::vector<cv::Mat> swept = SweptInverseDepths();
  for (int t = 0; t < num_frames_; ++t) {
    if (options_.depth_edges.radius_px > 0) RefineDepthEdges(latents_[t], options_.depth_edges, &swept[t]);
    SetInverseDepth(t, swept[t]);
  }
}

// Every D_t through the edge-aware weighted median guided by its current
// latent image (EstimatorOptions::depth_edges; nothing when off).
void WindowSolver::RefineAllDepthEdges() {
  if (options_.depth_edges.radius_px <= 0) return;
  const double begin = NowMs();
  ForEachFrame([this](int t) {
    cv::Mat refined = inverse_depth_[t].clone();
    RefineDepthEdges(latents_[t], options_.depth_edges, &refined);
    SetInverseDepth(t, refined);
  });
  timer_.AddSince("depth edge refinement", begin);
}

// D_t from the pairs (t <- s), s in N(t), and, for kBlurred, the
// self-consistency term linearised in depth.
void WindowSolver::UpdateFrameDepth(int t, int iteration, bool isolated, const std::vector<SE3>& poses,
                                    const StructureUpdateOptions& structure_options, bool recentred_inputs) {
  if (omp_get_thread_num() == 0) {
    Report(double(t) / (num_frames_ + 1),
           "iteration " + std::to_string(iteration) + ": structure " + std::to_string(t));
  }
  const double before = isolated ? FrameEnergy(t, nullptr) : 0.0;
  const cv::Mat saved = inverse_depth_[t].clone();
  std::vector<PairMatching> pairs;
  HeldOperators held;
  AppendPairs(t, neighbours_[t], options_.depth_input_pairs, /*weigh_inputs=*/true, &pairs, &held,
              recentred_inputs);
  SelfConsistencyLinearization self;
  if (blurred_matching()) self = SelfConsistencyOf(t);
  const double depth_begin = NowMs();
  UpdateDepth(camera_hr_, poses, latents_, pairs, blurred_matching() ? &self : nullptr, edge_weight_[t],
              ParallaxScale(), structure_options, &inverse_depth_[t]);
  timer_.AddSince("depth updates (thread seconds)", depth_begin);
  SetInverseDepth(t, inverse_depth_[t]);
  if (isolated && !(FrameEnergy(t, nullptr) <= before)) {
    SetInverseDepth(t, saved);  // the surrogate step did not pay: keep D_t
  }
}

// Every D_t and the free poses in one Gauss-Newton/IRLS step from the depth
// updates' terms (UpdateDepthAndPoses), in place of the per-frame depth
// updates (with joint_step_pose_pairs, from the pairs within the pose
// radius); the pose update with its longer baselines follows. With
// `isolated` (baseline) the step is kept only if it lowers the energy.
// The tracks' terms at the current structure: the camera of each
// observation at the mid-exposure of its row on the frame's blur path (the
// tracks follow the blur centroid), then the tracks' least cost over the
// poses for the gate (TrackPoseTerms).
void WindowSolver::RefreshTrackTerms() {
  TrackPoseTerms& terms = pose_prior_.tracks;
  if (!terms.any()) return;
  const double begin = NowMs();
  std::vector<SE3> poses(num_frames_), T_cam_mid(num_frames_);
  std::vector<CaptureGeometry> geometries(num_frames_);
  for (int f = 0; f < num_frames_; ++f) {
    const FrameStructure& frame = frames_[f];
    geometries[f] = MakeCaptureGeometry(frames_, camera_hr_, f, f);
    T_cam_mid[f] =
        frame.T_world_cam.Inverse() * PoseAtTime(geometries[f], frame.stamp - 0.5 * frame.exposure);
    poses[f] = frame.T_world_cam;
  }
  for (size_t i = 0; i < terms.tracks.size(); ++i) {
    const FeatureTrack& track = terms.tracks[i];
    for (size_t k = 0; k < track.points.size(); ++k) {
      const FrameStructure& frame = frames_[track.first_frame + k];
      const double row_delay = frame.readout_time * track.points[k].y() / terms.camera.height;
      terms.T_cam_seen[i][k] =
          row_delay == 0.0
              ? T_cam_mid[track.first_frame + k]
              : frame.T_world_cam.Inverse() * PoseAtTime(geometries[track.first_frame + k],
                                                         frame.stamp - 0.5 * frame.exposure + row_delay);
    }
  }
  terms.min_cost = TrackCostMinimum(terms, poses, options_.fixed_leading_poses);
  timer_.AddSince("track terms", begin);
}

void WindowSolver::UpdateDepthsAndPosesJointly(int iteration, bool isolated,
                                               const StructureUpdateOptions& structure_options) {
  Report(0.0, "iteration " + std::to_string(iteration) + ": joint depth + pose step");
  const double before = isolated ? TotalEnergy(iteration, "structure").total : 0.0;
  std::vector<FrameDepthTerms> terms(num_frames_);
  std::vector<SelfConsistencyLinearization> selves(num_frames_);
  std::vector<HeldOperators> held(num_frames_);
  std::vector<SE3> poses(num_frames_);
  std::vector<cv::Mat> inverse_depths(num_frames_), saved_depths = inverse_depth_;
  // Frame by frame in parallel (the pairs' masks are a visibility test each).
  ForEachFrame([&](int t) {
    const std::vector<int> sources = structure_options.joint_step_pose_pairs
                                         ? Neighbours(t, num_frames_, PoseRadius())
                                         : neighbours_[t];
    AppendPairs(t, sources, options_.depth_input_pairs, /*weigh_inputs=*/true, &terms[t].pairs, &held[t]);
    if (blurred_matching()) {
      selves[t] = SelfConsistencyOf(t);
      terms[t].self = &selves[t];
    }
    terms[t].edge_weight = edge_weight_[t];
    poses[t] = frames_[t].T_world_cam;
    inverse_depths[t] = inverse_depth_[t].clone();
  });
  const std::vector<SE3> saved_poses = poses;
  RefreshTrackTerms();
  const double begin = NowMs();
  UpdateDepthAndPoses(camera_hr_, latents_, terms, ParallaxScale(), structure_options,
                      options_.fixed_leading_poses, &poses, &inverse_depths, &pose_prior_);
  timer_.AddSince("joint depth + pose steps", begin);
  for (int t = 0; t < num_frames_; ++t) SetInverseDepth(t, inverse_depths[t]);
  SetPoses(poses);
  if (isolated && !(TotalEnergy(iteration, "structure").total <= before)) {
    for (int t = 0; t < num_frames_; ++t) SetInverseDepth(t, saved_depths[t]);
    SetPoses(saved_poses);
  }
}

// All poses but the held leading ones, jointly from every pair within the
// pose radius (longer baselines than N(t); the blurred form needs the
// operators of N(t) only).
void WindowSolver::UpdateAllPoses(int iteration, bool isolated, const std::vector<SE3>& poses,
                                  const StructureUpdateOptions& structure_options) {
  const int pose_radius = PoseRadius();
  Report(double(num_frames_) / (num_frames_ + 1), "iteration " + std::to_string(iteration) + ": poses");
  const double before = isolated ? TotalEnergy(iteration, "structure").total : 0.0;
  std::vector<std::vector<PairMatching>> frame_pairs(num_frames_);
  std::vector<HeldOperators> held(num_frames_);
  // Pairs between two held poses would enter only held rows (their masks
  // and terms are not formed: StructureUpdateOptions::skip_held_pose_work).
  const int held_poses =
      structure_options.skip_held_pose_work && !pose_prior_.any() ? options_.fixed_leading_poses : 0;
  // Frame by frame in parallel (the pairs' masks are a visibility test
  // each), then in frame order.
  ForEachFrame([&](int t) {
    std::vector<int> sources = Neighbours(t, num_frames_, pose_radius);
    if (t < held_poses) {
      sources.erase(sources.begin(), std::lower_bound(sources.begin(), sources.end(), held_poses));
    }
    AppendPairs(t, sources, /*with_inputs=*/true, /*weigh_inputs=*/false, &frame_pairs[t], &held[t]);
    DropRestoredPairsOfEqualBlur(t, &frame_pairs[t]);
  });
  std::vector<PairMatching> pairs;
  for (std::vector<PairMatching>& frame : frame_pairs) {
    for (PairMatching& pair : frame) pairs.push_back(std::move(pair));
  }
  std::vector<SE3> updated = poses;
  const bool blur_evidence = joint_ && options_.blur_pose_evidence;
  const std::vector<BlurPoseTerm> blur_terms =
      blur_evidence ? BlurPoseTerms(structure_options) : std::vector<BlurPoseTerm>();
  RefreshTrackTerms();
  const double pose_begin = NowMs();
  UpdatePoses(camera_hr_, inverse_depth_, latents_, pairs, structure_options, &updated,
              options_.fixed_leading_poses, &pose_prior_, blur_evidence ? &blur_terms : nullptr);
  timer_.AddSince("pose updates", pose_begin);
  SetPoses(updated);
  if (isolated && !(TotalEnergy(iteration, "structure").total <= before)) SetPoses(poses);
}

// Blur as motion evidence (EstimatorOptions::blur_pose_evidence): every
// frame's self-consistency term (or, with blur_pose_from_pairs, its blurred
// matching pairs with N(t)) linearised in the poses of its blur path, at the
// current structure and latent images.
std::vector<BlurPoseTerm> WindowSolver::BlurPoseTerms(const StructureUpdateOptions& structure_options) {
  const double begin = NowMs();
  const bool from_pairs = structure_options.blur_pose_from_pairs;
  std::vector<std::vector<BlurPoseTerm>> per_frame(num_frames_);
  ForEachFrame([this, from_pairs, &per_frame, &structure_options](int t) {
    const auto self_op = Operator(t, t);
    std::vector<int> frames = {t};
    for (int f : BlurPathFrames(t, num_frames_)) frames.push_back(f);
    const CaptureGeometry geometry = MakeCaptureGeometry(frames_, camera_hr_, t, t);
    const double weight = structure_options.blur_pose_weight;
    if (from_pairs) {
      for (int s : neighbours_[t]) {
        per_frame[t].push_back(LinearizeBlurredPairInPoses(
            geometry, frames, s, options_.samples, scale_, inverse_depth_[t], frames_[s].T_world_cam,
            latents_[s], self_op->op, observations_[t], weight, structure_options));
      }
      return;
    }
    cv::Mat predicted;
    self_op->op.Apply(latents_[t], &predicted);
    per_frame[t].push_back(LinearizeBlurInPoses(geometry, frames, options_.samples, scale_, inverse_depth_[t],
                                                latents_[t], observations_[t], predicted,
                                                weight * options_.lambda_s, structure_options));
  });
  std::vector<BlurPoseTerm> terms;
  for (std::vector<BlurPoseTerm>& frame_terms : per_frame) {
    for (BlurPoseTerm& term : frame_terms) terms.push_back(std::move(term));
  }
  timer_.AddSince("blur pose evidence", begin);
  return terms;
}

// The pairs (t <- s) of frame t with s in `sources` (eq:matchingTerm), with
// the input pairs where the matching uses them and `with_inputs`, but not
// where the two frames' blurs differ by more than
// EstimatorOptions::unequal_blur_tolerance_px, and with `weigh_inputs` at
// the weight of their blur difference (InputPairWeight); `held` keeps their
// operators alive.
void WindowSolver::AppendPairs(int t, const std::vector<int>& sources, bool with_inputs, bool weigh_inputs,
                               std::vector<PairMatching>* pairs, HeldOperators* held, bool recentred_inputs) {
  // EstimatorOptions::unequal_blur_tolerance_px: t's blur geometry, once.
  const bool drop_unequal = input_matching() && with_inputs && options_.unequal_blur_tolerance_px > 0.0;
  const CaptureGeometry geometry_t =
      drop_unequal ? MakeCaptureGeometry(frames_, camera_hr_, t, t) : CaptureGeometry();
  for (int s : sources) {
    PairMatching pair;
    pair.t = t;
    pair.s = s;
    if (blurred_matching()) {
      held->push_back(Operator(t, s));
      pair.mask = held->back()->mask;
      held->push_back(Operator(t, t));
      pair.blur = &held->back()->op;
      pair.observation = &observations_[t];
      pairs->push_back(pair);
      continue;
    }
    // Restored (or, in the baseline, bicubic) HR images of t and s.
    pair.observation = &latents_[t];
    pair.mask = VisibleFromSource(camera_hr_, frames_, t, s, options_.visibility);
    pairs->push_back(pair);
    // Frames whose blurs differ: their inputs compare with a bias, the
    // restored pair alone stays (NaN, blurs not comparable: both stay).
    const double blur_difference = drop_unequal ? BlurDifference(geometry_t, s) : NAN;
    if (blur_difference > options_.unequal_blur_tolerance_px) continue;
    if (input_matching() && with_inputs) {
      // The same pair on the up-sampled inputs, which do not depend on
      // the current structure (see StructureMatching), plain or each
      // blurred by the other frame's blur.
      const int radius = PoseRadius();
      pair.observation = cross_blurred_inputs() ? &cross_blurred_[t][s - t + radius] : &bicubic_[t];
      pair.source = cross_blurred_inputs() ? &cross_blurred_[s][t - s + radius] : &bicubic_[s];
      if (recentred_inputs) {
        // Re-centred on the shutter close (BuildRecentredInputs), without
        // the pixels of t whose mid-exposure point leaves the image.
        pair.observation = &recentred_inputs_[t];
        pair.source = &recentred_inputs_[s];
        cv::Mat mask;
        if (pair.mask.empty()) {
          mask = recentred_valid_[t].clone();
        } else {
          cv::bitwise_and(pair.mask, recentred_valid_[t], mask);
        }
        pair.mask = mask;
      }
      if (weigh_inputs) pair.weight = InputPairWeight(blur_difference);
      pairs->push_back(pair);
    }
  }
}

// An input pair's weight in the depth update and the joint step
// (EstimatorOptions::equal_blur_input_weight): the input pairs compare
// without bias as far as their frames' blurs agree. 1 where
// equal_blur_input_weight is 0 or the blurs cannot be compared (NaN, also
// where the blur difference is not measured: unequal_blur_tolerance_px 0).
float WindowSolver::InputPairWeight(double blur_difference) const {
  const double weight = options_.equal_blur_input_weight;
  if (weight <= 0.0 || !std::isfinite(blur_difference)) return 1.0f;
  return static_cast<float>(weight *
                            std::max(0.0, 1.0 - blur_difference / options_.unequal_blur_tolerance_px));
}

// The pose update's pairs of frame t without the restored pairs whose two
// frames carry the same blur (EstimatorOptions::equal_blur_tolerance_px):
// their input pairs, which stay, compare them without bias. A pair whose
// blurs cannot be compared (BlurDifferenceHr NaN) keeps both. Off where a
// pose prior enters the update: there the prior holds the poses, and the rule
// cost the depth's metric scale (EstimatorOptions::equal_blur_tolerance_px).
void WindowSolver::DropRestoredPairsOfEqualBlur(int t, std::vector<PairMatching>* pairs) const {
  if (!input_matching() || options_.equal_blur_tolerance_px <= 0.0 || pose_prior_.any()) return;
  const CaptureGeometry geometry_t = MakeCaptureGeometry(frames_, camera_hr_, t, t);
  std::vector<PairMatching> kept;
  for (PairMatching& pair : *pairs) {
    const bool restored = pair.blur == nullptr && pair.source == nullptr;
    if (restored && BlurDifference(geometry_t, pair.s) < options_.equal_blur_tolerance_px) continue;
    kept.push_back(std::move(pair));
  }
  *pairs = std::move(kept);
}

// How much the blurs of frame t (its geometry) and frame s differ, in HR px
// (BlurDifferenceHr at the current structure; NaN: not comparable).
double WindowSolver::BlurDifference(const CaptureGeometry& geometry_t, int s) const {
  return BlurDifferenceHr(geometry_t, MakeCaptureGeometry(frames_, camera_hr_, s, s), options_.scale);
}

// Every B_t up-sampled, re-centred on the shutter close at the current depth
// and poses (RecentreOnShutterClose; EstimatorOptions::recentred_depth_pass).
void WindowSolver::BuildRecentredInputs() {
  const double begin = NowMs();
  recentred_inputs_.assign(num_frames_, cv::Mat());
  recentred_valid_.assign(num_frames_, cv::Mat());
  ForEachFrame([this](int t) {
    RecentreOnShutterClose(MakeCaptureGeometry(frames_, camera_hr_, t, t), scale_, inverse_depth_[t],
                           bicubic_[t], &recentred_inputs_[t], &recentred_valid_[t]);
  });
  timer_.AddSince("re-centred inputs", begin);
}

// Psi_b o B_a and Psi_a o B_b for every pair of frames within the pose
// radius, at HR (scale-1 operators on the up-sampled inputs) from the current
// depth and poses (CrossBlurGeometry).
void WindowSolver::BuildCrossBlurredInputs() {
  const double begin = NowMs();
  const int radius = PoseRadius();
  cross_blurred_.assign(num_frames_, std::vector<cv::Mat>(2 * radius + 1));
  CaptureOperatorOptions op_options = EstimatorOperatorOptions(options_);
  op_options.scale = 1;
  ForEachFrame([this, radius, &op_options](int a) {
    CaptureOperatorBuilder builder(op_options);
    CaptureOperator op;
    for (int b = std::max(0, a - radius); b <= std::min(num_frames_ - 1, a + radius); ++b) {
      if (b == a) continue;
      builder.Build(CrossBlurGeometry(frames_, camera_hr_, a, b), &op);
      op.Apply(bicubic_[a], &cross_blurred_[a][b - a + radius]);
    }
  });
  timer_.AddSince("cross-blurred inputs", begin);
}

// lambda_s |B_t - Psi_t I_t| (eq:IPterm) linearised in the inverse depth of t.
SelfConsistencyLinearization WindowSolver::SelfConsistencyOf(int t) {
  SelfConsistencyLinearization self;
  const auto self_op = Operator(t, t);
  self.observation = &observations_[t];
  self_op->op.Apply(latents_[t], &self.predicted);
  self.derivative = BlurDerivativeWrtInverseDepth(MakeCaptureGeometry(frames_, camera_hr_, t, t),
                                                  options_.samples, scale_, inverse_depth_[t], latents_[t],
                                                  /*max_samples=*/10);
  self.weight = options_.lambda_s;
  self.scale = scale_;
  return self;
}

// rho_t and D_t; the version (and D_t's buffer, which the shared virtual
// depths identify) change only if D_t does.
void WindowSolver::SetInverseDepth(int t, const cv::Mat& inverse_depth) {
  inverse_depth_[t] = inverse_depth;
  cv::Mat depth = DepthFromInverse(inverse_depth);
  if (SameBits(depth, frames_[t].depth_hr)) return;
  frames_[t].depth_hr = depth;
  ++depth_version_[t];
}

// P_t of every frame but the first (the gauge) from `T_world_cam`; a version
// changes only with its pose (held poses keep theirs and their operators).
void WindowSolver::SetPoses(const std::vector<SE3>& T_world_cam) {
  for (int t = 1; t < num_frames_; ++t) SetPose(t, T_world_cam[t]);
}

void WindowSolver::SetPose(int t, const SE3& T_world_cam) {
  const SE3& current = frames_[t].T_world_cam;
  if (current.rotation() == T_world_cam.rotation() && current.translation() == T_world_cam.translation())
    return;
  frames_[t].T_world_cam = T_world_cam;
  ++pose_version_[t];
}

// E_t (eq:energyFunctiont) of one frame at the current state; `parts`
// (optional) accumulates its terms.
double WindowSolver::FrameEnergy(int t, EnergyRecord* parts) {
  double matching = 0.0, self = 0.0;
  cv::Mat predicted;
  if (joint_) {
    for (int s : neighbours_[t]) {
      const auto e = Operator(t, s);
      e->op.Apply(latents_[s], &predicted);
      matching += SumAbsMasked(predicted, observations_[t], e->mask);
    }
    const auto e = Operator(t, t);
    e->op.Apply(latents_[t], &predicted);
    self = options_.lambda_s * SumAbsMasked(predicted, observations_[t], cv::Mat());
  } else {
    for (int s : neighbours_[t]) {
      const WarpLinearization lin = LinearizeWarp(camera_hr_, inverse_depth_[t], frames_[t].T_world_cam,
                                                  frames_[s].T_world_cam, latents_[s], nullptr);
      matching += SumAbsMasked(lin.warped, latents_[t], BaselineMask(t, s, lin.valid));
    }
  }
  const double image_tv = joint_ ? options_.image.lambda_i * TotalVariation(latents_[t]) : 0.0;
  const double depth_tv =
      options_.structure.lambda_d * DepthTv(inverse_depth_[t], edge_weight_[t], ParallaxScale());
  if (parts != nullptr) {
    parts->matching += matching;
    parts->self_consistency += self;
    parts->image_tv += image_tv;
    parts->depth_tv += depth_tv;
    parts->total += matching + self + image_tv + depth_tv;
  }
  return matching + self + image_tv + depth_tv;
}

// E of eq:energyFunction: the frames' parts, summed in frame order.
EnergyRecord WindowSolver::TotalEnergy(int iteration, const std::string& stage) {
  const double begin = NowMs();
  std::vector<EnergyRecord> parts(num_frames_);
  ForEachFrame([this, &parts](int t) { FrameEnergy(t, &parts[t]); });
  EnergyRecord record;
  record.iteration = iteration;
  record.stage = stage;
  for (const EnergyRecord& part : parts) {
    record.total += part.total;
    record.matching += part.matching;
    record.self_consistency += part.self_consistency;
    record.image_tv += part.image_tv;
    record.depth_tv += part.depth_tv;
  }
  timer_.AddSince("energy", begin);
  return record;
}

// Baseline matching at HR: visible, validly warped pixels of t.
cv::Mat WindowSolver::BaselineMask(int t, int s, const cv::Mat& valid) const {
  cv::Mat mask = VisibleFromSource(camera_hr_, frames_, t, s, options_.visibility);
  cv::bitwise_and(mask, valid, mask);
  return mask;
}

// Parallax scale: inverse depth in HR pixels of parallax per mean baseline.
double WindowSolver::ParallaxScale() const {
  double baseline = 0.0;
  for (int t = 1; t < num_frames_; ++t) {
    baseline += (frames_[t].T_world_cam.translation() - frames_[t - 1].T_world_cam.translation()).norm();
  }
  baseline /= (num_frames_ - 1);
  return camera_hr_.fx * std::max(baseline, 1e-9);
}

WindowSolver::Snapshot WindowSolver::TakeSnapshot() const {
  Snapshot snapshot;
  snapshot.latents = CloneAll(latents_);
  snapshot.inverse_depth = CloneAll(inverse_depth_);
  snapshot.edge_weight = CloneAll(edge_weight_);
  snapshot.T_world_cam.resize(num_frames_);
  for (int t = 0; t < num_frames_; ++t) snapshot.T_world_cam[t] = frames_[t].T_world_cam;
  return snapshot;
}

// Back to `snapshot` after an iteration that raised (or lost) the energy;
// records the restored energy and says so in the notes (`stop`: the
// iterations stop; else the iteration runs again without the re-sweep).
void WindowSolver::Undo(int iteration, const Snapshot& snapshot, bool stop) {
  latents_ = snapshot.latents;
  edge_weight_ = snapshot.edge_weight;
  for (int t = 0; t < num_frames_; ++t) {
    SetPose(t, snapshot.T_world_cam[t]);
    SetInverseDepth(t, snapshot.inverse_depth[t]);
  }
  const double rejected = result_.energies.back().total;
  EnergyRecord restored = TotalEnergy(iteration, "restored");
  result_.energies.push_back(restored);
  result_.notes.push_back("iteration " + std::to_string(iteration) +
                          (std::isfinite(rejected) ? " raised the energy" : " lost the energy (not finite)") +
                          (stop ? ": undone, iterations stopped"
                                : " from the re-swept depth: undone, run again from the solver's depth"));
}

// The time cap (options.max_seconds): true, with a note, once it is past.
bool WindowSolver::OutOfTime(int iterations_done) {
  if (options_.max_seconds <= 0.0 || (NowMs() - run_start_ms_) / 1000.0 <= options_.max_seconds) return false;
  result_.notes.push_back("time cap of " + std::to_string(options_.max_seconds) + " s reached after " +
                          std::to_string(iterations_done) + " iteration(s)");
  return true;
}

void WindowSolver::RequireFiniteEnergy(const char* where) const {
  if (!std::isfinite(result_.energies.back().total)) {
    throw EstimationDiverged(std::string("the energy is not finite ") + where);
  }
}

void WindowSolver::ThrowIfCancelled() const {
  if (cancel_ != nullptr && cancel_->load()) throw EstimationCancelled();
}

// Progress within the current phase (`within` in [0, 1]); also the point
// where a raised cancel flag stops the run.
void WindowSolver::Report(double within, const std::string& what) {
  ThrowIfCancelled();
  if (progress_) progress_(std::min(1.0, (steps_done_ + within) / total_steps_), what);
}

// Psi_t sampling I_source with its mask, from the cache.
std::shared_ptr<const OperatorCache::Entry> WindowSolver::Operator(int t, int source) {
  return cache_->Get(frames_, depth_version_, pose_version_, t, source, &timer_);
}

// The result in the output gauge (EstimatorOptions::keep_input_gauge);
// latent images clamped to [0, 1].
EstimatorResult WindowSolver::GaugedResult() {
  // Monocular scale: world = first camera, median scene depth of the window
  // 1 unit (docs/file_formats.md#monocular-scale), unless the input's gauge is kept.
  // The output depth maps, refined at their edges where asked, before the gauge's scale.
  std::vector<cv::Mat> depths = OutputDepths();
  RefineOutputDepthsDuringFramePass(&depths);
  // The consistency between neighbouring depth maps, on the result's
  // copies, before the gauge's scale: the published depth keeps the median
  // of 1 unit (so the poses' scale follows it, by a common factor); the
  // output images below are fused with the depth before it, so that they
  // are the same with and without it.
  const std::vector<cv::Mat> consistent = ConsistentOutputDepths(depths);
  SE3 T_first_world;
  double rescale = 1.0;
  if (!options_.keep_input_gauge) {
    T_first_world = frames_[0].T_world_cam.Inverse();
    const double median = MedianDepth(consistent);
    if (median > 0.0) rescale = 1.0 / median;
  }
  for (int t = 0; t < num_frames_; ++t) {
    if (options_.keep_input_gauge) {
      // Bit for bit (no re-orthonormalisation): the next window of a stream
      // holds these poses, and its operators match the ones built with them.
      result_.T_world_cam.push_back(frames_[t].T_world_cam);
    } else {
      const SE3 pose = T_first_world * frames_[t].T_world_cam;
      result_.T_world_cam.emplace_back(pose.rotation(), pose.translation() * rescale);
    }
    result_.depth.push_back(consistent[t] * rescale);
    result_.solver_depth.push_back(frames_[t].depth_hr * rescale);
  }
  for (const cv::Mat& latent : OutputLatents(depths)) {
    cv::Mat clamped;
    cv::min(cv::max(latent, 0.0), 1.0, clamped);
    result_.latent.push_back(clamped);
  }
  result_.timings = timer_.timings();
  result_.operators_reused = cache_->reused();
  if (options_.carried_frames > 0 && options_.keep_input_gauge) {
    result_.carried_operators = cache_->Carry(frames_, depth_version_, pose_version_,
                                              std::max(0, num_frames_ - options_.carried_frames));
  }
  return std::move(result_);
}

// EstimatorOptions::depth_consistency: the output depth maps `depths` made
// consistent with their neighbours' (FuseNeighbourDepths) at the solver's
// poses, on the result's copies (RefineOutputDepthEdges); a stream's held
// leading frames (given out with the previous window) keep theirs.
std::vector<cv::Mat> WindowSolver::ConsistentOutputDepths(const std::vector<cv::Mat>& depths) {
  if (options_.depth_consistency.radius <= 0) return depths;
  const double begin = NowMs();
  std::vector<SE3> T_world_cam;
  for (const FrameStructure& frame : frames_) T_world_cam.push_back(frame.T_world_cam);
  std::vector<cv::Mat> fused = FuseNeighbourDepths(camera_hr_, depths, T_world_cam, options_.depth_consistency);
  for (int t = 0; t < FirstRefinedOutput() && t < num_frames_; ++t) fused[t] = depths[t];
  timer_.AddSince("depth consistency", begin);
  return fused;
}

// The output images: the restored latents, fused across time in joint mode
// (EstimatorOptions::fusion), with the output depth maps `depths` and the
// solver's poses (one gauge for both).
std::vector<cv::Mat> WindowSolver::OutputLatents(const std::vector<cv::Mat>& depths) {
  if (!joint_ || options_.fusion.radius <= 0) return latents_;
  const double begin = NowMs();
  std::vector<SE3> T_world_cam;
  for (const FrameStructure& frame : frames_) T_world_cam.push_back(frame.T_world_cam);
  std::vector<cv::Mat> fused =
      FuseRestoredImages(camera_hr_, latents_, depths, T_world_cam, options_.fusion, options_.held_leading_latents);
  timer_.AddSince("temporal fusion", begin);
  return fused;
}

// The output depths through the edge-aware weighted median where that is
// on (RefineOutputDepthEdges), guided by the latent images before the
// multi-frame data pass, and in joint mode that pass
// (EstimatorOptions::multi_frame_data: each I_t, not the held leading ones,
// re-solved from its current value with its agreeing neighbours' matching
// terms raised towards lambda_s, MultiFrameDataOptions, and the denoised
// anchor where the noise asks for it, DenoisedAnchorOptions, with the
// solver's final depth and poses, which it does not change). The two do not
// read each other's results, so they run side by side: the weighted median
// runs one call at a time process-wide (RefineDepthEdges), so it is task 0,
// one thread's, frame after frame, while the other threads start the pass
// (task 1 + t: frame t); the median's guides are copies of the latents
// taken before the pass. Each result is the one of the two in sequence
// (the timer's "multi-frame data pass" now covers both).
void WindowSolver::RefineOutputDepthsDuringFramePass(std::vector<cv::Mat>* depths) {
  const bool refine = RefineOutputDepthEdges();
  const bool raise = joint_ && options_.multi_frame_data.relative_weight > 0.0;
  const bool anchor = joint_ && anchor_.active;
  const bool pass = raise || anchor;
  if (!refine && !pass) return;
  const double begin = NowMs();
  const std::vector<cv::Mat> guides = refine && pass ? CloneAll(latents_) : latents_;
  if (anchor && options_.denoised_anchor.denoiser == AnchorDenoiser::kTemporalFusion) {
    std::vector<cv::Mat> solver_depths;
    std::vector<SE3> T_world_cam;
    for (const FrameStructure& frame : frames_) {
      solver_depths.push_back(frame.depth_hr);
      T_world_cam.push_back(frame.T_world_cam);
    }
    TemporalFusionOptions fusion = options_.fusion;
    fusion.radius = options_.denoised_anchor.fusion_radius;
    anchor_images_ = FuseRestoredImages(camera_hr_, latents_, solver_depths, T_world_cam, fusion,
                                        options_.held_leading_latents);
  }
  ForEachTask(1 + num_frames_, [this, refine, raise, anchor, depths, &guides](int task) {
    if (task == 0) {
      for (int t = FirstRefinedOutput(); refine && t < num_frames_; ++t) {
        (*depths)[t] = (*depths)[t].clone();
        RefineDepthEdges(guides[t], options_.depth_edges, &(*depths)[t]);
      }
      return;
    }
    const int t = task - 1;
    const bool raised = raise && !(options_.multi_frame_data.skip_first_frame && t == 0);
    if ((raised || anchor) && t >= options_.held_leading_latents) UpdateLatentFromFrames(t, raised);
  });
  if (raise || anchor) timer_.AddSince("multi-frame data pass", begin);
}

// One I_t of the pass: the self term lambda_s of eq:imgUpdate and, for each
// neighbour s within multi_frame_data.radius, its matching term: with
// `raised`, at relative_weight x lambda_s (at least 1, eq:imgUpdate's weight)
// on the pixels that agree with Psi_s I_t (MultiFrameAgreementMask at the
// expected residual), B_0 with skip_first_frame keeping weight 1 where it is
// visible; without, at eq:imgUpdate's weight 1 where visible. With an active
// anchor (anchor_) the proximity term to z_t = NLM(I_t) is added
// (DenoisedAnchorOptions).
void WindowSolver::UpdateLatentFromFrames(int t, bool raised) {
  const MultiFrameDataOptions& pass = options_.multi_frame_data;
  const double expected = std::hypot(options_.model_error_sigma, std::max(options_.noise_sigma, 0.0));
  std::vector<LinearL1Term> terms;
  HeldOperators held;
  std::vector<cv::Mat> agreeing;
  agreeing.reserve(2 * pass.radius);
  cv::Mat predicted;
  for (int s : Neighbours(t, num_frames_, pass.radius)) {
    held.push_back(Operator(s, t));
    if (!raised || (pass.skip_first_frame && s == 0)) {  // eq:imgUpdate's weight
      terms.push_back({&held.back()->op, &observations_[s], held.back()->mask, 1.0});
      continue;
    }
    held.back()->op.Apply(latents_[t], &predicted);
    agreeing.push_back(MultiFrameAgreementMask(predicted, observations_[s], held.back()->mask,
                                               pass.agreement_scale * expected, pass.patch_px));
    // One term per neighbour: the disagreeing pixels are left out rather
    // than kept at weight 1 (1/30 of the self term's weight) in a second
    // term, which would stream the operator twice per product.
    terms.push_back({&held.back()->op, &observations_[s], agreeing.back(),
                     std::max(1.0, pass.relative_weight * options_.lambda_s)});
  }
  held.push_back(Operator(t, t));
  terms.push_back({&held.back()->op, &observations_[t], cv::Mat(), options_.lambda_s});
  ImageUpdateOptions image_options = options_.image;
  image_options.irls_iterations = pass.irls_iterations;
  image_options.cg_iterations = pass.cg_iterations;
  image_options.num_threads = 1;
  cv::Mat anchor_image;
  QuadraticAnchor anchor;
  if (joint_ && anchor_.active) {
    anchor_image = options_.denoised_anchor.denoiser == AnchorDenoiser::kTemporalFusion
                       ? anchor_images_[t]
                       : DenoisedAnchor(latents_[t], anchor_.h, options_.denoised_anchor);
    anchor = {&anchor_image, anchor_.weight};
  }
  const ImageUpdateStats stats = UpdateImage(terms, image_options, &latents_[t], &anchor);
  std::lock_guard<std::mutex> lock(work_mutex_);
  result_.image_work += stats;
}

// TemporalFusionOptions::between_updates: the restored images fused before
// each structure update (which then matches them, and the next image update
// starts from them), with the solver's current depth.
void WindowSolver::FuseBetweenUpdates() {
  if (!options_.fusion.between_updates || options_.fusion.radius <= 0) return;
  const double begin = NowMs();
  std::vector<cv::Mat> depths;
  std::vector<SE3> T_world_cam;
  for (const FrameStructure& frame : frames_) {
    depths.push_back(frame.depth_hr);
    T_world_cam.push_back(frame.T_world_cam);
  }
  latents_ =
      FuseRestoredImages(camera_hr_, latents_, depths, T_world_cam, options_.fusion, options_.held_leading_latents);
  for (int t = options_.held_leading_latents; t < num_frames_; ++t) UpdateEdgeWeight(t);
  timer_.AddSince("temporal fusion", begin);
}

// Counts, sizes and camera of RunFromStructure's input.
void CheckWindowCounts(const EstimatorInput& input, const std::vector<cv::Mat>& depth_hr,
                       const std::vector<SE3>& T_world_cam) {
  if (input.images.size() < 2) throw InputError("estimator: needs at least 2 frames");
  if (input.frames.size() != input.images.size() || depth_hr.size() != input.images.size() ||
      T_world_cam.size() != input.images.size()) {
    throw InputError("estimator: images, frames, depths and poses differ in number");
  }
  const std::string problem = input.camera.Problem();
  if (!problem.empty()) throw InputError("estimator: camera: " + problem);
  if (input.initial_latents.size() > input.images.size()) {
    throw InputError("estimator: more initial latent images than frames");
  }
  if (!std::isfinite(input.readout_time) || input.readout_time < 0.0) {
    throw InputError("estimator: readout_time must be finite and >= 0, got " +
                     std::to_string(input.readout_time));
  }
}

// Pixel types and finiteness of the frames, finiteness of the poses.
void CheckWindowValues(const EstimatorInput& input, const std::vector<SE3>& T_world_cam) {
  for (const cv::Mat& image : input.images) {
    if (image.depth() != CV_32F || image.cols != input.camera.width || image.rows != input.camera.height ||
        image.channels() != input.images[0].channels()) {
      throw InputError("estimator: every frame must be a float image of the camera size");
    }
    if (!cv::checkRange(image)) throw InputError("estimator: a frame has NaN or infinite pixels");
  }
  for (const SE3& pose : T_world_cam) {
    if (!pose.translation().allFinite() || !pose.rotation().allFinite()) {
      throw InputError("estimator: an initial pose is not finite");
    }
  }
}

// Frames the gain estimation can read (float, one size and channel count);
// others pass through uncompensated for the estimator to reject.
bool GainReadable(const EstimatorInput& input) {
  for (const cv::Mat& image : input.images) {
    if (image.empty() || image.depth() != CV_32F || image.size() != input.images[0].size() ||
        image.channels() != input.images[0].channels() || !cv::checkRange(image)) {
      return false;
    }
  }
  return !input.images.empty();
}

}  // namespace

// EstimatorOptions::input_denoising: the frames filtered (DenoiseInputFrames)
// at the strength the noise estimate asks for, then `run` on them without
// the stage; frames below its noise floor go to `run` as they are.
EstimatorResult Estimator::RunInputDenoised(const EstimatorInput& input, const InnerRun& run) const {
  EstimatorOptions inner = options_;
  inner.input_denoising.enabled = false;
  Estimator estimator(inner);
  estimator.SetCancelFlag(cancel_);
  const double start = NowMs();
  const double estimate = options_.noise_sigma >= 0.0 ? options_.noise_sigma : EstimateNoiseSigma(input.images);
  const double h = InputDenoisingStrength(options_.input_denoising, estimate);
  if (h <= 0.0) return run(&estimator, input);
  EstimatorInput denoised = input;
  denoised.images = DenoiseInputFrames(input.images, h, options_.input_denoising);
  const double denoise_seconds = (NowMs() - start) / 1000.0;
  EstimatorResult result = run(&estimator, denoised);
  result.input_denoising_h = h;
  result.timings.insert(result.timings.begin(), StageTiming{"input denoising", denoise_seconds});
  return result;
}

EstimatorResult Estimator::RunGainCompensated(const EstimatorInput& input, const InnerRun& run) const {
  EstimatorOptions inner = options_;
  inner.gain_compensation = false;
  const bool readable = GainReadable(input);
  // The noise is estimated on the frames as they came (EstimateNoiseSigma
  // reads the 8-bit quantisation steps, which dividing by a gain moves):
  // the divided frames read 20 % high at sigma 2 (2.40 for 2.0).
  if (inner.noise_sigma < 0.0 && readable) inner.noise_sigma = EstimateNoiseSigma(input.images);
  Estimator estimator(inner);
  estimator.SetCancelFlag(cancel_);
  if (!readable) return run(&estimator, input);
  const double start = NowMs();
  const std::vector<double> gains = EstimateFrameGains(input.images, options_.gain);
  EstimatorInput compensated = input;  // the images and the warm start follow
  compensated.images.clear();
  compensated.initial_latents.clear();
  for (size_t t = 0; t < gains.size(); ++t) compensated.images.push_back(input.images[t] * (1.0 / gains[t]));
  // A warm start has its frame's brightness, as the latent images given out.
  for (size_t t = 0; t < input.initial_latents.size() && t < gains.size(); ++t) {
    compensated.initial_latents.push_back(
        input.initial_latents[t].empty() ? cv::Mat() : input.initial_latents[t] * (1.0 / gains[t]));
  }
  const double gain_seconds = (NowMs() - start) / 1000.0;
  EstimatorResult result = run(&estimator, compensated);
  // The gt latent of a frame with gain g is g times the scene, clamped to 1.
  for (size_t t = 0; t < result.latent.size() && t < gains.size(); ++t) {
    // A held latent (held_leading_latents) is given back as it came, not
    // divided and multiplied by its gain (which would round it).
    if (static_cast<int>(t) < options_.held_leading_latents && t < input.initial_latents.size() &&
        !input.initial_latents[t].empty()) {
      result.latent[t] = input.initial_latents[t].clone();
      continue;
    }
    result.latent[t] *= gains[t];
    cv::min(result.latent[t], 1.0, result.latent[t]);
  }
  result.frame_gains = gains;
  result.timings.insert(result.timings.begin(), StageTiming{"gain estimation", gain_seconds});
  return result;
}

const char* ToString(EstimatorMode mode) {
  return mode == EstimatorMode::kJoint ? "joint" : "baseline";
}

const char* ToString(StructureMatching matching) {
  switch (matching) {
    case StructureMatching::kBlurred:
      return "blurred";
    case StructureMatching::kRestored:
      return "restored";
    case StructureMatching::kRestoredAndInput:
      return "both";
  }
  return "?";
}

StructureMatching ParseStructureMatching(const std::string& text) {
  if (text == "blurred") return StructureMatching::kBlurred;
  if (text == "restored") return StructureMatching::kRestored;
  if (text == "both") return StructureMatching::kRestoredAndInput;
  throw InputError("structure matching must be 'both', 'restored' or 'blurred', got '" + text + "'");
}

EstimatorMode ParseEstimatorMode(const std::string& text) {
  if (text == "joint") return EstimatorMode::kJoint;
  if (text == "baseline") return EstimatorMode::kBaseline;
  throw InputError("mode must be 'joint' or 'baseline', got '" + text + "'");
}

// The names are those of the node's parameters and the tools' flags.
void EstimatorOptions::Check() const {
  CheckInRange("scale", scale, 1, 4);
  CheckInRange("samples", samples, 1, 1000);
  CheckInRange("iterations", max_iterations, 0, 100);
  CheckInRange("neighbour_radius", neighbour_radius, 1, 5);
  CheckInRange("pose_neighbour_radius", pose_neighbour_radius, 1, 5);
  CheckAtLeast("lambda_s", lambda_s, 0.0);
  CheckAtLeast("threads", num_threads, 0);
  CheckAtLeast("fixed_leading_poses", fixed_leading_poses, 1);
  CheckAtLeast("held_leading_latents", held_leading_latents, 0);
  CheckInRange("recentred_depth_passes", recentred_depth_passes, 1, 10);
  CheckInRange("recentred_depth_cg_iterations", recentred_depth_cg_iterations, 1, 1000);
  CheckInRange("recentred_depth_cg_tolerance", recentred_depth_cg_tolerance, 0.0, 1.0);
  CheckAtLeast("carried_frames", carried_frames, 0);
  CheckInRange("continued_joint_irls_iterations", continued_joint_irls_iterations, 0, 20);
  CheckInRange("continued_joint_cg_iterations", continued_joint_cg_iterations, 0, 1000);
  CheckInRange("continued_pose_iterations", continued_pose_iterations, 0, 100);
  CheckInRange("continued_max_iterations", continued_max_iterations, -1, 100);
  CheckInRange("continued_recentred_depth_passes", continued_recentred_depth_passes, 0, 10);
  CheckAtLeast("max_seconds", max_seconds, 0.0);
  CheckAbove("pose_prior_weight", pose_prior_weight, 0.0);
  CheckAtLeast("track_pose_weight", track_pose_weight, 0.0);
  CheckAbove("track_pose_sigma_px", track_pose_sigma_px, 0.0);
  CheckAtLeast("track_pose_gate_start", track_pose_gate_start, 0.0);
  CheckAbove("track_pose_gate_width", track_pose_gate_width, 0.0);
  CheckInRange("equal_blur_tolerance_px", equal_blur_tolerance_px, 0.0, 1000.0);
  CheckInRange("unequal_blur_tolerance_px", unequal_blur_tolerance_px, 0.0, 1000.0);
  CheckInRange("equal_blur_input_weight", equal_blur_input_weight, 0.0, 100.0);
  if (equal_blur_tolerance_px > 0.0 && unequal_blur_tolerance_px > 0.0 &&
      !(unequal_blur_tolerance_px > equal_blur_tolerance_px)) {
    throw InputError("unequal_blur_tolerance_px must exceed equal_blur_tolerance_px when both are on, got " +
                     std::to_string(unequal_blur_tolerance_px) + " and " +
                     std::to_string(equal_blur_tolerance_px));
  }
  CheckInRange("model_error_sigma", model_error_sigma, 1e-6, 1.0);
  if (noise_sigma > 1.0) throw InputError("noise_sigma must be <= 1 (intensity units; negative: auto)");
  gain.Check();
  image.Check();
  structure.Check();
  visibility.Check();
  initializer.Check();
  depth_edges.Check();
  fusion.Check();
  depth_consistency.Check();
  multi_frame_data.Check();
  denoised_anchor.Check();
  input_denoising.Check();
  depth_sweep.Check();
}

Estimator::Estimator(const EstimatorOptions& options) : options_(options) {
  options_.Check();
}

const char kNoParallaxNote[] =
    "no parallax: depth not observable (a rotation explains the motion: the images are restored with "
    "depth at infinity, the cameras keep one translation, depth is NaN)";

double MedianDepth(const std::vector<cv::Mat>& depths) {
  std::vector<float> values;
  for (const cv::Mat& depth : depths) {
    CV_Assert(depth.type() == CV_32FC1);
    for (int y = 0; y < depth.rows; ++y) {
      const float* row = depth.ptr<float>(y);
      for (int x = 0; x < depth.cols; ++x) {
        if (std::isfinite(row[x]) && row[x] > 0.0f) values.push_back(row[x]);
      }
    }
  }
  if (values.empty()) return 0.0;
  const auto middle = values.begin() + values.size() / 2;
  std::nth_element(values.begin(), middle, values.end());
  return *middle;
}

std::vector<cv::Mat> UpsampleInitialDepth(const std::vector<cv::Mat>& depth_lr, int scale) {
  std::vector<cv::Mat> depth_hr;
  for (const cv::Mat& depth : depth_lr) {
    depth_hr.push_back(DepthFromInverse(UpsampleBicubic(InverseDepthFromDepth(depth), scale)));
  }
  return depth_hr;
}

// Algorithm 1 (alg:optimization): D_t and P_t initialised by
// eq:initializationScene, then the main loop from that structure. Without
// parallax, the images of the rotation-only motion (RunRotationOnly).
EstimatorResult Estimator::Run(const EstimatorInput& input, const ProgressCallback& progress) {
  if (options_.gain_compensation) {
    return RunGainCompensated(input,
                              [&](Estimator* e, const EstimatorInput& in) { return e->Run(in, progress); });
  }
  if (options_.input_denoising.enabled) {
    return RunInputDenoised(input, [&](Estimator* e, const EstimatorInput& in) { return e->Run(in, progress); });
  }
  const double start = NowMs();
  if (progress) progress(0.0, "initialisation");
  InitializerOptions init_options = options_.initializer;
  init_options.num_threads = options_.num_threads;
  InitialStructure initial;
  try {
    initial = InitializeStructure(input.images, input.camera, input.frames, init_options, input.readout_time,
                                  input.T_prior_cam);
  } catch (const NoParallaxError& no_parallax) {
    const RotationOnlyMotion motion =
        EstimateRotationOnlyMotion(input.images, input.camera, input.frames, init_options);
    ThrowIfCancelled();
    std::vector<SE3> T_world_cam;
    for (const Eigen::Matrix3d& R_world_cam : motion.R_world_cam)
      T_world_cam.emplace_back(R_world_cam, Eigen::Vector3d::Zero());
    const double init_seconds = (NowMs() - start) / 1000.0;
    EstimatorResult result = RunRotationOnly(input, T_world_cam, progress);
    result.timings.insert(result.timings.begin(), StageTiming{"initialization", init_seconds});
    result.initializer_summary = std::string(no_parallax.what()) + "\n" + motion.summary;
    return result;
  }
  ThrowIfCancelled();
  const std::vector<cv::Mat> depth_hr = UpsampleInitialDepth(initial.depth_lr, options_.scale);
  const double init_seconds = (NowMs() - start) / 1000.0;
  EstimatorInput tracked = input;
  tracked.tracks = std::move(initial.tracks);
  EstimatorResult result = RunFromStructure(tracked, depth_hr, initial.T_world_cam, progress);
  result.timings.insert(result.timings.begin(), StageTiming{"initialization", init_seconds});
  result.initializer_summary = initial.summary;
  return result;
}

EstimatorResult Estimator::RunRotationOnly(const EstimatorInput& input, const std::vector<SE3>& T_world_cam,
                                           const ProgressCallback& progress) {
  if (options_.gain_compensation) {
    return RunGainCompensated(input, [&](Estimator* e, const EstimatorInput& in) {
      return e->RunRotationOnly(in, T_world_cam, progress);
    });
  }
  if (T_world_cam.empty()) throw InputError("estimator: no poses for the rotation-only window");
  // One translation for every camera: the warps and the rotation path of
  // the capture operator (eq:interpolatingP) are then homographies, whatever
  // the depth (here 1 unit everywhere, the median-depth gauge).
  std::vector<SE3> held;
  for (const SE3& pose : T_world_cam) held.emplace_back(pose.rotation(), T_world_cam[0].translation());
  const PinholeCamera camera_hr = input.camera.Upscaled(options_.scale);
  const cv::Size hr_size(camera_hr.width, camera_hr.height);
  const std::vector<cv::Mat> unit_depth(T_world_cam.size(), cv::Mat(hr_size, CV_32FC1, cv::Scalar(1.0f)));
  EstimatorOptions images_only = options_;
  images_only.update_structure = false;
  images_only.keep_input_gauge = true;
  // No depth to refine: the output depth is NaN below.
  images_only.depth_sweep.on_output = false;
  images_only.depth_edges.on_output = false;
  images_only.depth_consistency.radius = 0;
  Estimator estimator(images_only);
  estimator.SetCancelFlag(cancel_);
  EstimatorResult result = estimator.RunFromStructure(input, unit_depth, held, progress);
  for (cv::Mat& depth : result.depth) depth.setTo(std::numeric_limits<float>::quiet_NaN());
  result.solver_depth.clear();
  result.depth_observable = false;
  result.notes.push_back(kNoParallaxNote);
  return result;
}

EstimatorResult Estimator::RunFromStructure(const EstimatorInput& input, const std::vector<cv::Mat>& depth_hr,
                                            const std::vector<SE3>& T_world_cam,
                                            const ProgressCallback& progress) {
  if (options_.gain_compensation) {
    return RunGainCompensated(input, [&](Estimator* e, const EstimatorInput& in) {
      return e->RunFromStructure(in, depth_hr, T_world_cam, progress);
    });
  }
  CheckWindowCounts(input, depth_hr, T_world_cam);
  for (int t = 0; t < options_.held_leading_latents && t < static_cast<int>(input.images.size()); ++t) {
    if (static_cast<size_t>(t) >= input.initial_latents.size() || input.initial_latents[t].empty()) {
      throw InputError(
          "estimator: every held leading latent image (held_leading_latents) needs an initial latent image");
    }
  }
  const int threads = ResolveThreads(options_.num_threads);
  omp_set_num_threads(threads);
  CheckWindowValues(input, T_world_cam);
  EstimatorOptions noise_aware = options_;
  const double noise_sigma =
      options_.noise_sigma >= 0.0 ? options_.noise_sigma : EstimateNoiseSigma(input.images);
  noise_aware.image = NoiseAwareImageOptions(options_, noise_sigma);
  noise_aware.noise_sigma = noise_sigma;  // the multi-frame data pass's agreement threshold
  WindowSolver solver(noise_aware, threads, input, depth_hr, T_world_cam, cancel_, progress);
  EstimatorResult result = solver.Solve();
  result.noise_sigma = noise_sigma;
  result.image_lambda_i = noise_aware.image.lambda_i;
  return result;
}

ImageUpdateOptions NoiseAwareImageOptions(const EstimatorOptions& options, double noise_sigma) {
  ImageUpdateOptions image = options.image;
  const double relative = std::max(noise_sigma, 0.0) / options.model_error_sigma;
  image.lambda_i *= std::sqrt(1.0 + relative * relative);
  return image;
}

}  // namespace deblur_sr_mvs
