// The common command line and main() of the command-line tools: flags through
// CLI11, and every error turned into one line on stderr and exit code 2
// (docs/tools.md#exit-codes: never a signal, an abort or a stack trace).
#pragma once

#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <exception>
#include <iostream>
#include <limits>
#include <sstream>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/common/text.h"

namespace deblur_sr_mvs {

// " in [min, max]", " >= min", " <= max" or nothing (the bound at the limit of
// the type is left out).
template <typename T>
std::string FlagRangeText(T min, T max, T lowest, T highest) {
  std::ostringstream text;
  if (min > lowest && max < highest) {
    text << " in [" << min << ", " << max << "]";
  } else if (min > lowest) {
    text << " >= " << min;
  } else if (max < highest) {
    text << " <= " << max;
  }
  return text.str();
}

// CLI11 validator of a number flag: the whole text must parse, be finite and
// lie in [min, max] (CLI11 alone takes "nan", "inf" and ""). Message:
// "--flag: expects a number[ in [min, max]], got 'text'".
inline CLI::Validator FlagNumber(double min = -std::numeric_limits<double>::max(),
                                 double max = std::numeric_limits<double>::max()) {
  const std::string range =
      FlagRangeText(min, max, -std::numeric_limits<double>::max(), std::numeric_limits<double>::max());
  return CLI::Validator(
      [min, max, range](std::string& text) -> std::string {
        char* end = nullptr;
        const double value = std::strtod(text.c_str(), &end);
        if (text.empty() || end != text.c_str() + text.size() || !std::isfinite(value) || value < min ||
            value > max) {
          return "expects a number" + range + ", got '" + text + "'";
        }
        return std::string();
      },
      "NUMBER" + range);
}

// Likewise for an integer (default: any of at most 9 digits):
// "--flag: expects an integer[ in [min, max]], got 'text'".
inline CLI::Validator FlagInt(int min = -999999999, int max = 999999999) {
  const std::string range = FlagRangeText(min, max, -999999999, 999999999);
  return CLI::Validator(
      [min, max, range](std::string& text) -> std::string {
        char* end = nullptr;
        errno = 0;
        const long value = std::strtol(text.c_str(), &end, 10);
        if (text.empty() || end != text.c_str() + text.size() || errno == ERANGE || value < min ||
            value > max) {
          return "expects an integer" + range + ", got '" + text + "'";
        }
        return std::string();
      },
      "INTEGER" + range);
}

// A tool's command line (CLI11) with the tools' conventions: --help / -h
// prints the help to stdout; a flag given twice keeps its last value.
class ToolCommandLine : public CLI::App {
 public:
  ToolCommandLine(const std::string& tool, const std::string& description) : CLI::App(description, tool) {
    option_defaults()->multi_option_policy(CLI::MultiOptionPolicy::TakeLast);
  }

  // Parses argv. Returns false after printing the help (the tool then exits
  // 0); a parse or validation error throws InputError with CLI11's message
  // ("--flag: ..."), which ToolMain prints as one line.
  bool Parse(int argc, char** argv) {
    try {
      parse(argc, argv);
    } catch (const CLI::CallForHelp&) {
      std::cout << help();
      return false;
    } catch (const CLI::ParseError& error) {
      // CLI11 checks required flags and values before it reports arguments it
      // does not know; a mistyped flag is the more useful message.
      const std::vector<std::string> unknown = remaining();
      const std::string message = unknown.empty() ? error.what() : CLI::ExtrasError(unknown).what();
      throw InputError(message + " (see --help)");
    }
    return true;
  }
};

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
