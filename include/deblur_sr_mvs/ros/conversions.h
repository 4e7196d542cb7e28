// ROS message <-> core conversions of the estimator node. Every function that
// reads a message validates it and throws InputError with one line saying
// what is wrong, so that the nodelet can warn and skip the frame.
#pragma once

#include <string>

#include <geometry_msgs/PoseStamped.h>
#include <geometry_msgs/Transform.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/PointCloud2.h>
#include <opencv2/core.hpp>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/geometry/camera.h"
#include "deblur_sr_mvs/core/geometry/se3.h"

namespace deblur_sr_mvs {
namespace ros_glue {

// Input encodings the node accepts; the restored image keeps the family.
enum class ImageFamily { kMono8, kMono16, kRgb8, kBgr8 };
ImageFamily FamilyOf(const std::string& encoding);  // InputError if unsupported
std::string EncodingOf(ImageFamily family);

// Image -> float in [0, 1] (1 channel, or 3 in OpenCV's BGR order); mono16 is
// divided by 65535. Throws InputError on unsupported encodings, empty images
// or inconsistent step/data sizes.
cv::Mat ImageToFloat01(const sensor_msgs::Image& image, ImageFamily* family);
// Float [0, 1] image (as above) -> message of `family` (values clamped,
// rounded; NaN becomes 0).
sensor_msgs::Image Float01ToImage(const cv::Mat& image01, ImageFamily family, const std_msgs::Header& header);

// What to do with a camera_info whose distortion coefficients are not zero.
enum class DistortionPolicy {
  kReject,           // the image is raw: reject it (the node needs rectified input)
  kAssumeRectified,  // the image is already rectified (image_rect): use P
};

// Intrinsics of the image from camera_info: K when D is zero; P's left 3x3
// when D is not zero and the policy says the image is rectified. Throws
// InputError for: zero or non-finite K/P entries, non-positive focal
// lengths, a size that differs from the image's, distortion under kReject.
PinholeCamera CameraFromInfo(const sensor_msgs::CameraInfo& info, int image_width, int image_height,
                             DistortionPolicy policy);

// camera_info of the `scale` x up-sampled output of `camera` (docs/file_formats.md#scaling-rule;
// rule: f' = s f, c' = s c + (s - 1) / 2): width, height, K and P rewritten
// from `camera` (the intrinsics the node used), D zero, R identity, no ROI.
sensor_msgs::CameraInfo ScaledCameraInfo(const PinholeCamera& camera_lr, int scale,
                                         const std_msgs::Header& header);

// CV_32FC1 depth (m, NaN invalid) -> 32FC1 image message (REP 118).
sensor_msgs::Image DepthToImage(const cv::Mat& depth, const std_msgs::Header& header);

// CV_32FC1 values -> 32FC1 image message, values as they are (the depth
// confidence in [0, 1]).
sensor_msgs::Image Float32ToImage(const cv::Mat& values, const std_msgs::Header& header);

// Coloured point cloud (x, y, z, rgb) in the camera frame from every
// `stride`-th pixel (in x and y) with a finite positive depth.
sensor_msgs::PointCloud2 DepthToPoints(const cv::Mat& depth, const cv::Mat& image01,
                                       const PinholeCamera& camera, int stride,
                                       const std_msgs::Header& header);

// Poses (tf2_eigen's conversions). The quaternion is the rotation's,
// normalised, copied as it is (no sign flip): PoseFromMsg(PoseToMsg(T)) gives
// T back to double precision, and pose and transform carry the same numbers.
geometry_msgs::Pose PoseToMsg(const SE3& T_world_cam);
geometry_msgs::Transform TransformToMsg(const SE3& T_world_cam);
// Throws InputError on non-finite values or a zero quaternion; normalises it.
SE3 PoseFromMsg(const geometry_msgs::Pose& pose);
// A tf transform (parent <- child) as the child's pose in the parent, checked
// as PoseFromMsg.
SE3 TransformFromMsg(const geometry_msgs::Transform& transform);

}  // namespace ros_glue
}  // namespace deblur_sr_mvs
