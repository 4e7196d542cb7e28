// The depth consistency stage in the estimator (EstimatorOptions::
// depth_consistency): a depth-only stage after the output depth, so the
// output images are bit for bit those without it, and the poses too up to
// the common scale of the gauge (median depth 1 unit of the published
// depth, docs/file_formats.md#monocular-scale); unknown depth stays unknown
// and nothing new becomes unknown. Whether the depth
// gets closer to the truth is measured, not asserted: on this small
// sequence (one iteration) it does not (1.015x the error without it;
// BENCHMARKS.md "Consistency between neighbouring depth maps").
#include <cstdio>

#include <gtest/gtest.h>

#include "../support/test_sequences.h"
#include "deblur_sr_mvs/core/estimation/estimator.h"

namespace deblur_sr_mvs {
namespace {

TEST(DepthConsistencyInEstimator, ChangesOnlyTheDepth) {
  const Sequence sequence = SynthesizedSequence(
      "depth_consistency", "Dolls", "--frames 5 --subframes 100 --hr-width 240 --hr-height 180 --seed 1 --noise 1");
  ASSERT_TRUE(sequence.ground_truth.has_value());
  EstimatorOptions options = FastEstimatorOptions();
  options.num_threads = 1;
  options.depth_consistency.radius = 0;
  const EstimatorResult off = Estimator(options).Run(InputOf(sequence));
  options.depth_consistency.radius = 2;
  const EstimatorResult on = Estimator(options).Run(InputOf(sequence));
  ASSERT_EQ(on.depth.size(), off.depth.size());
  double changed = 0.0;
  for (size_t t = 0; t < on.depth.size(); ++t) {
    EXPECT_EQ(cv::norm(on.latent[t], off.latent[t], cv::NORM_INF), 0.0) << t;
    EXPECT_EQ((on.T_world_cam[t].rotation() - off.T_world_cam[t].rotation()).norm(), 0.0) << t;
    // One scale for every translation (the gauge's), within float rounding.
    const double scale = on.T_world_cam.back().translation().norm() / off.T_world_cam.back().translation().norm();
    EXPECT_LT((on.T_world_cam[t].translation() - scale * off.T_world_cam[t].translation()).norm(),
              1e-9 + 1e-6 * off.T_world_cam[t].translation().norm())
        << t;
    cv::Mat nan_on = on.depth[t] != on.depth[t];
    cv::Mat nan_off = off.depth[t] != off.depth[t];
    EXPECT_EQ(cv::countNonZero(nan_on != nan_off), 0) << t;  // unknown stays unknown, nothing new is NaN
    changed += cv::countNonZero(cv::abs(on.depth[t] - off.depth[t]) > 0.0f);
  }
  EXPECT_GT(changed, 0.0);
  EXPECT_NEAR(MedianDepth(on.depth), 1.0, 1e-6);  // the gauge holds for the published depth
  const double before = MeanDepthRel(off.depth, sequence.ground_truth->depth);
  const double after = MeanDepthRel(on.depth, sequence.ground_truth->depth);
  std::printf("depth rel. error (70 %% crop): off %.5f, on %.5f (%.3fx)\n", before, after, after / before);
}

}  // namespace
}  // namespace deblur_sr_mvs
