// Plain per-frame records shared by the estimator, the file readers and the
// evaluation: when a frame was exposed, and a pose at a stamp.
#pragma once

#include <vector>

#include <Eigen/Core>

#include "deblur_sr_mvs/core/geometry/se3.h"

namespace deblur_sr_mvs {

// One row of frames.csv: `index,stamp,exposure`; stamp is the shutter close
// time t_c in seconds, exposure = t_c - t_o in seconds.
struct FrameRecord {
  int index = 0;
  double stamp = 0.0;
  double exposure = 0.0;
};

// The stamps of `frames`, in order.
inline std::vector<double> FrameStamps(const std::vector<FrameRecord>& frames) {
  std::vector<double> stamps;
  stamps.reserve(frames.size());
  for (const FrameRecord& frame : frames) stamps.push_back(frame.stamp);
  return stamps;
}

// A feature followed through consecutive frames: its pixel (x right, y
// down, in the LR input camera) in frames first_frame, first_frame + 1, ...
// Tracked on the blurred frames, it observes the camera at mid-exposure of
// its row: t_c - exposure / 2 + y readout_time / height.
struct FeatureTrack {
  int first_frame = 0;
  std::vector<Eigen::Vector2d> points;
  int LastFrame() const { return first_frame + static_cast<int>(points.size()) - 1; }
};

struct StampedPose {
  double stamp = 0.0;
  SE3 T_world_cam;  // camera -> world at the stamp
};

}  // namespace deblur_sr_mvs
