// Errors a user can cause (bad files, bad parameters). Tools catch InputError
// at the top level, print what() as one line and exit non-zero.
#pragma once

#include <stdexcept>
#include <string>

namespace deblur_sr_mvs {

// A one-line, user-facing description of bad input: names the file or the
// parameter and the problem, e.g. "seq/frames.csv:4: stamp 0.1 is not after 0.2".
class InputError : public std::runtime_error {
 public:
  explicit InputError(const std::string& message) : std::runtime_error(message) {}
};

}  // namespace deblur_sr_mvs
