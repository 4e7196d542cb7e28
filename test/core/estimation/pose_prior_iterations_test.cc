// The pose prior in the joint iterations (EstimatorOptions::
// pose_prior_in_iterations, PosePriorTerms). Its normal equations against
// numeric differences; and with an exact prior, the
// window's depth in metres (the output carried into the prior's frame by
// the robust Sim(3) of its poses, as estimate_sequence --pose-prior writes
// it) must stay within 10 % of the per-frame scale-aligned depth error after
// the joint iterations (issue 11's criterion), as it is after the
// initialisation. Aloe, lateral, 6 frames, the benchmark's synthesis: the
// iterations without the prior moved the depth against the translations by
// 3 % (when measured: depth in metres 0.0388 against 0.0226 aligned, ratio
// 1.72, rotation error 0.071 deg; with it 0.0245 / 0.0225, ratio 1.09,
// 0.035 deg; estimate_sequence --threads 1: 1.02 after the initialiser
// alone). What the prior leaves to the iterations is its orientations'
// sigma: see the test.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <vector>

#include <gtest/gtest.h>

#include "../support/test_sequences.h"
#include "deblur_sr_mvs/core/estimation/structure_update.h"
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

// The prior's energy 0.5 b w sum_f (|e_c / sigma|^2 + |e_R / sigma_R|^2)
// at P_f <- Exp(eps_f) P_f, inside Huber's quadratic region.
double PriorEnergy(const PosePriorTerms& prior, const std::vector<SE3>& T_world_cam, double scale) {
  double energy = 0.0;
  for (size_t f = 0; f < T_world_cam.size(); ++f) {
    if (!prior.centre_world[f]) continue;
    const Eigen::Vector3d e_c = T_world_cam[f].translation() - *prior.centre_world[f];
    const Eigen::Vector3d e_r = SO3Log(T_world_cam[f].rotation() * prior.R_world_cam[f].transpose());
    energy += 0.5 * scale * prior.weight *
              (e_c.squaredNorm() / (prior.position_sigma * prior.position_sigma) +
               e_r.squaredNorm() / (prior.rotation_sigma * prior.rotation_sigma));
  }
  return energy;
}

// AddPosePriorNormalEquations: its right-hand side is minus the gradient of
// the prior's energy in the free frames' tangents (central differences), and
// its step (H eps = g) removes the free frames' energy (to 1e-4 of it) at
// residuals that small.
TEST(PosePriorTerms, NormalEquationsMatchNumericDifferences) {
  PosePriorTerms prior;
  prior.position_sigma = 0.01;
  prior.rotation_sigma = 0.1 * M_PI / 180.0;
  prior.weight = 3.0;
  std::vector<SE3> T_world_cam;
  for (int f = 0; f < 3; ++f) {
    const Eigen::Matrix3d R = SO3Exp(Eigen::Vector3d(0.01 * f, -0.02, 0.03 * f));
    const Eigen::Vector3d c(0.1 * f, 0.02 * f, -0.05);
    T_world_cam.emplace_back(R, c);
    // The prior a few thousandths of a sigma away (quadratic region).
    prior.centre_world.push_back(c + Eigen::Vector3d(0.004, -0.003, 0.002 * f));
    prior.R_world_cam.push_back(SO3Exp(Eigen::Vector3d(0.0005, 0.001, -0.0007 * f)) * R);
  }
  const double scale = 0.02;
  const int num_fixed = 1, unknowns = 12;
  Eigen::MatrixXd hessian = Eigen::MatrixXd::Zero(unknowns, unknowns);
  Eigen::VectorXd gradient = Eigen::VectorXd::Zero(unknowns);
  AddPosePriorNormalEquations(prior, T_world_cam, num_fixed, num_fixed, scale, &hessian, &gradient);
  const double h = 1e-6;
  for (int i = 0; i < unknowns; ++i) {
    const int f = num_fixed + i / 6;
    std::vector<SE3> plus = T_world_cam, minus = T_world_cam;
    Vector6d eps = Vector6d::Zero();
    eps(i % 6) = h;
    plus[f] = SE3::Exp(eps) * plus[f];
    minus[f] = SE3::Exp(-eps) * minus[f];
    const double numeric = (PriorEnergy(prior, plus, scale) - PriorEnergy(prior, minus, scale)) / (2.0 * h);
    EXPECT_NEAR(-gradient(i), numeric, 1e-5 * std::max(1.0, std::abs(numeric))) << "unknown " << i;
  }
  const Eigen::VectorXd step = hessian.ldlt().solve(gradient);
  std::vector<SE3> stepped = T_world_cam;
  for (int f = num_fixed; f < 3; ++f) stepped[f] = SE3::Exp(step.segment<6>(6 * (f - num_fixed))) * stepped[f];
  double held = 0.0, before = 0.0;
  {
    PosePriorTerms only_held = prior;
    for (int f = num_fixed; f < 3; ++f) only_held.centre_world[f].reset();
    held = PriorEnergy(only_held, T_world_cam, scale);
    before = PriorEnergy(prior, T_world_cam, scale);
  }
  EXPECT_GT(before - held, 0.0);
  EXPECT_LT(PriorEnergy(prior, stepped, scale) - held, 1e-4 * (before - held));
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
  // The prior is exact, and says so for its orientations: 0.01 degree (a
  // gyroscope's or motion capture's grade) instead of the default 0.1, which
  // leaves the orientations free to turn by a few hundredths of a degree
  // along the weak direction of a narrow field of view (a turn traded
  // against an offset of the inverse depths, which shrinks the depth against
  // the prior's translations). Measured here (BENCHMARKS.md "Orientation,
  // the smooth paths' weak direction"): metres 0.0215 against 0.0191
  // aligned (ratio 1.122, rotation error 0.028 degree) at 0.1 degree;
  // 0.0194 / 0.0190 (1.022, 0.001 degree) at 0.01. Before, this test kept
  // 0.1 degree and met the bound only with gain compensation off and one
  // re-centred depth pass instead of the defaults.
  options.initializer.pose_prior_rotation_sigma_deg = 0.01;
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
