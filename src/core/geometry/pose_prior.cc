// Metric scale from a pose prior (docs/file_formats.md#monocular-scale).
// AlignToPrior fits the similarity in two steps:
//  1. the rotation from the orientations: a chordal mean of the per-frame
//     rotations R_prior_i R_est_i^T, frames whose rotation is far from the
//     medoid's left out. The positions alone would not fix it: on a straight
//     (e.g. lateral constant-velocity) path they are collinear and the rotation
//     about the path is free.
//  2. the scale and translation from the positions, given the rotation:
//     exhaustive RANSAC (MSAC score) over pairs of frames, then least squares
//     on the frames within outlier_distance, repeated until the inliers settle.
#include "deblur_sr_mvs/core/geometry/pose_prior.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <utility>

#include <Eigen/LU>
#include <Eigen/SVD>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/common/options_check.h"

namespace deblur_sr_mvs {

namespace {

constexpr double kPi = 3.14159265358979323846;
// A frame's rotation R_prior_i R_est_i^T agrees with the others when it lies
// within 3 median deviations of theirs, clamped to [5, 15] degrees: prior and
// estimate orientation noise of a few degrees passes, a prior orientation off
// by 20 degrees does not.
constexpr double kMinRotationInlierAngle = 5.0 * kPi / 180.0;
constexpr double kMaxRotationInlierAngle = 15.0 * kPi / 180.0;
// Least-squares refinements of scale and translation on the inliers.
constexpr int kRefinements = 5;

std::string Format(const char* format, double a, double b = 0.0, double c = 0.0) {
  char text[160];
  std::snprintf(text, sizeof(text), format, a, b, c);
  return text;
}

double RotationAngle(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b) {
  return SO3Log(a * b.transpose()).norm();
}

// Largest distance between two of the points (0 for fewer than 2).
double Diameter(const std::vector<Eigen::Vector3d>& points, const std::vector<int>& which) {
  double diameter = 0.0;
  for (size_t i = 0; i < which.size(); ++i) {
    for (size_t j = i + 1; j < which.size(); ++j) {
      diameter = std::max(diameter, (points[which[i]] - points[which[j]]).norm());
    }
  }
  return diameter;
}

std::vector<int> AllIndices(size_t n) {
  std::vector<int> all(n);
  for (size_t i = 0; i < n; ++i) all[i] = static_cast<int>(i);
  return all;
}

// The rotation nearest (Frobenius) to the mean of the given rotations.
Eigen::Matrix3d ChordalMean(const std::vector<Eigen::Matrix3d>& rotations, const std::vector<int>& which) {
  Eigen::Matrix3d sum = Eigen::Matrix3d::Zero();
  for (int i : which) sum += rotations[i];
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(sum, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Vector3d s = Eigen::Vector3d::Ones();
  if (svd.matrixU().determinant() * svd.matrixV().determinant() < 0.0) s(2) = -1.0;
  return svd.matrixU() * s.asDiagonal() * svd.matrixV().transpose();
}

// Frames whose rotation lies within the adaptive angle of `centre`.
std::vector<int> RotationInliers(const std::vector<Eigen::Matrix3d>& rotations,
                                 const Eigen::Matrix3d& centre) {
  std::vector<double> angles;
  for (const Eigen::Matrix3d& rotation : rotations) angles.push_back(RotationAngle(rotation, centre));
  std::vector<double> sorted = angles;
  std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
  const double threshold =
      std::clamp(3.0 * sorted[sorted.size() / 2], kMinRotationInlierAngle, kMaxRotationInlierAngle);
  std::vector<int> inliers;
  for (size_t i = 0; i < angles.size(); ++i) {
    if (angles[i] <= threshold) inliers.push_back(static_cast<int>(i));
  }
  return inliers;
}

// Robust rotation of the similarity: the chordal mean of the frames that
// agree with the medoid (the rotation with most others within the maximum
// angle, ties to the smallest sum of angles), the agreeing frames in *inliers.
Eigen::Matrix3d FitRotation(const std::vector<Eigen::Matrix3d>& rotations, std::vector<int>* inliers) {
  int best = 0, best_count = -1;
  double best_sum = std::numeric_limits<double>::infinity();
  for (size_t i = 0; i < rotations.size(); ++i) {
    int count = 0;
    double sum = 0.0;
    for (const Eigen::Matrix3d& other : rotations) {
      const double angle = RotationAngle(rotations[i], other);
      count += angle <= kMaxRotationInlierAngle;
      sum += std::min(angle, kMaxRotationInlierAngle);
    }
    if (count > best_count || (count == best_count && sum < best_sum)) {
      best = static_cast<int>(i);
      best_count = count;
      best_sum = sum;
    }
  }
  Eigen::Matrix3d rotation = rotations[best];
  for (int pass = 0; pass < 3; ++pass) {
    *inliers = RotationInliers(rotations, rotation);
    rotation = ChordalMean(rotations, *inliers);
  }
  *inliers = RotationInliers(rotations, rotation);
  return rotation;
}

// Scale and translation: target ~= scale * source + translation.
struct ScaleShift {
  double scale = 0.0;
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();
};

double Residual(const ScaleShift& fit, const Eigen::Vector3d& source, const Eigen::Vector3d& target) {
  return (target - fit.scale * source - fit.translation).norm();
}

// Least squares over `which`; scale 0 when the sources coincide.
ScaleShift LeastSquares(const std::vector<Eigen::Vector3d>& source,
                        const std::vector<Eigen::Vector3d>& target, const std::vector<int>& which) {
  Eigen::Vector3d mean_source = Eigen::Vector3d::Zero(), mean_target = Eigen::Vector3d::Zero();
  for (int i : which) {
    mean_source += source[i];
    mean_target += target[i];
  }
  mean_source /= static_cast<double>(which.size());
  mean_target /= static_cast<double>(which.size());
  double cross = 0.0, variance = 0.0;
  for (int i : which) {
    cross += (target[i] - mean_target).dot(source[i] - mean_source);
    variance += (source[i] - mean_source).squaredNorm();
  }
  ScaleShift fit;
  fit.scale = variance > 0.0 ? cross / variance : 0.0;
  fit.translation = mean_target - fit.scale * mean_source;
  return fit;
}

std::vector<int> PositionInliers(const ScaleShift& fit, const std::vector<Eigen::Vector3d>& source,
                                 const std::vector<Eigen::Vector3d>& target,
                                 const std::vector<int>& candidates, double max_distance) {
  std::vector<int> inliers;
  for (int i : candidates) {
    if (Residual(fit, source[i], target[i]) <= max_distance) inliers.push_back(i);
  }
  return inliers;
}

// The pair hypothesis with the best MSAC score among `candidates`.
ScaleShift BestPairHypothesis(const std::vector<Eigen::Vector3d>& source,
                              const std::vector<Eigen::Vector3d>& target, const std::vector<int>& candidates,
                              double max_distance) {
  ScaleShift best;
  double best_cost = std::numeric_limits<double>::infinity();
  for (size_t a = 0; a < candidates.size(); ++a) {
    for (size_t b = a + 1; b < candidates.size(); ++b) {
      const int i = candidates[a], j = candidates[b];
      const Eigen::Vector3d d_source = source[j] - source[i], d_target = target[j] - target[i];
      if (!(d_source.squaredNorm() > 0.0)) continue;
      ScaleShift fit;
      fit.scale = d_target.dot(d_source) / d_source.squaredNorm();
      if (!(fit.scale > 0.0)) continue;
      fit.translation = 0.5 * (target[i] + target[j] - fit.scale * (source[i] + source[j]));
      double cost = 0.0;
      for (int k : candidates)
        cost += std::min(std::pow(Residual(fit, source[k], target[k]), 2), max_distance * max_distance);
      if (cost < best_cost) {
        best_cost = cost;
        best = fit;
      }
    }
  }
  return best;
}

// Robust scale and translation over `candidates`; the inliers in *inliers.
ScaleShift FitScaleShift(const std::vector<Eigen::Vector3d>& source,
                         const std::vector<Eigen::Vector3d>& target, const std::vector<int>& candidates,
                         double max_distance, std::vector<int>* inliers) {
  ScaleShift fit = BestPairHypothesis(source, target, candidates, max_distance);
  *inliers = PositionInliers(fit, source, target, candidates, max_distance);
  for (int pass = 0; pass < kRefinements && inliers->size() >= 2; ++pass) {
    const ScaleShift refined = LeastSquares(source, target, *inliers);
    if (!(refined.scale > 0.0)) break;
    fit = refined;
    std::vector<int> next = PositionInliers(fit, source, target, candidates, max_distance);
    if (next == *inliers) break;
    *inliers = std::move(next);
  }
  return fit;
}

// The similarity from the frames that agree in orientation and in position:
// the robust rotation, the robust scale and translation given it, then all
// three refitted on the frames that pass both tests until those settle (a
// frame off in position only leaves the rotation too). *inliers: those
// frames; scale 0 when there is no fit.
Sim3 FitSimilarity(const std::vector<Eigen::Vector3d>& estimated, const std::vector<Eigen::Vector3d>& prior,
                   const std::vector<Eigen::Matrix3d>& rotations, double max_distance,
                   std::vector<int>* inliers) {
  std::vector<int> candidates;
  Sim3 similarity;
  similarity.rotation = FitRotation(rotations, &candidates);
  std::vector<Eigen::Vector3d> rotated(estimated.size());
  for (size_t i = 0; i < estimated.size(); ++i) rotated[i] = similarity.rotation * estimated[i];
  ScaleShift fit = FitScaleShift(rotated, prior, candidates, max_distance, inliers);
  for (int pass = 0; pass < kRefinements && inliers->size() >= 2 && fit.scale > 0.0; ++pass) {
    const Eigen::Matrix3d rotation = ChordalMean(rotations, *inliers);
    for (size_t i = 0; i < estimated.size(); ++i) rotated[i] = rotation * estimated[i];
    const ScaleShift refined = LeastSquares(rotated, prior, *inliers);
    if (!(refined.scale > 0.0)) break;
    similarity.rotation = rotation;
    fit = refined;
    std::vector<int> next = PositionInliers(fit, rotated, prior, candidates, max_distance);
    if (next == *inliers) break;
    *inliers = std::move(next);
  }
  similarity.scale = fit.scale;
  similarity.translation = fit.translation;
  return similarity;
}

void CheckCorrespondences(const std::vector<SE3>& T_world_cam, const std::vector<SE3>& T_prior_cam) {
  if (T_world_cam.size() != T_prior_cam.size()) {
    throw InputError("pose prior alignment: " + std::to_string(T_world_cam.size()) + " estimated vs " +
                     std::to_string(T_prior_cam.size()) + " prior poses");
  }
  for (size_t i = 0; i < T_world_cam.size(); ++i) {
    if (!T_world_cam[i].Matrix().allFinite() || !T_prior_cam[i].Matrix().allFinite()) {
      throw InputError("pose prior alignment: pose " + std::to_string(i) + " is not finite");
    }
  }
}

PriorAlignment Invalid(int used, const std::string& note) {
  PriorAlignment alignment;
  alignment.used = used;
  alignment.note = note;
  return alignment;
}

std::string ExtentNote(double extent) {
  return Format("prior translation %.3g m over the window is too small to fix the scale", extent);
}

double SquaredResidualSum(const Sim3& s, const std::vector<Eigen::Vector3d>& estimated,
                          const std::vector<Eigen::Vector3d>& prior, const std::vector<int>& inliers) {
  double sum = 0.0;
  for (int i : inliers) sum += (TransformPoint(s, estimated[i]) - prior[i]).squaredNorm();
  return sum;
}

double InlierRms(const Sim3& s, const std::vector<Eigen::Vector3d>& estimated,
                 const std::vector<Eigen::Vector3d>& prior, const std::vector<int>& inliers) {
  return std::sqrt(SquaredResidualSum(s, estimated, prior, inliers) / static_cast<double>(inliers.size()));
}

// PriorAlignment::scale_uncertainty: for target = s q + t + noise (sigma per
// axis), the least-squares s has variance sigma^2 / sum |q - mean q|^2 with
// q the rotated estimated positions; relative to s, in prior units q -> s q.
double ScaleUncertainty(const Sim3& s, const std::vector<Eigen::Vector3d>& estimated,
                        const std::vector<Eigen::Vector3d>& prior, const std::vector<int>& inliers) {
  const int dof = 3 * static_cast<int>(inliers.size()) - 4;
  if (dof <= 0) return std::numeric_limits<double>::infinity();
  const double sigma = std::sqrt(SquaredResidualSum(s, estimated, prior, inliers) / dof);
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (int i : inliers) mean += s.scale * estimated[i] / static_cast<double>(inliers.size());
  double spread = 0.0;
  for (int i : inliers) spread += (s.scale * estimated[i] - mean).squaredNorm();
  return spread > 0.0 ? sigma / std::sqrt(spread) : std::numeric_limits<double>::infinity();
}

}  // namespace

void PosePriorOptions::Check() const {
  CheckAtLeast("history_frames", history_frames, 2);
  CheckAbove("min_prior_extent", min_prior_extent, 0.0);
  CheckAbove("outlier_distance", outlier_distance, 0.0);
}

bool HasAnyPriorPose(const std::vector<std::optional<SE3>>& T_prior_cam) {
  return std::any_of(T_prior_cam.begin(), T_prior_cam.end(), [](const auto& T) { return T.has_value(); });
}

PriorAlignment AlignToPrior(const std::vector<SE3>& T_world_cam, const std::vector<SE3>& T_prior_cam,
                            const PosePriorOptions& options) {
  options.Check();
  CheckCorrespondences(T_world_cam, T_prior_cam);
  const int n = static_cast<int>(T_world_cam.size());
  if (n < 2) return Invalid(n, "needs at least 2 frames with a prior pose, got " + std::to_string(n));
  std::vector<Eigen::Vector3d> estimated, prior;
  std::vector<Eigen::Matrix3d> rotations;
  for (int i = 0; i < n; ++i) {
    estimated.push_back(T_world_cam[i].translation());
    prior.push_back(T_prior_cam[i].translation());
    rotations.push_back(T_prior_cam[i].rotation() * T_world_cam[i].rotation().transpose());
  }
  const double prior_extent = Diameter(prior, AllIndices(n));
  if (prior_extent < options.min_prior_extent) return Invalid(n, ExtentNote(prior_extent));
  double magnitude = 1.0;
  for (const Eigen::Vector3d& p : estimated) magnitude = std::max(magnitude, p.norm());
  if (!(Diameter(estimated, AllIndices(n)) > 1e-12 * magnitude)) {
    return Invalid(n, "the estimated cameras do not move (rotation only), so the scale cannot be fixed");
  }

  std::vector<int> inliers;
  const Sim3 similarity = FitSimilarity(estimated, prior, rotations, options.outlier_distance, &inliers);
  const int count = static_cast<int>(inliers.size());
  if (count < 2 || !(similarity.scale > 0.0) || !std::isfinite(similarity.scale)) {
    return Invalid(n, "only " + std::to_string(count) + " of " + std::to_string(n) +
                          " frames agree with the prior within " +
                          Format("%.3g m", options.outlier_distance));
  }
  const double inlier_extent = Diameter(prior, inliers);
  if (inlier_extent < options.min_prior_extent) return Invalid(n, ExtentNote(inlier_extent));

  PriorAlignment alignment;
  alignment.valid = alignment.updated = true;
  alignment.estimate_to_prior = similarity;
  alignment.used = n;
  alignment.inliers = count;
  alignment.inlier_frames = inliers;
  alignment.rms = InlierRms(similarity, estimated, prior, inliers);
  alignment.scale_uncertainty = ScaleUncertainty(similarity, estimated, prior, inliers);
  alignment.note =
      Format("scale %.4g +- %.2g %% from ", similarity.scale, 100.0 * alignment.scale_uncertainty) +
      std::to_string(count) + " of " + std::to_string(n) + Format(" frames, rms %.3g m", alignment.rms);
  return alignment;
}

PosePriorAligner::PosePriorAligner(const PosePriorOptions& options) : options_(options) {
  options_.Check();
}

void PosePriorAligner::Add(uint64_t id, const SE3& T_world_cam, const SE3& T_prior_cam) {
  frames_[id] = {T_world_cam, T_prior_cam};
  while (static_cast<int>(frames_.size()) > options_.history_frames) frames_.erase(frames_.begin());
}

PriorAlignment PosePriorAligner::Fit() {
  std::vector<SE3> estimated, prior;
  for (const auto& [id, frame] : frames_) {
    estimated.push_back(frame.T_world_cam);
    prior.push_back(frame.T_prior_cam);
  }
  PriorAlignment alignment = AlignToPrior(estimated, prior, options_);
  if (alignment.valid) {
    last_valid_ = alignment;
    return alignment;
  }
  if (!last_valid_.valid) {
    alignment.note += "; no scale yet";
    return alignment;
  }
  // The previous fit, with its inliers and rms; note says why it is kept.
  PriorAlignment kept = last_valid_;
  kept.updated = false;
  kept.used = alignment.used;
  kept.inlier_frames.clear();
  kept.note = alignment.note + "; keeping the previous scale";
  return kept;
}

void PosePriorAligner::Reset() {
  frames_.clear();
  last_valid_ = PriorAlignment();
}

}  // namespace deblur_sr_mvs
