#include "deblur_sr_mvs/core/evaluation/evaluation.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

#include <Eigen/Geometry>
#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/common/options_check.h"
#include "deblur_sr_mvs/core/common/text.h"
#include "deblur_sr_mvs/core/geometry/sim3.h"
#include "deblur_sr_mvs/core/imaging/image_ops.h"

namespace deblur_sr_mvs {
namespace {

constexpr double kStampTolerance = 1e-6;  // s, as sequence_io and result_io
constexpr int kMinAteFrames = 3;          // Sim(3) needs 3 points for the rotation

std::string Printf(const char* format, double value) {
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), format, value);
  return buffer;
}

// Same channel count as the comparison needs (only colour -> gray happens:
// colour is used only when every image involved is colour).
cv::Mat WithChannels(const cv::Mat& image, int channels) {
  if (image.channels() == channels) return image;
  cv::Mat converted;
  cv::cvtColor(image, converted, channels == 1 ? cv::COLOR_BGR2GRAY : cv::COLOR_GRAY2BGR);
  return converted;
}

void CheckEightBit(const cv::Mat& image, const std::string& what) {
  if (image.empty() || image.depth() != CV_8U || (image.channels() != 1 && image.channels() != 3)) {
    throw InputError(what + " must be a non-empty 8-bit gray or colour image");
  }
}

// Pixels inside `crop` where `depth` is finite and > 0 (as EvaluateDepth counts).
int CountValidDepth(const cv::Mat& depth, const cv::Rect& crop) {
  int count = 0;
  for (int y = crop.y; y < crop.y + crop.height; ++y) {
    const float* row = depth.ptr<float>(y);
    for (int x = crop.x; x < crop.x + crop.width; ++x) {
      if (row[x] > 0.0f && std::isfinite(row[x])) ++count;
    }
  }
  return count;
}

int CountJointValidDepth(const cv::Mat& estimate, const cv::Mat& truth, const cv::Rect& crop) {
  int count = 0;
  for (int y = crop.y; y < crop.y + crop.height; ++y) {
    const float* pe = estimate.ptr<float>(y);
    const float* pg = truth.ptr<float>(y);
    for (int x = crop.x; x < crop.x + crop.width; ++x) {
      if (pe[x] > 0.0f && std::isfinite(pe[x]) && pg[x] > 0.0f && std::isfinite(pg[x])) ++count;
    }
  }
  return count;
}

