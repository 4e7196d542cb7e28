// Pinhole camera model (no distortion: rectified input is expected) and the
// resolution-scaling rule of docs/file_formats.md#scaling-rule.
#pragma once

#include <Eigen/Core>
#include <string>

namespace deblur_sr_mvs {

// Intrinsics of an undistorted pinhole camera. Pixel-centre convention:
// integer coordinates are pixel centres (OpenCV, ROS).
struct PinholeCamera {
  int width = 0;
  int height = 0;
  double fx = 0.0;
  double fy = 0.0;
  double cx = 0.0;
  double cy = 0.0;

  PinholeCamera() = default;
  PinholeCamera(int width_px, int height_px, double fx_px, double fy_px, double cx_px, double cy_px)
      : width(width_px), height(height_px), fx(fx_px), fy(fy_px), cx(cx_px), cy(cy_px) {}

  Eigen::Matrix3d K() const;

  // Projection of a point in camera coordinates (z > 0 is in front).
  Eigen::Vector2d Project(const Eigen::Vector3d& point_cam) const {
    return {fx * point_cam.x() / point_cam.z() + cx, fy * point_cam.y() / point_cam.z() + cy};
  }
  // Ray through pixel (u, v) with z = 1, so that point = depth * Ray(u, v).
  Eigen::Vector3d Ray(double u, double v) const { return {(u - cx) / fx, (v - cy) / fy, 1.0}; }
  bool InImage(double u, double v) const {
    return u >= 0.0 && v >= 0.0 && u <= width - 1.0 && v <= height - 1.0;
  }
  int NumPixels() const { return width * height; }

  // The camera seen at `scale` times the resolution, for box up/down-sampling
  // by an integer factor. HR coordinate X maps to LR (X - (s-1)/2)/s, hence
  // fx' = s fx, cx' = s cx + (s-1)/2 (likewise y) (docs/file_formats.md#scaling-rule).
  PinholeCamera Upscaled(int scale) const;
  // The inverse of Upscaled(scale); width and height must be divisible by scale.
  PinholeCamera Downscaled(int scale) const;

  // Empty string when the intrinsics are usable, else a one-line reason.
  std::string Problem() const;
};

}  // namespace deblur_sr_mvs
