// End-to-end properties of the estimator on a small synthesized sequence.
#include "deblur_sr_mvs/core/estimation/estimator.h"

#include <sys/wait.h>

#include <cstdlib>
#include <fstream>
#include <iostream>
#include <string>
#include <utility>
#include <vector>

#include <opencv2/imgproc.hpp>

#include <unistd.h>

#include <filesystem>
#include <limits>

#include <gtest/gtest.h>

#include "../support/test_sequences.h"
#include "deblur_sr_mvs/core/evaluation/metrics.h"
#include "deblur_sr_mvs/core/imaging/image_ops.h"
#include "deblur_sr_mvs/core/io/sequence_io.h"

namespace deblur_sr_mvs {
namespace {

// Synthesizes (once per test binary) a short Dolls sequence with ground truth.
const Sequence& SmallSequence() {
  static const Sequence sequence =
      SynthesizedSequence("estimator_seq", "Dolls", "--frames 5 --subframes 100");
  return sequence;
}

std::vector<SE3> TruePoses(const Sequence& sequence) {
  std::vector<SE3> poses;
  for (const StampedPose& p : sequence.ground_truth->poses) poses.push_back(p.T_world_cam);
  return poses;
}

TEST(Estimator, ImageUpdateWithTrueStructureBeatsBicubic) {
  const Sequence& sequence = SmallSequence();
  ASSERT_TRUE(sequence.ground_truth.has_value());
  const EstimatorInput input = InputOf(sequence);
  const std::vector<SE3> poses = TruePoses(sequence);
  EstimatorOptions options;
  options.update_structure = false;
  options.max_iterations = 1;
  Estimator estimator(options);
  const EstimatorResult result = estimator.RunFromStructure(input, sequence.ground_truth->depth, poses);
  std::vector<cv::Mat> bicubic;
  for (const cv::Mat& image : input.images) bicubic.push_back(UpsampleBicubic(image, 2));
  const double psnr_bicubic = MeanPsnr(bicubic, sequence.ground_truth->latent);
  const double psnr_restored = MeanPsnr(result.latent, sequence.ground_truth->latent);
  std::printf("true structure: bicubic %.2f dB, restored %.2f dB\n", psnr_bicubic, psnr_restored);
  for (const EnergyRecord& e : result.energies) {
    std::printf("  iteration %d %-14s E %.2f (match %.2f self %.2f imgtv %.2f depthtv %.2f)\n", e.iteration,
                e.stage.c_str(), e.total, e.matching, e.self_consistency, e.image_tv, e.depth_tv);
  }
  EXPECT_GT(psnr_restored, psnr_bicubic + 3.0);
  // The image update may only lower the energy.
  ASSERT_GE(result.energies.size(), 2u);
  EXPECT_LT(result.energies.back().total, result.energies.front().total);
}

}  // namespace
}  // namespace deblur_sr_mvs