void CheckInputs(const SequenceResult& result, const Sequence& sequence) {
  if (!sequence.ground_truth) {
    throw InputError("the sequence has no ground truth (gt/) to evaluate against");
  }
  const SequenceGroundTruth& gt = *sequence.ground_truth;
  const std::size_t count = sequence.frames.size();
  if (count == 0) throw InputError("the sequence has no frames");
  if (result.frames.size() != count) {
    throw InputError("the result has " + std::to_string(result.frames.size()) +
                     " frames but the sequence has " + std::to_string(count));
  }
  if (result.latent.size() != count || sequence.images.size() != count || gt.latent.size() != count ||
      gt.depth.size() != count || gt.poses.size() != count) {
    throw InputError("inconsistent frame counts: result latent " + std::to_string(result.latent.size()) +
                     ", sequence images " + std::to_string(sequence.images.size()) +
                     ", gt latent/depth/poses " + std::to_string(gt.latent.size()) + "/" +
                     std::to_string(gt.depth.size()) + "/" + std::to_string(gt.poses.size()) + " for " +
                     std::to_string(count) + " frames");
  }
  if (result.HasDepth() && result.depth.size() != count) {
    throw InputError("the result has " + std::to_string(result.depth.size()) + " depth maps for " +
                     std::to_string(count) + " frames");
  }
  if (result.HasPoses() && result.poses.size() != count) {
    throw InputError("the result has " + std::to_string(result.poses.size()) + " poses for " +
                     std::to_string(count) + " frames");
  }
  for (std::size_t i = 0; i < count; ++i) {
    const FrameRecord& a = result.frames[i];
    const FrameRecord& b = sequence.frames[i];
    if (a.index != b.index || !(std::abs(a.stamp - b.stamp) <= kStampTolerance)) {
      throw InputError("result frame " + std::to_string(i) + " (index " + std::to_string(a.index) +
                       ", stamp " + Printf("%.9g", a.stamp) + ") is not sequence frame " +
                       std::to_string(b.index) + " (stamp " + Printf("%.9g", b.stamp) +
                       "): the result was made from another sequence");
    }
  }
  const cv::Size hr_size = gt.latent.front().size();
  const cv::Size lr_size = sequence.images.front().size();
  if (lr_size.width <= 0 || hr_size.width % lr_size.width != 0 ||
      hr_size.width / lr_size.width * lr_size.height != hr_size.height) {
    throw InputError("the ground-truth size " + SizeText(hr_size) +
                     " is not an integer multiple of the input size " + SizeText(lr_size));
  }
  for (std::size_t i = 0; i < count; ++i) {
    const std::string frame = " of frame " + std::to_string(sequence.frames[i].index);
    CheckEightBit(result.latent[i], "the result latent image" + frame);
    CheckEightBit(gt.latent[i], "the ground-truth latent image" + frame);
    CheckEightBit(sequence.images[i], "the input image" + frame);
    if (result.latent[i].size() != hr_size) {
      throw InputError("the result latent image" + frame + " is " + SizeText(result.latent[i].size()) +
                       " but the ground truth is " + SizeText(hr_size) +
                       " (the result must be at the ground-truth HR size)");
    }
    if (gt.latent[i].size() != hr_size || sequence.images[i].size() != lr_size) {
      throw InputError("image sizes change within the sequence at frame " +
                       std::to_string(sequence.frames[i].index));
    }
    if (gt.depth[i].type() != CV_32FC1 || gt.depth[i].size() != hr_size) {
      throw InputError("the ground-truth depth" + frame + " must be 32FC1 of size " + SizeText(hr_size));
    }
    if (result.HasDepth() && (result.depth[i].type() != CV_32FC1 || result.depth[i].size() != hr_size)) {
      throw InputError("the result depth" + frame + " must be 32FC1 of the ground-truth size " +
                       SizeText(hr_size));
    }
  }
}

// ----------------------------------------------------------------- output

using Json = nlohmann::ordered_json;  // keeps the keys in the order written

// JSON has no NaN or infinity: those, and absent values, are null.
Json JsonNumber(double value) {
  return std::isfinite(value) ? Json(value) : Json(nullptr);
}

Json JsonNumber(const std::optional<double>& value) {
  return value ? JsonNumber(*value) : Json(nullptr);
}

// Table cells: fixed decimals like the paper, "inf" for an exact match.
std::string Cell(double value, int decimals) {
  if (std::isnan(value)) return "n/a";
  if (std::isinf(value)) return value > 0 ? "inf" : "-inf";
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), "%.*f", decimals, value);
  return buffer;
}

std::string Cell(const std::optional<double>& value, int decimals) {
  return value ? Cell(*value, decimals) : "n/a";
}

std::string MarkdownText(const std::string& text) {
  std::string out;
  for (const char c : text) {
    if (c == '|') out += '\\';
    out += (c == '\n' || c == '\r') ? ' ' : c;
  }
  return out;
}

}  // namespace

void EvaluationOptions::Check() const {
  // In (0, 1].
  CheckAbove("crop_fraction", crop_fraction, 0.0);
  CheckInRange("crop_fraction", crop_fraction, 0.0, 1.0);
}

