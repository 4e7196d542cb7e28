// The result folder of docs/file_formats.md#result-folder, written by the offline estimator and by
// the peer methods (bicubic, BTV-L1), read by evaluate_sequence:
//
//   <out>/camera.yaml            intrinsics of the latent images (HR)
//   <out>/frames.csv             copy of the input's index,stamp,exposure, so a
//                                result names its frames without its input
//   <out>/latent/000000.png      8-bit restored image, one per frame
//   <out>/depth/000000.tiff      float32 depth (m up to the monocular scale),
//                                NaN invalid; only for methods that estimate it
//   <out>/depth_color/000000.png preview, one depth range for the whole
//                                sequence so that colours compare across frames
//   <out>/poses.txt              TUM, T_world_cam, world = first camera; only
//                                for methods that estimate poses
//   <out>/report.json            free-form JSON supplied by the method
//
// Readers and writers throw InputError with one line naming the file and the
// problem, like sequence_io.
#pragma once

#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "deblur_sr_mvs/core/io/sequence_io.h"

namespace deblur_sr_mvs {

struct SequenceResult {
  CameraCalibration calibration;    // intrinsics at the latent (HR) size
  std::vector<FrameRecord> frames;  // as in the input sequence
  std::vector<cv::Mat> latent;      // CV_8UC1 or CV_8UC3 (BGR), one per frame
  // Empty for image-only methods; else one CV_32FC1 map per frame (HR size,
  // NaN or <= 0 invalid).
  std::vector<cv::Mat> depth;
  // Empty for image-only methods; else one pose per frame, stamped like it.
  std::vector<StampedPose> poses;
  // Free-form JSON text (parameters, energies, timings); "{}" when empty.
  std::string report_json;

  bool HasDepth() const { return !depth.empty(); }
  bool HasPoses() const { return !poses.empty(); }
};

// Writes every file of the folder (creating it), after checking that the
// result is consistent: one latent image per frame of the calibrated size, and
// depth/poses either absent or one per frame (pose stamps = frame stamps).
void WriteResult(const std::string& folder, const SequenceResult& result);

// Reads camera.yaml, frames.csv, latent/, and depth/ and poses.txt when they
// exist (report.json when it exists; depth_color/ is a preview, not read), with
// the same checks as WriteResult.
SequenceResult ReadResult(const std::string& folder);

}  // namespace deblur_sr_mvs
