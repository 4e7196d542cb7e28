// The two blur rules. The unequal-blur rule
// (EstimatorOptions::unequal_blur_tolerance_px): a pair whose frames' blurs
// differ by more than the tolerance matches its restored pair only. On a
// constant-velocity path every pair carries the same blur, so the rule
// changes nothing, bit for bit; on a hand-held path the blurs differ and the
// rule changes the estimate. The equal-blur rule
// (EstimatorOptions::equal_blur_tolerance_px) changes the pose update's
// pairs on a constant-velocity path, except where a pose prior enters the
// structure update. The input pairs' weight by their blur difference
// (EstimatorOptions::equal_blur_input_weight) changes the estimate on a
// constant-velocity path, and only with the unequal-blur rule on (it
// measures the blur difference). The re-centred depth pass moves the depth
// and leaves the poses.
#include <vector>

#include <opencv2/core.hpp>

#include <gtest/gtest.h>

#include "../support/same_bits.h"
#include "../support/test_sequences.h"
#include "deblur_sr_mvs/core/estimation/estimator.h"

namespace deblur_sr_mvs {
namespace {

std::vector<SE3> TruePoses(const Sequence& sequence) {
  std::vector<SE3> poses;
  for (const StampedPose& p : sequence.ground_truth->poses) poses.push_back(p.T_world_cam);
  return poses;
}

// One joint iteration from the true structure with the two rules'
// tolerances, on one thread (so that two runs with the same pairs give the
// same bits); with `prior`, the true poses as a pose prior; every input
// pair at weight 1 unless `input_weight` (equal_blur_input_weight) is set.
EstimatorResult RunWithTolerances(const Sequence& sequence, double equal_px, double unequal_px,
                                  bool prior = false, double input_weight = 0.0) {
  EstimatorOptions options;
  options.max_iterations = 1;
  options.num_threads = 1;
  options.equal_blur_tolerance_px = equal_px;
  options.unequal_blur_tolerance_px = unequal_px;
  options.equal_blur_input_weight = input_weight;
  EstimatorInput input = InputOf(sequence);
  if (prior) {
    for (const SE3& pose : TruePoses(sequence)) input.T_prior_cam.emplace_back(pose);
  }
  return Estimator(options).RunFromStructure(input, sequence.ground_truth->depth, TruePoses(sequence));
}

// The unequal-blur rule alone.
EstimatorResult RunWithTolerance(const Sequence& sequence, double tolerance_px) {
  return RunWithTolerances(sequence, 0.0, tolerance_px);
}

bool SameEstimate(const EstimatorResult& a, const EstimatorResult& b) {
  if (a.latent.size() != b.latent.size()) return false;
  for (size_t t = 0; t < a.latent.size(); ++t) {
    if (!SameBits(a.latent[t], b.latent[t]) || !SameBits(a.depth[t], b.depth[t])) return false;
    if (!(a.T_world_cam[t].translation() == b.T_world_cam[t].translation())) return false;
    if (!(a.T_world_cam[t].rotation() == b.T_world_cam[t].rotation())) return false;
  }
  return true;
}

TEST(UnequalBlur, ConstantVelocityPathIsUnchanged) {
  const Sequence sequence = SynthesizedSequence("unequal_blur_lateral", "Dolls", "--frames 4 --subframes 60");
  ASSERT_TRUE(sequence.ground_truth.has_value());
  EXPECT_TRUE(SameEstimate(RunWithTolerance(sequence, 0.0), RunWithTolerance(sequence, 0.5)));
}

TEST(UnequalBlur, HandHeldPairsOfDifferentBlurLoseTheirInputPair) {
  const Sequence sequence = SynthesizedSequence("unequal_blur_handheld", "Dolls",
                                                "--path handheld --frames 4 --subframes 60 --seed 2");
  ASSERT_TRUE(sequence.ground_truth.has_value());
  EXPECT_FALSE(SameEstimate(RunWithTolerance(sequence, 0.0), RunWithTolerance(sequence, 1e-3)));
}

// Pairs of a lateral path carry equal blurs, so the equal-blur rule takes
// their restored pairs out of the pose update; under a pose prior it is off.
TEST(EqualBlur, RuleChangesTheEstimateExceptUnderAPosePrior) {
  const Sequence sequence = SynthesizedSequence("equal_blur_lateral", "Dolls", "--frames 4 --subframes 60");
  ASSERT_TRUE(sequence.ground_truth.has_value());
  EXPECT_FALSE(SameEstimate(RunWithTolerances(sequence, 0.0, 0.0), RunWithTolerances(sequence, 0.5, 0.0)));
  EXPECT_TRUE(SameEstimate(RunWithTolerances(sequence, 0.0, 0.0, /*prior=*/true),
                           RunWithTolerances(sequence, 0.5, 0.0, /*prior=*/true)));
}

// On a lateral path the blurs are equal, so the input pairs weigh 1.5 in the
// depth update; without the unequal-blur rule the weight is not applied.
TEST(EqualBlurInputWeight, ChangesTheEstimateWhereTheBlurDifferenceIsMeasured) {
  const Sequence sequence = SynthesizedSequence("equal_blur_lateral", "Dolls", "--frames 4 --subframes 60");
  ASSERT_TRUE(sequence.ground_truth.has_value());
  EXPECT_FALSE(SameEstimate(RunWithTolerances(sequence, 0.0, 2.0, false, 0.0),
                            RunWithTolerances(sequence, 0.0, 2.0, false, 1.5)));
  EXPECT_TRUE(SameEstimate(RunWithTolerances(sequence, 0.0, 0.0, false, 0.0),
                           RunWithTolerances(sequence, 0.0, 0.0, false, 1.5)));
}

// The re-centred depth pass (EstimatorOptions::recentred_depth_pass) ends the
// last structure update, after its pose update: it moves the depth and leaves
// the poses, up to the window's scale (the output's median depth is 1, and
// the pass moves the depth): the same rotations bit for bit, the
// translations in one ratio. So does each further alternation of
// re-centring and depth update (recentred_depth_passes), and a pass solved
// to the structure update's own looser CG stop instead of the passes'
// (recentred_depth_cg_iterations / _tolerance).
TEST(RecentredDepthPass, MovesTheDepthAndLeavesThePoses) {
  const Sequence sequence = SynthesizedSequence("equal_blur_lateral", "Dolls", "--frames 4 --subframes 60");
  ASSERT_TRUE(sequence.ground_truth.has_value());
  const auto run = [&sequence](bool pass, int passes, bool loose_cg = false) {
    EstimatorOptions options;
    options.max_iterations = 1;
    options.num_threads = 1;
    options.recentred_depth_pass = pass;
    options.recentred_depth_passes = passes;
    if (loose_cg) {
      options.recentred_depth_cg_iterations = options.structure.depth_cg_iterations;
      options.recentred_depth_cg_tolerance = options.structure.depth_cg_tolerance;
    }
    return Estimator(options).RunFromStructure(InputOf(sequence), sequence.ground_truth->depth,
                                               TruePoses(sequence));
  };
  const EstimatorResult without = run(false, 1), once = run(true, 1), twice = run(true, 2),
                        once_loose = run(true, 1, /*loose_cg=*/true);
  for (const EstimatorResult* with : {&once, &twice, &once_loose}) {
    const EstimatorResult& before = with == &once ? without : once;
    ASSERT_EQ(with->depth.size(), before.depth.size());
    ASSERT_GE(with->depth.size(), 2u);
    const double ratio =
        with->T_world_cam[1].translation().norm() / before.T_world_cam[1].translation().norm();
    bool depth_moved = false;
    for (size_t t = 0; t < with->depth.size(); ++t) {
      depth_moved = depth_moved || !SameBits(with->depth[t], before.depth[t]);
      EXPECT_TRUE(with->T_world_cam[t].rotation() == before.T_world_cam[t].rotation()) << t;
      const Eigen::Vector3d scaled = ratio * before.T_world_cam[t].translation();
      EXPECT_LE((with->T_world_cam[t].translation() - scaled).norm(), 1e-12 + 1e-9 * scaled.norm()) << t;
    }
    EXPECT_TRUE(depth_moved) << (with == &once    ? "one pass against none"
                                 : with == &twice ? "two passes against one"
                                                  : "a loosely solved pass against the default");
  }
}

}  // namespace
}  // namespace deblur_sr_mvs