namespace {

// The report's header: options, sizes, scale and colour space.
EvaluationReport StartReport(const SequenceResult& result, const Sequence& sequence,
                             const EvaluationOptions& options) {
  const SequenceGroundTruth& gt = *sequence.ground_truth;
  EvaluationReport report;
  report.options = options;
  report.num_frames = static_cast<int>(sequence.frames.size());
  report.hr_size = gt.latent.front().size();
  report.scale = report.hr_size.width / sequence.images.front().cols;
  // Colour only when every image involved is colour, so that the method and
  // bicubic are measured in the same space.
  report.colour = result.latent.front().channels() == 3 && gt.latent.front().channels() == 3 &&
                  sequence.images.front().channels() == 3;
  report.frames.resize(report.num_frames);
  return report;
}

// Image PSNR of the result and of the bicubic up-sampled input, per frame and mean.
void EvaluateImages(const SequenceResult& result, const Sequence& sequence, EvaluationReport* report) {
  const SequenceGroundTruth& gt = *sequence.ground_truth;
  const int count = report->num_frames;
  const int channels = report->colour ? 3 : 1;
  double sum_image = 0.0, sum_bicubic = 0.0;
  for (int i = 0; i < count; ++i) {
    FrameEvaluation& frame = report->frames[i];
    frame.index = sequence.frames[i].index;
    frame.stamp = sequence.frames[i].stamp;
    const cv::Mat truth = WithChannels(gt.latent[i], channels);
    frame.image_psnr_db = Psnr(WithChannels(result.latent[i], channels), truth, 255.0);
    const cv::Mat bicubic = ToImage8(UpsampleBicubic(ToFloat01(sequence.images[i]), report->scale));
    frame.bicubic_psnr_db = Psnr(WithChannels(bicubic, channels), truth, 255.0);
    sum_image += frame.image_psnr_db;
    sum_bicubic += frame.bicubic_psnr_db;
  }
  report->mean_image_psnr_db = sum_image / count;
  report->mean_bicubic_psnr_db = sum_bicubic / count;
}

// Coverage and errors of every frame's depth inside `crop_fraction` (1 = full
// frame), written through the member pointers, and the means over the frames
// with at least one pixel to compare. Returns that number of frames.
struct DepthRegionMeans {
  double psnr_db = 0.0, relative_error = 0.0, coverage = 0.0;
  int num_frames = 0;
};

DepthRegionMeans EvaluateDepthRegion(const SequenceResult& result, const SequenceGroundTruth& gt,
                                     double crop_fraction,
                                     std::optional<DepthErrors> FrameEvaluation::*errors,
                                     double FrameEvaluation::*coverage, EvaluationReport* report) {
  const int count = report->num_frames;
  const cv::Rect crop = CentreCrop(report->hr_size, crop_fraction);
  DepthMetricOptions depth_options;
  depth_options.crop_fraction = crop_fraction;
  depth_options.align_scale = report->options.align_depth_scale;
  DepthRegionMeans means;
  for (int i = 0; i < count; ++i) {
    FrameEvaluation& frame = report->frames[i];
    const int gt_valid = CountValidDepth(gt.depth[i], crop);
    const int joint_valid = CountJointValidDepth(result.depth[i], gt.depth[i], crop);
    frame.*coverage = gt_valid > 0 ? static_cast<double>(joint_valid) / gt_valid : 0.0;
    means.coverage += frame.*coverage;
    if (joint_valid == 0) continue;  // nothing to compare; counted in num_frames
    frame.*errors = EvaluateDepth(result.depth[i], gt.depth[i], depth_options);
    means.psnr_db += (frame.*errors)->psnr_db;
    means.relative_error += (frame.*errors)->relative_error;
    ++means.num_frames;
  }
  means.coverage /= count;
  if (means.num_frames > 0) {
    means.psnr_db /= means.num_frames;
    means.relative_error /= means.num_frames;
  }
  return means;
}

// Depth coverage, PSNR and relative error inside the centre crop and on the
// full frame, per frame and mean over the frames with a valid estimate;
// depth_note says what is left out.
void EvaluateDepths(const SequenceResult& result, const SequenceGroundTruth& gt, EvaluationReport* report) {
  if (!result.HasDepth()) {
    report->depth_note = "the result has no depth";
    return;
  }
  const int count = report->num_frames;
  const DepthRegionMeans crop =
      EvaluateDepthRegion(result, gt, report->options.crop_fraction, &FrameEvaluation::depth,
                          &FrameEvaluation::depth_coverage, report);
  report->mean_depth_coverage = crop.coverage;
  report->num_depth_frames = crop.num_frames;
  if (crop.num_frames > 0) {
    report->mean_depth_psnr_db = crop.psnr_db;
    report->mean_depth_relative_error = crop.relative_error;
  }
  const DepthRegionMeans full = EvaluateDepthRegion(result, gt, 1.0, &FrameEvaluation::depth_full_frame,
                                                    &FrameEvaluation::depth_coverage_full_frame, report);
  report->mean_depth_coverage_full_frame = full.coverage;
  if (full.num_frames > 0) {
    report->mean_depth_psnr_db_full_frame = full.psnr_db;
    report->mean_depth_relative_error_full_frame = full.relative_error;
  }
  if (report->num_depth_frames < count) {
    report->depth_note = std::to_string(count - report->num_depth_frames) + " of " + std::to_string(count) +
                         " frames have no valid estimated depth where the ground truth has one "
                         "(left out of the means)";
  }
}

// ATE RMSE after Sim(3) alignment and each frame's position error; ate_note
// says why when there is none.
void EvaluateTrajectory(const SequenceResult& result, const SequenceGroundTruth& gt,
                        EvaluationReport* report) {
  const int count = report->num_frames;
  if (!result.HasPoses()) {
    report->ate_note = "the result has no poses";
    return;
  }
  if (count < kMinAteFrames) {
    report->ate_note =
        "ATE needs at least " + std::to_string(kMinAteFrames) + " frames, got " + std::to_string(count);
    return;
  }
  // Associated by frame index (stamps were checked by CheckInputs).
  std::vector<Eigen::Vector3d> estimate(count), truth(count);
  for (int i = 0; i < count; ++i) {
    estimate[i] = result.poses[i].T_world_cam.translation();
    truth[i] = gt.poses[i].T_world_cam.translation();
  }
  try {
    Sim3 alignment;  // identity unless the options ask for the Sim(3) one
    if (report->options.align_trajectory) {
      report->ate_rmse = AbsoluteTrajectoryRmse(estimate, truth, &alignment);
      report->trajectory_alignment = alignment;
    }
    double squares = 0.0;
    for (int i = 0; i < count; ++i) {
      const Eigen::Vector3d aligned = TransformPoint(alignment, estimate[i]);
      report->frames[i].position_error = (aligned - truth[i]).norm();
      squares += (aligned - truth[i]).squaredNorm();
    }
    if (!report->options.align_trajectory) report->ate_rmse = std::sqrt(squares / count);
  } catch (const InputError& error) {
    // A degenerate estimate (all positions equal, non-finite) has no ATE;
    // it is a result to report, not bad input.
    report->ate_note = std::string("no ATE: ") + error.what();
  }
}

// Orientation of every frame relative to the first, estimate against ground
// truth: needs no alignment, so it is measured also where the ATE is not
// (a rotation-only window, whose cameras share one centre).
void EvaluateRotations(const SequenceResult& result, const SequenceGroundTruth& gt,
                       EvaluationReport* report) {
  if (!result.HasPoses() || report->num_frames == 0) return;
  const Eigen::Matrix3d R_est0 = result.poses[0].T_world_cam.rotation();
  const Eigen::Matrix3d R_gt0 = gt.poses[0].T_world_cam.rotation();
  double sum = 0.0, worst = 0.0;
  for (int i = 0; i < report->num_frames; ++i) {
    const Eigen::Matrix3d relative_est = R_est0.transpose() * result.poses[i].T_world_cam.rotation();
    const Eigen::Matrix3d relative_gt = R_gt0.transpose() * gt.poses[i].T_world_cam.rotation();
    const double degrees = Eigen::AngleAxisd(relative_est.transpose() * relative_gt).angle() * 180.0 / M_PI;
    report->frames[i].rotation_error_deg = degrees;
    sum += degrees;
    worst = std::max(worst, degrees);
  }
  report->mean_rotation_error_deg = sum / report->num_frames;
  report->max_rotation_error_deg = worst;
}

}  // namespace

