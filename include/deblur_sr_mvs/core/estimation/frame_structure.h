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
// pose path over t's exposure interpolates towards the previous frame; the
// first frame extrapolates from the next one (constant velocity).
CaptureGeometry MakeCaptureGeometry(const std::vector<FrameStructure>& frames, const PinholeCamera& camera_hr,
                                    int t, int source);

// N(t): the neighbouring frames of t used by the matching terms, `radius`
// frames on each side inside [0, num_frames).
std::vector<int> Neighbours(int t, int num_frames, int radius);

}  // namespace deblur_sr_mvs
