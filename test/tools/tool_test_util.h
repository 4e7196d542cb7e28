// Runs a tool of the build as a child process and captures its exit code,
// stdout and stderr (for the tests of the tools' command lines).
#pragma once

#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <fstream>
#include <iterator>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

namespace deblur_sr_mvs {
namespace test {

struct ToolRun {
  int exit_code = -1;  // -1: did not exit normally (signal)
  std::string out, err;
};

inline std::string ShellQuoted(const std::string& text) {
  std::string quoted = "'";
  for (const char c : text) {
    if (c == '\'') {
      quoted += "'\\''";
    } else {
      quoted += c;
    }
  }
  return quoted + "'";
}

inline std::string FileText(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

// DSM_TOOL_DIR/tool with the arguments, each passed as one word.
inline ToolRun RunTool(const std::string& tool, const std::vector<std::string>& arguments) {
  const std::string stem = testing::TempDir() + "/dsm_tool_run_" + std::to_string(::getpid());
  std::string command = ShellQuoted(std::string(DSM_TOOL_DIR) + "/" + tool);
  for (const std::string& argument : arguments) command += " " + ShellQuoted(argument);
  command += " > " + ShellQuoted(stem + ".out") + " 2> " + ShellQuoted(stem + ".err");
  const int status = std::system(command.c_str());
  ToolRun run;
  if (WIFEXITED(status)) run.exit_code = WEXITSTATUS(status);
  run.out = FileText(stem + ".out");
  run.err = FileText(stem + ".err");
  return run;
}

// synthesize_sequence of data/middlebury/`scene` into `output` with the
// further `flags` (one string, as on a command line); its exit status.
inline int SynthesizeInto(const std::string& output, const std::string& scene, const std::string& flags) {
  const std::string command = std::string(DSM_TOOL_DIR) + "/synthesize_sequence --scene " + DSM_SOURCE_DIR +
                              "/data/middlebury/" + scene + " --output " + ShellQuoted(output) + " " + flags +
                              " > /dev/null";
  return std::system(command.c_str());
}

inline int LineCount(const std::string& text) {
  int lines = 0;
  for (const char c : text) lines += c == '\n';
  return lines;
}

// Exit code 2 and exactly one line "<tool>: ..." on stderr containing `needle`.
inline void ExpectOneLineError(const std::string& tool, const std::vector<std::string>& arguments,
                               const std::string& needle) {
  std::string joined;
  for (const std::string& argument : arguments) joined += " " + argument;
  SCOPED_TRACE(tool + joined);
  const ToolRun run = RunTool(tool, arguments);
  EXPECT_EQ(run.exit_code, 2);
  EXPECT_EQ(LineCount(run.err), 1) << run.err;
  EXPECT_EQ(run.err.rfind(tool + ": ", 0), 0u) << run.err;
  EXPECT_NE(run.err.find(needle), std::string::npos) << run.err;
}

}  // namespace test
}  // namespace deblur_sr_mvs
