// Depth confidence: how well each pixel's depth is supported by the other
// frames of its window, so that depth nothing observes is not published as
// if it were known (REP 118: NaN = no reading).
//
// For a pixel x of frame t and each frame s within `neighbour_radius` of t
// (the frames the structure update matched t against, N(t) of
// eq:matchingTerm), x must be visible from s (Omega_ts of eq:occUpdate: it
// projects into camera s and is not occluded there) and the restored latent
// images must agree around it: the zero-mean normalised cross-correlation
// (ZNCC) of I_t and I_s warped into t (eq:warpingFunction) over a small
// patch, and the depth maps must agree: the depth D_t gives to x in camera s
// must match D_s where x lands (g_ts(x) = 1 within max_depth_disagreement,
// falling to 0 at twice it). The best agreement over the frames s is
// multiplied by a texture factor, min(1, patch standard deviation of I_t /
// min_contrast): a textureless patch matches anywhere, so it gives no
// evidence of depth.
//
//   confidence(x) = min(1, std_t(x) / min_contrast)
//                   * max_s g_ts(x) max(0, ZNCC_ts(x))
//
// in [0, 1]; 0 where no frame sees x (borders leaving the view,
// disocclusions) or where the depth is unknown. The latent images were
// restored with the same depth and poses (the self-consistency term pulls
// I_t towards I_s warped with them), so the agreement is a necessary, not a
// sufficient, condition. The depth maps of neighbouring frames were each
// fitted to their own frame's data, so where D_t was extrapolated (a strip
// leaving the view, a disocclusion) it rarely lands on the depth s measured
// there: that test catches much of what the images alone let through.
#pragma once

#include <vector>

#include <opencv2/core.hpp>

#include "deblur_sr_mvs/core/geometry/camera.h"
#include "deblur_sr_mvs/core/geometry/se3.h"
#include "deblur_sr_mvs/core/geometry/visibility.h"

namespace deblur_sr_mvs {

struct DepthConfidenceOptions {
  // Frames s compared with frame t: |s - t| <= neighbour_radius (the
  // estimator's EstimatorOptions::neighbour_radius, the frames its depth was
  // matched against).
  int neighbour_radius = 1;
  // The ZNCC and the contrast use (2 patch_radius + 1)^2 pixels.
  int patch_radius = 2;
  // Patch standard deviation (intensity in [0, 1]) from which a patch counts
  // as fully textured; below it the confidence falls linearly to 0. 0.005
  // is about 1.3 gray levels: flatter patches carry no more than 8-bit
  // rounding and sensor noise, so their correlation says nothing. Measured
  // (BENCHMARKS.md, "Depth confidence"): 0.02 masked a third of a smooth
  // scene whose depth was as good as the rest.
  double min_contrast = 0.005;
  // Geometric consistency of the depth maps of t and s: where the depth D_t
  // gives to a pixel in camera s differs from D_s at the pixel it lands on by
  // more than this (relative), the agreement with s is scaled down linearly,
  // to 0 at twice this. 0 turns the test off.
  double max_depth_disagreement = 0.05;
  // A ZNCC needs at least this share of the patch visible from s.
  double min_visible_share = 0.5;
  // Depth whose confidence is below this becomes NaN (MaskUnconfidentDepth);
  // 0 keeps every depth. At 0.5 a pixel needs a visible, textured patch
  // whose best ZNCC is at least 0.5.
  double threshold = 0.5;
  VisibilityOptions visibility;  // the occlusion test of Omega_ts
  void Check() const;            // throws InputError naming the bad value
};

// One CV_32FC1 map in [0, 1] per frame (see above). `latent`: HR float images
// in [0, 1] (1 or 3 channels); `depth`: HR CV_32FC1 (NaN / <= 0 unknown);
// T_world_cam: the poses, all of the same size and `camera`'s image size.
// Throws InputError on inconsistent input.
std::vector<cv::Mat> ComputeDepthConfidence(const PinholeCamera& camera, const std::vector<cv::Mat>& latent,
                                            const std::vector<cv::Mat>& depth,
                                            const std::vector<SE3>& T_world_cam,
                                            const DepthConfidenceOptions& options);

// A copy of `depth` with NaN where `confidence` is below `threshold`
// (threshold 0: an unchanged copy).
cv::Mat MaskUnconfidentDepth(const cv::Mat& depth, const cv::Mat& confidence, double threshold);

}  // namespace deblur_sr_mvs
