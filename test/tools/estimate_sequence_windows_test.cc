// estimate_sequence --window-size / --window-overlap (docs/tools.md#estimate_sequence):
// a sequence longer than the window runs in overlapping windows, as the node
// streams it; every frame gets its outputs, report.json lists the windows,
// and the exposure and the readout time are measured per window; the
// windows are tied to the whole sequence's trajectory (--tie-windows).
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <string>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "deblur_sr_mvs/core/io/sequence_io.h"
#include "tool_test_util.h"

namespace deblur_sr_mvs {
namespace {

using test::ExpectOneLineError;
using test::FileText;
using test::RunTool;
using test::SynthesizeInto;
using test::ToolRun;

int CountFiles(const std::string& folder) {
  int count = 0;
  for (const auto& entry : std::filesystem::directory_iterator(folder)) count += entry.is_regular_file();
  return count;
}

TEST(EstimateSequenceWindows, LongerSequencesRunInWindowsAndEveryFrameIsWritten) {
  const std::string folder = testing::TempDir() + "/dsm_windows_tool_" + std::to_string(::getpid());
  const std::string input = folder + "/seq";
  ASSERT_EQ(
      SynthesizeInto(input, "Dolls",
                     "--path handheld --frames 8 --hr-width 160 --hr-height 120 --subframes 60 --seed 2"),
      0);

  const ToolRun run = RunTool(
      "estimate_sequence", {"--input", input, "--output", folder + "/windows", "--window-size", "5",
                            "--iterations", "0", "--exposure", "auto", "--readout-time", "auto", "--quiet"});
  ASSERT_EQ(run.exit_code, 0) << run.err;
  EXPECT_EQ(CountFiles(folder + "/windows/latent"), 8);
  EXPECT_EQ(CountFiles(folder + "/windows/depth"), 8);
  const nlohmann::json report = nlohmann::json::parse(FileText(folder + "/windows/report.json"));
  const nlohmann::json& windows = report["windows"];
  ASSERT_EQ(windows.size(), 2u) << report.dump();
  EXPECT_EQ(windows[0]["first_frame"].get<int>(), 0);
  EXPECT_EQ(windows[0]["last_frame"].get<int>(), 4);
  EXPECT_EQ(windows[1]["first_frame"].get<int>(), 3);
  EXPECT_EQ(windows[1]["last_frame"].get<int>(), 7);
  EXPECT_EQ(windows[1]["first_output_frame"].get<int>(), 4);
  EXPECT_TRUE(windows[1]["continued"].get<bool>()) << windows[1].dump();
  EXPECT_EQ(report["frame_gains"].size(), 8u);
  // The exposure is measured on each window's frames (0.8 of the frame
  // interval, the synthesizer's default), the readout on each window and
  // combined (a global shutter: 0).
  EXPECT_EQ(report["exposure_estimate"]["frame_exposures"].size(), 8u);
  for (const nlohmann::json& window : windows) {
    EXPECT_NEAR(window["exposure_fraction"].get<double>(), 0.8, 0.08) << window.dump();
  }
  const std::vector<FrameRecord> written = ReadFramesCsv(folder + "/windows/frames.csv");
  ASSERT_EQ(written.size(), 8u);
  for (size_t t = 0; t < written.size(); ++t)
    EXPECT_DOUBLE_EQ(written[t].exposure, report["exposure_estimate"]["frame_exposures"][t].get<double>());
  const nlohmann::json& readout = report["readout_estimate"];
  EXPECT_NE(readout["summary"].get<std::string>().find("2 windows' measurements"), std::string::npos)
      << readout.dump();
  EXPECT_LT(readout["seconds"].get<double>(), 0.1 / 30.0);

  EXPECT_EQ(report["window_size"].get<int>(), 5);
  // The windows are tied to the whole sequence's trajectory unless told not to.
  auto says_tied = [](const nlohmann::json& notes) {
    for (const nlohmann::json& note : notes) {
      if (note.get<std::string>().find("windows tied to the whole sequence's trajectory") !=
          std::string::npos)
        return true;
    }
    return false;
  };
  EXPECT_TRUE(says_tied(report["solver_notes"])) << report["solver_notes"].dump();
  const ToolRun untied =
      RunTool("estimate_sequence", {"--input", input, "--output", folder + "/untied", "--window-size", "5",
                                    "--iterations", "0", "--no-tie-windows", "--quiet"});
  ASSERT_EQ(untied.exit_code, 0) << untied.err;
  const nlohmann::json untied_report = nlohmann::json::parse(FileText(folder + "/untied/report.json"));
  EXPECT_FALSE(says_tied(untied_report["solver_notes"])) << untied_report["solver_notes"].dump();
  EXPECT_EQ(untied_report["windows"].size(), 2u);

  // --window-size auto (the default): at 160x120 HR in colour 8 GiB holds
  // far more than the stream's 64 frames, so the sequence is one window.
  const ToolRun whole = RunTool(
      "estimate_sequence", {"--input", input, "--output", folder + "/whole", "--iterations", "0", "--quiet"});
  ASSERT_EQ(whole.exit_code, 0) << whole.err;
  const nlohmann::json whole_report = nlohmann::json::parse(FileText(folder + "/whole/report.json"));
  EXPECT_EQ(whole_report["window_size"].get<int>(), 64);
  const nlohmann::json& one = whole_report["windows"];
  ASSERT_EQ(one.size(), 1u);
  EXPECT_EQ(one[0]["last_frame"].get<int>(), 7);

  ExpectOneLineError("estimate_sequence",
                     {"--input", input, "--output", folder + "/bad", "--window-size", "2"}, "--window-size");
  ExpectOneLineError("estimate_sequence",
                     {"--input", input, "--output", folder + "/bad", "--window-size", "many"},
                     "--window-size");
  ExpectOneLineError(
      "estimate_sequence",
      {"--input", input, "--output", folder + "/bad", "--window-size", "5", "--window-overlap", "5"},
      "--window-overlap");
  std::filesystem::remove_all(folder);
}

}  // namespace
}  // namespace deblur_sr_mvs
