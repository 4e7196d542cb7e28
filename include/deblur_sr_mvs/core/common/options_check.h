// One message style for every Options::Check():
//   "<name> must be in [min, max], got <value>"
//   "<name> must be >= min, got <value>"
// Each throws InputError; a non-finite value never passes.
#pragma once

#include <cmath>
#include <sstream>
#include <string>

#include "deblur_sr_mvs/core/common/errors.h"

namespace deblur_sr_mvs {

namespace options_check_detail {
template <typename T>
std::string Text(T value) {
  std::ostringstream text;
  text << value;
  return text.str();
}
}  // namespace options_check_detail

// Throws unless min <= value <= max (and value is finite).
template <typename T>
void CheckInRange(const std::string& name, T value, T min, T max) {
  if (!(value >= min && value <= max) || !std::isfinite(static_cast<double>(value))) {
    using options_check_detail::Text;
    throw InputError(name + " must be in [" + Text(min) + ", " + Text(max) + "], got " + Text(value));
  }
}

// Which ends of an interval belong to it.
enum class Interval { kClosed, kOpen, kLeftClosed /* [min, max) */, kRightClosed /* (min, max] */ };

// Throws unless value lies in the interval between min and max of the given
// kind (and is finite): "<name> must be in (0, 1), got 1.5".
template <typename T>
void CheckInInterval(const std::string& name, T value, T min, T max, Interval kind) {
  const bool left_closed = kind == Interval::kClosed || kind == Interval::kLeftClosed;
  const bool right_closed = kind == Interval::kClosed || kind == Interval::kRightClosed;
  const bool above = left_closed ? value >= min : value > min;
  const bool below = right_closed ? value <= max : value < max;
  if (!(above && below) || !std::isfinite(static_cast<double>(value))) {
    using options_check_detail::Text;
    throw InputError(name + " must be in " + (left_closed ? "[" : "(") + Text(min) + ", " + Text(max) +
                     (right_closed ? "]" : ")") + ", got " + Text(value));
  }
}

// Throws unless value >= min (and value is finite).
template <typename T>
void CheckAtLeast(const std::string& name, T value, T min) {
  if (!(value >= min) || !std::isfinite(static_cast<double>(value))) {
    using options_check_detail::Text;
    throw InputError(name + " must be >= " + Text(min) + ", got " + Text(value));
  }
}

// Throws unless value > min (and value is finite).
template <typename T>
void CheckAbove(const std::string& name, T value, T min) {
  if (!(value > min) || !std::isfinite(static_cast<double>(value))) {
    using options_check_detail::Text;
    throw InputError(name + " must be > " + Text(min) + ", got " + Text(value));
  }
}

}  // namespace deblur_sr_mvs
