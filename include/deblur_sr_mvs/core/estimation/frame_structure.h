// The per-frame state the estimator works on, and the capture geometry of
// eq:blurOperator that it implies.
#pragma once

#include <vector>

#include <opencv2/core.hpp>

#include "deblur_sr_mvs/core/geometry/se3.h"
#include "deblur_sr_mvs/core/imaging/capture_operator.h"

namespace deblur_sr_mvs {

struct FrameStructure {
  double stamp = 0.0;         // shutter close time t_c, s
  double exposure = 0.0;      // t_c - t_o, s
  double readout_time = 0.0;  // rolling shutter (CaptureGeometry::readout_time), s
  SE3 T_world_cam;            // P_t at t_c
  cv::Mat depth_hr;           // D_t: CV_32FC1 at HR, NaN where unknown
};

// Geometry of Psi_t sampling the latent image of frame `source` (eq:blurOperator;
// source == t: the self-consistency term, otherwise the matching term). The
// pose path over t's exposure is the curve through the poses of t and its
// BlurPathFrames (t-1 and t+1; at the ends of the window the geodesic to the
// one neighbour, extrapolated backwards for the first frame).
CaptureGeometry MakeCaptureGeometry(const std::vector<FrameStructure>& frames, const PinholeCamera& camera_hr,
                                    int t, int source);

// The frames whose poses MakeCaptureGeometry(frames, camera_hr, t, source)
// reads: t, its BlurPathFrames, then source if it is none of those. A cache
// of operators keys on their versions (with D_t's).
std::vector<int> CaptureGeometryFrames(int t, int source, int num_frames);

// Geometry of `frame` swept by the exposure of `kernel_frame` (at scale 1
// applied to frame's up-sampled input: B_frame blurred by kernel_frame's
// blur). kernel_frame's pose path is moved rigidly onto frame (the same
// motion in the camera frame: MoveBlurPath), with k's exposure and a global
// shutter. The cross-blurred pair
// (B_t through s's blur against B_s through t's blur) carries equal blur in
// both images whatever the two frames' motions, which the plain inputs do
// only when t and s move alike (the Psi_s o B_t and Psi_t o B_s of
// eq:initializationScene). frame == kernel_frame gives Psi_t's own path.
CaptureGeometry CrossBlurGeometry(const std::vector<FrameStructure>& frames, const PinholeCamera& camera_hr,
                                  int frame, int kernel_frame);

// N(t): the neighbouring frames of t used by the matching terms, `radius`
// frames on each side inside [0, num_frames).
std::vector<int> Neighbours(int t, int num_frames, int radius);

}  // namespace deblur_sr_mvs
