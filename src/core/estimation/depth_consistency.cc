#include "deblur_sr_mvs/core/estimation/depth_consistency.h"

#include <algorithm>
#include <array>
#include <cmath>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/common/options_check.h"
#include "deblur_sr_mvs/core/estimation/frame_structure.h"
#include "deblur_sr_mvs/core/geometry/warp.h"

namespace deblur_sr_mvs {
namespace {

constexpr int kMaxRadius = 10;
// D_t(x) and at most one candidate per neighbour.
using Values = std::array<float, 2 * kMaxRadius + 1>;

// 1 / depth where the depth is known, else 0 (CV_32FC1).
cv::Mat InverseOrZero(const cv::Mat& depth) {
  cv::Mat inverse(depth.size(), CV_32FC1);
  for (int y = 0; y < depth.rows; ++y) {
    const float* d = depth.ptr<float>(y);
    float* r = inverse.ptr<float>(y);
    for (int x = 0; x < depth.cols; ++x) r[x] = ValidDepth(d[x]) ? 1.0f / d[x] : 0.0f;
  }
  return inverse;
}

// Bilinear inverse depth at (u, v), or 0 unless all four samples are known
// and agree within the relative `tolerance` (no blend across a depth edge,
// which would lend a depth that neither side has).
float SampleInverse(const cv::Mat& inverse, float u, float v, float tolerance) {
  if (!(u >= 0.0f && v >= 0.0f && u <= inverse.cols - 1.0f && v <= inverse.rows - 1.0f)) return 0.0f;
  const int x0 = std::min(static_cast<int>(u), inverse.cols - 2);
  const int y0 = std::min(static_cast<int>(v), inverse.rows - 2);
  const float ax = u - x0;
  const float ay = v - y0;
  const float* top = inverse.ptr<float>(y0) + x0;
  const float* bottom = inverse.ptr<float>(y0 + 1) + x0;
  const float lowest = std::min(std::min(top[0], top[1]), std::min(bottom[0], bottom[1]));
  const float highest = std::max(std::max(top[0], top[1]), std::max(bottom[0], bottom[1]));
  if (!(lowest > 0.0f) || highest - lowest > tolerance * lowest) return 0.0f;
  return (1.0f - ay) * ((1.0f - ax) * top[0] + ax * top[1]) + ay * ((1.0f - ax) * bottom[0] + ax * bottom[1]);
}

// The transfers of one neighbour s of t: t -> s and back.
struct NeighbourTransfer {
  const cv::Mat* inverse_s;
  PixelTransferF t_to_s;
  PixelTransferF s_to_t;
};

// The inverse depth that s reports for the point D_t(x) x of t (0: none):
// W^{t->s}(x) (eq:warpingFunction), s's inverse depth there, back into t.
float Candidate(const NeighbourTransfer& n, const float base[3], float u, float depth_t, float tolerance) {
  float u_s, v_s, z_s;
  if (!n.t_to_s.Warp(base, u, depth_t, &u_s, &v_s, &z_s)) return 0.0f;
  const float inverse_s = SampleInverse(*n.inverse_s, u_s, v_s, tolerance);
  if (inverse_s <= 0.0f) return 0.0f;
  float base_s[3];
  n.s_to_t.RowBase(v_s, base_s);
  float u_t, v_t, z_t;
  if (!n.s_to_t.Warp(base_s, u_s, 1.0f / inverse_s, &u_t, &v_t, &z_t)) return 0.0f;
  return 1.0f / z_t;
}

// The combination of values[0, count) (inverse depths) as a depth.
float Combine(Values* values, int count, DepthConsistencyOptions::Combination combination) {
  float inverse = 0.0f;
  if (combination == DepthConsistencyOptions::Combination::kMean) {
    for (int i = 0; i < count; ++i) inverse += (*values)[i];
    inverse /= static_cast<float>(count);
  } else {
    std::sort(values->begin(), values->begin() + count);
    inverse = count % 2 == 1 ? (*values)[count / 2] : 0.5f * ((*values)[count / 2 - 1] + (*values)[count / 2]);
  }
  return 1.0f / inverse;
}

// D_t made consistent with the neighbours `transfers` (FuseNeighbourDepths).
cv::Mat FuseOne(const PinholeCamera& camera, const cv::Mat& depth_t, const std::vector<NeighbourTransfer>& transfers,
                const DepthConsistencyOptions& options) {
  cv::Mat fused = depth_t.clone();
  const float tolerance = static_cast<float>(options.tolerance);
  Values values;
  std::vector<std::array<float, 3>> bases(transfers.size());
  for (int y = 0; y < camera.height; ++y) {
    for (size_t i = 0; i < transfers.size(); ++i) transfers[i].t_to_s.RowBase(static_cast<float>(y), bases[i].data());
    const float* d = depth_t.ptr<float>(y);
    float* out = fused.ptr<float>(y);
    for (int x = 0; x < camera.width; ++x) {
      if (!ValidDepth(d[x])) continue;
      const float inverse_t = 1.0f / d[x];
      values[0] = inverse_t;
      int count = 1;
      for (size_t i = 0; i < transfers.size(); ++i) {
        const float candidate = Candidate(transfers[i], bases[i].data(), static_cast<float>(x), d[x], tolerance);
        if (candidate > 0.0f && std::abs(candidate - inverse_t) <= tolerance * inverse_t) values[count++] = candidate;
      }
      if (count > 1) out[x] = Combine(&values, count, options.combination);
    }
  }
  return fused;
}

}  // namespace

void DepthConsistencyOptions::Check() const {
  CheckInRange("depth_consistency_radius", radius, 0, kMaxRadius);
  CheckInInterval("depth_consistency_tolerance", tolerance, 0.0, 1.0, Interval::kRightClosed);
  if (combination != Combination::kMean && combination != Combination::kMedian) {
    throw InputError("depth_consistency_combination must be mean or median");
  }
}

std::vector<cv::Mat> FuseNeighbourDepths(const PinholeCamera& camera, const std::vector<cv::Mat>& depths,
                                         const std::vector<SE3>& T_world_cam,
                                         const DepthConsistencyOptions& options) {
  options.Check();
  const int n = static_cast<int>(depths.size());
  if (static_cast<int>(T_world_cam.size()) != n) {
    throw InputError("FuseNeighbourDepths: one pose per depth map");
  }
  for (const cv::Mat& depth : depths) {
    if (depth.type() != CV_32FC1 || depth.cols != camera.width || depth.rows != camera.height) {
      throw InputError("FuseNeighbourDepths: depth maps must be CV_32FC1 of the camera's size");
    }
  }
  std::vector<cv::Mat> fused(n);
  if (options.radius <= 0 || n < 2) {
    for (int t = 0; t < n; ++t) fused[t] = depths[t].clone();
    return fused;
  }
  std::vector<cv::Mat> inverse(n);
  for (int t = 0; t < n; ++t) inverse[t] = InverseOrZero(depths[t]);
  std::vector<NeighbourTransfer> transfers;
  for (int t = 0; t < n; ++t) {
    transfers.clear();
    for (int s : Neighbours(t, n, options.radius)) {
      const SE3 T_s_t = T_world_cam[s].Inverse() * T_world_cam[t];
      transfers.push_back({&inverse[s], PixelTransferF(PixelTransfer(camera, T_s_t)),
                           PixelTransferF(PixelTransfer(camera, T_s_t.Inverse()))});
    }
    fused[t] = FuseOne(camera, depths[t], transfers, options);
  }
  return fused;
}

}  // namespace deblur_sr_mvs
