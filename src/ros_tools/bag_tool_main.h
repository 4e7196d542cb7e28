// The common main() of the rosbag tools: ToolMain (one line on stderr, exit
// code 2) with rosbag's console output silenced and its and cv_bridge's
// exceptions named as such.
#pragma once

#include <string>

#include <console_bridge/console.h>
#include <cv_bridge/cv_bridge.h>
#include <rosbag/exceptions.h>

#include "deblur_sr_mvs/core/common/errors.h"
#include "tool_main.h"

namespace deblur_sr_mvs {

template <typename Run>
int BagToolMain(const char* tool, Run&& run, int argc, char** argv) {
  // rosbag reports through console_bridge as well as by exceptions; keep
  // stderr to ToolMain's one line.
  console_bridge::setLogLevel(console_bridge::CONSOLE_BRIDGE_LOG_NONE);
  auto named = [&run](int count, char** values) {
    try {
      return run(count, values);
    } catch (const rosbag::BagException& error) {
      throw InputError(std::string("rosbag error: ") + error.what());
    } catch (const cv_bridge::Exception& error) {
      throw InputError(std::string("cv_bridge error: ") + error.what());
    }
  };
  return ToolMain(tool, named, argc, argv);
}

}  // namespace deblur_sr_mvs
