// Photometric robustness (issue 12): a per-frame gain between the frames of
// a window, so that auto-gain changes do not bias the brightness-constancy
// matching of the structure update (eq:matchingTerm) and the initialiser.
#pragma once

#include <vector>

#include <opencv2/core.hpp>

namespace deblur_sr_mvs {

struct GainEstimationOptions {
  int max_corners = 300;        // Shi-Tomasi corners tracked per frame pair
  int box_radius = 2;           // local means over (2 r + 1)^2 pixels
  double min_intensity = 0.05;  // darker local means give no ratio (noise)
  // Pixels at least this bright (any channel) count as clipped at white;
  // points near them give no ratio.
  double max_intensity = 0.98;
  int min_matches = 20;  // fewer matched points: the pair's gain is 1
  // A corner tracked into the other frame and back must land within this
  // many pixels of where it started (forward-backward check), else it gives
  // no ratio.
  double max_track_error_px = 0.5;
  void Check() const;  // throws InputError naming the bad value
};

// Gain of every frame relative to the first (gains[0] = 1): frame t is about
// gains[t] times frame 0 where they see the same scene. Per consecutive pair
// the median of the ratios of local mean intensities at KLT-matched corners
// (robust to outliers and to the differing motion blur: a box mean barely
// changes under blur), chained from frame 0. `images`: float in [0, 1], 1 or
// 3 channels (the mean of the channels is used).
std::vector<double> EstimateFrameGains(const std::vector<cv::Mat>& images,
                                       const GainEstimationOptions& options = GainEstimationOptions());

}  // namespace deblur_sr_mvs
