// libFuzzer target: the sequence-folder readers (docs/file_formats.md#sequence-folder) on arbitrary
// bytes. The first byte picks the reader, the rest is the file. A reader may
// only return a value or throw InputError (one line); anything else -- a
// crash, a sanitizer report, another exception type -- is a finding.
// Build and run: scripts/fuzz.sh.
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <fstream>
#include <string>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/io/sequence_io.h"

namespace {

const std::string& Scratch() {
  static const std::string path = "/tmp/dsm_fuzz_readers_" + std::to_string(::getpid());
  return path;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 1) return 0;
  const int reader = data[0] % 5;
  static const char* const kExtensions[] = {".yaml", ".csv", ".txt", ".tiff", ".png"};
  const std::string path = Scratch() + kExtensions[reader];
  {
    std::ofstream file(path, std::ios::binary | std::ios::trunc);
    file.write(reinterpret_cast<const char*>(data + 1), static_cast<std::streamsize>(size - 1));
  }
  try {
    switch (reader) {
      case 0:
        deblur_sr_mvs::ReadCameraYaml(path);
        break;
      case 1:
        deblur_sr_mvs::ReadFramesCsv(path);
        break;
      case 2:
        deblur_sr_mvs::ReadTumTrajectory(path);
        break;
      case 3:
        deblur_sr_mvs::ReadDepthTiff(path);
        break;
      case 4:
        deblur_sr_mvs::ReadImage8(path);
        break;
    }
  } catch (const deblur_sr_mvs::InputError& error) {
    const std::string message = error.what();
    if (message.empty() || message.find('\n') != std::string::npos) __builtin_trap();  // one line
  }
  return 0;
}
