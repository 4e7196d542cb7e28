#include "deblur_sr_mvs/core/estimation/exposure_estimation.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <sstream>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/common/options_check.h"
#include "deblur_sr_mvs/core/common/runtime.h"

namespace deblur_sr_mvs {
namespace {

// The window's structure at the assumed exposure: depth maps (HR) and poses
// at shutter close, or orientations only when the window has no parallax.
struct AssumedStructure {
  std::vector<FrameRecord> frames;  // with the assumed exposure
  std::vector<cv::Mat> depth_hr;    // empty without parallax
  std::vector<SE3> T_world_cam;
};

AssumedStructure InitialiseAtFraction(const EstimatorInput& input, const EstimatorOptions& estimator_options,
                                      double fraction) {
  AssumedStructure structure;
  structure.frames = WithExposureFraction(input.frames, fraction);
  InitializerOptions init_options = estimator_options.initializer;
  init_options.num_threads = estimator_options.num_threads;
  try {
    const InitialStructure initial =
        InitializeStructure(input.images, input.camera, structure.frames, init_options);
    structure.depth_hr = UpsampleInitialDepth(initial.depth_lr, estimator_options.scale);
    structure.T_world_cam = initial.T_world_cam;
  } catch (const NoParallaxError&) {
    const RotationOnlyMotion motion =
        EstimateRotationOnlyMotion(input.images, input.camera, structure.frames, init_options);
    for (const Eigen::Matrix3d& R_world_cam : motion.R_world_cam)
      structure.T_world_cam.emplace_back(R_world_cam, Eigen::Vector3d::Zero());
  }
  return structure;
}

// Poses at shutter close for `frames`' exposures, from those of the assumed
// exposure: the mid-exposure pose t_c - e/2 is what the tracks fixed, so
// P_t moves along eq:interpolatingP by (e_t - e_assumed_t) / 2.
std::vector<SE3> MovedPoses(const AssumedStructure& structure, const std::vector<FrameRecord>& frames) {
  const int n = static_cast<int>(frames.size());
  std::vector<SE3> moved(n);
  for (int t = 0; t < n; ++t) {
    const int a = t > 0 ? t - 1 : 0;
    const int b = t > 0 ? t : 1;
    const double shift = 0.5 * (frames[t].exposure - structure.frames[t].exposure);
    const double alpha = (frames[t].stamp + shift - frames[a].stamp) / (frames[b].stamp - frames[a].stamp);
    moved[t] = InterpolatePose(structure.T_world_cam[a], structure.T_world_cam[b], alpha);
  }
  return moved;
}

// The estimator that runs the probes: one image phase, structure held.
EstimatorOptions ProbeOptions(const EstimatorOptions& estimator_options,
                              const ExposureEstimationOptions& options) {
  EstimatorOptions probe = estimator_options;
  probe.mode = EstimatorMode::kJoint;
  probe.update_structure = false;
  probe.max_iterations = 1;
  probe.max_seconds = 0.0;
  probe.samples = options.samples;
  probe.image.irls_iterations = options.irls_iterations;
  probe.image.cg_iterations = options.cg_iterations;
  return probe;
}

// The data residual (matching + self-consistency of eq:energyFunction)
// after one image update with the exposure `fraction`.
double ProbeResidual(const EstimatorInput& input, const AssumedStructure& structure,
                     const EstimatorOptions& probe_options, double fraction, const std::atomic<bool>* cancel) {
  EstimatorInput probe_input = input;
  probe_input.frames = WithExposureFraction(input.frames, fraction);
  const std::vector<SE3> poses = MovedPoses(structure, probe_input.frames);
  Estimator estimator(probe_options);
  estimator.SetCancelFlag(cancel);
  const EstimatorResult result = structure.depth_hr.empty()
                                     ? estimator.RunRotationOnly(probe_input, poses)
                                     : estimator.RunFromStructure(probe_input, structure.depth_hr, poses);
  const EnergyRecord& energy = result.energies.back();
  return energy.matching + energy.self_consistency;
}

// Golden-section search of `residual` over [low, high], `steps` probes
// after the two first; every probe is appended to `probes`.
template <typename Residual>
void GoldenSection(double low, double high, int steps, const Residual& residual,
                   std::vector<std::pair<double, double>>* probes) {
  const double ratio = 0.5 * (std::sqrt(5.0) - 1.0);
  double x1 = high - ratio * (high - low), x2 = low + ratio * (high - low);
  double f1 = residual(x1), f2 = residual(x2);
  probes->emplace_back(x1, f1);
  probes->emplace_back(x2, f2);
  for (int step = 0; step < steps; ++step) {
    if (f1 <= f2) {
      high = x2;
      x2 = x1;
      f2 = f1;
      x1 = high - ratio * (high - low);
      f1 = residual(x1);
      probes->emplace_back(x1, f1);
    } else {
      low = x1;
      x1 = x2;
      f1 = f2;
      x2 = low + ratio * (high - low);
      f2 = residual(x2);
      probes->emplace_back(x2, f2);
    }
  }
}

double Median(std::vector<double> values) {
  const auto middle = values.begin() + values.size() / 2;
  std::nth_element(values.begin(), middle, values.end());
  return *middle;
}

}  // namespace

void ExposureEstimationOptions::Check() const {
  CheckInInterval("exposure min_fraction", min_fraction, 0.0, 1.0, Interval::kRightClosed);
  CheckInInterval("exposure max_fraction", max_fraction, min_fraction, 1.0, Interval::kRightClosed);
  CheckInInterval("exposure initial_fraction", initial_fraction, 0.0, 1.0, Interval::kRightClosed);
  CheckInRange("exposure grid_points", grid_points, 3, 50);
  CheckInRange("exposure refine_steps", refine_steps, 0, 50);
  CheckInRange("exposure samples", samples, 1, 1000);
  CheckInRange("exposure irls_iterations", irls_iterations, 1, 100);
  CheckInRange("exposure cg_iterations", cg_iterations, 1, 1000);
}

std::vector<double> FrameIntervals(const std::vector<FrameRecord>& frames) {
  if (frames.size() < 2) throw InputError("exposure estimation: needs at least 2 frames");
  std::vector<double> intervals(frames.size());
  for (size_t t = 1; t < frames.size(); ++t) {
    intervals[t] = frames[t].stamp - frames[t - 1].stamp;
    if (!(intervals[t] > 0.0) || !std::isfinite(intervals[t])) {
      throw InputError("exposure estimation: frame stamps must increase");
    }
  }
  intervals[0] = intervals[1];
  return intervals;
}

std::vector<FrameRecord> WithExposureFraction(const std::vector<FrameRecord>& frames, double fraction) {
  const std::vector<double> intervals = FrameIntervals(frames);
  std::vector<FrameRecord> result = frames;
  for (size_t t = 0; t < frames.size(); ++t) result[t].exposure = fraction * intervals[t];
  return result;
}

ExposureEstimate EstimateExposure(const EstimatorInput& input, const EstimatorOptions& estimator_options,
                                  const ExposureEstimationOptions& options, const std::atomic<bool>* cancel) {
  options.Check();
  estimator_options.Check();
  const double start = NowMs();
  const std::vector<double> intervals = FrameIntervals(input.frames);
  const AssumedStructure structure = InitialiseAtFraction(input, estimator_options, options.initial_fraction);
  const EstimatorOptions probe_options = ProbeOptions(estimator_options, options);
  const auto residual = [&](double fraction) {
    return ProbeResidual(input, structure, probe_options, fraction, cancel);
  };
  ExposureEstimate estimate;
  const double step = (options.max_fraction - options.min_fraction) / (options.grid_points - 1);
  for (int i = 0; i < options.grid_points; ++i) {
    const double fraction = options.min_fraction + i * step;
    estimate.probes.emplace_back(fraction, residual(fraction));
  }
  const auto best_grid = std::min_element(estimate.probes.begin(), estimate.probes.end(),
                                          [](const auto& a, const auto& b) { return a.second < b.second; });
  const double centre = best_grid->first;
  if (options.refine_steps > 0) {
    GoldenSection(std::max(options.min_fraction, centre - step), std::min(options.max_fraction, centre + step),
                  options.refine_steps - 1, residual, &estimate.probes);
  }
  const auto best = std::min_element(estimate.probes.begin(), estimate.probes.end(),
                                     [](const auto& a, const auto& b) { return a.second < b.second; });
  estimate.fraction = best->first;
  estimate.seconds = estimate.fraction * Median(intervals);
  for (double interval : intervals) estimate.frame_exposures.push_back(estimate.fraction * interval);
  estimate.elapsed_seconds = (NowMs() - start) / 1000.0;
  std::ostringstream summary;
  char line[160];
  std::snprintf(line, sizeof(line), "exposure estimated from the blur: %.3f of the frame interval (%.5f s), %zu probes, %.1f s",
                estimate.fraction, estimate.seconds, estimate.probes.size(), estimate.elapsed_seconds);
  summary << line;
  estimate.summary = summary.str();
  return estimate;
}

}  // namespace deblur_sr_mvs
