// Depth re-sweep: a plane sweep over the restored images with edge-aware
// cost aggregation (issue 14, "Depth re-sweep on the restored images").
//
// The initialiser matches the blurry LR inputs over (2r+1)^2 box windows
// (eq:initializationScene); a textured foreground's depth spreads over the
// background next to it (fattening), and the structure update keeps it: the
// background band carries little data (BENCHMARKS.md, "Occlusion-aware
// matching and coarse-to-fine in the structure update"). After the joint
// iterations the latent images I_t are sharp and HR: the re-sweep matches
// I_t against its neighbours' I_s warped through fronto-parallel planes
// (eq:warpingFunction at the current poses) over the frame's whole inverse-
// depth range, and aggregates every plane's cost with a guided filter
// (He et al., PAMI 2013) guided by I_t (in gray), so that a
// window does not mix the costs of the two sides of an image edge. The
// per-pixel cost of a plane is the smaller of the aggregated costs of the
// earlier and of the later neighbours (a band that one side cannot see is
// matched by the other). Where the sweep's best plane lies more than
// `keep_steps` plane steps from the current inverse depth, the pixel takes the
// sweep's (parabola-refined) inverse depth; elsewhere it keeps the estimate,
// whose precision the sweep's plane spacing cannot reach.
#pragma once

#include <vector>

#include <opencv2/core.hpp>

#include "deblur_sr_mvs/core/geometry/camera.h"
#include "deblur_sr_mvs/core/geometry/se3.h"

namespace deblur_sr_mvs {

struct DepthSweepOptions {
  // Whether the estimator re-sweeps the output depth of joint mode (on the
  // result's copy, before the depth-edge median; the solver's depth,
  // energy, poses and images are unchanged; a stream's next window starts
  // from the solver's depth, EstimatorResult::solver_depth). Baseline mode
  // has no restored images and never re-sweeps. On 8 sequences (Dolls, Aloe
  // x lateral, arc, forward,
  // hand-held) it lowers joint's crop depth from 0.874x to 0.799x the
  // baseline's, lower on every sequence, full frame 1.050x -> 0.950x, for
  // +8 % CPU (BENCHMARKS.md "Depth re-sweep on the restored images"):
  // estimate_sequence and the node turn it on by default (in the node's
  // windows: BENCHMARKS.md "The node's published depth refined as offline").
  // The library's default stays
  // off: with it, PosePriorIterations.DepthInMetresStaysWithinTenPercentOf-
  // TheAlignedError fails (depth in metres 0.0246 -> 0.0201, scale-aligned
  // 0.0224 -> 0.0179: the same 0.0022 gap, a ratio of 1.123 against the
  // test's 1.10).
  bool on_output = false;
  // Whether the estimator also re-sweeps the solver's own D_t (joint mode)
  // before the last `before_last_structure_updates` structure updates of
  // Algorithm 1, so that the structure update (depth and poses) continues
  // from the swept depth and the image update that follows judges it (a
  // rise in energy undoes the iteration, as for any structure update).
  // The swept map goes through the depth-edge median first where that is on
  // (DepthEdgeOptions::radius_px > 0). An iteration from the swept depth
  // that raises the energy is run again
  // from the solver's depth. 0: never. Not in a window that carries
  // operators nor in a stream (StreamEstimator sets 0). Measured, not adopted (BENCHMARKS.md "The
  // re-sweep inside the joint iterations"): at 2 (with the median), crop
  // depth 0.799x -> 0.778x the baseline's on 8 sequences, but ATE 0.849x ->
  // 0.861x and above the baseline on lateral / Aloe, +37 % CPU (loaded).
  int before_last_structure_updates = 0;
  // Fronto-parallel planes, equally spaced in inverse depth over the frame's
  // range (its 1st to 99th percentile of the current inverse depth, widened
  // by `range_margin` of the span on each side).
  int num_planes = 48;
  double range_margin = 0.1;
  // Guided-filter aggregation of each plane's cost: window radius (HR px)
  // and regularisation eps (guide intensities in [0, 1]; smaller follows
  // the guide's edges more closely).
  int aggregation_radius_px = 3;
  double aggregation_eps = 1e-4;
  // Per-neighbour cap of the colour-averaged |difference| (occlusion).
  double cost_truncation = 0.05;
  // A pixel keeps its inverse depth where the sweep's best plane lies within
  // this many plane steps of it; 0: every pixel takes the sweep's.
  double keep_steps = 2.0;
  // ... and where the sweep's best aggregated cost is not below (1 -
  // min_cost_gain) times the cost of the plane nearest its inverse depth
  // (0: any lower cost replaces it).
  double min_cost_gain = 0.1;
  // ... and where the restored image is flat: its gray standard deviation
  // over the aggregation window below min_guide_std (intensity in [0, 1];
  // 0: no such test). There every plane matches about as well, noise picks
  // the sweep's best plane, and the guided filter (whose eps is 1e-4, a
  // standard deviation of 0.01) aggregates as a plain box. On 4 sequences
  // (lateral Reindeer, hand-held Reindeer, arc Aloe, lateral Dolls) 0.01
  // lowered joint's crop depth from 0.910x to 0.896x the baseline's
  // (BENCHMARKS.md "The re-sweep kept off flat image regions").
  double min_guide_std = 0.01;
  // The estimator matches frame t against the frames within this distance
  // (its own N(t) is often one frame per side: too noisy for a sweep).
  int neighbour_radius = 2;
  // The sweep runs on the images box-downsampled by this factor (1: the
  // images' own grid); its inverse depth and costs are resized back.
  int downsample = 1;
  void Check() const;  // throws InputError naming the bad value
};

// Re-sweeps frame t's inverse depth (CV_32FC1, camera's size; NaN or <= 0:
// unknown, left as is) against `images[s]` for s in `sources` (s != t), all
// of the camera's size (CV_32FC1 or CV_32FC3, [0, 1]), with the poses
// T_world_cam (shutter close, the images' poses). Sources earlier than t
// form one side, later ones the other. No sources: no change.
void SweepInverseDepth(const std::vector<cv::Mat>& images, const PinholeCamera& camera,
                       const std::vector<SE3>& T_world_cam, int t, const std::vector<int>& sources,
                       const DepthSweepOptions& options, cv::Mat* inverse_depth);

}  // namespace deblur_sr_mvs
