// Geometric warping between cameras that share one set of intrinsics
// (paper Sec. 3, eq:warpingFunction) and the depth reprojection that gives the
// virtual camera's depth D_tau from D_t (Sec. 3, last paragraph).
#pragma once

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "deblur_sr_mvs/core/geometry/camera.h"
#include "deblur_sr_mvs/core/geometry/se3.h"

namespace deblur_sr_mvs {

// Precomputed pixel -> target-pixel map for one relative pose, in the form
// pixel_target ~ depth * H * [u v 1]^T + K t (H = K R K^-1): two multiply-adds
// per coordinate instead of an unproject / transform / project chain.
struct PixelTransfer {
  PixelTransfer(const PinholeCamera& camera, const SE3& T_target_source);
  Eigen::Matrix3d homography;   // K R K^-1
  Eigen::Vector3d translation;  // K t

  // W^{source->target}(x) (eq:warpingFunction) for a pixel with depth `depth`
  // (metres along the source optical axis). Returns false when the point lands
  // behind the target camera. `target_depth` receives its depth there.
  bool Warp(double u, double v, double depth, Eigen::Vector2d* target, double* target_depth = nullptr) const {
    const Eigen::Vector3d p =
        depth * (homography.col(0) * u + homography.col(1) * v + homography.col(2)) + translation;
    if (!(p.z() > 1e-9)) return false;
    *target = p.head<2>() / p.z();
    if (target_depth != nullptr) *target_depth = p.z();
    return true;
  }
};

// Single-precision form of PixelTransfer for the hot loops (sub-millipixel
// accuracy for images up to several thousand pixels wide). The row part
// h1 * v + h2 is hoisted out of the loops over u.
struct PixelTransferF {
  explicit PixelTransferF(const PixelTransfer& transfer);
  float h[9];  // row-major K R K^-1
  float t[3];  // K t
  // Row-constant part for image row v: (h1 v + h2) per output coordinate.
  void RowBase(float v, float base[3]) const {
    base[0] = h[1] * v + h[2];
    base[1] = h[4] * v + h[5];
    base[2] = h[7] * v + h[8];
  }
  // Same contract as PixelTransfer::Warp.
  bool Warp(const float base[3], float u, float depth, float* target_u, float* target_v,
            float* target_depth) const {
    WarpUnchecked(base, u, depth, target_u, target_v, target_depth);
    return *target_depth > 1e-9f;
  }
  // Warp's arithmetic without its check (branch-free, so that a loop over a
  // row vectorises): the caller must reject target_depth <= 1e-9 (or NaN),
  // where target_u and target_v mean nothing.
  void WarpUnchecked(const float base[3], float u, float depth, float* target_u, float* target_v,
                     float* target_depth) const {
    const float z = depth * (h[6] * u + base[2]) + t[2];
    const float inv_z = 1.0f / z;
    *target_u = (depth * (h[0] * u + base[0]) + t[0]) * inv_z;
    *target_v = (depth * (h[3] * u + base[1]) + t[1]) * inv_z;
    *target_depth = z;
  }
};

// True for a usable depth sample (finite and > 0); 0 and NaN mark unknown.
inline bool ValidDepth(float depth) {
  return depth > 0.0f && depth < 1e30f;
}

// Depth map of the camera T_world_target rendered from the depth map D_source
// of T_world_source (same intrinsics and size) by reprojecting every source
// pixel to its nearest target pixel with a z-buffer. Target pixels that no
// source pixel reaches get `fill_from_source` ? D_source(x) : NaN.
// `depth_target` is reused when it already has the right size and type.
void ReprojectDepth(const PinholeCamera& camera, const cv::Mat& depth_source, const SE3& T_target_source,
                    bool fill_from_source, cv::Mat* depth_target);

// Per-pixel warp W^{source->target} of a whole depth map: CV_32FC2 of target
// coordinates, NaN where the depth is unknown or the point is behind.
cv::Mat WarpCoordinates(const PinholeCamera& camera, const cv::Mat& depth_source, const SE3& T_target_source);

}  // namespace deblur_sr_mvs