EvaluationReport EvaluateResult(const SequenceResult& result, const Sequence& sequence,
                                const EvaluationOptions& options) {
  options.Check();
  CheckInputs(result, sequence);
  EvaluationReport report = StartReport(result, sequence, options);
  EvaluateImages(result, sequence, &report);
  EvaluateDepths(result, *sequence.ground_truth, &report);
  EvaluateTrajectory(result, *sequence.ground_truth, &report);
  EvaluateRotations(result, *sequence.ground_truth, &report);
  return report;
}

std::string ToMarkdown(const EvaluationReport& report, const std::string& method_name) {
  const std::string method = MarkdownText(method_name);
  std::string out;
  out += "### Image restoration (cf. paper table tab:quantBlur)\n\n";
  out += "| Method | Image PSNR (dB) | Bicubic PSNR (dB) | Gain (dB) |\n";
  out += "|---|---:|---:|---:|\n";
  out += "| " + method + " | " + Cell(report.mean_image_psnr_db, 2) + " | " +
         Cell(report.mean_bicubic_psnr_db, 2) + " | " +
         Cell(report.mean_image_psnr_db - report.mean_bicubic_psnr_db, 2) + " |\n\n";

  out += "### Depth and pose (cf. paper table tab:quant)\n\n";
  out +=
      "| Method | Depth PSNR (dB) | rel. | ATE RMSE | Rotation error (deg, mean / max) | "
      "Full frame: depth PSNR (dB) | rel. | coverage |\n";
  out += "|---|---:|---:|---:|---:|---:|---:|---:|\n";
  out += "| " + method + " | " + Cell(report.mean_depth_psnr_db, 2) + " | " +
         Cell(report.mean_depth_relative_error, 4) + " | " + Cell(report.ate_rmse, 4) + " | " +
         Cell(report.mean_rotation_error_deg, 3) + " / " + Cell(report.max_rotation_error_deg, 3) + " | " +
         Cell(report.mean_depth_psnr_db_full_frame, 2) + " | " +
         Cell(report.mean_depth_relative_error_full_frame, 4) + " | " +
         Printf("%.1f%%", 100.0 * report.mean_depth_coverage_full_frame) + " |\n\n";

  out += std::to_string(report.num_frames) + " frames, x" + std::to_string(report.scale) + " (" +
         SizeText(report.hr_size) + "), image PSNR in " + (report.colour ? "colour" : "gray") +
         " over the whole image; depth " +
         (report.options.align_depth_scale ? "scale-aligned per frame (median), " : "") +
         Printf("%.0f%%", 100.0 * report.options.crop_fraction) + " centre crop";
  if (report.mean_depth_psnr_db) {
    out += ", " + Printf("%.1f%%", 100.0 * report.mean_depth_coverage) + " of it covered";
  }
  out += report.options.align_trajectory ? "; ATE Sim(3)-aligned, in ground-truth units"
                                         : "; ATE without alignment (metric result), in ground-truth units";
  out += "; rotations relative to the first frame.\n";
  if (!report.depth_note.empty()) out += "Depth: " + report.depth_note + ".\n";
  if (!report.ate_note.empty()) out += "Pose: " + report.ate_note + ".\n";

  out += "\n#### Per frame\n\n";
  out +=
      "| Frame | Stamp (s) | Image PSNR (dB) | Bicubic PSNR (dB) | Depth PSNR (dB) | rel. | "
      "Position error | Rotation error (deg) |\n";
  out += "|---:|---:|---:|---:|---:|---:|---:|---:|\n";
  for (const FrameEvaluation& frame : report.frames) {
    out += "| " + std::to_string(frame.index) + " | " + Printf("%.6f", frame.stamp) + " | " +
           Cell(frame.image_psnr_db, 2) + " | " + Cell(frame.bicubic_psnr_db, 2) + " | " +
           (frame.depth ? Cell(frame.depth->psnr_db, 2) : "n/a") + " | " +
           (frame.depth ? Cell(frame.depth->relative_error, 4) : "n/a") + " | " +
           Cell(frame.position_error, 4) + " | " + Cell(frame.rotation_error_deg, 3) + " |\n";
  }
  return out;
}

