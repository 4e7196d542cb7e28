#include "deblur_sr_mvs/core/estimation/estimator.h"

#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <exception>
#include <functional>
#include <list>
#include <map>
#include <memory>
#include <mutex>

#include <opencv2/imgproc.hpp>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/estimation/frame_structure.h"
#include "deblur_sr_mvs/core/imaging/image_ops.h"

namespace deblur_sr_mvs {
namespace {

double Now() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

// Accumulates wall time per named stage, in first-seen order.
class Timer {
 public:
  void Add(const std::string& stage, double seconds) {
    std::lock_guard<std::mutex> lock(mutex_);
    for (StageTiming& t : timings_) {
      if (t.stage == stage) {
        t.seconds += seconds;
        return;
      }
    }
    timings_.push_back({stage, seconds});
  }
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

// Gray image in [0, 1] for edge weights.
cv::Mat EdgeWeightOf(const cv::Mat& latent, const EdgeWeightOptions& options) {
  return EdgeWeight(latent, options);
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

// Operators Psi_t[src] and their visibility masks, rebuilt only when the
// structure they depend on (D_t, P_t, P_neighbour(t), P_src) changed. Memory
// is bounded: the least recently used entries go first.
class OperatorCache {
 public:
  struct Entry {
    CaptureOperator op;
    cv::Mat mask;  // LR CV_8UC1: Omega_{t,src} and full coverage
    std::vector<long> versions;
  };

  // One builder (scratch buffers) per thread: Get may be called from the
  // threads of a parallel loop over frames, each building its own operators.
  OperatorCache(const CaptureOperatorOptions& options, int threads, const PinholeCamera& camera_hr,
                const VisibilityOptions& visibility, size_t max_bytes)
      : camera_hr_(camera_hr), visibility_(visibility), max_bytes_(max_bytes) {
    for (int i = 0; i < threads; ++i) builders_.emplace_back(options);
  }

  // Callers hold the returned pointer while they use the operator: eviction
  // only drops the cache's reference.
  std::shared_ptr<const Entry> Get(const std::vector<FrameStructure>& frames, const std::vector<long>& depth_version,
                   const std::vector<long>& pose_version, int t, int source, Timer* timer) {
    const int neighbour = t > 0 ? t - 1 : t + 1;
    const std::vector<long> versions = {depth_version[t], pose_version[t], pose_version[neighbour],
                                        pose_version[source]};
    const auto key = std::make_pair(t, source);
    {
      std::lock_guard<std::mutex> lock(mutex_);
      auto it = entries_.find(key);
      if (it != entries_.end() && it->second->versions == versions) {
        Touch(key);
        return it->second;
      }
    }
    const double start = Now();
    auto entry = std::make_shared<Entry>();
    const size_t thread = std::min<size_t>(omp_get_thread_num(), builders_.size() - 1);
    builders_[thread].Build(MakeCaptureGeometry(frames, camera_hr_, t, source), &entry->op);
    entry->versions = versions;
    const cv::Size lr = entry->op.lr_size();
    entry->mask = cv::Mat(lr, CV_8UC1);
    const std::vector<float>& coverage = entry->op.coverage();
    for (int i = 0; i < lr.area(); ++i) entry->mask.ptr<uchar>()[i] = coverage[i] >= 1.0f ? 255 : 0;
    if (source != t) {
      const SE3 T_s_t = frames[source].T_world_cam.Inverse() * frames[t].T_world_cam;
      const cv::Mat visible = DownscaleMaskAll(
          ComputeVisibility(camera_hr_, frames[t].depth_hr, T_s_t, visibility_),
          camera_hr_.width / lr.width);
      cv::bitwise_and(entry->mask, visible, entry->mask);
    }
    timer->Add("operator builds (thread seconds)", Now() - start);
    std::lock_guard<std::mutex> lock(mutex_);
    auto it = entries_.find(key);
    if (it != entries_.end()) {
      bytes_ -= Bytes(*it->second);
      it->second = entry;
    } else {
      entries_[key] = entry;
    }
    bytes_ += Bytes(*entry);
    Touch(key);
    Evict(key);
    return entry;
  }

 private:
  static size_t Bytes(const Entry& e) {
    return static_cast<size_t>(e.op.matrix().nonZeros()) * 8 + e.mask.total();
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
        bytes_ -= Bytes(*it->second);
        entries_.erase(it);
      }
    }
  }