namespace deblur_sr_mvs {
namespace {

// From a degraded structure (depth smoothed and scaled wrongly in places,
// poses perturbed), the joint iterations must lower the energy at every
// recorded step and improve depth.
TEST(Estimator, StructureUpdateImprovesDegradedStructure) {
  const Sequence& sequence = SmallSequence();
  const EstimatorInput input = InputOf(sequence);
  std::vector<SE3> poses;
  std::vector<cv::Mat> depths;
  for (size_t t = 0; t < sequence.frames.size(); ++t) {
    const SE3& truth = sequence.ground_truth->poses[t].T_world_cam;
    const Vector6d noise = (Vector6d() << 0.002, -0.001, 0.003, 0.001, -0.0015, 0.0005).finished();
    poses.push_back(t == 0 ? truth : SE3::Exp(noise * ((t % 2) ? 1.0 : -1.0)) * truth);
    // Over-smoothed and tilted by up to 8 %: a typical initialisation error.
    cv::Mat smooth;
    cv::GaussianBlur(sequence.ground_truth->depth[t], smooth, cv::Size(0, 0), 12.0);
    for (int y = 0; y < smooth.rows; ++y) {
      for (int x = 0; x < smooth.cols; ++x) smooth.at<float>(y, x) *= 1.0f + 0.08f * x / smooth.cols;
    }
    depths.push_back(smooth);
  }
  EstimatorOptions options;
  options.max_iterations = 1;
  Estimator estimator(options);
  const EstimatorResult result = estimator.RunFromStructure(input, depths, poses);
  const double rel_before = MeanDepthRel(depths, sequence.ground_truth->depth);
  const double rel_after = MeanDepthRel(result.depth, sequence.ground_truth->depth);
  std::printf("degraded structure: depth rel %.4f -> %.4f, PSNR %.2f dB\n", rel_before, rel_after,
              MeanPsnr(result.latent, sequence.ground_truth->latent));
  for (const EnergyRecord& e : result.energies) {
    std::printf("  iteration %d %-14s E %.2f (match %.2f self %.2f imgtv %.2f depthtv %.2f)\n", e.iteration,
                e.stage.c_str(), e.total, e.matching, e.self_consistency, e.image_tv, e.depth_tv);
  }
  // The energy after every kept iteration (each ends with an image update)
  // never increases, and falls well below the starting point.
  double previous = result.energies.front().total;
  int image_stages = 0;
  for (const EnergyRecord& e : result.energies) {
    if (e.stage != "image") continue;
    EXPECT_LE(e.total, previous * (1.0 + 1e-9)) << "iteration " << e.iteration;
    previous = e.total;
    ++image_stages;
  }
  EXPECT_EQ(image_stages, options.max_iterations + 1);
  EXPECT_LT(result.energies.back().total, 0.2 * result.energies.front().total);
  // The matching energy (how well the structure explains the frames) falls
  // substantially (measured: to 0.53 after two iterations, 0.66 after one).
  EXPECT_LT(result.energies.back().matching, 0.75 * result.energies[1].matching);
  EXPECT_LT(rel_after, 0.05);
  // The first image phase restores from the input latents with the first
  // phase's reweightings; with one iteration the phase after the structure
  // update is the last (it gives the output images) and follows no
  // refinement phase, so it runs the full counts (the refinement and final
  // counts are for the phases after a refinement).
  // The multi-frame data pass (on by default) adds its reweightings for
  // every frame but frame 0.
  const int frames = static_cast<int>(sequence.frames.size());
  const ImageUpdateOptions& image = options.image;
  const MultiFrameDataOptions& pass = options.multi_frame_data;
  EXPECT_EQ(result.image_work.reweightings,
            frames * (image.first_irls_iterations + image.irls_iterations) + (frames - 1) * pass.irls_iterations);
  EXPECT_LE(result.image_work.cg_steps,
            frames * (image.first_irls_iterations + image.irls_iterations) * image.cg_iterations +
                (frames - 1) * pass.irls_iterations * pass.cg_iterations);
  for (const StageTiming& s : result.timings) std::printf("  %s: %.2f s\n", s.stage.c_str(), s.seconds);
}

}  // namespace
}  // namespace deblur_sr_mvs

namespace deblur_sr_mvs {
namespace {

// The whole pipeline from the blurry frames alone (initialisation included):
// joint restores far better than bicubic and estimates depth better than the
// baseline, which never deblurs; both recover the trajectory.
TEST(Estimator, JointBeatsBicubicAndBaselineFromScratch) {
  const Sequence& sequence = SmallSequence();
  const EstimatorInput input = InputOf(sequence);
  EstimatorOptions joint_options;
  joint_options.max_iterations = 1;
  const EstimatorResult joint = Estimator(joint_options).Run(input);
  EstimatorOptions baseline_options;
  baseline_options.mode = EstimatorMode::kBaseline;
  const EstimatorResult baseline = Estimator(baseline_options).Run(input);

  std::vector<cv::Mat> bicubic;
  for (const cv::Mat& image : input.images) bicubic.push_back(UpsampleBicubic(image, 2));
  const double psnr_bicubic = MeanPsnr(bicubic, sequence.ground_truth->latent);
  const double psnr_joint = MeanPsnr(joint.latent, sequence.ground_truth->latent);
  const double rel_joint = MeanDepthRel(joint.depth, sequence.ground_truth->depth);
  const double rel_baseline = MeanDepthRel(baseline.depth, sequence.ground_truth->depth);
  std::vector<Eigen::Vector3d> truth, joint_positions, baseline_positions;
  for (size_t t = 0; t < sequence.frames.size(); ++t) {
    truth.push_back(sequence.ground_truth->poses[t].T_world_cam.translation());
    joint_positions.push_back(joint.T_world_cam[t].translation());
    baseline_positions.push_back(baseline.T_world_cam[t].translation());
  }
  const double path = (truth.back() - truth.front()).norm();
  const double ate_joint = AbsoluteTrajectoryRmse(joint_positions, truth);
  const double ate_baseline = AbsoluteTrajectoryRmse(baseline_positions, truth);
  std::printf(
      "from scratch: PSNR bicubic %.2f joint %.2f dB; depth rel joint %.4f baseline %.4f; "
      "ATE joint %.5f baseline %.5f (path %.3f)\n",
      psnr_bicubic, psnr_joint, rel_joint, rel_baseline, ate_joint, ate_baseline, path);
  EXPECT_GT(psnr_joint, psnr_bicubic + 3.0);
  EXPECT_LT(rel_joint, rel_baseline);
  EXPECT_LT(ate_joint, 0.02 * path);
  EXPECT_LT(ate_baseline, 0.02 * path);
  // Output gauge: world = first camera, median scene depth 1 unit.
  for (const EstimatorResult* result : {&joint, &baseline}) {
    EXPECT_LT(result->T_world_cam[0].Log().norm(), 1e-9);
    EXPECT_NEAR(MedianDepth(result->depth), 1.0, 1e-6);
  }
}

}  // namespace
}  // namespace deblur_sr_mvs

