// The tools' command lines: CLI11 with the tools' contract (bad input: exit
// code 2 and one line "<tool>: <reason>" on stderr; --help: usage on stdout,
// exit code 0).
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "deblur_sr_mvs/core/common/errors.h"
#include "tool_main.h"
#include "tool_test_util.h"

namespace deblur_sr_mvs {
namespace {

using test::ExpectOneLineError;
using test::RunTool;

// The message of the InputError that parsing `arguments` throws, or
// "(accepted)".
std::string ParseMessage(const std::vector<std::string>& arguments, int* n = nullptr, double* x = nullptr) {
  int n_value = 0;
  double x_value = 0.0;
  ToolCommandLine cli("tool", "a test");
  cli.add_option("--n", n_value)->check(FlagInt());
  cli.add_option("--x", x_value)->check(FlagNumber());
  cli.add_option("--scale", n_value)->check(FlagInt(2, 8));
  cli.add_option("--exposure", x_value)->check(FlagNumber(1e-6));
  cli.add_option("--crop", x_value)->check(FlagNumber(1e-6, 1.0));
  std::vector<std::string> words = {"tool"};
  words.insert(words.end(), arguments.begin(), arguments.end());
  std::vector<char*> argv;
  for (std::string& word : words) argv.push_back(word.data());
  try {
    cli.Parse(static_cast<int>(argv.size()), argv.data());
  } catch (const InputError& error) {
    return error.what();
  }
  if (n) *n = n_value;
  if (x) *x = x_value;
  return "(accepted)";
}

// The validators every tool shares: whole text, finite, in range; the
// message names the flag, the range and the text.
TEST(ToolFlags, ParseWholeFiniteValuesInRange) {
  int n = 0;
  double x = 0.0;
  EXPECT_EQ(ParseMessage({"--n", "12"}, &n), "(accepted)");
  EXPECT_EQ(n, 12);
  EXPECT_EQ(ParseMessage({"--n", "-3"}, &n), "(accepted)");
  EXPECT_EQ(n, -3);
  EXPECT_EQ(ParseMessage({"--x", "0.25"}, nullptr, &x), "(accepted)");
  EXPECT_DOUBLE_EQ(x, 0.25);
  EXPECT_EQ(ParseMessage({"--crop", "1e-3"}, nullptr, &x), "(accepted)");
  EXPECT_DOUBLE_EQ(x, 1e-3);
  EXPECT_EQ(ParseMessage({"--n=7", "--n", "9"}, &n), "(accepted)");
  EXPECT_EQ(n, 9);  // a repeated flag keeps its last value
  for (const char* bad : {"", "1.5", "12a", "a", " ", "99999999999"}) {
    EXPECT_NE(ParseMessage({"--n", bad}).find("--n: expects an integer"), std::string::npos) << bad;
  }
  for (const char* bad : {"", "nan", "inf", "-inf", "1e999", "1..2", "0.5x"}) {
    EXPECT_NE(ParseMessage({"--x", bad}).find("--x: expects a number"), std::string::npos) << bad;
  }
  EXPECT_EQ(ParseMessage({"--scale", "1"}), "--scale: expects an integer in [2, 8], got '1' (see --help)");
  EXPECT_EQ(ParseMessage({"--exposure", "-1"}),
            "--exposure: expects a number >= 1e-06, got '-1' (see --help)");
  EXPECT_NE(ParseMessage({"--frobnicate"}).find("--frobnicate"), std::string::npos);
  EXPECT_NE(ParseMessage({"--frobnicate", "--scale", "1"}).find("--frobnicate"), std::string::npos);
  EXPECT_NE(ParseMessage({"--n"}).find("--n"), std::string::npos);  // no value
  EXPECT_NE(ParseMessage({"stray"}).find("stray"), std::string::npos);
}

TEST(ToolFlags, HelpPrintsUsageAndExitsZero) {
  for (const char* tool : {"estimate_sequence", "evaluate_sequence", "synthesize_sequence",
                           "make_comparison_figure", "benchmark_capture_operator", "benchmark_stream"}) {
    for (const char* flag : {"--help", "-h"}) {
      const test::ToolRun run = RunTool(tool, {flag});
      EXPECT_EQ(run.exit_code, 0) << tool << " " << flag;
      EXPECT_NE(run.out.find("Usage: "), std::string::npos) << tool << "\n" << run.out;
      EXPECT_NE(run.out.find("--"), std::string::npos) << tool;
      EXPECT_TRUE(run.err.empty()) << tool << ": " << run.err;
    }
  }
}

TEST(ToolFlags, BadFlagsGiveOneLineAndExitCode2) {
  const std::string scene = std::string(DSM_SOURCE_DIR) + "/data/middlebury/Dolls";
  const std::string out = testing::TempDir() + "/dsm_tool_flags_out";
  // Bad numbers, out of range, unknown flags, missing values and flags.
  ExpectOneLineError("synthesize_sequence", {"--scene", scene, "--output", out, "--frames", "ten"},
                     "--frames");
  ExpectOneLineError("synthesize_sequence", {"--scene", scene, "--output", out, "--noise", "nan"}, "--noise");
  ExpectOneLineError("synthesize_sequence", {"--scene", scene, "--output", out, "--seed", "-1"}, "--seed");
  ExpectOneLineError("synthesize_sequence", {"--scene", scene, "--output", out, "--path", "loop"}, "--path");
  ExpectOneLineError("synthesize_sequence", {"--scene", scene, "--output", out, "--bogus", "1"}, "--bogus");
  ExpectOneLineError("synthesize_sequence", {"--output", out}, "--scene");
  ExpectOneLineError("synthesize_sequence", {"--frobnicate", "x"}, "--frobnicate");  // before --scene
  ExpectOneLineError("evaluate_sequence", {"--result", scene, "--sequence", scene, "--crop", "1.5"},
                     "--crop");
  ExpectOneLineError("evaluate_sequence", {"--result", scene, "--sequence"}, "--sequence");
  ExpectOneLineError("make_comparison_figure", {"--sequence", scene, "--output", out, "--frame", "-1"},
                     "--frame");
  ExpectOneLineError("benchmark_capture_operator", {"--repeats", "abc"}, "--repeats");
  ExpectOneLineError("benchmark_capture_operator", {"--samples", "0"}, "--samples");
  ExpectOneLineError("benchmark_capture_operator", {"--threads", "2"}, "--threads");
  ExpectOneLineError("benchmark_stream", {"--input", scene, "--output", out, "--window-size", "2"},
                     "--window-size");
  ExpectOneLineError("benchmark_stream", {"--output", out}, "--input");
  ExpectOneLineError("benchmark_stream", {"--input", scene, "--output", out, "--iterations", "-1"},
                     "--iterations");
  ExpectOneLineError("benchmark_stream", {"--input", scene, "--output", out, "--continued-iterations", "x"},
                     "--continued-iterations");
  ExpectOneLineError("benchmark_stream",
                     {"--input", scene, "--output", out, "--window-size", "4", "--window-overlap", "4"},
                     "window_overlap");
}

// estimate_sequence: bad input gives exit code 2 and exactly one line on stderr.
TEST(EstimateSequenceTool, BadInputGivesOneLineAndExitCode2) {
  const std::string out = testing::TempDir() + "/out";
  const std::string folder = std::string(DSM_SOURCE_DIR) + "/data";  // exists, no sequence
  ExpectOneLineError("estimate_sequence", {"--input", "/nonexistent/seq", "--output", out},
                     "/nonexistent/seq");
  ExpectOneLineError("estimate_sequence", {"--input", folder, "--output", out}, folder);
  ExpectOneLineError("estimate_sequence", {"--input", folder, "--output", out, "--mode", "fancy"}, "--mode");
  ExpectOneLineError("estimate_sequence", {"--input", folder, "--output", out, "--samples", "0"}, "samples");
  ExpectOneLineError("estimate_sequence", {"--input", folder, "--output", out, "--lambda-d", "abc"},
                     "--lambda-d");
  ExpectOneLineError("estimate_sequence", {"--input", folder, "--output", out, "--lambda-s", "inf"},
                     "--lambda-s");
  ExpectOneLineError("estimate_sequence", {"--input", folder, "--output", out, "--output-scale", "5"},
                     "--output-scale");
  ExpectOneLineError("estimate_sequence", {"--input", folder, "--output", out, "--structure-matching", "x"},
                     "--structure-matching");
  ExpectOneLineError("estimate_sequence",
                     {"--input", folder, "--output", out, "--recentred-depth-preconditioner", "ilu"},
                     "--recentred-depth-preconditioner");
  ExpectOneLineError("estimate_sequence", {"--output", out}, "--input");
}

}  // namespace
}  // namespace deblur_sr_mvs