  std::vector<CaptureOperatorBuilder> builders_;
  std::mutex mutex_;
  PinholeCamera camera_hr_;
  VisibilityOptions visibility_;
  size_t max_bytes_;
  size_t bytes_ = 0;
  std::map<std::pair<int, int>, std::shared_ptr<Entry>> entries_;
  std::list<std::pair<int, int>> order_;
};

}  // namespace

const char* ToString(EstimatorMode mode) {
  return mode == EstimatorMode::kJoint ? "joint" : "baseline";
}

const char* ToString(StructureMatching matching) {
  switch (matching) {
    case StructureMatching::kBlurred: return "blurred";
    case StructureMatching::kRestored: return "restored";
    case StructureMatching::kRestoredAndInput: return "both";
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

void EstimatorOptions::Check() const {
  if (scale < 1 || scale > 4) throw InputError("scale must be in [1, 4], got " + std::to_string(scale));
  if (samples < 1 || samples > 1000) throw InputError("samples must be in [1, 1000], got " + std::to_string(samples));
  if (max_iterations < 0 || max_iterations > 100) throw InputError("iterations must be in [0, 100]");
  if (neighbour_radius < 1 || neighbour_radius > 5) throw InputError("neighbour_radius must be in [1, 5]");
  if (pose_neighbour_radius < 1 || pose_neighbour_radius > 5) {
    throw InputError("pose_neighbour_radius must be in [1, 5]");
  }
  if (!(lambda_s >= 0.0) || !std::isfinite(lambda_s)) throw InputError("lambda_s must be >= 0");
  if (num_threads < 0) throw InputError("threads must be >= 0");
  if (fixed_leading_poses < 1) throw InputError("fixed_leading_poses must be >= 1");
  if (!(max_seconds >= 0.0) || !std::isfinite(max_seconds)) throw InputError("max_seconds must be >= 0");
  image.Check();
  structure.Check();
  visibility.Check();
  initializer.Check();
}

Estimator::Estimator(const EstimatorOptions& options) : options_(options) { options_.Check(); }

std::vector<cv::Mat> UpsampleInitialDepth(const std::vector<cv::Mat>& depth_lr, int scale) {
  std::vector<cv::Mat> depth_hr;
  for (const cv::Mat& depth : depth_lr) {
    depth_hr.push_back(DepthFromInverse(UpsampleBicubic(InverseDepthFromDepth(depth), scale)));
  }
  return depth_hr;
}

EstimatorResult Estimator::Run(const EstimatorInput& input, const ProgressCallback& progress) {
  const double start = Now();
  if (progress) progress(0.0, "initialisation");
  InitializerOptions init_options = options_.initializer;
  init_options.num_threads = options_.num_threads;
  const InitialStructure initial =
      InitializeStructure(input.images, input.camera, input.frames, init_options);
  ThrowIfCancelled();
  const std::vector<cv::Mat> depth_hr = UpsampleInitialDepth(initial.depth_lr, options_.scale);
  const double init_seconds = Now() - start;
  EstimatorResult result = RunFromStructure(input, depth_hr, initial.T_world_cam, progress);
  result.timings.insert(result.timings.begin(), StageTiming{"initialization", init_seconds});
  result.initializer_summary = initial.summary;
  return result;
}

EstimatorResult Estimator::RunFromStructure(const EstimatorInput& input,
                                            const std::vector<cv::Mat>& depth_hr_in,
                                            const std::vector<SE3>& T_world_cam_in,
                                            const ProgressCallback& progress) {
  const int num_frames = static_cast<int>(input.images.size());
  if (num_frames < 2) throw InputError("estimator: needs at least 2 frames");
  if (input.frames.size() != input.images.size() || depth_hr_in.size() != input.images.size() ||
      T_world_cam_in.size() != input.images.size()) {
    throw InputError("estimator: images, frames, depths and poses differ in number");
  }
  {
    const std::string problem = input.camera.Problem();
    if (!problem.empty()) throw InputError("estimator: camera: " + problem);
  }
  const int scale = options_.scale;
  const bool joint = options_.mode == EstimatorMode::kJoint;
  const PinholeCamera camera_hr = input.camera.Upscaled(scale);
  const int threads = options_.num_threads > 0 ? options_.num_threads : omp_get_max_threads();
  omp_set_num_threads(threads);
  for (const cv::Mat& image : input.images) {
    if (image.depth() != CV_32F || image.cols != input.camera.width || image.rows != input.camera.height ||
        image.channels() != input.images[0].channels()) {
      throw InputError("estimator: every frame must be a float image of the camera size");
    }
    if (!cv::checkRange(image)) throw InputError("estimator: a frame has NaN or infinite pixels");
  }
  for (const SE3& pose : T_world_cam_in) {
    if (!pose.translation().allFinite() || !pose.rotation().allFinite()) {
      throw InputError("estimator: an initial pose is not finite");
    }
  }

  Timer timer;
  EstimatorResult result;
  result.camera_hr = camera_hr;

  // State: latent images, frame structure, inverse depths, edge weights.
  std::vector<cv::Mat> observations(num_frames), bicubic(num_frames), latents(num_frames);
  std::vector<FrameStructure> frames(num_frames);
  std::vector<cv::Mat> inverse_depth(num_frames), edge_weight(num_frames);
  std::vector<long> depth_version(num_frames, 0), pose_version(num_frames, 0);
  for (int t = 0; t < num_frames; ++t) {
    observations[t] = input.images[t].isContinuous() ? input.images[t] : input.images[t].clone();
    bicubic[t] = UpsampleBicubic(observations[t], scale);
    latents[t] = bicubic[t].clone();
    frames[t].stamp = input.frames[t].stamp;
    frames[t].exposure = input.frames[t].exposure;
    frames[t].T_world_cam = T_world_cam_in[t];
    if (depth_hr_in[t].type() != CV_32FC1 || depth_hr_in[t].size() != cv::Size(camera_hr.width, camera_hr.height)) {
      throw InputError("estimator: depth maps must be CV_32FC1 of the HR size");
    }
    inverse_depth[t] = InverseDepthFromDepth(depth_hr_in[t]);
    frames[t].depth_hr = DepthFromInverse(inverse_depth[t]);
    edge_weight[t] = EdgeWeightOf(latents[t], options_.structure.edge_weight);
  }
  // Parallax scale: inverse depth in HR pixels of parallax per mean baseline.
  auto parallax_scale = [&]() {
    double baseline = 0.0;
    for (int t = 1; t < num_frames; ++t) {
      baseline += (frames[t].T_world_cam.translation() - frames[t - 1].T_world_cam.translation()).norm();
    }
    baseline /= (num_frames - 1);
    return camera_hr.fx * std::max(baseline, 1e-9);
  };

  CaptureOperatorOptions op_options;
  op_options.samples = options_.samples;
  op_options.scale = scale;
  // The estimator parallelises over frames (no barriers inside a frame's
  // work, which matters when the cores are shared); every operator runs on
  // the thread that uses it.
  op_options.num_threads = 1;
  op_options.transposed_copy = false;  // half the memory, same speed on one thread
  omp_set_max_active_levels(1);
  // Every operator of a 10-frame 640x480 window (30 operators of ~38 MiB)
  // fits; larger windows evict the least recently used ones and rebuild them,
  // which keeps the peak memory bounded.
  OperatorCache cache(op_options, threads, camera_hr, options_.visibility, size_t(3) << 29);

  // Runs body(t) for every frame on `threads` threads; the first exception
  // thrown by any frame is rethrown here (exceptions must not leave an
  // OpenMP region).
  auto for_each_frame = [&](const std::function<void(int)>& body) {
    std::exception_ptr error;
    std::mutex error_mutex;
#pragma omp parallel for schedule(dynamic, 1) num_threads(threads)
    for (int t = 0; t < num_frames; ++t) {
      try {
        ThrowIfCancelled();
        body(t);
      } catch (...) {
        std::lock_guard<std::mutex> lock(error_mutex);
        if (!error) error = std::current_exception();
      }
    }
    if (error) std::rethrow_exception(error);
  };

  const std::vector<std::vector<int>> neighbours = [&] {
    std::vector<std::vector<int>> n(num_frames);
    for (int t = 0; t < num_frames; ++t) n[t] = Neighbours(t, num_frames, options_.neighbour_radius);
    return n;
  }();

  // Baseline matching at HR: visible, validly warped pixels of t.
  auto baseline_mask = [&](int t, int s, const cv::Mat& valid) {
    const SE3 T_s_t = frames[s].T_world_cam.Inverse() * frames[t].T_world_cam;
    cv::Mat mask = ComputeVisibility(camera_hr, frames[t].depth_hr, T_s_t, options_.visibility);
    cv::bitwise_and(mask, valid, mask);
    return mask;
  };

  // E_t (eq:energyFunctiont) of one frame at the current state.
  auto frame_energy = [&](int t, EnergyRecord* parts) {
    double matching = 0.0, self = 0.0;
    cv::Mat predicted;
    if (joint) {
      for (int s : neighbours[t]) {
        const auto e = cache.Get(frames, depth_version, pose_version, t, s, &timer);
        e->op.Apply(latents[s], &predicted);
        matching += SumAbsMasked(predicted, observations[t], e->mask);
      }
      const auto e = cache.Get(frames, depth_version, pose_version, t, t, &timer);
      e->op.Apply(latents[t], &predicted);
      self = options_.lambda_s * SumAbsMasked(predicted, observations[t], cv::Mat());
    } else {
      for (int s : neighbours[t]) {
        const WarpLinearization lin = LinearizeWarp(camera_hr, inverse_depth[t], frames[t].T_world_cam,
                                                    frames[s].T_world_cam, latents[s], nullptr);
        matching += SumAbsMasked(lin.warped, latents[t], baseline_mask(t, s, lin.valid));
      }
    }
    const double image_tv = joint ? options_.image.lambda_i * TotalVariation(latents[t]) : 0.0;
    const double depth_tv =
        options_.structure.lambda_d * DepthTv(inverse_depth[t], edge_weight[t], parallax_scale());
    if (parts != nullptr) {
      parts->matching += matching;
      parts->self_consistency += self;
      parts->image_tv += image_tv;
      parts->depth_tv += depth_tv;
      parts->total += matching + self + image_tv + depth_tv;
    }
    return matching + self + image_tv + depth_tv;
  };
  auto total_energy = [&](int iteration, const std::string& stage) {
    const double begin = Now();
    std::vector<EnergyRecord> parts(num_frames);
    for_each_frame([&](int t) { frame_energy(t, &parts[t]); });
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
    timer.Add("energy", Now() - begin);
    return record;
  };

  const double run_start = Now();
  auto out_of_time = [&](int iterations_done) {
    if (options_.max_seconds <= 0.0 || Now() - run_start <= options_.max_seconds) return false;
    result.notes.push_back("time cap of " + std::to_string(options_.max_seconds) + " s reached after " +
                           std::to_string(iterations_done) + " iteration(s)");
    return true;
  };
  auto require_finite = [&](const char* where) {
    if (!std::isfinite(result.energies.back().total)) {
      throw EstimationDiverged(std::string("the energy is not finite ") + where);
    }
  };
  result.energies.push_back(total_energy(0, "initialization"));
  require_finite("at the initial structure");
  const int total_steps = std::max(1, 2 * options_.max_iterations + 1);
  int steps_done = 0;
  auto report = [&](double within, const std::string& what) {
    ThrowIfCancelled();
    if (progress) progress(std::min(1.0, (steps_done + within) / total_steps), what);
  };

  // ---- Phase 1: latent images (eq:imgUpdate), one frame at a time.
  auto image_phase = [&](int iteration) {
    const double begin = Now();
    for_each_frame([&](int t) {
      if (omp_get_thread_num() == 0) {
        report(double(t) / num_frames, "iteration " + std::to_string(iteration) + ": image " + std::to_string(t));
      }
      std::vector<LinearL1Term> terms;
      std::vector<std::shared_ptr<const OperatorCache::Entry>> held;
      for (int s : neighbours[t]) {
        held.push_back(cache.Get(frames, depth_version, pose_version, s, t, &timer));
        terms.push_back({&held.back()->op, &observations[s], held.back()->mask, 1.0});
      }
      held.push_back(cache.Get(frames, depth_version, pose_version, t, t, &timer));
      terms.push_back({&held.back()->op, &observations[t], cv::Mat(), options_.lambda_s});
      ImageUpdateOptions image_options = options_.image;
      image_options.num_threads = 1;
      UpdateImage(terms, image_options, &latents[t]);
      edge_weight[t] = EdgeWeightOf(latents[t], options_.structure.edge_weight);
    });
    ++steps_done;
    timer.Add("image update (incl. operator builds)", Now() - begin);
    result.energies.push_back(total_energy(iteration, "image"));
  };

  // ---- Phase 2: depths and poses (eq:taylorExpansion, eq:updateVariables).
  // With `isolated` (baseline: the images are fixed) each depth map and the
  // pose update is kept only if it lowers the energy on its own. In joint
  // mode the latent images were fitted to the old structure, so a step
  // towards the true structure can raise the energy until the images follow:
  // the caller judges the structure update after the next image update.
  auto structure_phase = [&](int iteration, bool isolated) {
    const double begin = Now();
    StructureUpdateOptions structure_options = options_.structure;
    structure_options.num_threads = threads;
    std::vector<SE3> poses(num_frames);
    for (int t = 0; t < num_frames; ++t) poses[t] = frames[t].T_world_cam;
    // The pairs (t <- s) of frame t with s in `sources`; `held` keeps their
    // operators alive.
    const bool blurred_matching = joint && options_.structure_matching == StructureMatching::kBlurred;
    const bool input_matching = joint && options_.structure_matching == StructureMatching::kRestoredAndInput;
    auto pairs_of = [&](int t, const std::vector<int>& sources, std::vector<PairMatching>* pairs,
                        std::vector<std::shared_ptr<const OperatorCache::Entry>>* held) {
      for (int s : sources) {
        PairMatching pair;
        pair.t = t;
        pair.s = s;
        if (blurred_matching) {
          held->push_back(cache.Get(frames, depth_version, pose_version, t, s, &timer));
          pair.mask = held->back()->mask;
          held->push_back(cache.Get(frames, depth_version, pose_version, t, t, &timer));
          pair.blur = &held->back()->op;
          pair.observation = &observations[t];
          pairs->push_back(pair);
          continue;
        }
        // Restored (or, in the baseline, bicubic) HR images of t and s.
        pair.observation = &latents[t];
        const SE3 T_s_t = frames[s].T_world_cam.Inverse() * frames[t].T_world_cam;
        pair.mask = ComputeVisibility(camera_hr, frames[t].depth_hr, T_s_t, options_.visibility);
        pairs->push_back(pair);
        if (input_matching) {
          // The same pair on the up-sampled inputs, which do not depend on
          // the current structure (see StructureMatching).
          pair.observation = &bicubic[t];
          pair.source = &bicubic[s];
          pairs->push_back(pair);
        }
      }
    };
    // Pose pairs reach further than N(t) (longer baselines); the blurred
    // form needs the operators of N(t) only.
    const int pose_radius = blurred_matching ? options_.neighbour_radius
                                             : std::max(options_.neighbour_radius, options_.pose_neighbour_radius);
    for_each_frame([&](int t) {
      if (omp_get_thread_num() == 0) {
        report(double(t) / (num_frames + 1),
               "iteration " + std::to_string(iteration) + ": structure " + std::to_string(t));
      }
      const double before = isolated ? frame_energy(t, nullptr) : 0.0;
      const cv::Mat saved = inverse_depth[t].clone();
      std::vector<PairMatching> pairs;
      std::vector<std::shared_ptr<const OperatorCache::Entry>> held;
      pairs_of(t, neighbours[t], &pairs, &held);
      SelfConsistencyLinearization self;
      if (blurred_matching) {
        const auto self_op = cache.Get(frames, depth_version, pose_version, t, t, &timer);
        self.observation = &observations[t];
        self_op->op.Apply(latents[t], &self.predicted);
        self.derivative = BlurDerivativeWrtInverseDepth(
            MakeCaptureGeometry(frames, camera_hr, t, t), options_.samples, inverse_depth[t],
            latents[t], /*max_samples=*/10);
        self.weight = options_.lambda_s;
        self.scale = scale;
      }
      const double depth_begin = Now();
      UpdateDepth(camera_hr, poses, latents, pairs, blurred_matching ? &self : nullptr, edge_weight[t],
                  parallax_scale(), structure_options, &inverse_depth[t]);
      timer.Add("depth updates (thread seconds)", Now() - depth_begin);
      frames[t].depth_hr = DepthFromInverse(inverse_depth[t]);
      ++depth_version[t];
      if (isolated && !(frame_energy(t, nullptr) <= before)) {
        inverse_depth[t] = saved;  // the surrogate step did not pay: keep D_t
        frames[t].depth_hr = DepthFromInverse(saved);
        ++depth_version[t];
      }
    });
    if (options_.update_poses) {
      report(double(num_frames) / (num_frames + 1), "iteration " + std::to_string(iteration) + ": poses");
      const double before = isolated ? total_energy(iteration, "structure").total : 0.0;
      std::vector<PairMatching> pairs;
      std::vector<std::shared_ptr<const OperatorCache::Entry>> held;
      for (int t = 0; t < num_frames; ++t) pairs_of(t, Neighbours(t, num_frames, pose_radius), &pairs, &held);
      std::vector<SE3> updated = poses;
      const double pose_begin = Now();
      UpdatePoses(camera_hr, inverse_depth, latents, pairs, structure_options, &updated,
                  options_.fixed_leading_poses);
      timer.Add("pose updates", Now() - pose_begin);
      for (int t = 1; t < num_frames; ++t) {
        frames[t].T_world_cam = updated[t];
        ++pose_version[t];
      }
      if (isolated && !(total_energy(iteration, "structure").total <= before)) {
        for (int t = 1; t < num_frames; ++t) {
          frames[t].T_world_cam = poses[t];
          ++pose_version[t];
        }
      }
    }
    ++steps_done;
    timer.Add("structure update", Now() - begin);
    result.energies.push_back(total_energy(iteration, "structure"));
  };

  if (!joint) {
    for (int iteration = 1; iteration <= options_.max_iterations && options_.update_structure; ++iteration) {
      if (out_of_time(iteration - 1)) break;
      structure_phase(iteration, /*isolated=*/true);
    }
  } else if (!options_.update_structure) {
    for (int iteration = 1; iteration <= options_.max_iterations; ++iteration) {
      if (out_of_time(iteration - 1)) break;
      image_phase(iteration);
    }
  } else if (options_.max_iterations > 0) {
    // Algorithm 1: image update, then max_iter times structure update followed
    // by the image update that judges it (the last one gives the output
    // images that match the final structure). A structure update whose
    // following image update does not lower the energy is undone, with the
    // images, and the iterations stop: the recorded energy after each kept
    // iteration never increases.
    image_phase(1);
    require_finite("after the first image update");
    double accepted = result.energies.back().total;
    for (int iteration = 1; iteration <= options_.max_iterations; ++iteration) {
      if (out_of_time(iteration - 1)) break;
      const std::vector<cv::Mat> saved_latents = CloneAll(latents);
      const std::vector<cv::Mat> saved_inverse_depth = CloneAll(inverse_depth);
      const std::vector<cv::Mat> saved_edge_weight = CloneAll(edge_weight);
      std::vector<SE3> saved_poses(num_frames);
      for (int t = 0; t < num_frames; ++t) saved_poses[t] = frames[t].T_world_cam;
      structure_phase(iteration, /*isolated=*/false);
      image_phase(iteration + 1);
      if (result.energies.back().total <= accepted) {
        accepted = result.energies.back().total;
        continue;
      }
      latents = saved_latents;
      inverse_depth = saved_inverse_depth;
      edge_weight = saved_edge_weight;
      for (int t = 0; t < num_frames; ++t) {
        frames[t].T_world_cam = saved_poses[t];
        frames[t].depth_hr = DepthFromInverse(inverse_depth[t]);
        ++depth_version[t];
        ++pose_version[t];
      }
      const double rejected = result.energies.back().total;
      EnergyRecord restored = total_energy(iteration, "restored");
      result.energies.push_back(restored);
      result.notes.push_back("iteration " + std::to_string(iteration) +
                             (std::isfinite(rejected) ? " raised the energy" : " lost the energy (not finite)") +
                             ": undone, iterations stopped");
      break;
    }
  }
  if (progress) progress(1.0, "done");

  // Monocular scale: first two cameras 1 unit apart (SPEC section 2).
  const double baseline =
      (frames[1].T_world_cam.translation() - frames[0].T_world_cam.translation()).norm();
  const double rescale = baseline > 1e-12 ? 1.0 / baseline : 1.0;
  const SE3 T_first_world = frames[0].T_world_cam.Inverse();
  for (int t = 0; t < num_frames; ++t) {
    const SE3 pose = T_first_world * frames[t].T_world_cam;
    result.T_world_cam.emplace_back(pose.rotation(), pose.translation() * rescale);
    cv::Mat depth = frames[t].depth_hr * rescale;
    result.depth.push_back(depth);
    cv::Mat clamped;
    cv::min(cv::max(latents[t], 0.0), 1.0, clamped);
    result.latent.push_back(clamped);
  }
  result.timings = timer.timings();
  return result;
}

}  // namespace deblur_sr_mvs