namespace deblur_sr_mvs {
namespace {

TEST(EstimatorSafety, ExtremeBlurStillRestoresAndStaysFinite) {
  // Exposure = the whole frame interval and 30 px of motion blur per frame.
  const std::string folder = testing::TempDir() + "/dsm_extreme_blur_" + std::to_string(::getpid());
  const std::string command = std::string(DSM_TOOL_DIR) + "/synthesize_sequence --scene " + DSM_SOURCE_DIR +
                              "/data/middlebury/Dolls --output " + folder +
                              " --frames 4 --subframes 100 --exposure-ratio 1.0 --blur-px 30"
                              " --hr-width 240 --hr-height 180 > /dev/null";
  ASSERT_EQ(std::system(command.c_str()), 0);
  const Sequence sequence = ReadSequence(folder, true);
  std::filesystem::remove_all(folder);
  EstimatorOptions options;
  options.samples = 20;
  options.max_iterations = 1;
  const EstimatorResult result = Estimator(options).Run(InputOf(sequence));
  for (const cv::Mat& latent : result.latent) EXPECT_TRUE(cv::checkRange(latent));
  for (const SE3& pose : result.T_world_cam) EXPECT_TRUE(pose.translation().allFinite());
  std::vector<cv::Mat> bicubic;
  for (const cv::Mat& image : sequence.images) bicubic.push_back(UpsampleBicubic(ToFloat01(image), 2));
  const double restored = MeanPsnr(result.latent, sequence.ground_truth->latent);
  const double baseline = MeanPsnr(bicubic, sequence.ground_truth->latent);
  std::cout << "extreme blur: bicubic " << baseline << " dB, restored " << restored << " dB\n";
  EXPECT_GT(restored, baseline);
}

// Image phases 1, 2 and 3 of a 3-phase run (images only: each phase
// restores every frame) run the first, the refinement and the final counts;
// every reweighting runs, so the count of reweightings is exact.
TEST(EstimatorSchedule, ImagePhasesRunTheFirstRefinementAndFinalCounts) {
  const Sequence& sequence = SmallSequence();
  const std::vector<SE3> poses = TruePoses(sequence);
  EstimatorOptions options;
  options.samples = 10;
  options.update_structure = false;
  options.max_iterations = 3;
  options.image.first_irls_iterations = 3;
  options.image.refine_irls_iterations = 1;
  options.image.refine_cg_iterations = 2;
  options.image.final_irls_iterations = 2;
  options.image.final_cg_iterations = 4;
  const EstimatorResult result =
      Estimator(options).RunFromStructure(InputOf(sequence), sequence.ground_truth->depth, poses);
  // Plus the multi-frame data pass after the last phase (on by default;
  // every frame but frame 0).
  const int frames = static_cast<int>(sequence.frames.size());
  const MultiFrameDataOptions& pass = options.multi_frame_data;
  const int pass_reweightings = (frames - 1) * pass.irls_iterations;
  EXPECT_EQ(result.image_work.reweightings, frames * (3 + 1 + 2) + pass_reweightings);
  EXPECT_LE(result.image_work.cg_steps, frames * (3 * options.image.cg_iterations + 1 * 2 + 2 * 4) +
                                            pass_reweightings * pass.cg_iterations);
  // Two phases: the second is last right after the first: the full counts.
  options.max_iterations = 2;
  const EstimatorResult two =
      Estimator(options).RunFromStructure(InputOf(sequence), sequence.ground_truth->depth, poses);
  EXPECT_EQ(two.image_work.reweightings, frames * (3 + options.image.irls_iterations) + pass_reweightings);
}

TEST(EstimatorSafety, TimeCapStopsBetweenIterationsAndSaysSo) {
  const Sequence& sequence = SmallSequence();
  const std::vector<SE3> poses = TruePoses(sequence);
  EstimatorOptions options;
  options.samples = 10;
  options.max_iterations = 3;
  options.max_seconds = 1e-9;  // already over when the first iteration would start
  const EstimatorResult result =
      Estimator(options).RunFromStructure(InputOf(sequence), sequence.ground_truth->depth, poses);
  ASSERT_EQ(result.notes.size(), 1u);
  EXPECT_NE(result.notes[0].find("time cap"), std::string::npos) << result.notes[0];
  for (const EnergyRecord& energy : result.energies) EXPECT_LE(energy.iteration, 1) << energy.stage;
  for (const cv::Mat& latent : result.latent) EXPECT_TRUE(cv::checkRange(latent));
}

TEST(EstimatorSafety, NonFiniteInputIsRejectedWithOneLine) {
  const Sequence& sequence = SmallSequence();
  const std::vector<SE3> poses = TruePoses(sequence);
  EstimatorOptions options;
  options.samples = 10;
  options.max_iterations = 1;
  EstimatorInput input = InputOf(sequence);
  input.images[1] = input.images[1].clone();
  input.images[1].at<cv::Vec3f>(3, 4)[0] = std::numeric_limits<float>::quiet_NaN();
  EXPECT_THROW(Estimator(options).RunFromStructure(input, sequence.ground_truth->depth, poses), InputError);
  std::vector<SE3> bad_poses = poses;
  bad_poses[2] = SE3(Eigen::Matrix3d::Identity(), Eigen::Vector3d(std::nan(""), 0, 0));
  EXPECT_THROW(
      Estimator(options).RunFromStructure(InputOf(sequence), sequence.ground_truth->depth, bad_poses),
      InputError);
}

TEST(EstimatorSafety, BadOptionsAreRejected) {
  EstimatorOptions options;
  options.max_seconds = -1.0;
  EXPECT_THROW(options.Check(), InputError);
  options = EstimatorOptions();
  options.fixed_leading_poses = 0;
  EXPECT_THROW(options.Check(), InputError);
  options = EstimatorOptions();
  options.image.lambda_i = std::numeric_limits<double>::infinity();
  EXPECT_THROW(options.Check(), InputError);
  options = EstimatorOptions();
  options.equal_blur_tolerance_px = -0.5;
  EXPECT_THROW(options.Check(), InputError);
  options.equal_blur_tolerance_px = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(options.Check(), InputError);
  options = EstimatorOptions();
  options.unequal_blur_tolerance_px = -1.0;
  EXPECT_THROW(options.Check(), InputError);
  options.unequal_blur_tolerance_px = 0.4;  // on, but not above the equal-blur rule's tolerance
  options.equal_blur_tolerance_px = 0.5;
  EXPECT_THROW(options.Check(), InputError);
  options.unequal_blur_tolerance_px = 2.0;
  EXPECT_NO_THROW(options.Check());
  options.equal_blur_input_weight = -0.5;
  EXPECT_THROW(options.Check(), InputError);
  options.equal_blur_input_weight = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(options.Check(), InputError);
  options.equal_blur_input_weight = 0.0;  // off
  EXPECT_NO_THROW(options.Check());
  options = EstimatorOptions();
  options.recentred_depth_cg_iterations = 0;
  EXPECT_THROW(options.Check(), InputError);
  options = EstimatorOptions();
  options.recentred_depth_cg_tolerance = -0.1;
  EXPECT_THROW(options.Check(), InputError);
  options.recentred_depth_cg_tolerance = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(options.Check(), InputError);
  options.recentred_depth_cg_tolerance = 0.0;  // every step
  EXPECT_NO_THROW(options.Check());
}

// Every Options::Check() names the value, its range and what it got.
TEST(EstimatorSafety, BadOptionsNameTheRangeAndTheValue) {
  auto message = [](const EstimatorOptions& options) {
    try {
      options.Check();
    } catch (const InputError& error) {
      return std::string(error.what());
    }
    return std::string("(no error)");
  };
  EstimatorOptions options;
  options.scale = 5;
  EXPECT_EQ(message(options), "scale must be in [1, 4], got 5");
  options = EstimatorOptions();
  options.lambda_s = -1.0;
  EXPECT_EQ(message(options), "lambda_s must be >= 0, got -1");
  // The image update's counts, each set to 0 in turn.
  const std::vector<std::pair<const char*, int ImageUpdateOptions::*>> counts = {
      {"cg_iterations", &ImageUpdateOptions::cg_iterations},
      {"refine_irls_iterations", &ImageUpdateOptions::refine_irls_iterations},
      {"refine_cg_iterations", &ImageUpdateOptions::refine_cg_iterations},
      {"first_irls_iterations", &ImageUpdateOptions::first_irls_iterations},
      {"final_irls_iterations", &ImageUpdateOptions::final_irls_iterations},
      {"final_cg_iterations", &ImageUpdateOptions::final_cg_iterations}};
  for (const auto& [name, count] : counts) {
    options = EstimatorOptions();
    options.image.*count = 0;
    EXPECT_EQ(message(options), std::string("image update: ") + name + " must be >= 1, got 0");
  }
  options = EstimatorOptions();
  options.structure.tv_epsilon = 0.0;
  EXPECT_EQ(message(options), "structure update: tv_epsilon must be > 0, got 0");
}

}  // namespace
}  // namespace deblur_sr_mvs
