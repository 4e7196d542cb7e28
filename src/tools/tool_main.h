// The common main() of the command-line tools: run, and turn every error into
// one line on stderr and exit code 2 (SPEC section 4: never a signal, an
// abort or a stack trace).
#pragma once

#include <cmath>
#include <exception>
#include <iostream>
#include <limits>
#include <sstream>
#include <string>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/common/text.h"

namespace deblur_sr_mvs {

// " in [min, max]", " >= min", " <= max" or nothing, for the messages below.
inline std::string FlagRange(double min, double max, double no_min, double no_max) {
  std::ostringstream text;
  if (min > no_min && max < no_max) {
    text << " in [" << min << ", " << max << "]";
  } else if (min > no_min) {
    text << " >= " << min;
  } else if (max < no_max) {
    text << " <= " << max;
  }
  return text.str();
}

// The value of a command-line flag as a number: the whole text must parse, be
// finite and lie in [min, max]; otherwise InputError
// "<flag> expects a number[ in [min, max]], got '<text>'".
inline double ParseFlagNumber(const std::string& flag, const std::string& text,
                              double min = -std::numeric_limits<double>::max(),
                              double max = std::numeric_limits<double>::max()) {
  char* end = nullptr;
  const double value = std::strtod(text.c_str(), &end);
  if (text.empty() || end != text.c_str() + text.size() || !std::isfinite(value) || value < min ||
      value > max) {
    throw InputError(flag + " expects a number" +
                     FlagRange(min, max, -std::numeric_limits<double>::max(), std::numeric_limits<double>::max()) +
                     ", got '" + text + "'");
  }
  return value;
}

// Likewise for an integer in [min, max] (default: any int of at most 9 digits).
inline int ParseFlagInt(const std::string& flag, const std::string& text, int min = -999999999,
                        int max = 999999999) {
  char* end = nullptr;
  const long value = std::strtol(text.c_str(), &end, 10);
  if (text.empty() || end != text.c_str() + text.size() || value < min || value > max) {
    throw InputError(flag + " expects an integer" + FlagRange(min, max, -999999999, 999999999) + ", got '" +
                     text + "'");
  }
  return static_cast<int>(value);
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
