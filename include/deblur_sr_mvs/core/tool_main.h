// The common main() of the command-line tools: run, and turn every error into
// one line on stderr and exit code 2 (SPEC section 4: never a signal, an
// abort or a stack trace).
#pragma once

#include <exception>
#include <iostream>
#include <string>

namespace deblur_sr_mvs {

// `text` on one line (cv::Exception messages span several).
inline std::string OneLine(const std::string& text) {
  std::string out;
  for (const char c : text) out += (c == '\n' || c == '\r') ? ' ' : c;
  while (!out.empty() && out.back() == ' ') out.pop_back();
  return out;
}

// Returns run(argc, argv), or 2 after printing "<tool>: <reason>".
template <typename Run>
int ToolMain(const char* tool, Run&& run, int argc, char** argv) {
  try {
    return run(argc, argv);
  } catch (const std::exception& error) {
    std::cerr << tool << ": " << OneLine(error.what()) << "\n";
  } catch (...) {
    std::cerr << tool << ": unexpected error\n";
  }
  return 2;
}

}  // namespace deblur_sr_mvs