namespace {

Json AlignmentJson(const std::optional<Sim3>& alignment) {
  if (!alignment) return nullptr;
  Json rotation = Json::array();
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) rotation.push_back(JsonNumber(alignment->rotation(r, c)));
  }
  const Eigen::Vector3d& t = alignment->translation;
  return Json{{"scale", JsonNumber(alignment->scale)},
              {"rotation", rotation},
              {"translation", {JsonNumber(t.x()), JsonNumber(t.y()), JsonNumber(t.z())}}};
}

Json FrameJson(const FrameEvaluation& frame) {
  const std::optional<DepthErrors>& depth = frame.depth;
  const std::optional<DepthErrors>& full = frame.depth_full_frame;
  return Json{{"index", frame.index},
              {"stamp", JsonNumber(frame.stamp)},
              {"image_psnr_db", JsonNumber(frame.image_psnr_db)},
              {"bicubic_psnr_db", JsonNumber(frame.bicubic_psnr_db)},
              {"depth_psnr_db", depth ? JsonNumber(depth->psnr_db) : Json(nullptr)},
              {"depth_relative_error", depth ? JsonNumber(depth->relative_error) : Json(nullptr)},
              {"depth_scale", depth ? JsonNumber(depth->scale) : Json(nullptr)},
              {"depth_pixels", depth ? depth->num_pixels : 0},
              {"depth_coverage", JsonNumber(frame.depth_coverage)},
              {"depth_psnr_db_full_frame", full ? JsonNumber(full->psnr_db) : Json(nullptr)},
              {"depth_relative_error_full_frame", full ? JsonNumber(full->relative_error) : Json(nullptr)},
              {"depth_scale_full_frame", full ? JsonNumber(full->scale) : Json(nullptr)},
              {"depth_pixels_full_frame", full ? full->num_pixels : 0},
              {"depth_coverage_full_frame", JsonNumber(frame.depth_coverage_full_frame)},
              {"position_error", JsonNumber(frame.position_error)},
              {"rotation_error_deg", JsonNumber(frame.rotation_error_deg)}};
}

}  // namespace

