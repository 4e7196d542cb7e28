// libFuzzer target: the node's input conversions (image message -> float
// image, camera_info -> intrinsics) on arbitrary messages. They may only
// return or throw InputError; anything else is a finding. Run: scripts/fuzz.sh.
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <string>

#include "deblur_sr_mvs/ros/conversions.h"

namespace {

// Reads values off the front of the input.
struct Reader {
  const uint8_t* data;
  size_t size;
  template <typename T>
  T Take() {
    T value{};
    const size_t n = std::min(sizeof(T), size);
    std::memcpy(&value, data, n);
    data += n;
    size -= n;
    return value;
  }
};

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace deblur_sr_mvs;
  Reader in{data, size};
  static const char* const kEncodings[] = {"mono8", "mono16", "rgb8", "bgr8", "bgra8", "32FC1", "yuv422", ""};
  sensor_msgs::Image image;
  image.encoding = kEncodings[in.Take<uint8_t>() % 8];
  image.width = in.Take<uint16_t>() % 512;
  image.height = in.Take<uint16_t>() % 512;
  image.step = in.Take<uint16_t>() % 2048;
  image.is_bigendian = in.Take<uint8_t>() & 1;
  sensor_msgs::CameraInfo info;
  info.width = in.Take<uint8_t>() ? image.width : in.Take<uint16_t>();
  info.height = in.Take<uint8_t>() ? image.height : in.Take<uint16_t>();
  for (double& k : info.K) k = in.Take<double>();
  for (double& p : info.P) p = in.Take<double>();
  info.D.resize(in.Take<uint8_t>() % 9);
  for (double& d : info.D) d = in.Take<double>();
  info.binning_x = in.Take<uint8_t>() % 3;
  const bool rectified = in.Take<uint8_t>() & 1;
  image.data.assign(in.data, in.data + in.size);
  try {
    ros_glue::ImageFamily family;
    const cv::Mat float01 = ros_glue::ImageToFloat01(image, &family);
    const PinholeCamera camera = ros_glue::CameraFromInfo(
        info, float01.cols, float01.rows,
        rectified ? ros_glue::DistortionPolicy::kAssumeRectified : ros_glue::DistortionPolicy::kReject);
    // What the node publishes back must hold for any accepted input.
    const sensor_msgs::Image back = ros_glue::Float01ToImage(float01, family, image.header);
    if (back.width != image.width || back.height != image.height) __builtin_trap();
    if (!(camera.fx > 0.0) || !(camera.fy > 0.0)) __builtin_trap();
  } catch (const InputError&) {
  }
  return 0;
}
