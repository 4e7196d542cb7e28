// Temporal fusion of the restored images (issue 12, "the image update must
// not amplify noise"; BENCHMARKS.md "Temporal fusion of the restored images").
//
// The self-consistency term (eq:IPterm, lambda_s 30 against 1 for each
// matching term) makes I_t reproduce its own frame B_t, noise included, and
// the deblurring amplifies that noise; the neighbours' restored images I_s
// come from other frames with independent noise (and independent restoration
// artefacts). The fusion warps each I_s of the frames within `radius` of t
// into t with D_t and the poses (eq:warpingFunction, I_s(W^{t->s}(x)), bicubic)
// and replaces I_t by the weighted mean
//
//   I'_t(x) = (I_t(x) + sum_s w_s(x) I_s(W(x))) / (1 + sum_s w_s(x)),
//   w_s(x)  = exp(-d_s(x) / (2 h^2)),
//
// where d_s(x) is the mean squared difference between I_t and the warped I_s
// over the patch_px x patch_px patch around x (and the channels), so that an
// occluded, mis-registered or out-of-view neighbour (weight 0) leaves I_t as
// it is: a non-local-means weight across time along the estimated geometry.
// h does not follow the noise level: the best h measured the same at sigma
// 0, 1, 2 and 4 gray levels (9-13 gray levels on Aloe, 20-30 on Dolls, on
// every path); the averaging itself scales with the noise, and the fusion
// gains on noise-free frames too (independent restoration errors).
#pragma once

#include <vector>

#include <opencv2/core.hpp>

#include "deblur_sr_mvs/core/geometry/camera.h"
#include "deblur_sr_mvs/core/geometry/se3.h"

namespace deblur_sr_mvs {

struct TemporalFusionOptions {
  // Frames on either side of t whose restored images are fused into I_t;
  // 0 turns the fusion off (the output images are the image update's,
  // bit for bit). 2 measured best (1 and 5 lower; BENCHMARKS.md section above).
  int radius = 2;
  // h of the patch weight (intensity in [0, 1]; 13 gray levels): the best
  // single value over Dolls and Aloe, four paths, sigma 0-4.
  double distance_scale = 13.0 / 255.0;
  // Side of the patch over which the squared differences are averaged (odd, px).
  int patch_px = 5;
  // Also fuse the restored images before each structure update (the solver's
  // current depth and poses), not only the output images.
  bool between_updates = false;
  void Check() const;  // throws InputError naming the bad value
};

// Fuses the restored images `latents` (CV_32FC1 or CV_32FC3, one size) of
// cameras T_world_cam (intrinsics `camera_hr`, depth maps `depths` of the
// same size, NaN or <= 0 unknown: such pixels keep I_t) with the weights
// above (h = options.distance_scale). Frames t < first_fused keep their images (a
// stream's held latents, already fused in the window that published them)
// but still lend them to the others. Returns the fused images (new Mats; the
// inputs are not changed). radius 0: copies of the inputs.
std::vector<cv::Mat> FuseRestoredImages(const PinholeCamera& camera_hr, const std::vector<cv::Mat>& latents,
                                        const std::vector<cv::Mat>& depths,
                                        const std::vector<SE3>& T_world_cam,
                                        const TemporalFusionOptions& options, int first_fused);

}  // namespace deblur_sr_mvs
