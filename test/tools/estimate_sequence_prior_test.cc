// estimate_sequence --pose-prior (docs/tools.md#estimate_sequence,
// docs/file_formats.md#monocular-scale): on a short synthesized sequence
// whose ground-truth poses plus 1 cm noise are the prior, the output poses
// are in the prior's frame and the depth in metres without any alignment; a
// prior that does not move leaves the estimate unchanged (report and one
// stderr line); bad prior files are one-line errors before the estimation.
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "deblur_sr_mvs/core/evaluation/evaluation.h"
#include "deblur_sr_mvs/core/io/result_io.h"
#include "deblur_sr_mvs/core/io/sequence_io.h"
#include "tool_test_util.h"

namespace deblur_sr_mvs {
namespace {

using test::ExpectOneLineError;
using test::LineCount;
using test::RunTool;
using test::ToolRun;

const std::string& Folder() {
  static const std::string folder = testing::TempDir() + "/dsm_prior_tool_" + std::to_string(::getpid());
  return folder;
}

// Ten lateral frames, 120x90 LR (synthesized once per test binary).
const Sequence& SmallSequence() {
  static const Sequence sequence = [] {
    const std::string command = std::string(DSM_TOOL_DIR) + "/synthesize_sequence --scene " + DSM_SOURCE_DIR +
                                "/data/middlebury/Dolls --output " + Folder() +
                                "/seq --frames 10 --subframes 60 --hr-width 240 --hr-height 180 > /dev/null";
    EXPECT_EQ(std::system(command.c_str()), 0);
    return ReadSequence(Folder() + "/seq", true);
  }();
  return sequence;
}

// Writes the prior: the ground-truth poses with their positions moved by
// Gaussian noise of `sigma` (m) per axis, or all at the first position.
std::string WritePrior(const std::string& name, double sigma, bool still) {
  std::vector<StampedPose> prior = SmallSequence().ground_truth->poses;
  std::mt19937 rng(1);
  std::normal_distribution<double> normal(0.0, sigma);
  const Eigen::Vector3d first = prior.front().T_world_cam.translation();
  for (StampedPose& pose : prior) {
    const Eigen::Vector3d noise(normal(rng), normal(rng), normal(rng));
    pose.T_world_cam =
        SE3(pose.T_world_cam.rotation(), (still ? first : pose.T_world_cam.translation()) + noise);
  }
  const std::string path = Folder() + "/" + name;
  WriteTumTrajectory(path, prior);
  return path;
}

ToolRun Estimate(const std::string& prior, const std::string& output) {
  SmallSequence();
  return RunTool("estimate_sequence",
                 {"--input", Folder() + "/seq", "--output", output, "--pose-prior", prior, "--iterations",
                  "1", "--samples", "20", "--threads", "2", "--quiet"});
}

struct MetricErrors {
  double worst_position = 0.0;  // m, no alignment
  double depth_in_metres = 0.0, depth_scale_aligned = 0.0;
};

// Runs with the prior and measures the result as written (no alignment)
// against the ground truth, and the depth after the per-frame median scale
// alignment of the paper's evaluation.
MetricErrors RunWithPrior(const std::string& name, double sigma) {
  const std::string output = Folder() + "/out_" + name;
  const ToolRun run = Estimate(WritePrior(name + ".txt", sigma, false), output);
  EXPECT_EQ(run.exit_code, 0) << run.err;
  const SequenceResult result = ReadResult(output);
  const nlohmann::json report = nlohmann::json::parse(result.report_json);
  std::printf("prior %s (%.3f m noise): pose_prior %s\n", name.c_str(), sigma,
              report["pose_prior"].dump().c_str());
  EXPECT_TRUE(report["pose_prior"]["valid"].get<bool>());
  EXPECT_EQ(report["pose_prior"]["inliers"], 10);

  const Sequence& sequence = SmallSequence();
  MetricErrors errors;
  for (size_t t = 0; t < result.poses.size(); ++t) {
    const Eigen::Vector3d truth = sequence.ground_truth->poses[t].T_world_cam.translation();
    errors.worst_position =
        std::max(errors.worst_position, (result.poses[t].T_world_cam.translation() - truth).norm());
  }
  EvaluationOptions metric;
  metric.align_depth_scale = false;
  const EvaluationReport raw = EvaluateResult(result, sequence, metric);
  const EvaluationReport aligned = EvaluateResult(result, sequence);
  EXPECT_TRUE(raw.mean_depth_relative_error && aligned.mean_depth_relative_error);
  errors.depth_in_metres = raw.mean_depth_relative_error.value_or(NAN);
  errors.depth_scale_aligned = aligned.mean_depth_relative_error.value_or(NAN);
  std::printf(
      "  max position error (no alignment) %.4f m; depth rel. error in metres %.4f, scale-aligned %.4f\n",
      errors.worst_position, errors.depth_in_metres, errors.depth_scale_aligned);
  return errors;
}

// Standard deviation of the relative scale that a least-squares fit takes
// from prior positions with `sigma` noise per axis: sigma / sqrt(sum |p - mean|^2).
double ScaleSigma(double sigma) {
  const std::vector<StampedPose>& truth = SmallSequence().ground_truth->poses;
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const StampedPose& pose : truth) mean += pose.T_world_cam.translation() / truth.size();
  double spread = 0.0;
  for (const StampedPose& pose : truth) spread += (pose.T_world_cam.translation() - mean).squaredNorm();
  return sigma / std::sqrt(spread);
}

// An exact prior: the depth in metres is as good as the scale-aligned depth.
TEST(EstimateSequencePosePrior, ExactPriorGivesPosesInItsFrameAndDepthInMetres) {
  const MetricErrors errors = RunWithPrior("exact", 0.0);
  EXPECT_LT(errors.worst_position, 0.01);
  EXPECT_LE(errors.depth_in_metres, 1.1 * errors.depth_scale_aligned);
}

// 1 cm noise: positions within 3 sigma; the depth in metres within the
// scale-aligned error plus 3 sigma of the scale the noisy prior allows.
TEST(EstimateSequencePosePrior, NoisyPriorGivesPosesInItsFrameAndDepthInMetres) {
  const MetricErrors errors = RunWithPrior("noisy", 0.01);
  std::printf("  scale sigma of the prior's noise: %.4f\n", ScaleSigma(0.01));
  EXPECT_LT(errors.worst_position, 0.03);
  EXPECT_LE(errors.depth_in_metres, errors.depth_scale_aligned + 3.0 * ScaleSigma(0.01));
}

TEST(EstimateSequencePosePrior, StillPriorLeavesTheEstimateUnchanged) {
  const std::string output = Folder() + "/out_still";
  const ToolRun run = Estimate(WritePrior("still.txt", 0.0, true), output);
  ASSERT_EQ(run.exit_code, 0) << run.err;
  EXPECT_EQ(LineCount(run.err), 1) << run.err;
  EXPECT_NE(run.err.find("pose prior not used (prior translation 0 m over the window is too small"),
            std::string::npos)
      << run.err;
  const nlohmann::json report = nlohmann::json::parse(ReadResult(output).report_json);
  EXPECT_FALSE(report["pose_prior"]["valid"].get<bool>());
  EXPECT_TRUE(report["pose_prior"]["scale"].is_null());
  EXPECT_EQ(report["monocular_scale"].get<std::string>().rfind("metric", 0), std::string::npos);
}

TEST(EstimateSequencePosePrior, BadPriorFilesAreOneLineErrors) {
  SmallSequence();
  const std::vector<std::string> base = {"--input", Folder() + "/seq", "--output", Folder() + "/out_bad"};
  auto with = [&](const std::string& prior) {
    std::vector<std::string> arguments = base;
    arguments.insert(arguments.end(), {"--pose-prior", prior});
    return arguments;
  };
  ExpectOneLineError("estimate_sequence", with(Folder() + "/missing.txt"), "--pose-prior");
  const auto write = [&](const std::string& name, const std::string& text) {
    const std::string path = Folder() + "/" + name;
    FILE* file = std::fopen(path.c_str(), "w");
    std::fputs(text.c_str(), file);
    std::fclose(file);
    return path;
  };
  const std::string malformed = write("malformed.txt", "0.1 1 2 3\n");
  ExpectOneLineError("estimate_sequence", with(malformed), malformed + ":1: expected 8 values");
  const std::string later = write("later.txt", "100 0 0 0 0 0 0 1\n101 1 0 0 0 0 0 1\n");
  ExpectOneLineError("estimate_sequence", with(later), "no prior pose in the frames' time span");
  const std::string backwards = write("backwards.txt", "0.2 0 0 0 0 0 0 1\n0.1 1 0 0 0 0 0 1\n");
  ExpectOneLineError("estimate_sequence", with(backwards), "stamps must increase");
  EXPECT_FALSE(std::filesystem::exists(Folder() + "/out_bad"));
}

// Removes the test folder after the last test.
class RemoveFolder : public testing::Environment {
 public:
  void TearDown() override { std::filesystem::remove_all(Folder()); }
};
const testing::Environment* const kRemoveFolder = testing::AddGlobalTestEnvironment(new RemoveFolder);

}  // namespace
}  // namespace deblur_sr_mvs
