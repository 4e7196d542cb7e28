// The JSON files the tools write are strict JSON: read back with
// nlohmann::json::parse, which throws on anything that is not.
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <limits>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "estimate_report.h"
#include "report_json.h"
#include "tool_test_util.h"

namespace deblur_sr_mvs {
namespace {

namespace fs = std::filesystem;
using test::FileText;
using test::RunTool;

TEST(ReportJson, NonFiniteNumbersBecomeNullAndStringsAreEscaped) {
  Json json;
  json["nan"] = JsonNumber(std::numeric_limits<double>::quiet_NaN());
  json["inf"] = JsonNumber(-std::numeric_limits<double>::infinity());
  json["number"] = JsonNumber(0.125);
  json["text"] = std::string("a \"quoted\" back\\slash\nnew line \x01 and \xff not UTF-8");
  const nlohmann::json read = nlohmann::json::parse(JsonText(json));
  EXPECT_TRUE(read["nan"].is_null());
  EXPECT_TRUE(read["inf"].is_null());
  EXPECT_EQ(read["number"].get<double>(), 0.125);
  EXPECT_EQ(read["text"].get<std::string>(),
            "a \"quoted\" back\\slash\nnew line \x01 and \xEF\xBF\xBD not UTF-8");  // U+FFFD
  EXPECT_EQ(JsonText(json).back(), '\n');
}

// An iteration undone because it lost the energy: its energies are NaN; the
// report keeps the keys, writes null and carries the note.
TEST(ReportJson, UndoneIterationWithNanEnergiesIsStrictJson) {
  EstimatorOptions options;
  EstimatorResult result;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  result.energies = {{0, "initialization", 10.0, 6.0, 2.0, 1.0, 1.0},
                     {1, "image", 8.0, 5.0, 1.5, 1.0, 0.5},
                     {1, "structure", nan, nan, 1.5, 1.0, nan},
                     {2, "image", nan, nan, nan, nan, nan},
                     {1, "restored", 8.0, 5.0, 1.5, 1.0, 0.5}};
  result.timings = {{"image update", 0.5}, {"structure update", nan}};
  result.initializer_summary = "tracks: 40\n\"pairs\": 3";
  result.notes = {"iteration 1 lost the energy (not finite): undone, iterations stopped"};
  const std::string input = "/tmp/a \"quoted\" and back\\slashed folder";
  const std::string text = JsonText(EstimateReportJson(options, input, result, 1.5, 100.0));
  nlohmann::json report;
  ASSERT_NO_THROW(report = nlohmann::json::parse(text)) << text;
  EXPECT_EQ(report["input"], input);
  ASSERT_EQ(report["energies"].size(), 5u);
  EXPECT_TRUE(report["energies"][2]["total"].is_null());
  EXPECT_TRUE(report["energies"][2]["matching"].is_null());
  EXPECT_EQ(report["energies"][2]["self_consistency"].get<double>(), 1.5);
  EXPECT_TRUE(report["energies"][3]["depth_tv"].is_null());
  EXPECT_EQ(report["energies"][4]["stage"], "restored");
  EXPECT_TRUE(report["stage_seconds"]["structure update"].is_null());
  EXPECT_EQ(report["initializer"], "tracks: 40;\"pairs\": 3");
  ASSERT_EQ(report["solver_notes"].size(), 1u);
  EXPECT_NE(report["solver_notes"][0].get<std::string>().find("undone"), std::string::npos);
  // The keys, in the order report.json has always had them (frame_gains
  // and noise appended for issue 12, image_work for the image-solve counts).
  const nlohmann::ordered_json ordered = nlohmann::ordered_json::parse(text);
  std::vector<std::string> keys;
  for (auto it = ordered.begin(); it != ordered.end(); ++it) keys.push_back(it.key());
  const std::vector<std::string> expected = {
      "input",       "parameters",   "energies",        "stage_seconds", "wall_seconds", "peak_memory_mib",
      "initializer", "solver_notes", "monocular_scale", "frame_gains",   "noise",        "image_work"};
  EXPECT_EQ(keys, expected);
  EXPECT_EQ(report["parameters"]["mode"], "joint");
  EXPECT_EQ(report["parameters"]["update_poses"], true);
  EXPECT_EQ(report["parameters"]["gain_compensation"], true);  // the default
  EXPECT_TRUE(report["frame_gains"].is_array());
  EXPECT_TRUE(report["noise"]["sigma_gray_levels"].is_number());
}

// The case: an input folder whose name has a quote and a backslash
// gives a report.json that a strict parser reads, naming the folder exactly.
TEST(EstimateSequenceTool, ReportIsStrictJsonForAPathWithQuoteAndBackslash) {
  const fs::path root = fs::path(testing::TempDir()) / ("dsm_report_json_" + std::to_string(::getpid()));
  const std::string input = (root / "seq \"quoted\" back\\slash").string();
  const std::string output = (root / "result").string();
  const test::ToolRun synth =
      RunTool("synthesize_sequence",
              {"--scene", std::string(DSM_SOURCE_DIR) + "/data/middlebury/Dolls", "--output", input,
               "--frames", "3", "--subframes", "51", "--hr-width", "160", "--hr-height", "120"});
  ASSERT_EQ(synth.exit_code, 0) << synth.err;
  const test::ToolRun run = RunTool("estimate_sequence", {"--input", input, "--output", output,
                                                          "--iterations", "1", "--samples", "8", "--quiet"});
  ASSERT_EQ(run.exit_code, 0) << run.err;
  const std::string text = FileText(output + "/report.json");
  nlohmann::json report;
  ASSERT_NO_THROW(report = nlohmann::json::parse(text)) << text;
  EXPECT_EQ(report["input"], input);
  EXPECT_EQ(report["parameters"]["iterations"], 1);
  EXPECT_EQ(report["parameters"]["samples"], 8);
  ASSERT_FALSE(report["energies"].empty());
  for (const auto& energy : report["energies"]) {
    EXPECT_TRUE(energy["total"].is_number() || energy["total"].is_null());
  }
  EXPECT_TRUE(report["solver_notes"].is_array());
  std::error_code ignored;
  fs::remove_all(root, ignored);
}

}  // namespace
}  // namespace deblur_sr_mvs
