// estimate_sequence --readout-time auto (docs/tools.md#estimate_sequence): a
// rolling-shutter sequence whose sensor.yaml is gone (a camera whose readout
// time nobody knows) gets its readout time measured from the tracks, which
// report.json (`readout_estimate`) gives; without the flag the report says
// null.
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <string>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "tool_test_util.h"

namespace deblur_sr_mvs {
namespace {

using test::ExpectOneLineError;
using test::FileText;
using test::RunTool;
using test::SynthesizeInto;
using test::ToolRun;

TEST(EstimateSequenceReadout, AutoMeasuresTheReadoutAndReportsIt) {
  const std::string folder = testing::TempDir() + "/dsm_readout_tool_" + std::to_string(::getpid());
  const std::string input = folder + "/seq";
  ASSERT_EQ(SynthesizeInto(
                input, "Dolls",
                "--path handheld --frames 6 --hr-width 240 --hr-height 180 --seed 3 --readout-ratio 0.8"),
            0);
  ASSERT_TRUE(std::filesystem::remove(input + "/sensor.yaml"));

  const ToolRun run = RunTool("estimate_sequence", {"--input", input, "--output", folder + "/auto",
                                                    "--readout-time", "auto", "--iterations", "0", "--quiet"});
  ASSERT_EQ(run.exit_code, 0) << run.err;
  const nlohmann::json report = nlohmann::json::parse(FileText(folder + "/auto/report.json"));
  const nlohmann::json& estimate = report["readout_estimate"];
  ASSERT_TRUE(estimate.is_object()) << report.dump();
  EXPECT_TRUE(estimate["measured"].get<bool>());
  EXPECT_NEAR(estimate["fraction"].get<double>(), 0.8, 0.1);
  EXPECT_NEAR(estimate["seconds"].get<double>(), estimate["fraction"].get<double>() / 30.0, 1e-6);
  EXPECT_EQ(estimate["rms_px_by_fraction"].size(), 11u);
  EXPECT_TRUE(report["stage_seconds"].contains("readout estimation")) << report["stage_seconds"].dump();

  const ToolRun unknown = RunTool(
      "estimate_sequence", {"--input", input, "--output", folder + "/unknown", "--iterations", "0", "--quiet"});
  ASSERT_EQ(unknown.exit_code, 0) << unknown.err;
  EXPECT_TRUE(nlohmann::json::parse(FileText(folder + "/unknown/report.json"))["readout_estimate"].is_null());
  ExpectOneLineError("estimate_sequence",
                     {"--input", input, "--output", folder + "/bad", "--readout-time", "0.01"}, "--readout-time");
  std::filesystem::remove_all(folder);
}

// A rotation has no parallax to measure on: the run goes on with readout 0
// and the report says why.
TEST(EstimateSequenceReadout, ARotationIsNotMeasured) {
  const std::string folder = testing::TempDir() + "/dsm_readout_rotation_" + std::to_string(::getpid());
  const std::string input = folder + "/seq";
  ASSERT_EQ(SynthesizeInto(input, "Moebius",
                           "--path rotate --frames 5 --hr-width 160 --hr-height 120 --readout-ratio 0.5"),
            0);
  const ToolRun run = RunTool("estimate_sequence", {"--input", input, "--output", folder + "/auto",
                                                    "--readout-time", "auto", "--iterations", "0", "--quiet"});
  ASSERT_EQ(run.exit_code, 0) << run.err;
  const nlohmann::json estimate =
      nlohmann::json::parse(FileText(folder + "/auto/report.json"))["readout_estimate"];
  ASSERT_TRUE(estimate.is_object());
  EXPECT_FALSE(estimate["measured"].get<bool>());
  EXPECT_EQ(estimate["seconds"].get<double>(), 0.0);
  EXPECT_NE(estimate["summary"].get<std::string>().find("no pair of the 5 frames has parallax"), std::string::npos)
      << estimate.dump();
  std::filesystem::remove_all(folder);
}

}  // namespace
}  // namespace deblur_sr_mvs