std::string ToJson(const EvaluationReport& report, const std::string& method_name) {
  Json json;
  json["method"] = method_name;
  json["num_frames"] = report.num_frames;
  json["scale"] = report.scale;
  json["hr_width"] = report.hr_size.width;
  json["hr_height"] = report.hr_size.height;
  json["colour"] = report.colour;
  json["crop_fraction"] = JsonNumber(report.options.crop_fraction);
  json["align_depth_scale"] = report.options.align_depth_scale;
  json["align_trajectory"] = report.options.align_trajectory;
  json["mean"] =
      Json{{"image_psnr_db", JsonNumber(report.mean_image_psnr_db)},
           {"bicubic_psnr_db", JsonNumber(report.mean_bicubic_psnr_db)},
           {"depth_psnr_db", JsonNumber(report.mean_depth_psnr_db)},
           {"depth_relative_error", JsonNumber(report.mean_depth_relative_error)},
           {"depth_coverage", JsonNumber(report.mean_depth_coverage)},
           {"depth_psnr_db_full_frame", JsonNumber(report.mean_depth_psnr_db_full_frame)},
           {"depth_relative_error_full_frame", JsonNumber(report.mean_depth_relative_error_full_frame)},
           {"depth_coverage_full_frame", JsonNumber(report.mean_depth_coverage_full_frame)},
           {"ate_rmse", JsonNumber(report.ate_rmse)},
           {"rotation_error_deg", JsonNumber(report.mean_rotation_error_deg)},
           {"max_rotation_error_deg", JsonNumber(report.max_rotation_error_deg)}};
  json["num_depth_frames"] = report.num_depth_frames;
  json["depth_note"] = report.depth_note;
  json["ate_note"] = report.ate_note;
  json["trajectory_alignment"] = AlignmentJson(report.trajectory_alignment);
  json["frames"] = Json::array();
  for (const FrameEvaluation& frame : report.frames) json["frames"].push_back(FrameJson(frame));
  // Bytes that are not UTF-8 (e.g. from a path) become U+FFFD instead of an exception.
  return json.dump(2, ' ', false, Json::error_handler_t::replace) + "\n";
}

}  // namespace deblur_sr_mvs
