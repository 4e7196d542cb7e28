// Metric scale from a pose prior (docs/file_formats.md#monocular-scale):
// exact recovery of a known similarity on curved and straight paths, the
// effect of prior noise and of bad prior poses, the too-small-extent and
// rotation-only cases, the aligner's history and fallback, option checks.
#include "deblur_sr_mvs/core/geometry/pose_prior.h"

#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "deblur_sr_mvs/core/common/errors.h"

namespace deblur_sr_mvs {
namespace {

constexpr double kDegree = 3.14159265358979323846 / 180.0;

// T_world_cam after a similarity of the world (as TransformPose of stream.h).
SE3 Apply(const Sim3& s, const SE3& pose) {
  return SE3(s.rotation * pose.rotation(), s.scale * (s.rotation * pose.translation()) + s.translation);
}

Sim3 KnownSimilarity() {
  Sim3 s;
  s.scale = 2.7;
  s.rotation = SO3Exp(Eigen::Vector3d(0.3, -1.1, 0.6));
  s.translation = Eigen::Vector3d(4.0, -2.0, 0.5);
  return s;
}

// Ten cameras on an arc (positions and orientations change), estimate units.
std::vector<SE3> CurvedPath() {
  std::vector<SE3> poses;
  for (int i = 0; i < 10; ++i) {
    const double a = 0.08 * i;
    poses.emplace_back(SO3Exp(Eigen::Vector3d(0.02 * i, a, 0.0)),
                       Eigen::Vector3d(std::sin(a), 0.05 * i * i / 10.0, 1.0 - std::cos(a)));
  }
  return poses;
}

// Ten cameras on a line with one orientation: the lateral constant-velocity
// path, whose positions leave the rotation about the line free.
std::vector<SE3> LateralPath() {
  std::vector<SE3> poses;
  const Eigen::Matrix3d rotation = SO3Exp(Eigen::Vector3d(0.1, 0.2, -0.05));
  for (int i = 0; i < 10; ++i) poses.emplace_back(rotation, Eigen::Vector3d(0.04 * i, 0.0, 0.0));
  return poses;
}

std::vector<SE3> ApplyAll(const Sim3& s, const std::vector<SE3>& poses) {
  std::vector<SE3> out;
  for (const SE3& pose : poses) out.push_back(Apply(s, pose));
  return out;
}

// The prior with Gaussian position noise (sigma per axis, metres) and
// orientation noise (sigma per axis, radians).
std::vector<SE3> Noisy(const std::vector<SE3>& poses, double position_sigma, double angle_sigma, int seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  std::vector<SE3> out;
  for (const SE3& pose : poses) {
    const Eigen::Vector3d dp(normal(rng), normal(rng), normal(rng));
    const Eigen::Vector3d dr(normal(rng), normal(rng), normal(rng));
    out.emplace_back(SO3Exp(angle_sigma * dr) * pose.rotation(), pose.translation() + position_sigma * dp);
  }
  return out;
}

// Largest distance between aligned estimated and true prior positions.
double MaxPositionError(const Sim3& s, const std::vector<SE3>& estimated, const std::vector<SE3>& truth) {
  double worst = 0.0;
  for (size_t i = 0; i < estimated.size(); ++i) {
    worst = std::max(worst, (Apply(s, estimated[i]).translation() - truth[i].translation()).norm());
  }
  return worst;
}

double RotationError(const Sim3& a, const Sim3& b) {
  return SO3Log(a.rotation * b.rotation.transpose()).norm();
}

void ExpectExactRecovery(const std::vector<SE3>& estimated) {
  const Sim3 truth = KnownSimilarity();
  const PriorAlignment alignment = AlignToPrior(estimated, ApplyAll(truth, estimated), PosePriorOptions());
  ASSERT_TRUE(alignment.valid) << alignment.note;
  EXPECT_TRUE(alignment.updated);
  EXPECT_EQ(alignment.used, 10);
  EXPECT_EQ(alignment.inliers, 10);
  EXPECT_NEAR(alignment.estimate_to_prior.scale, truth.scale, 1e-9);
  EXPECT_LT(RotationError(alignment.estimate_to_prior, truth), 1e-9);
  EXPECT_LT((alignment.estimate_to_prior.translation - truth.translation).norm(), 1e-9);
  EXPECT_LT(alignment.rms, 1e-9);
  EXPECT_LT(alignment.scale_uncertainty, 1e-9);
}

// InverseTransformPoint undoes the similarity of a camera centre
// (TransformPose) and of a point, to rounding.
TEST(Sim3Test, InverseTransformPointRoundTrips) {
  const Sim3 s = KnownSimilarity();
  const Eigen::Vector3d centre(0.4, -1.3, 2.2);
  const SE3 moved = TransformPose(s, SE3(SO3Exp(Eigen::Vector3d(0.1, 0.2, -0.3)), centre));
  EXPECT_LT((InverseTransformPoint(s, moved.translation()) - centre).norm(), 1e-12);
  const Eigen::Vector3d target(-3.0, 0.5, 7.0);
  const Eigen::Vector3d source = InverseTransformPoint(s, target);
  EXPECT_LT((TransformPoint(s, source) - target).norm(), 1e-12);
  EXPECT_GT((source - target).norm(), 1.0);  // a real similarity, not the identity
}

// TransformPoint is scale * rotation * point + translation, checked on a
// similarity worked out by hand: a quarter turn about z, scale 2, shift x 1.
TEST(Sim3Test, TransformPointMatchesAWorkedExample) {
  Sim3 s;
  s.scale = 2.0;
  s.rotation = Eigen::AngleAxisd(M_PI / 2.0, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  s.translation = Eigen::Vector3d(1.0, 0.0, 0.0);
  // (1, 0, 3) -> rotated (0, 1, 3) -> scaled (0, 2, 6) -> shifted (1, 2, 6).
  EXPECT_LT((TransformPoint(s, Eigen::Vector3d(1.0, 0.0, 3.0)) - Eigen::Vector3d(1.0, 2.0, 6.0)).norm(),
            1e-12);
}

TEST(AlignToPrior, RecoversAKnownSimilarityOnACurvedPath) {
  ExpectExactRecovery(CurvedPath());
}

TEST(AlignToPrior, RecoversAKnownSimilarityOnACollinearLateralPath) {
  ExpectExactRecovery(LateralPath());
}

// 1 cm position and 0.5 degree orientation noise on the prior: the aligned
// estimate stays within a few noise sigmas of the truth.
TEST(AlignToPrior, OneCentimetreNoiseMovesTheResultByTheNoiseLevel) {
  const Sim3 truth = KnownSimilarity();
  for (const auto& path : {CurvedPath(), LateralPath()}) {
    const std::vector<SE3> exact = ApplyAll(truth, path);
    for (int seed = 1; seed <= 5; ++seed) {
      const PriorAlignment alignment =
          AlignToPrior(path, Noisy(exact, 0.01, 0.5 * kDegree, seed), PosePriorOptions());
      ASSERT_TRUE(alignment.valid) << alignment.note;
      const double scale_error = alignment.estimate_to_prior.scale / truth.scale - 1.0;
      const double position_error = MaxPositionError(alignment.estimate_to_prior, path, exact);
      std::printf(
          "noise 1 cm seed %d: scale error %+.4f, rotation error %.3f deg, max position error %.4f m, "
          "rms %.4f m, inliers %d\n",
          seed, scale_error, RotationError(alignment.estimate_to_prior, truth) / kDegree, position_error,
          alignment.rms, alignment.inliers);
      EXPECT_EQ(alignment.inliers, 10);
      EXPECT_LT(RotationError(alignment.estimate_to_prior, truth), 1.0 * kDegree);
      EXPECT_LT(position_error, 0.03);  // 3 sigma of one axis' noise
      EXPECT_NEAR(alignment.rms, 0.01 * std::sqrt(3.0), 0.01);
    }
  }
}

// scale_uncertainty is the spread of the fitted scale that the prior's noise
// causes: over 200 noisy priors on each path, the standard deviation of the
// relative scale error and the mean reported uncertainty agree within 20 %
// (the sampling error of a standard deviation from 200 draws is 5 %), and
// the reported figure is about noise / sqrt(sum |p - mean p|^2).
TEST(AlignToPrior, ScaleUncertaintyMatchesTheSpreadOfTheScale) {
  const Sim3 truth = KnownSimilarity();
  for (const auto& path : {CurvedPath(), LateralPath()}) {
    const std::vector<SE3> exact = ApplyAll(truth, path);
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (const SE3& pose : exact) mean += pose.translation() / static_cast<double>(exact.size());
    double spread = 0.0;
    for (const SE3& pose : exact) spread += (pose.translation() - mean).squaredNorm();
    const double expected = 0.01 / std::sqrt(spread);
    constexpr int kDraws = 200;
    double sum_sq = 0.0, sum_reported = 0.0;
    for (int seed = 1; seed <= kDraws; ++seed) {
      const PriorAlignment alignment = AlignToPrior(path, Noisy(exact, 0.01, 0.0, seed), PosePriorOptions());
      ASSERT_TRUE(alignment.valid) << alignment.note;
      const double error = alignment.estimate_to_prior.scale / truth.scale - 1.0;
      sum_sq += error * error / kDraws;
      sum_reported += alignment.scale_uncertainty / kDraws;
    }
    std::printf("scale error std %.4f, mean reported uncertainty %.4f, noise / spread %.4f\n",
                std::sqrt(sum_sq), sum_reported, expected);
    EXPECT_NEAR(sum_reported / std::sqrt(sum_sq), 1.0, 0.2);
    EXPECT_NEAR(sum_reported / expected, 1.0, 0.2);
  }
}

// Two bad prior poses of ten (one 0.5 m off, one rotated by 20 degrees): they
// are left out and the result is the fit of the eight good frames alone.
TEST(AlignToPrior, TwoBadPriorPosesOfTenAreLeftOut) {
  const Sim3 truth = KnownSimilarity();
  for (const auto& path : {CurvedPath(), LateralPath()}) {
    const std::vector<SE3> exact = ApplyAll(truth, path);
    for (int seed = 1; seed <= 5; ++seed) {
      std::vector<SE3> prior = Noisy(exact, 0.01, 0.5 * kDegree, seed);
      prior[3] = SE3(prior[3].rotation(), prior[3].translation() + Eigen::Vector3d(0.3, -0.4, 0.0));
      prior[7] = SE3(SO3Exp(Eigen::Vector3d(0.0, 0.0, 20.0 * kDegree)) * prior[7].rotation(),
                     prior[7].translation());
      const PriorAlignment alignment = AlignToPrior(path, prior, PosePriorOptions());
      ASSERT_TRUE(alignment.valid) << alignment.note;
      EXPECT_EQ(alignment.inliers, 8);

      std::vector<SE3> good_path, good_prior;
      for (int i = 0; i < 10; ++i) {
        if (i == 3 || i == 7) continue;
        good_path.push_back(path[i]);
        good_prior.push_back(prior[i]);
      }
      const PriorAlignment good = AlignToPrior(good_path, good_prior, PosePriorOptions());
      ASSERT_TRUE(good.valid);
      const double position_error = MaxPositionError(alignment.estimate_to_prior, path, exact);
      std::printf(
          "2 bad of 10, seed %d: scale error %+.4f, max position error %.4f m (good frames only: %.4f m)\n",
          seed, alignment.estimate_to_prior.scale / truth.scale - 1.0, position_error,
          MaxPositionError(good.estimate_to_prior, path, exact));
      EXPECT_NEAR(alignment.estimate_to_prior.scale, good.estimate_to_prior.scale, 1e-9);
      EXPECT_LT(RotationError(alignment.estimate_to_prior, good.estimate_to_prior), 1e-9);
      EXPECT_LT((alignment.estimate_to_prior.translation - good.estimate_to_prior.translation).norm(), 1e-9);
      EXPECT_LT(position_error, 0.03);
    }
  }
}

TEST(AlignToPrior, TooSmallPriorExtentIsNotValid) {
  std::vector<SE3> path = CurvedPath(), prior;
  for (int i = 0; i < 10; ++i) prior.emplace_back(path[i].rotation(), Eigen::Vector3d(0.0004 * i, 0.0, 0.0));
  const PriorAlignment alignment = AlignToPrior(path, prior, PosePriorOptions());
  EXPECT_FALSE(alignment.valid);
  EXPECT_FALSE(alignment.updated);
  EXPECT_EQ(alignment.note, "prior translation 0.0036 m over the window is too small to fix the scale");
}

TEST(AlignToPrior, RotationOnlyEstimateIsNotValid) {
  std::vector<SE3> path, prior = ApplyAll(KnownSimilarity(), CurvedPath());
  for (const SE3& pose : CurvedPath()) path.emplace_back(pose.rotation(), Eigen::Vector3d(1.0, 2.0, 3.0));
  const PriorAlignment alignment = AlignToPrior(path, prior, PosePriorOptions());
  EXPECT_FALSE(alignment.valid);
  EXPECT_NE(alignment.note.find("do not move"), std::string::npos) << alignment.note;
}

TEST(AlignToPrior, FewerThanTwoAgreeingFramesIsNotValid) {
  const std::vector<SE3> path = CurvedPath();
  const PriorAlignment one = AlignToPrior({path[0]}, {path[0]}, PosePriorOptions());
  EXPECT_FALSE(one.valid);
  EXPECT_NE(one.note.find("at least 2 frames"), std::string::npos) << one.note;
  // Prior positions unrelated to the estimate: no two-frame scale explains a third.
  std::vector<SE3> prior;
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> uniform(-5.0, 5.0);
  for (const SE3& pose : path)
    prior.emplace_back(pose.rotation(), Eigen::Vector3d(uniform(rng), uniform(rng), uniform(rng)));
  PosePriorOptions options;
  const PriorAlignment unrelated = AlignToPrior(path, prior, options);
  std::printf("unrelated prior: valid %d, inliers %d, note '%s'\n", unrelated.valid, unrelated.inliers,
              unrelated.note.c_str());
  EXPECT_LE(unrelated.inliers, 2);
}

TEST(AlignToPrior, RejectsMismatchedInput) {
  const std::vector<SE3> path = CurvedPath();
  EXPECT_THROW(AlignToPrior(path, {path[0]}, PosePriorOptions()), InputError);
  std::vector<SE3> bad = path;
  bad[2] = SE3(Eigen::Matrix3d::Identity(), Eigen::Vector3d(NAN, 0.0, 0.0));
  EXPECT_THROW(AlignToPrior(path, bad, PosePriorOptions()), InputError);
}

TEST(PosePriorAligner, KeepsThePreviousFitWhenThePriorStops) {
  PosePriorOptions options;
  options.history_frames = 10;
  PosePriorAligner aligner(options);
  EXPECT_FALSE(aligner.Fit().valid);  // nothing yet
  const Sim3 truth = KnownSimilarity();
  const std::vector<SE3> path = CurvedPath();
  for (int i = 0; i < 10; ++i) aligner.Add(i, path[i], Apply(truth, path[i]));
  const PriorAlignment first = aligner.Fit();
  ASSERT_TRUE(first.valid && first.updated) << first.note;
  EXPECT_NEAR(first.estimate_to_prior.scale, truth.scale, 1e-9);

  // Ten more frames in which the prior stands still (the estimate drifts):
  // the window holds only them, its fit fails, the first fit is kept.
  for (int i = 10; i < 20; ++i) {
    aligner.Add(i, SE3(path[9].rotation(), path[9].translation() + Eigen::Vector3d(0.01 * i, 0.0, 0.0)),
                Apply(truth, path[9]));
  }
  const PriorAlignment kept = aligner.Fit();
  EXPECT_TRUE(kept.valid);
  EXPECT_FALSE(kept.updated);
  EXPECT_EQ(kept.used, 10);
  EXPECT_EQ(kept.estimate_to_prior.scale, first.estimate_to_prior.scale);
  EXPECT_EQ(kept.estimate_to_prior.translation, first.estimate_to_prior.translation);
  EXPECT_EQ(
      kept.note,
      "prior translation 0 m over the window is too small to fix the scale; keeping the previous scale");
}

TEST(PosePriorAligner, FitsTheLastHistoryFramesByIdAndReplacesReAddedFrames) {
  PosePriorOptions options;
  options.history_frames = 10;
  PosePriorAligner aligner(options);
  const std::vector<SE3> path = CurvedPath();
  Sim3 other = KnownSimilarity();
  other.scale = 0.4;
  // Ids 0..9 with a wrong prior, then re-added with the right one, then ids
  // 10..19 (newer) with the right one: only the newest ten are fitted.
  for (int i = 0; i < 10; ++i) aligner.Add(i, path[i], Apply(other, path[i]));
  const Sim3 truth = KnownSimilarity();
  for (int i = 0; i < 10; ++i) aligner.Add(i, path[i], Apply(truth, path[i]));
  EXPECT_NEAR(aligner.Fit().estimate_to_prior.scale, truth.scale, 1e-9);
  for (int i = 19; i >= 10; --i) aligner.Add(i, path[i - 10], Apply(other, path[i - 10]));
  const PriorAlignment newest = aligner.Fit();
  ASSERT_TRUE(newest.valid);
  EXPECT_EQ(newest.used, 10);
  EXPECT_NEAR(newest.estimate_to_prior.scale, other.scale, 1e-9);
}

TEST(PosePriorAligner, ResetForgetsFramesAndTheLastFit) {
  PosePriorAligner aligner{PosePriorOptions()};
  const std::vector<SE3> path = CurvedPath();
  const Sim3 truth = KnownSimilarity();
  for (int i = 0; i < 10; ++i) aligner.Add(i, path[i], Apply(truth, path[i]));
  ASSERT_TRUE(aligner.Fit().valid);
  aligner.Reset();
  const PriorAlignment empty = aligner.Fit();
  EXPECT_FALSE(empty.valid);
  EXPECT_EQ(empty.used, 0);
  // A still prior after the reset: no previous fit to fall back on.
  for (int i = 0; i < 10; ++i) aligner.Add(100 + i, path[i], Apply(truth, path[0]));
  const PriorAlignment still = aligner.Fit();
  EXPECT_FALSE(still.valid);
  EXPECT_EQ(still.used, 10);
}

TEST(PosePriorOptions, CheckNamesTheBadField) {
  const auto message = [](const PosePriorOptions& options) {
    try {
      options.Check();
    } catch (const InputError& error) {
      return std::string(error.what());
    }
    return std::string("no error");
  };
  PosePriorOptions options;
  EXPECT_NO_THROW(options.Check());
  options.history_frames = 1;
  EXPECT_EQ(message(options), "history_frames must be >= 2, got 1");
  options = PosePriorOptions();
  options.min_prior_extent = 0.0;
  EXPECT_EQ(message(options), "min_prior_extent must be > 0, got 0");
  options.min_prior_extent = NAN;
  EXPECT_NE(message(options).find("min_prior_extent"), std::string::npos);
  options = PosePriorOptions();
  options.outlier_distance = -0.1;
  EXPECT_EQ(message(options), "outlier_distance must be > 0, got -0.1");
  EXPECT_THROW(PosePriorAligner{options}, InputError);
}

}  // namespace
}  // namespace deblur_sr_mvs
