// Metric scale from a pose prior (docs/file_formats.md#monocular-scale): the
// similarity that carries an estimated trajectory (monocular: arbitrary
// world and scale) onto the poses that a prior gives for the same frames
// (wheel odometry, VIO, motion capture; the node's tf `pose_prior_frame`,
// estimate_sequence's --pose-prior). Poses then come out in the prior's frame
// and depth in the prior's units (metres, REP 118).
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "deblur_sr_mvs/core/geometry/se3.h"
#include "deblur_sr_mvs/core/geometry/sim3.h"

namespace deblur_sr_mvs {

struct PosePriorOptions {
  // Most recent frames of a trajectory segment that the aligner fits on.
  int history_frames = 30;
  // Spread of the prior's camera positions (prior units, metres) needed to
  // fix the scale; below it the previous alignment is kept.
  double min_prior_extent = 0.02;
  // A frame whose aligned position is further than this from the prior's
  // (prior units) is an outlier of the prior and does not enter the fit.
  double outlier_distance = 0.05;
  void Check() const;  // throws InputError naming the bad field
};

// The result of one alignment.
struct PriorAlignment {
  bool valid = false;    // estimate_to_prior is usable (fitted now, or kept from before)
  bool updated = false;  // fitted by this call
  // T_prior_cam ~= estimate_to_prior applied to T_world_cam (TransformPose
  // of sim3.h); depths scale by estimate_to_prior.scale.
  Sim3 estimate_to_prior;
  int used = 0;      // corresponding frames offered to the fit
  int inliers = 0;   // of them, within outlier_distance after the fit
  // Those frames: indices into the fit's input, increasing (AlignToPrior
  // only; a kept previous fit of PosePriorAligner has none).
  std::vector<int> inlier_frames;
  double rms = 0.0;  // position residual of the inliers (prior units)
  // Standard deviation of estimate_to_prior.scale relative to itself (0.02 =
  // 2 %) that the prior's position noise leaves: the least-squares figure
  // sigma / sqrt(sum_i |q_i - mean q|^2), sigma the per-axis noise estimated
  // from the inliers' residuals (3 n - 4 degrees of freedom: scale and
  // translation come from the positions, the rotation from the
  // orientations), q_i the aligned estimated positions
  // (docs/file_formats.md#monocular-scale). The residuals hold the prior's
  // noise and the estimate's own trajectory error. With 1 cm noise it is
  // about 1 cm / (path length * sqrt(n / 12)): 10 % for 10 frames over
  // 10 cm, 1.6 % for 16 frames over 50 cm. (Few inliers estimate sigma
  // poorly: 4 frames give 8 degrees of freedom.)
  double scale_uncertainty = 0.0;
  std::string note;  // one line: what was fitted, or why the previous fit is kept
};

// Whether a per-frame prior (T_prior_cam, none where the prior has no
// pose) has a pose for any frame.
bool HasAnyPriorPose(const std::vector<std::optional<SE3>>& T_prior_cam);

// Robust similarity from corresponding camera poses (same frames, same
// order): the rotation from the orientations, the scale and translation from
// the positions, frames that disagree (outliers of the prior) left out.
// valid = false (with the reason in note) when fewer than 2 frames agree or
// the prior's positions spread less than min_prior_extent.
PriorAlignment AlignToPrior(const std::vector<SE3>& T_world_cam, const std::vector<SE3>& T_prior_cam,
                            const PosePriorOptions& options);

// The alignment of a trajectory segment that grows window after window. The
// estimated poses must all be in one world (a segment of the stream);
// Reset() when a new segment starts.
class PosePriorAligner {
 public:
  explicit PosePriorAligner(const PosePriorOptions& options);
  // Records frame `id` (its latest estimate replaces an earlier one).
  void Add(uint64_t id, const SE3& T_world_cam, const SE3& T_prior_cam);
  // Fits on the last history_frames recorded frames. When that fails (too
  // little prior translation, too few inliers), returns the last valid
  // alignment with updated = false and the reason in note; valid = false if
  // there was none.
  PriorAlignment Fit();
  void Reset();

 private:
  struct Correspondence {
    SE3 T_world_cam, T_prior_cam;
  };
  PosePriorOptions options_;
  std::map<uint64_t, Correspondence> frames_;  // by id (ids increase)
  PriorAlignment last_valid_;
};

}  // namespace deblur_sr_mvs
