// estimate_sequence --pose-prior (docs/tools.md#estimate_sequence,
// docs/file_formats.md#monocular-scale): on synthesized sequences whose
// ground-truth poses (exact, or plus 1 cm noise) are the prior, the output
// poses are in the prior's frame and the depth in metres without any
// alignment, as accurate as the prior's noise allows (report.json's
// scale_uncertainty); a prior that does not move leaves the estimate
// unchanged (report and one stderr line); bad prior files are one-line
// errors before the estimation.
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

Sequence Synthesize(const std::string& name, const std::string& flags) {
  EXPECT_EQ(test::SynthesizeInto(Folder() + "/" + name, "Dolls", "--subframes 60 " + flags), 0);
  return ReadSequence(Folder() + "/" + name, true);
}

// Ten lateral frames, 120x90 LR, a 21 cm path (synthesized once per test binary).
const Sequence& SmallSequence() {
  static const Sequence sequence = Synthesize("seq", "--frames 10 --hr-width 240 --hr-height 180");
  return sequence;
}

// Sixteen lateral frames with more motion (--blur-px 20): a 51 cm path, LR
// 116x184 (the automatic covered crop). The scale that 1 cm of prior noise
// leaves is about 1 cm / (path sqrt(n / 12)) (docs/file_formats.md#monocular-scale):
// 1.6 % here against 5 % on the small sequence's path, the longest path the
// scene renders without large holes within the test's time.
const Sequence& LongSequence() {
  static const Sequence sequence = Synthesize("long", "--frames 16 --blur-px 20");
  return sequence;
}

// Writes the prior for `sequence`: the ground-truth poses with their
// positions moved by Gaussian noise of `sigma` (m) per axis, or all at the
// first position.
std::string WritePrior(const Sequence& sequence, const std::string& name, double sigma, bool still) {
  std::vector<StampedPose> prior = sequence.ground_truth->poses;
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

ToolRun Estimate(const std::string& input, const std::string& prior, const std::string& output) {
  return RunTool("estimate_sequence",
                 {"--input", Folder() + "/" + input, "--output", output, "--pose-prior", prior,
                  "--iterations", "1", "--samples", "20", "--threads", "2", "--quiet"});
}

struct MetricErrors {
  double worst_position = 0.0;  // m, no alignment
  double depth_in_metres = 0.0, depth_scale_aligned = 0.0;
  double scale_error = 0.0;        // relative, of the written result (Sim(3) to the ground truth)
  double scale_uncertainty = 0.0;  // relative, report.json's
};

// Runs on `input` (SmallSequence's "seq" or LongSequence's "long") with the
// prior and measures the result as written (no alignment) against the
// ground truth, and the depth after the per-frame median scale alignment of
// the paper's evaluation.
MetricErrors RunWithPrior(const std::string& input, const Sequence& sequence, const std::string& name,
                          double sigma) {
  const std::string output = Folder() + "/out_" + name;
  const ToolRun run = Estimate(input, WritePrior(sequence, name + ".txt", sigma, false), output);
  EXPECT_EQ(run.exit_code, 0) << run.err;
  const SequenceResult result = ReadResult(output);
  const nlohmann::json report = nlohmann::json::parse(result.report_json);
  std::printf("prior %s (%.3f m noise): pose_prior %s\n", name.c_str(), sigma,
              report["pose_prior"].dump().c_str());
  EXPECT_TRUE(report["pose_prior"]["valid"].get<bool>());
  EXPECT_EQ(report["pose_prior"]["inliers"], static_cast<int>(sequence.images.size()));

  MetricErrors errors;
  errors.scale_uncertainty = report["pose_prior"]["scale_uncertainty"].get<double>();
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
  EXPECT_TRUE(aligned.trajectory_alignment.has_value());
  errors.scale_error = aligned.trajectory_alignment ? 1.0 / aligned.trajectory_alignment->scale - 1.0 : NAN;
  std::printf(
      "  max position error (no alignment) %.4f m; scale error %+.4f (reported uncertainty %.4f); depth rel. "
      "error in metres %.4f, scale-aligned %.4f; issue 11's criterion (metres <= 1.1 x aligned): %s\n",
      errors.worst_position, errors.scale_error, errors.scale_uncertainty, errors.depth_in_metres,
      errors.depth_scale_aligned,
      errors.depth_in_metres <= 1.1 * errors.depth_scale_aligned ? "met" : "missed");
  return errors;
}

// Standard deviation of the relative scale that a least-squares fit takes
// from prior positions with `sigma` noise per axis: sigma / sqrt(sum |p - mean|^2).
double ScaleSigma(const Sequence& sequence, double sigma) {
  const std::vector<StampedPose>& truth = sequence.ground_truth->poses;
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const StampedPose& pose : truth) mean += pose.T_world_cam.translation() / truth.size();
  double spread = 0.0;
  for (const StampedPose& pose : truth) spread += (pose.T_world_cam.translation() - mean).squaredNorm();
  return sigma / std::sqrt(spread);
}

// An exact prior: issue 11's criterion, the depth in metres within 10 % of
// the per-frame scale-aligned error.
TEST(EstimateSequencePosePrior, ExactPriorGivesPosesInItsFrameAndDepthInMetres) {
  const MetricErrors errors = RunWithPrior("seq", SmallSequence(), "exact", 0.0);
  EXPECT_LT(errors.worst_position, 0.01);
  EXPECT_LE(errors.depth_in_metres, 1.1 * errors.depth_scale_aligned);
}

// 1 cm noise per axis on the long path. Issue 11's criterion (depth in
// metres <= 1.1 x the per-frame scale-aligned error, about 0.013 here) needs
// the scale within about 0.5 %, i.e. a scale uncertainty of 0.2 % to hold at
// 3 sigma: 1 cm / 0.002 = 5 m of sqrt(sum |p - mean p|^2), a path of several
// metres that neither this scene nor a test's time allows. It is printed,
// not asserted. Asserted: the reported uncertainty is the physics' figure
// (within 30 %; it is estimated from 16 frames' residuals); the scale is
// within 3 of it; positions within 3 noise sigmas; the depth in metres
// within the scale-aligned error plus 3 scale uncertainties.
TEST(EstimateSequencePosePrior, NoisyPriorGivesPosesInItsFrameAndDepthInMetres) {
  const MetricErrors errors = RunWithPrior("long", LongSequence(), "noisy", 0.01);
  const double sigma = ScaleSigma(LongSequence(), 0.01);
  std::printf("  scale sigma of the prior's noise: %.4f\n", sigma);
  EXPECT_NEAR(errors.scale_uncertainty / sigma, 1.0, 0.3);
  EXPECT_LE(std::abs(errors.scale_error), 3.0 * errors.scale_uncertainty);
  EXPECT_LT(errors.worst_position, 0.03);
  EXPECT_LE(errors.depth_in_metres, errors.depth_scale_aligned + 3.0 * errors.scale_uncertainty);
}

TEST(EstimateSequencePosePrior, StillPriorLeavesTheEstimateUnchanged) {
  const std::string output = Folder() + "/out_still";
  const ToolRun run = Estimate("seq", WritePrior(SmallSequence(), "still.txt", 0.0, true), output);
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
  std::vector<std::string> negative = with(later);
  negative.insert(negative.end(), {"--pose-prior-sigma", "-0.01"});
  ExpectOneLineError("estimate_sequence", negative, "--pose-prior-sigma");
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
