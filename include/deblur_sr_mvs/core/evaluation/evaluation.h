// The paper's evaluation (Sec. experimentalResults, tables tab:quantBlur and
// tab:quant) of a result folder against a sequence's ground truth:
//   - image PSNR (dB, 8-bit, peak 255, whole image) of the restored latent
//     images, beside the PSNR of the bicubic up-sampled input;
//   - depth PSNR and relative error after per-frame median scale alignment,
//     inside a centre crop (70% in the paper) and on the full frame, each with
//     its coverage (NaN or 0 estimated depth = unknown, left out of the errors);
//   - ATE RMSE of the camera positions after Sim(3) alignment.
// All per-frame values are averaged over the frames, as in the paper.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "deblur_sr_mvs/core/evaluation/metrics.h"
#include "deblur_sr_mvs/core/io/result_io.h"
#include "deblur_sr_mvs/core/io/sequence_io.h"

namespace deblur_sr_mvs {

struct EvaluationOptions {
  // Centre crop of the depth maps (fraction of width and height), to ignore
  // the invalid borders warping introduces; 0.7 as in the paper, 1 = none.
  double crop_fraction = 0.7;
  // Monocular depth is up to scale: multiply each estimated depth map by the
  // median of gt / estimate before comparing (the paper's "scaling").
  bool align_depth_scale = true;
  // Align the estimated positions to the ground truth by Sim(3) before the
  // ATE. false: compare them as they are (a metric result in the ground
  // truth's frame, e.g. aligned to a pose prior).
  bool align_trajectory = true;
  // Throws InputError naming the option when out of range.
  void Check() const;
};

struct FrameEvaluation {
  int index = 0;
  double stamp = 0.0;
  double image_psnr_db = 0.0;    // result latent vs gt latent (+inf when equal)
  double bicubic_psnr_db = 0.0;  // bicubic up-sampled input vs gt latent
  // Absent when the result has no depth, or this frame's estimate has no valid
  // pixel inside the crop where the ground truth has one.
  std::optional<DepthErrors> depth;
  // Fraction of the ground truth's valid pixels in the crop that the estimate
  // also covers (0 when the result has no depth).
  double depth_coverage = 0.0;
  // The same on the full frame (no crop; its own median scale): an estimator
  // that marks unobserved pixels NaN trades coverage for error here.
  std::optional<DepthErrors> depth_full_frame;
  double depth_coverage_full_frame = 0.0;
  // Distance (gt units) of the Sim(3)-aligned position to the gt position;
  // absent when the ATE is.
  std::optional<double> position_error;
  // Angle (deg) between the estimated and the true orientation of this
  // frame relative to the first frame (independent of world and scale);
  // absent when the result has no poses.
  std::optional<double> rotation_error_deg;
};

struct EvaluationReport {
  EvaluationOptions options;
  int num_frames = 0;
  int scale = 1;  // HR / input size
  cv::Size hr_size;
  bool colour = false;  // image PSNRs computed in colour (else in gray)
  std::vector<FrameEvaluation> frames;

  double mean_image_psnr_db = 0.0;
  double mean_bicubic_psnr_db = 0.0;
  // Over the frames whose depth was evaluated; absent when none was.
  std::optional<double> mean_depth_psnr_db;
  std::optional<double> mean_depth_relative_error;
  double mean_depth_coverage = 0.0;
  int num_depth_frames = 0;
  // The full-frame counterparts (over the frames evaluated on the full frame).
  std::optional<double> mean_depth_psnr_db_full_frame;
  std::optional<double> mean_depth_relative_error_full_frame;
  double mean_depth_coverage_full_frame = 0.0;
  // Absent when the result has no poses, fewer than 3 frames, or a degenerate
  // trajectory; `ate_note` then says why.
  std::optional<double> ate_rmse;
  std::optional<Sim3> trajectory_alignment;  // result positions -> gt positions
  // Over the frames (FrameEvaluation::rotation_error_deg); absent without poses.
  std::optional<double> mean_rotation_error_deg, max_rotation_error_deg;
  std::string ate_note;
  std::string depth_note;  // why depth metrics are absent, when they are
};

// `sequence` must hold ground truth. Result and sequence must have the same
// frames (count and stamps) and the result's latent size must be the gt HR
// size; otherwise InputError with one line. Missing depth or poses in the
// result are not errors: those metrics are absent.
EvaluationReport EvaluateResult(const SequenceResult& result, const Sequence& sequence,
                                const EvaluationOptions& options = EvaluationOptions());

// Markdown: a tab:quantBlur-like table (image PSNR, bicubic PSNR), a
// tab:quant-like table (depth PSNR, rel., ATE; "n/a" when absent) and a
// per-frame table.
std::string ToMarkdown(const EvaluationReport& report, const std::string& method_name);

// JSON object with the same numbers (absent and non-finite values, e.g. the
// infinite PSNR of an exact match, are null).
std::string ToJson(const EvaluationReport& report, const std::string& method_name);

}  // namespace deblur_sr_mvs
