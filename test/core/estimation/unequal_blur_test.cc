// The unequal-blur rule (EstimatorOptions::unequal_blur_tolerance_px): a
// pair whose frames' blurs differ by more than the tolerance matches its
// restored pair only. On a constant-velocity path every pair carries the
// same blur, so the rule changes nothing, bit for bit; on a hand-held path
// the blurs differ and the rule changes the estimate.
#include <vector>

#include <opencv2/core.hpp>

#include <gtest/gtest.h>

#include "../support/same_bits.h"
#include "../support/test_sequences.h"
#include "deblur_sr_mvs/core/estimation/estimator.h"

namespace deblur_sr_mvs {
namespace {

// One joint iteration from the true structure, on one thread (so that two
// runs with the same pairs give the same bits).
EstimatorResult RunWithTolerance(const Sequence& sequence, double tolerance_px) {
  std::vector<SE3> poses;
  for (const StampedPose& p : sequence.ground_truth->poses) poses.push_back(p.T_world_cam);
  EstimatorOptions options;
  options.max_iterations = 1;
  options.num_threads = 1;
  options.equal_blur_tolerance_px = 0.0;  // the unequal-blur rule alone
  options.unequal_blur_tolerance_px = tolerance_px;
  return Estimator(options).RunFromStructure(InputOf(sequence), sequence.ground_truth->depth, poses);
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

}  // namespace
}  // namespace deblur_sr_mvs
