// Depth edges: an edge-aware refinement of the inverse depth guided by the
// frame's image (issue 14, "Depth edges").
//
// The window-based matching of the initialiser (eq:initializationScene, a
// (2r+1)^2 patch cost at LR) spreads the depth of a textured foreground over
// the background next to it (fattening), and the structure update keeps it:
// the background band carries little data (BENCHMARKS.md, "Occlusion-aware
// matching and coarse-to-fine in the structure update"). A depth edge
// usually coincides with an edge of the image, and in joint mode the
// restored I_t shows it sharply. The refinement replaces each inverse depth
// by the weighted median of its (2 radius + 1)^2 window, each window pixel y
// weighted by its similarity to x in the guide image,
//
//   w(x, y) = exp(-|I(x) - I(y)|^2 / (2 sigma^2)),
//
// (Zhang et al., "100+ times faster weighted median filter", CVPR 2014;
// cv::ximgproc::weightedMedianFilter). The pixels of the fattened band look
// like the background, so their median is taken over the background beyond
// the band; a median (unlike a mean) puts out a depth of the window, never a
// blend of the two sides.
#pragma once

#include <opencv2/core.hpp>

namespace deblur_sr_mvs {

struct DepthEdgeOptions {
  // Window radius of the weighted median (HR px); 0 turns the refinement
  // off. It must be more than twice the width of the fattened band (the
  // initialiser's patch radius times the scale, about 4 HR px at the
  // defaults): the band's pixels need more background beyond the band than
  // band in their window (test/core/estimation/depth_edges_test.cc).
  // Measured on 8 sequences (BENCHMARKS.md, "Depth edges: a weighted median
  // guided by the restored image"): radius 8 brings joint's depth below the
  // baseline's on all 8.
  int radius_px = 8;
  // Colour distance scale of the guide weights (intensity in [0, 1]).
  double sigma = 0.1;
  // Where the estimator applies it: to the output depth, guided by the
  // output latent images (joint: restored; baseline: the bicubic inputs), on
  // the result's copy; not in a window that hands operators on to the next
  // (EstimatorOptions::carried_frames > 0: they match the unrefined depth).
  // A stream (StreamEstimator) turns this off in its window estimator,
  // refines the frames it publishes itself and hands the solver's own depth
  // on to the next window ...
  bool on_output = true;
  // ... and/or to every D_t at the start of each structure update, guided
  // by the current latent I_t. Off: the structure update spreads the depth
  // again and the refined D_t fights the energy (joint depth 0.932x the
  // baseline refined the same way, 0.909x without; ATE 0.894x the
  // baseline's instead of 0.849x; image PSNR -0.05 dB; same section).
  bool before_structure_update = false;
  void Check() const;  // throws InputError naming the bad value
};

// The weighted median above of `inverse_depth` (CV_32FC1) guided by `guide`
// (CV_32FC1 or CV_32FC3, intensities in [0, 1], same size), in place. The
// median of a monotone function of the values is that function of their
// median: a depth map can be passed as well.
// Pixels whose inverse depth is not finite and positive neither vote nor
// change. Off (radius_px 0): no change.
void RefineDepthEdges(const cv::Mat& guide, const DepthEdgeOptions& options, cv::Mat* inverse_depth);

}  // namespace deblur_sr_mvs
