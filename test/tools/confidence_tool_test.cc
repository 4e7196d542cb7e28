// evaluate_sequence --recompute-confidence: recomputing the depth confidence
// from a written result (8-bit latents) masks the depth as the maps that
// estimate_sequence wrote do, so results of older builds can be evaluated as
// this build would publish them.
#include <string>

#include <unistd.h>

#include <filesystem>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "tool_test_util.h"

namespace deblur_sr_mvs {
namespace {

nlohmann::json Evaluate(const std::string& result_dir, const std::string& sequence_dir,
                        const std::vector<std::string>& extra) {
  const std::string json_path = result_dir + "_eval.json";
  std::vector<std::string> arguments = {"--result",   result_dir, "--sequence",
                                        sequence_dir, "--json",   json_path};
  arguments.insert(arguments.end(), extra.begin(), extra.end());
  const test::ToolRun run = test::RunTool("evaluate_sequence", arguments);
  EXPECT_EQ(run.exit_code, 0) << run.err;
  return nlohmann::json::parse(test::FileText(json_path))["mean"];
}

TEST(EvaluateSequenceTool, RecomputedConfidenceMasksLikeTheWrittenMaps) {
  const std::string root = testing::TempDir() + "/dsm_confidence_tool_" + std::to_string(::getpid());
  const std::string sequence_dir = root + "/sequence", result_dir = root + "/result";
  const test::ToolRun synthesized =
      test::RunTool("synthesize_sequence", {"--scene", std::string(DSM_SOURCE_DIR) + "/data/middlebury/Dolls",
                                            "--output", sequence_dir, "--path", "lateral", "--frames", "4",
                                            "--subframes", "100", "--hr-width", "240", "--hr-height", "180"});
  ASSERT_EQ(synthesized.exit_code, 0) << synthesized.err;
  const test::ToolRun estimated = test::RunTool(
      "estimate_sequence", {"--input", sequence_dir, "--output", result_dir, "--iterations", "1", "--samples",
                            "20", "--depth-confidence-threshold", "0", "--quiet"});
  ASSERT_EQ(estimated.exit_code, 0) << estimated.err;

  const nlohmann::json unmasked = Evaluate(result_dir, sequence_dir, {});
  const nlohmann::json written = Evaluate(result_dir, sequence_dir, {"--confidence-threshold", "0.5"});
  const nlohmann::json recomputed =
      Evaluate(result_dir, sequence_dir, {"--confidence-threshold", "0.5", "--recompute-confidence"});
  const double coverage_unmasked = unmasked["depth_coverage_full_frame"].get<double>();
  const double coverage_written = written["depth_coverage_full_frame"].get<double>();
  const double coverage_recomputed = recomputed["depth_coverage_full_frame"].get<double>();
  std::printf("coverage: unmasked %.3f, written maps %.3f, recomputed %.3f\n", coverage_unmasked,
              coverage_written, coverage_recomputed);
  EXPECT_LT(coverage_written, coverage_unmasked);  // the mask does something here
  // The same maps up to the 8-bit rounding of the written latents.
  EXPECT_NEAR(coverage_recomputed, coverage_written, 0.01);
  EXPECT_NEAR(recomputed["depth_relative_error_full_frame"].get<double>(),
              written["depth_relative_error_full_frame"].get<double>(),
              0.02 * written["depth_relative_error_full_frame"].get<double>());

  const test::ToolRun alone = test::RunTool(
      "evaluate_sequence", {"--result", result_dir, "--sequence", sequence_dir, "--recompute-confidence"});
  EXPECT_EQ(alone.exit_code, 2);
  EXPECT_NE(alone.err.find("--recompute-confidence needs --confidence-threshold"), std::string::npos)
      << alone.err;
  std::filesystem::remove_all(root);
}

}  // namespace
}  // namespace deblur_sr_mvs
