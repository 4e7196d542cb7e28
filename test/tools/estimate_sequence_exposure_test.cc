// estimate_sequence --exposure auto (docs/tools.md#estimate_sequence): the
// exposures of frames.csv are replaced by the one estimated from the blur,
// which report.json (`exposure_estimate`) and the result's frames.csv give;
// without the flag the report says null and frames.csv's exposures stay.
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

TEST(EstimateSequenceExposure, AutoReplacesTheExposuresAndReportsThem) {
  const std::string folder = testing::TempDir() + "/dsm_exposure_tool_" + std::to_string(::getpid());
  const std::string input = folder + "/seq";
  // A wrong exposure in frames.csv (0.8 of the interval) that auto must ignore: the blur is that of 0.4.
  ASSERT_EQ(SynthesizeInto(input, "Dolls",
                           "--frames 4 --subframes 60 --exposure-ratio 0.4 --hr-width 240 "
                           "--hr-height 180"),
            0);
  Sequence sequence = ReadSequence(input, false);
  const double truth = sequence.frames[1].exposure;
  for (FrameRecord& frame : sequence.frames) frame.exposure *= 2.0;
  WriteFramesCsv(input + "/frames.csv", sequence.frames);

  const ToolRun run = RunTool("estimate_sequence", {"--input", input, "--output", folder + "/auto",
                                                    "--exposure", "auto", "--iterations", "0", "--quiet"});
  ASSERT_EQ(run.exit_code, 0) << run.err;
  const nlohmann::json report = nlohmann::json::parse(FileText(folder + "/auto/report.json"));
  const nlohmann::json& estimate = report["exposure_estimate"];
  ASSERT_TRUE(estimate.is_object()) << report.dump();
  EXPECT_TRUE(estimate["measured"].get<bool>());
  EXPECT_NEAR(estimate["fraction"].get<double>(), 0.4, 0.04);
  EXPECT_NEAR(estimate["seconds"].get<double>(), truth, 0.1 * truth);
  ASSERT_EQ(estimate["frame_exposures"].size(), sequence.frames.size());
  EXPECT_GT(estimate["elapsed_seconds"].get<double>(), 0.0);
  const std::vector<FrameRecord> written = ReadFramesCsv(folder + "/auto/frames.csv");
  ASSERT_EQ(written.size(), sequence.frames.size());
  for (size_t t = 0; t < written.size(); ++t)
    EXPECT_DOUBLE_EQ(written[t].exposure, estimate["frame_exposures"][t].get<double>());

  const ToolRun known = RunTool(
      "estimate_sequence", {"--input", input, "--output", folder + "/known", "--iterations", "0", "--quiet"});
  ASSERT_EQ(known.exit_code, 0) << known.err;
  EXPECT_TRUE(nlohmann::json::parse(FileText(folder + "/known/report.json"))["exposure_estimate"].is_null());
  EXPECT_DOUBLE_EQ(ReadFramesCsv(folder + "/known/frames.csv")[1].exposure, 2.0 * truth);
  ExpectOneLineError("estimate_sequence",
                     {"--input", input, "--output", folder + "/bad", "--exposure", "0.01"}, "--exposure");
  std::filesystem::remove_all(folder);
}

}  // namespace
}  // namespace deblur_sr_mvs
