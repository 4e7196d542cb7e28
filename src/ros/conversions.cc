#include "deblur_sr_mvs/ros/conversions.h"

#include <cmath>
#include <cstring>
#include <limits>

#include <sensor_msgs/image_encodings.h>
#include <sensor_msgs/point_cloud2_iterator.h>
#include <tf2_eigen/tf2_eigen.h>
#include <opencv2/imgproc.hpp>

namespace deblur_sr_mvs {
namespace ros_glue {

namespace enc = sensor_msgs::image_encodings;

ImageFamily FamilyOf(const std::string& encoding) {
  if (encoding == enc::MONO8) return ImageFamily::kMono8;
  if (encoding == enc::MONO16) return ImageFamily::kMono16;
  if (encoding == enc::RGB8) return ImageFamily::kRgb8;
  if (encoding == enc::BGR8) return ImageFamily::kBgr8;
  throw InputError("unsupported image encoding '" + encoding + "' (use mono8, mono16, rgb8 or bgr8)");
}

std::string EncodingOf(ImageFamily family) {
  switch (family) {
    case ImageFamily::kMono8:
      return enc::MONO8;
    case ImageFamily::kMono16:
      return enc::MONO16;
    case ImageFamily::kRgb8:
      return enc::RGB8;
    case ImageFamily::kBgr8:
      return enc::BGR8;
  }
  return enc::MONO8;
}

namespace {

int BytesPerPixel(ImageFamily family) {
  switch (family) {
    case ImageFamily::kMono8:
      return 1;
    case ImageFamily::kMono16:
      return 2;
    default:
      return 3;
  }
}

}  // namespace

cv::Mat ImageToFloat01(const sensor_msgs::Image& image, ImageFamily* family_out) {
  const ImageFamily family = FamilyOf(image.encoding);
  if (image.width == 0 || image.height == 0) throw InputError("empty image (0 x 0)");
  if (image.width > 16384 || image.height > 16384) {
    throw InputError("image of " + std::to_string(image.width) + " x " + std::to_string(image.height) +
                     " px is larger than 16384 px a side");
  }
  const size_t row_bytes = static_cast<size_t>(image.width) * BytesPerPixel(family);
  if (image.step < row_bytes || image.data.size() < static_cast<size_t>(image.step) * image.height) {
    throw InputError("image data is shorter than width x height x pixel size (step " +
                     std::to_string(image.step) + ", " + std::to_string(image.data.size()) + " bytes)");
  }
  if (family == ImageFamily::kMono16 && image.step % 2 != 0) {
    throw InputError("mono16 image with an odd step (" + std::to_string(image.step) + " bytes)");
  }
  const int type = family == ImageFamily::kMono8    ? CV_8UC1
                   : family == ImageFamily::kMono16 ? CV_16UC1
                                                    : CV_8UC3;
  cv::Mat view(image.height, image.width, type, const_cast<uint8_t*>(image.data.data()), image.step);
  cv::Mat swapped;
  if (family == ImageFamily::kMono16 && image.is_bigendian != 0) {
    // Our machines are little-endian: swap the bytes of big-endian data.
    swapped.create(view.size(), CV_16UC1);
    for (int y = 0; y < view.rows; ++y) {
      const uint8_t* in = view.ptr<uint8_t>(y);
      uint16_t* out = swapped.ptr<uint16_t>(y);
      for (int x = 0; x < view.cols; ++x) out[x] = static_cast<uint16_t>((in[2 * x] << 8) | in[2 * x + 1]);
    }
    view = swapped;
  }
  cv::Mat result;
  const double divisor = family == ImageFamily::kMono16 ? 65535.0 : 255.0;
  if (family == ImageFamily::kRgb8) {
    cv::Mat bgr;
    cv::cvtColor(view, bgr, cv::COLOR_RGB2BGR);
    bgr.convertTo(result, CV_32FC3, 1.0 / divisor);
  } else {
    view.convertTo(result, family == ImageFamily::kBgr8 ? CV_32FC3 : CV_32FC1, 1.0 / divisor);
  }
  if (family_out != nullptr) *family_out = family;
  return result;
}

sensor_msgs::Image Float01ToImage(const cv::Mat& image01, ImageFamily family,
                                  const std_msgs::Header& header) {
  cv::Mat clean;
  image01.copyTo(clean);
  cv::patchNaNs(clean, 0.0);
  const bool colour = family == ImageFamily::kRgb8 || family == ImageFamily::kBgr8;
  if (colour && clean.channels() == 1) cv::cvtColor(clean, clean, cv::COLOR_GRAY2BGR);
  if (!colour && clean.channels() == 3) cv::cvtColor(clean, clean, cv::COLOR_BGR2GRAY);
  if (family == ImageFamily::kRgb8) cv::cvtColor(clean, clean, cv::COLOR_BGR2RGB);
  cv::Mat converted;
  if (family == ImageFamily::kMono16) {
    clean.convertTo(converted, CV_16UC1, 65535.0);  // saturating, rounding
  } else {
    clean.convertTo(converted, colour ? CV_8UC3 : CV_8UC1, 255.0);
  }
  sensor_msgs::Image message;
  message.header = header;
  message.height = converted.rows;
  message.width = converted.cols;
  message.encoding = EncodingOf(family);
  message.is_bigendian = 0;
  message.step = static_cast<uint32_t>(converted.cols * converted.elemSize());
  message.data.resize(static_cast<size_t>(message.step) * converted.rows);
  for (int y = 0; y < converted.rows; ++y) {
    std::memcpy(&message.data[static_cast<size_t>(y) * message.step], converted.ptr(y), message.step);
  }
  return message;
}

namespace {

bool AllFinite(const double* values, int count) {
  for (int i = 0; i < count; ++i) {
    if (!std::isfinite(values[i])) return false;
  }
  return true;
}

}  // namespace

PinholeCamera CameraFromInfo(const sensor_msgs::CameraInfo& info, int image_width, int image_height,
                             DistortionPolicy policy) {
  if (info.width == 0 || info.height == 0) throw InputError("camera_info has width or height 0");
  if (static_cast<int>(info.width) != image_width || static_cast<int>(info.height) != image_height) {
    throw InputError("camera_info is " + std::to_string(info.width) + " x " + std::to_string(info.height) +
                     " but the image is " + std::to_string(image_width) + " x " +
                     std::to_string(image_height));
  }
  if (info.binning_x > 1 || info.binning_y > 1 || info.roi.width != 0 || info.roi.height != 0) {
    throw InputError("camera_info with binning or a region of interest is not supported");
  }
  if (!AllFinite(info.K.data(), 9) || !AllFinite(info.P.data(), 12) ||
      !AllFinite(info.D.data(), static_cast<int>(info.D.size()))) {
    throw InputError("camera_info has NaN or infinite entries in K, P or D");
  }
  bool distorted = false;
  for (double d : info.D) distorted = distorted || d != 0.0;
  double fx = info.K[0], fy = info.K[4], cx = info.K[2], cy = info.K[5];
  if (distorted) {
    if (policy == DistortionPolicy::kReject) {
      throw InputError(
          "camera_info has non-zero distortion: the node needs rectified images "
          "(feed image_rect, and set ~assume_rectified if its camera_info keeps D)");
    }
    fx = info.P[0];
    fy = info.P[5];
    cx = info.P[2];
    cy = info.P[6];
  }
  if (!(fx > 0.0) || !(fy > 0.0)) {
    throw InputError(std::string("camera_info has no valid ") + (distorted ? "P" : "K") +
                     " (focal lengths must be > 0; an all-zero K means an uncalibrated camera)");
  }
  const PinholeCamera camera(image_width, image_height, fx, fy, cx, cy);
  const std::string problem = camera.Problem();
  if (!problem.empty()) throw InputError("camera_info: " + problem);
  return camera;
}

sensor_msgs::CameraInfo ScaledCameraInfo(const PinholeCamera& camera_lr, int scale,
                                         const std_msgs::Header& header) {
  const PinholeCamera hr = camera_lr.Upscaled(scale);
  sensor_msgs::CameraInfo info;
  info.header = header;
  info.width = hr.width;
  info.height = hr.height;
  info.distortion_model = "plumb_bob";
  info.D.assign(5, 0.0);
  info.K = {hr.fx, 0.0, hr.cx, 0.0, hr.fy, hr.cy, 0.0, 0.0, 1.0};
  info.R = {1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0};
  info.P = {hr.fx, 0.0, hr.cx, 0.0, 0.0, hr.fy, hr.cy, 0.0, 0.0, 0.0, 1.0, 0.0};
  return info;
}

sensor_msgs::Image Float32ToImage(const cv::Mat& values, const std_msgs::Header& header) {
  CV_Assert(values.type() == CV_32FC1);
  sensor_msgs::Image message;
  message.header = header;
  message.height = values.rows;
  message.width = values.cols;
  message.encoding = enc::TYPE_32FC1;
  message.is_bigendian = 0;
  message.step = values.cols * sizeof(float);
  message.data.resize(static_cast<size_t>(message.step) * values.rows);
  for (int y = 0; y < values.rows; ++y) {
    std::memcpy(&message.data[static_cast<size_t>(y) * message.step], values.ptr<float>(y), message.step);
  }
  return message;
}

sensor_msgs::Image DepthToImage(const cv::Mat& depth, const std_msgs::Header& header) {
  sensor_msgs::Image message = Float32ToImage(depth, header);
  float* values = reinterpret_cast<float*>(message.data.data());  // rows are contiguous
  for (size_t i = 0; i < depth.total(); ++i) {
    // REP 118: NaN for every invalid value (non-finite or not in front).
    if (!(std::isfinite(values[i]) && values[i] > 0.0f)) values[i] = std::numeric_limits<float>::quiet_NaN();
  }
  return message;
}

sensor_msgs::PointCloud2 DepthToPoints(const cv::Mat& depth, const cv::Mat& image01,
                                       const PinholeCamera& camera, int stride,
                                       const std_msgs::Header& header) {
  CV_Assert(depth.type() == CV_32FC1 && depth.size() == image01.size());
  stride = std::max(1, stride);
  size_t count = 0;
  for (int y = 0; y < depth.rows; y += stride) {
    const float* d = depth.ptr<float>(y);
    for (int x = 0; x < depth.cols; x += stride) count += std::isfinite(d[x]) && d[x] > 0.0f;
  }
  sensor_msgs::PointCloud2 cloud;
  cloud.header = header;
  sensor_msgs::PointCloud2Modifier modifier(cloud);
  modifier.setPointCloud2FieldsByString(2, "xyz", "rgb");
  modifier.resize(count);
  cloud.height = 1;
  cloud.width = static_cast<uint32_t>(count);
  cloud.is_dense = true;
  sensor_msgs::PointCloud2Iterator<float> out_x(cloud, "x"), out_y(cloud, "y"), out_z(cloud, "z");
  sensor_msgs::PointCloud2Iterator<uint8_t> out_r(cloud, "r"), out_g(cloud, "g"), out_b(cloud, "b");
  const bool colour = image01.channels() == 3;
  for (int y = 0; y < depth.rows; y += stride) {
    const float* d = depth.ptr<float>(y);
    for (int x = 0; x < depth.cols; x += stride) {
      if (!(std::isfinite(d[x]) && d[x] > 0.0f)) continue;
      const Eigen::Vector3d point = d[x] * camera.Ray(x, y);
      *out_x = static_cast<float>(point.x());
      *out_y = static_cast<float>(point.y());
      *out_z = static_cast<float>(point.z());
      float b, g, r;
      if (colour) {
        const cv::Vec3f& pixel = image01.at<cv::Vec3f>(y, x);
        b = pixel[0], g = pixel[1], r = pixel[2];
      } else {
        b = g = r = image01.at<float>(y, x);
      }
      auto to8 = [](float v) {
        return static_cast<uint8_t>(std::lround(std::min(1.0f, std::max(0.0f, v)) * 255.0f));
      };
      *out_r = to8(r);
      *out_g = to8(g);
      *out_b = to8(b);
      ++out_x, ++out_y, ++out_z, ++out_r, ++out_g, ++out_b;
    }
  }
  return cloud;
}

geometry_msgs::Pose PoseToMsg(const SE3& T_world_cam) {
  geometry_msgs::Pose pose;
  pose.position = tf2::toMsg(T_world_cam.translation());
  pose.orientation = tf2::toMsg(T_world_cam.quaternion().normalized());
  return pose;
}

geometry_msgs::Transform TransformToMsg(const SE3& T_world_cam) {
  geometry_msgs::Transform transform;
  tf2::toMsg(T_world_cam.translation(), transform.translation);
  transform.rotation = tf2::toMsg(T_world_cam.quaternion().normalized());
  return transform;
}

SE3 PoseFromMsg(const geometry_msgs::Pose& pose) {
  Eigen::Vector3d translation;
  Eigen::Quaterniond rotation;
  tf2::fromMsg(pose.position, translation);
  tf2::fromMsg(pose.orientation, rotation);
  if (!translation.allFinite() || !rotation.coeffs().allFinite() || rotation.norm() == 0.0) {
    throw InputError("pose with a non-finite position or orientation, or a zero quaternion");
  }
  return SE3(rotation.normalized(), translation);
}

SE3 TransformFromMsg(const geometry_msgs::Transform& transform) {
  geometry_msgs::Pose pose;
  pose.position.x = transform.translation.x;
  pose.position.y = transform.translation.y;
  pose.position.z = transform.translation.z;
  pose.orientation = transform.rotation;
  return PoseFromMsg(pose);
}

}  // namespace ros_glue
}  // namespace deblur_sr_mvs
