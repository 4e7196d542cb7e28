// Visibility sets Omega_ts (eq:occUpdate, eq:occSet) and the edge weight g_t
// of the depth TV term (eq:regularizingTerm).
#pragma once

#include <opencv2/core.hpp>

#include "deblur_sr_mvs/core/geometry/camera.h"
#include "deblur_sr_mvs/core/geometry/se3.h"

namespace deblur_sr_mvs {

struct VisibilityOptions {
  // A pixel stays visible when its depth seen from s is within this relative
  // margin of the nearest depth landing in the same place (absorbs the
  // sampling of slanted surfaces).
  double depth_tolerance = 0.01;
  // Occlusion by what camera s sees (issue 14, depth discontinuities): with
  // s's own depth map given, a pixel x of t is also left out of Omega_ts
  // when its depth seen from s lies more than this relative margin behind
  // D_s at the cell W^{t->s}(x) rounds to (a z-buffer test of D_t against
  // D_s, refreshed with the depth maps). The test of D_t against itself
  // above only sees an occluder that D_t also holds, so a background pixel
  // of t next to a foreground edge that D_t has not yet resolved (or whose
  // occluder leaves holes in the forward splat) keeps matching whatever
  // covers it in s. 0: off (Omega_ts from D_t alone, eq:occSet).
  double source_depth_margin = 0.0;
  void Check() const;
};

// Omega_ts on the pixels of frame t: CV_8UC1, 255 where x is visible from
// camera s. eq:occUpdate keeps x when it is the nearest of the pixels
// Theta_ts(x) whose warps W^{t->s} fall within 0.5 px of W^{t->s}(x)
// (eq:occSet); the paper's D is inverse depth, hence its ">". Theta_ts is
// approximated by the target pixel cell that W^{t->s}(x) rounds to. Pixels
// with unknown depth or warping outside camera s are not visible.
// `depth_s` (optional, CV_32FC1 of the camera size): D_s for the test of
// VisibilityOptions::source_depth_margin; ignored when the margin is 0.
cv::Mat ComputeVisibility(const PinholeCamera& camera, const cv::Mat& depth_t, const SE3& T_s_t,
                          const VisibilityOptions& options, const cv::Mat* depth_s = nullptr);

// LR mask of an HR mask for box-downsampling by `scale`: an LR pixel is kept
// only when all of its scale x scale HR pixels are.
cv::Mat DownscaleMaskAll(const cv::Mat& mask_hr, int scale);

struct EdgeWeightOptions {
  // g(x) = exp(-(|grad I(x)| / sigma)^exponent), I in [0, 1]: the edge-stopping
  // weight of Kim & Lee (CVPR 2015), the paper's reference for g_t.
  double sigma = 0.1;
  double exponent = 0.8;
  void Check() const;
};

// g_t on the image grid (CV_32FC1 in (0, 1]) from a 1- or 3-channel float
// image with values in [0, 1]; forward differences, channels averaged.
cv::Mat EdgeWeight(const cv::Mat& image, const EdgeWeightOptions& options);

}  // namespace deblur_sr_mvs
