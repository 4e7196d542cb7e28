// Initialisation of poses and depths from the blurry LR frames alone
// (paper Sec. optInitialization, eq:initializationScene).
#pragma once

#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "deblur_sr_mvs/core/camera.h"
#include "deblur_sr_mvs/core/se3.h"
#include "deblur_sr_mvs/core/sequence_io.h"

namespace deblur_sr_mvs {

struct InitializerOptions {
  // (fields documented in the implementation's header section; each with a
  // one-line comment saying what it controls and its unit)
  int num_threads = 0;  // OpenMP threads; 0 = default
  void Check() const;   // throws InputError naming the bad field
};

// Poses (T_world_cam, world = first camera, monocular scale fixed so that the
// first two cameras are 1 unit apart) and LR depth maps in the same units.
struct InitialStructure {
  std::vector<SE3> T_world_cam;
  std::vector<cv::Mat> depth_lr;  // CV_32FC1, input size; NaN where unknown
  std::string summary;            // one line per stage: matches, inliers, residuals
};

// Thrown when the frames do not allow an initialisation (too few features or
// inliers, no parallax, degenerate geometry); the message says which.
class InitializationError : public std::runtime_error {
 public:
  explicit InitializationError(const std::string& message) : std::runtime_error(message) {}
};

// images_lr: the input frames as float in [0, 1] (1 or 3 channels), all of
// camera_lr's size; frames: their stamps and exposures (>= 2 frames).
InitialStructure InitializeStructure(const std::vector<cv::Mat>& images_lr,
                                     const PinholeCamera& camera_lr,
                                     const std::vector<FrameRecord>& frames,
                                     const InitializerOptions& options);

}  // namespace deblur_sr_mvs
