// estimate_sequence on a pure rotation (docs/file_formats.md#no-parallax):
// every frame is written, with NaN depth, the orientations and restored
// images are measured by evaluate_sequence, and report.json says that depth
// is not observable.
#include <cmath>
#include <filesystem>
#include <string>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "deblur_sr_mvs/core/evaluation/evaluation.h"
#include "deblur_sr_mvs/core/io/result_io.h"
#include "deblur_sr_mvs/core/io/sequence_io.h"
#include "tool_test_util.h"

namespace deblur_sr_mvs {
namespace {

TEST(EstimateSequenceTool, PureRotationWritesEveryFrameWithNanDepthAndSaysWhy) {
  const std::string root = testing::TempDir() + "/dsm_rotation_tool_" + std::to_string(::getpid());
  const std::string sequence_dir = root + "/sequence", result_dir = root + "/result";
  const test::ToolRun synthesized = test::RunTool(
      "synthesize_sequence",
      {"--scene", std::string(DSM_SOURCE_DIR) + "/data/middlebury/Moebius", "--output", sequence_dir,
       "--path", "rotate", "--frames", "6", "--subframes", "100", "--hr-width", "240", "--hr-height", "180"});
  ASSERT_EQ(synthesized.exit_code, 0) << synthesized.err;
  const test::ToolRun estimated =
      test::RunTool("estimate_sequence", {"--input", sequence_dir, "--output", result_dir, "--quiet"});
  ASSERT_EQ(estimated.exit_code, 0) << estimated.err;

  const SequenceResult result = ReadResult(result_dir);
  ASSERT_EQ(result.latent.size(), 6u);
  ASSERT_EQ(result.depth.size(), 6u);
  for (const cv::Mat& depth : result.depth) EXPECT_EQ(cv::countNonZero(depth == depth), 0) << "depth not NaN";
  const nlohmann::json report = nlohmann::json::parse(test::FileText(result_dir + "/report.json"));
  EXPECT_NE(report["monocular_scale"].get<std::string>().find("no parallax: depth not observable"),
            std::string::npos)
      << report["monocular_scale"];
  bool noted = false;
  for (const auto& note : report["solver_notes"]) {
    noted |= note.get<std::string>().find("no parallax: depth not observable") != std::string::npos;
  }
  EXPECT_TRUE(noted) << report["solver_notes"];

  const EvaluationReport evaluation = EvaluateResult(result, ReadSequence(sequence_dir, true));
  ASSERT_TRUE(evaluation.max_rotation_error_deg.has_value());
  std::printf(
      "estimate_sequence, pure rotation (Moebius): bicubic %.2f dB, restored %.2f dB, rotation error "
      "mean %.3f max %.3f deg\n",
      evaluation.mean_bicubic_psnr_db, evaluation.mean_image_psnr_db, *evaluation.mean_rotation_error_deg,
      *evaluation.max_rotation_error_deg);
  EXPECT_GE(evaluation.mean_image_psnr_db, evaluation.mean_bicubic_psnr_db + 4.0);
  EXPECT_LE(*evaluation.max_rotation_error_deg, 0.2);
  std::filesystem::remove_all(root);
}

}  // namespace
}  // namespace deblur_sr_mvs
