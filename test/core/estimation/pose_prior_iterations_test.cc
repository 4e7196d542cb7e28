// The pose prior in the joint iterations (EstimatorOptions::
// pose_prior_in_iterations, PosePriorTerms): with an exact prior, the
// window's depth in metres (the output carried into the prior's frame by
// the robust Sim(3) of its poses, as estimate_sequence --pose-prior writes
// it) must stay within 10 % of the per-frame scale-aligned depth error after
// the joint iterations (issue 11's criterion), as it is after the
// initialisation. Aloe, lateral, 6 frames, the benchmark's synthesis: the
// iterations without the prior moved the depth against the translations by
// 3 % (here depth in metres 0.0388 against 0.0226 aligned, ratio 1.72,
// rotation error 0.071 deg; with it 0.0245 / 0.0225, ratio 1.09, 0.035 deg;
// estimate_sequence --threads 1: 1.02 after the initialiser alone).
#include <cmath>
#include <cstdio>
#include <vector>

#include <gtest/gtest.h>

#include "../support/test_sequences.h"
#include "deblur_sr_mvs/core/geometry/pose_prior.h"

namespace deblur_sr_mvs {
namespace {

struct DepthInMetres {
  double metric = 0.0;   // mean rel. error of the depth in metres, no alignment
  double aligned = 0.0;  // mean rel. error after each frame's median scale
  double rotation_error_deg = 0.0;  // mean, relative to frame 0
};

// The result carried into the prior's frame (ApplyPosePrior of
// estimate_sequence) and compared with the ground truth.
DepthInMetres Evaluate(const EstimatorResult& result, const Sequence& sequence,
                       const std::vector<SE3>& T_prior_cam) {
  const PriorAlignment alignment = AlignToPrior(result.T_world_cam, T_prior_cam, PosePriorOptions());
  EXPECT_TRUE(alignment.valid) << alignment.note;
  EXPECT_EQ(alignment.inliers, static_cast<int>(T_prior_cam.size()));
  DepthMetricOptions metric, aligned;
  metric.crop_fraction = aligned.crop_fraction = 0.7;
  metric.align_scale = false;
  DepthInMetres errors;
  const size_t n = result.depth.size();
  const SE3& truth_0 = sequence.ground_truth->poses[0].T_world_cam;
  for (size_t t = 0; t < n; ++t) {
    const cv::Mat depth_m = result.depth[t] * alignment.estimate_to_prior.scale;
    errors.metric += EvaluateDepth(depth_m, sequence.ground_truth->depth[t], metric).relative_error / n;
    errors.aligned += EvaluateDepth(result.depth[t], sequence.ground_truth->depth[t], aligned).relative_error / n;
    const Eigen::Matrix3d R_0t = result.T_world_cam[0].rotation().transpose() * result.T_world_cam[t].rotation();
    const Eigen::Matrix3d R_0t_truth =
        truth_0.rotation().transpose() * sequence.ground_truth->poses[t].T_world_cam.rotation();
    errors.rotation_error_deg += SO3Log(R_0t * R_0t_truth.transpose()).norm() * 180.0 / M_PI / n;
  }
  return errors;
}

TEST(PosePriorIterations, DepthInMetresStaysWithinTenPercentOfTheAlignedError) {
  const Sequence sequence = SynthesizedSequence("prior_iterations", "Aloe",
                                                "--frames 6 --scale 2 --noise 1 --seed 0 --path lateral");
  ASSERT_TRUE(sequence.ground_truth.has_value());
  EstimatorInput input = InputOf(sequence);
  std::vector<SE3> T_prior_cam;
  for (const StampedPose& pose : sequence.ground_truth->poses) {
    T_prior_cam.push_back(pose.T_world_cam);
    input.T_prior_cam.push_back(pose.T_world_cam);
  }
  ASSERT_EQ(input.T_prior_cam.size(), input.images.size());
  EstimatorOptions options;  // the defaults: 3 joint iterations, the prior in them
  options.num_threads = 2;
  Estimator estimator(options);
  const EstimatorResult result = estimator.Run(input);
  for (const std::string& note : result.notes) std::printf("note: %s\n", note.c_str());
  ASSERT_EQ(result.depth.size(), input.images.size());
  const DepthInMetres errors = Evaluate(result, sequence, T_prior_cam);
  std::printf("depth rel. error in metres %.4f, scale-aligned %.4f (ratio %.3f); rotation error %.3f deg\n",
              errors.metric, errors.aligned, errors.metric / errors.aligned, errors.rotation_error_deg);
  EXPECT_LE(errors.metric, 1.10 * errors.aligned);
  // The prior must not cost accuracy: without it the aligned error is
  // 0.0226 and the rotation error 0.071 deg here.
  EXPECT_LT(errors.aligned, 0.025);
  EXPECT_LT(errors.rotation_error_deg, 0.1);
}

}  // namespace
}  // namespace deblur_sr_mvs
