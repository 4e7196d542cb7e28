#include "deblur_sr_mvs/core/estimation/depth_confidence.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include <opencv2/imgproc.hpp>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/common/options_check.h"
#include "deblur_sr_mvs/core/common/text.h"
#include "deblur_sr_mvs/core/geometry/warp.h"

namespace deblur_sr_mvs {

void DepthConfidenceOptions::Check() const {
  CheckAtLeast("depth confidence: neighbour_radius", neighbour_radius, 1);
  CheckAtLeast("depth confidence: patch_radius", patch_radius, 1);
  CheckAbove("depth confidence: min_contrast", min_contrast, 0.0);
  CheckInInterval("depth confidence: min_visible_share", min_visible_share, 0.0, 1.0, Interval::kRightClosed);
  CheckInRange("depth confidence: threshold", threshold, 0.0, 1.0);
  CheckAtLeast("depth confidence: max_depth_disagreement", max_depth_disagreement, 0.0);
  visibility.Check();
}

namespace {

// Gray CV_32FC1 of a float latent image (channels averaged, as EdgeWeight).
cv::Mat Gray(const cv::Mat& latent) {
  if (latent.channels() == 1) return latent;
  cv::Mat gray;
  cv::transform(latent, gray, cv::Matx13f(1.0f / 3, 1.0f / 3, 1.0f / 3));
  return gray;
}

// Sum over the (2 r + 1)^2 patch around every pixel (borders replicated).
cv::Mat PatchSum(const cv::Mat& image, int radius) {
  cv::Mat sum;
  cv::boxFilter(image, sum, CV_32F, cv::Size(2 * radius + 1, 2 * radius + 1), cv::Point(-1, -1),
                /*normalize=*/false, cv::BORDER_REPLICATE);
  return sum;
}

// min(1, patch std of `gray` / min_contrast): the texture factor.
cv::Mat TextureFactor(const cv::Mat& gray, const DepthConfidenceOptions& options) {
  const int r = options.patch_radius;
  const float area = static_cast<float>((2 * r + 1) * (2 * r + 1));
  const cv::Mat sum = PatchSum(gray, r);
  const cv::Mat sum_squares = PatchSum(gray.mul(gray), r);
  cv::Mat factor(gray.size(), CV_32FC1);
  const float scale = static_cast<float>(1.0 / options.min_contrast);
  for (int y = 0; y < gray.rows; ++y) {
    const float* s = sum.ptr<float>(y);
    const float* q = sum_squares.ptr<float>(y);
    float* out = factor.ptr<float>(y);
    for (int x = 0; x < gray.cols; ++x) {
      const float mean = s[x] / area;
      const float deviation = std::sqrt(std::max(0.0f, q[x] / area - mean * mean));
      out[x] = std::min(1.0f, deviation * scale);
    }
  }
  return factor;
}

// I_s warped into t (bilinear) where Omega_ts holds, 0 elsewhere. `weight`
// receives, per pixel, how far the depth maps of t and s agree there: 1 where
// the depth D_t gives to the point in camera s is within
// `max_depth_disagreement` (relative) of D_s at the pixel it lands on,
// falling linearly to 0 at twice that; 0 where Omega_ts does not hold.
cv::Mat WarpVisible(const PinholeCamera& camera, const cv::Mat& depth_t, const cv::Mat& depth_s,
                    const SE3& T_s_t, const cv::Mat& visible, const cv::Mat& gray_s,
                    const DepthConfidenceOptions& options, cv::Mat* weight) {
  const PixelTransfer transfer(camera, T_s_t);
  cv::Mat map_x(depth_t.size(), CV_32FC1, cv::Scalar(-1.0f));
  cv::Mat map_y(depth_t.size(), CV_32FC1, cv::Scalar(-1.0f));
  weight->create(depth_t.size(), CV_32FC1);
  const double tolerance = options.max_depth_disagreement;
  for (int y = 0; y < depth_t.rows; ++y) {
    const float* d = depth_t.ptr<float>(y);
    const uchar* v = visible.ptr<uchar>(y);
    float* mx = map_x.ptr<float>(y);
    float* my = map_y.ptr<float>(y);
    float* w = weight->ptr<float>(y);
    for (int x = 0; x < depth_t.cols; ++x) {
      Eigen::Vector2d p;
      double depth_in_s = 0.0;
      w[x] = 0.0f;
      if (v[x] == 0 || !transfer.Warp(x, y, d[x], &p, &depth_in_s)) continue;
      mx[x] = static_cast<float>(p.x());
      my[x] = static_cast<float>(p.y());
      w[x] = 1.0f;
      if (tolerance <= 0.0) continue;
      const int u_s = static_cast<int>(std::lround(p.x()));
      const int v_s = static_cast<int>(std::lround(p.y()));
      if (u_s < 0 || v_s < 0 || u_s >= depth_s.cols || v_s >= depth_s.rows) continue;
      const float measured = depth_s.at<float>(v_s, u_s);
      if (!(measured > 0.0f)) continue;  // unknown in s: no evidence against
      const double disagreement = std::abs(depth_in_s - measured) / measured;
      w[x] = static_cast<float>(std::clamp(2.0 - disagreement / tolerance, 0.0, 1.0));
    }
  }
  cv::Mat warped;
  cv::remap(gray_s, warped, map_x, map_y, cv::INTER_LINEAR, cv::BORDER_REPLICATE);
  cv::Mat in_view = *weight > 0.0f;
  warped.setTo(0.0f, ~in_view);
  return warped;
}

// max(best, geometric agreement x max(0, ZNCC)) of gray_t against `warped`
// over the visible pixels of each patch (`weight` > 0), where x itself is
// visible and enough of the patch is; the geometric agreement is `weight`
// at x (see WarpVisible).
void AccumulateAgreement(const cv::Mat& gray_t, const cv::Mat& warped, const cv::Mat& weight,
                         const DepthConfidenceOptions& options, cv::Mat* best) {
  const int r = options.patch_radius;
  cv::Mat in_view;
  cv::threshold(weight, in_view, 0.0, 1.0, cv::THRESH_BINARY);
  const cv::Mat a = gray_t.mul(in_view);  // warped is 0 where in_view is
  const cv::Mat count = PatchSum(in_view, r);
  const cv::Mat sum_a = PatchSum(a, r);
  const cv::Mat sum_b = PatchSum(warped, r);
  const cv::Mat sum_aa = PatchSum(a.mul(a), r);
  const cv::Mat sum_bb = PatchSum(warped.mul(warped), r);
  const cv::Mat sum_ab = PatchSum(a.mul(warped), r);
  const float min_count = static_cast<float>(options.min_visible_share * (2 * r + 1) * (2 * r + 1));
  constexpr float kTinyVariance = 1e-8f;  // a flat patch has no defined ZNCC
  for (int y = 0; y < gray_t.rows; ++y) {
    const float* w = weight.ptr<float>(y);
    const float* n = count.ptr<float>(y);
    const float* sa = sum_a.ptr<float>(y);
    const float* sb = sum_b.ptr<float>(y);
    const float* saa = sum_aa.ptr<float>(y);
    const float* sbb = sum_bb.ptr<float>(y);
    const float* sab = sum_ab.ptr<float>(y);
    float* out = best->ptr<float>(y);
    for (int x = 0; x < gray_t.cols; ++x) {
      if (w[x] == 0.0f || n[x] < min_count) continue;
      const float mean_a = sa[x] / n[x];
      const float mean_b = sb[x] / n[x];
      const float var_a = saa[x] / n[x] - mean_a * mean_a;
      const float var_b = sbb[x] / n[x] - mean_b * mean_b;
      if (var_a <= kTinyVariance || var_b <= kTinyVariance) continue;
      const float zncc = (sab[x] / n[x] - mean_a * mean_b) / std::sqrt(var_a * var_b);
      out[x] = std::max(out[x], w[x] * std::min(1.0f, zncc));
    }
  }
}

void CheckConfidenceInput(const PinholeCamera& camera, const std::vector<cv::Mat>& latent,
                          const std::vector<cv::Mat>& depth, const std::vector<SE3>& T_world_cam) {
  if (latent.size() != depth.size() || latent.size() != T_world_cam.size()) {
    throw InputError("depth confidence: " + std::to_string(latent.size()) + " latent images, " +
                     std::to_string(depth.size()) + " depth maps and " + std::to_string(T_world_cam.size()) +
                     " poses (must be one each per frame)");
  }
  const cv::Size size(camera.width, camera.height);
  for (size_t t = 0; t < latent.size(); ++t) {
    if (latent[t].size() != size || latent[t].depth() != CV_32F ||
        (latent[t].channels() != 1 && latent[t].channels() != 3)) {
      throw InputError("depth confidence: latent image " + std::to_string(t) +
                       " must be float, 1 or 3 channels, " + SizeText(size));
    }
    if (depth[t].size() != size || depth[t].type() != CV_32FC1) {
      throw InputError("depth confidence: depth map " + std::to_string(t) + " must be CV_32FC1, " +
                       SizeText(size));
    }
  }
}

}  // namespace

std::vector<cv::Mat> ComputeDepthConfidence(const PinholeCamera& camera, const std::vector<cv::Mat>& latent,
                                            const std::vector<cv::Mat>& depth,
                                            const std::vector<SE3>& T_world_cam,
                                            const DepthConfidenceOptions& options) {
  options.Check();
  CheckConfidenceInput(camera, latent, depth, T_world_cam);
  const int count = static_cast<int>(latent.size());
  std::vector<cv::Mat> gray(count);
  for (int t = 0; t < count; ++t) gray[t] = Gray(latent[t]);
  std::vector<cv::Mat> confidence(count);
#pragma omp parallel for schedule(dynamic)
  for (int t = 0; t < count; ++t) {
    cv::Mat best(gray[t].size(), CV_32FC1, cv::Scalar(0.0f));
    const int first = std::max(0, t - options.neighbour_radius);
    const int last = std::min(count - 1, t + options.neighbour_radius);
    for (int s = first; s <= last; ++s) {
      if (s == t) continue;
      const SE3 T_s_t = T_world_cam[s].Inverse() * T_world_cam[t];
      const cv::Mat visible = ComputeVisibility(camera, depth[t], T_s_t, options.visibility);
      cv::Mat weight;
      const cv::Mat warped =
          WarpVisible(camera, depth[t], depth[s], T_s_t, visible, gray[s], options, &weight);
      AccumulateAgreement(gray[t], warped, weight, options, &best);
    }
    confidence[t] = best.mul(TextureFactor(gray[t], options));
  }
  return confidence;
}

cv::Mat MaskUnconfidentDepth(const cv::Mat& depth, const cv::Mat& confidence, double threshold) {
  if (depth.type() != CV_32FC1 || confidence.type() != CV_32FC1 || depth.size() != confidence.size()) {
    throw InputError("depth mask: depth and confidence must be CV_32FC1 of one size");
  }
  cv::Mat masked = depth.clone();
  if (threshold <= 0.0) return masked;
  masked.setTo(std::numeric_limits<float>::quiet_NaN(), confidence < threshold);
  return masked;
}

}  // namespace deblur_sr_mvs
