#include "deblur_sr_mvs/core/estimation/temporal_fusion.h"

#include <algorithm>
#include <cmath>

#include <opencv2/imgproc.hpp>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/common/options_check.h"
#include "deblur_sr_mvs/core/geometry/warp.h"

namespace deblur_sr_mvs {
namespace {

// I_source warped into t (bicubic), and the mask (CV_32FC1, 1 or 0) of the
// pixels of t that land inside the source image at least one pixel from its
// border, with a known depth.
void WarpIntoTarget(const PinholeCamera& camera_hr, const cv::Mat& depth_t, const SE3& T_source_t,
                    const cv::Mat& latent_source, cv::Mat* warped, cv::Mat* inside) {
  cv::Mat coordinates = WarpCoordinates(camera_hr, depth_t, T_source_t);
  inside->create(depth_t.size(), CV_32FC1);
  const float max_u = static_cast<float>(camera_hr.width - 2);
  const float max_v = static_cast<float>(camera_hr.height - 2);
  for (int y = 0; y < coordinates.rows; ++y) {
    cv::Vec2f* row = coordinates.ptr<cv::Vec2f>(y);
    float* mask = inside->ptr<float>(y);
    for (int x = 0; x < coordinates.cols; ++x) {
      const float u = row[x][0];
      const float v = row[x][1];
      const bool ok = u >= 1.0f && v >= 1.0f && u <= max_u && v <= max_v;  // false for NaN
      mask[x] = ok ? 1.0f : 0.0f;
      if (!ok) row[x] = cv::Vec2f(-10.0f, -10.0f);
    }
  }
  cv::remap(latent_source, *warped, coordinates, cv::noArray(), cv::INTER_CUBIC, cv::BORDER_REPLICATE);
}

// The weight map exp(-d / (2 h^2)) of the warped image against I_t (d: the
// patch mean of the channel-mean squared difference), times `inside`.
void PatchWeight(const cv::Mat& latent_t, const cv::Mat& warped, const cv::Mat& inside, int patch_px,
                 double h, cv::Mat* squared, cv::Mat* weight) {
  cv::subtract(warped, latent_t, *squared);
  cv::multiply(*squared, *squared, *squared);
  if (squared->channels() > 1) {
    cv::transform(*squared, *weight, cv::Matx13f(1.0f / 3.0f, 1.0f / 3.0f, 1.0f / 3.0f));
  } else {
    squared->copyTo(*weight);
  }
  cv::boxFilter(*weight, *weight, -1, cv::Size(patch_px, patch_px), cv::Point(-1, -1), true,
                cv::BORDER_REFLECT);
  *weight *= -1.0 / (2.0 * h * h);
  cv::exp(*weight, *weight);
  cv::multiply(*weight, inside, *weight);
}

}  // namespace

void TemporalFusionOptions::Check() const {
  CheckInRange("fusion_radius", radius, 0, 10);
  CheckAbove("fusion_distance_scale", distance_scale, 0.0);
  if (patch_px < 1 || patch_px % 2 == 0 || patch_px > 31) {
    throw InputError("fusion_patch must be odd and in [1, 31], got " + std::to_string(patch_px));
  }
}

std::vector<cv::Mat> FuseRestoredImages(const PinholeCamera& camera_hr, const std::vector<cv::Mat>& latents,
                                        const std::vector<cv::Mat>& depths,
                                        const std::vector<SE3>& T_world_cam,
                                        const TemporalFusionOptions& options, int first_fused) {
  const int n = static_cast<int>(latents.size());
  if (static_cast<int>(depths.size()) != n || static_cast<int>(T_world_cam.size()) != n) {
    throw InputError("FuseRestoredImages: one depth map and one pose per restored image");
  }
  std::vector<cv::Mat> fused(n);
  cv::Mat warped, inside, squared, weight, weight_c, sum, weight_sum;
  for (int t = 0; t < n; ++t) {
    fused[t] = latents[t].clone();
    if (options.radius <= 0 || t < first_fused) continue;
    latents[t].copyTo(sum);
    weight_sum = cv::Mat::ones(latents[t].size(), CV_32FC1);
    for (int s = std::max(0, t - options.radius); s <= std::min(n - 1, t + options.radius); ++s) {
      if (s == t) continue;
      const SE3 T_s_t = T_world_cam[s].Inverse() * T_world_cam[t];
      WarpIntoTarget(camera_hr, depths[t], T_s_t, latents[s], &warped, &inside);
      PatchWeight(latents[t], warped, inside, options.patch_px, options.distance_scale, &squared, &weight);
      weight_sum += weight;
      if (warped.channels() > 1) {
        cv::merge(std::vector<cv::Mat>(warped.channels(), weight), weight_c);
      } else {
        weight_c = weight;
      }
      cv::multiply(warped, weight_c, warped);
      sum += warped;
    }
    if (sum.channels() > 1) {
      cv::merge(std::vector<cv::Mat>(sum.channels(), weight_sum), weight_c);
    } else {
      weight_c = weight_sum;
    }
    cv::divide(sum, weight_c, fused[t]);
  }
  return fused;
}

}  // namespace deblur_sr_mvs
