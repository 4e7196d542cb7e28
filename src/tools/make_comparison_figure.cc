// Writes a side-by-side picture of one frame of a sequence folder with ground
// truth: the blurry LR input (pixel-replicated to HR size), its bicubic
// up-sampling and the sharp ground truth, with PSNRs against the ground truth,
// plus the ground-truth depth preview.
// Usage: make_comparison_figure --sequence SEQ --output PNG [--frame N] [--result OUT]
// With --result (a result folder of estimate_sequence) the restored image and
// the estimated depth join the picture.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <opencv2/imgproc.hpp>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/evaluation/metrics.h"
#include "deblur_sr_mvs/core/imaging/image_ops.h"
#include "deblur_sr_mvs/core/io/result_io.h"
#include "deblur_sr_mvs/core/io/sequence_io.h"
#include "tool_main.h"

namespace dsm = deblur_sr_mvs;

namespace {

constexpr char kDescription[] =
    "Writes a side-by-side picture of one frame of a sequence folder with ground truth:\n"
    "the blurry LR input, its bicubic up-sampling and the sharp ground truth, with PSNRs,\n"
    "plus the ground-truth depth. With --result, the restored image, the estimated depth\n"
    "and the trajectory join the picture.";

constexpr int kGap = 4;  // px between panels

std::string Format(const char* format, double value) {
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), format, value);
  return buffer;
}

// The panels every figure has: the input, pixel-replicated to the HR size,
// its bicubic up-sampling and the ground truth (in the input's channels).
struct Frame {
  int index = 0;
  int scale = 1;
  cv::Mat input_big, bicubic8, truth;
  double psnr_bicubic = 0.0;
};

Frame PrepareFrame(const dsm::Sequence& sequence, const std::string& sequence_dir, int frame) {
  const cv::Mat& input = sequence.images[frame];
  const cv::Mat& truth = sequence.ground_truth->latent[frame];
  Frame out;
  out.index = frame;
  out.scale = truth.cols / input.cols;
  if (out.scale < 1 || truth.cols != input.cols * out.scale || truth.rows != input.rows * out.scale) {
    throw dsm::InputError(sequence_dir + ": gt size is not an integer multiple of the input size");
  }
  cv::resize(input, out.input_big, truth.size(), 0, 0, cv::INTER_NEAREST);
  out.bicubic8 = dsm::ToImage8(dsm::UpsampleBicubic(dsm::ToFloat01(input), out.scale));
  out.truth = truth;
  if (truth.channels() != out.bicubic8.channels()) {
    cv::cvtColor(truth, out.truth, truth.channels() == 3 ? cv::COLOR_BGR2GRAY : cv::COLOR_GRAY2BGR);
  }
  out.psnr_bicubic = dsm::Psnr(out.bicubic8, out.truth, 255.0);
  return out;
}

std::string InputTitle(const Frame& frame) {
  return "blurry LR input (frame " + std::to_string(frame.index) + ")";
}
std::string BicubicTitle(const Frame& frame) {
  return "bicubic x" + std::to_string(frame.scale) + Format(": %.2f dB", frame.psnr_bicubic);
}

// Without a result: input | bicubic over ground truth | ground-truth depth.
void WriteInputFigure(const dsm::Sequence& sequence, const Frame& frame, const std::string& output) {
  const cv::Mat& truth = frame.truth;
  cv::Mat canvas(truth.rows * 2 + kGap, truth.cols * 2 + kGap, CV_8UC3, cv::Scalar::all(255));
  dsm::PastePanel(frame.input_big, InputTitle(frame), cv::Point(0, 0), &canvas);
  dsm::PastePanel(frame.bicubic8, BicubicTitle(frame), cv::Point(truth.cols + kGap, 0), &canvas);
  dsm::PastePanel(truth, "ground-truth sharp HR", cv::Point(0, truth.rows + kGap), &canvas);
  dsm::PastePanel(dsm::ColorizeDepth(sequence.ground_truth->depth[frame.index]), "ground-truth depth",
                  cv::Point(truth.cols + kGap, truth.rows + kGap), &canvas);
  dsm::WriteImage(output, canvas);
  std::printf("%s: frame %d, bicubic PSNR %.2f dB vs ground truth\n", output.c_str(), frame.index,
              frame.psnr_bicubic);
}

// The estimated depth beside the ground-truth depth, in one colour range.
void PasteDepthPanels(const cv::Mat& estimated, const cv::Mat& gt_depth, cv::Point at, int step,
                      cv::Mat* canvas) {
  // Estimated depth in its own (monocular) units: scale it to the truth by
  // the median ratio so that one colour range fits both.
  std::vector<float> ratios;
  for (int i = 0; i < static_cast<int>(gt_depth.total()); ++i) {
    const float g = gt_depth.ptr<float>()[i], e = estimated.ptr<float>()[i];
    if (g > 0.0f && e > 0.0f && std::isfinite(e)) ratios.push_back(g / e);
  }
  double scale_to_truth = 1.0;
  if (!ratios.empty()) {
    std::nth_element(ratios.begin(), ratios.begin() + ratios.size() / 2, ratios.end());
    scale_to_truth = ratios[ratios.size() / 2];
  }
  double min_depth, max_depth;
  cv::minMaxLoc(gt_depth, &min_depth, &max_depth, nullptr, nullptr, gt_depth > 0.0f);
  dsm::PastePanel(dsm::ColorizeDepth(estimated * scale_to_truth, min_depth, max_depth),
                  "estimated depth (median-scaled)", at, canvas);
  dsm::PastePanel(dsm::ColorizeDepth(gt_depth, min_depth, max_depth), "ground-truth depth",
                  cv::Point(at.x + step, at.y), canvas);
}

// Trajectory, top view (x right, z up the panel), estimate Sim(3)-aligned
// onto the ground truth: ground truth green, estimate red.
void PasteTrajectoryPanel(const std::vector<dsm::StampedPose>& estimated_poses,
                          const std::vector<dsm::StampedPose>& true_poses, cv::Size size, cv::Point at,
                          cv::Mat* canvas) {
  std::vector<Eigen::Vector3d> estimate, truth_positions;
  for (size_t t = 0; t < true_poses.size(); ++t) {
    estimate.push_back(estimated_poses[t].T_world_cam.translation());
    truth_positions.push_back(true_poses[t].T_world_cam.translation());
  }
  const dsm::Sim3 sim3 = dsm::UmeyamaAlignment(estimate, truth_positions, true);
  for (Eigen::Vector3d& p : estimate) p = sim3.scale * sim3.rotation * p + sim3.translation;
  cv::Mat plot(size, CV_8UC3, cv::Scalar::all(255));
  double min_x = 1e30, max_x = -1e30, min_z = 1e30, max_z = -1e30;
  for (const auto* list : {&estimate, &truth_positions}) {
    for (const Eigen::Vector3d& p : *list) {
      min_x = std::min(min_x, p.x()), max_x = std::max(max_x, p.x());
      min_z = std::min(min_z, p.z()), max_z = std::max(max_z, p.z());
    }
  }
  const double span = std::max({max_x - min_x, max_z - min_z, 1e-9});
  const double pixels_per_unit = 0.8 * std::min(plot.cols, plot.rows) / span;
  auto to_pixel = [&](const Eigen::Vector3d& p) {
    return cv::Point(static_cast<int>(plot.cols / 2 + (p.x() - (min_x + max_x) / 2) * pixels_per_unit),
                     static_cast<int>(plot.rows / 2 - (p.z() - (min_z + max_z) / 2) * pixels_per_unit));
  };
  for (size_t t = 0; t < estimate.size(); ++t) {
    if (t > 0) {
      cv::line(plot, to_pixel(truth_positions[t - 1]), to_pixel(truth_positions[t]), cv::Scalar(0, 160, 0), 2,
               cv::LINE_AA);
      cv::line(plot, to_pixel(estimate[t - 1]), to_pixel(estimate[t]), cv::Scalar(0, 0, 220), 1, cv::LINE_AA);
    }
    cv::circle(plot, to_pixel(truth_positions[t]), 4, cv::Scalar(0, 160, 0), 2, cv::LINE_AA);
    cv::circle(plot, to_pixel(estimate[t]), 2, cv::Scalar(0, 0, 220), -1, cv::LINE_AA);
  }
  const double ate = dsm::AbsoluteTrajectoryRmse(estimate, truth_positions);
  dsm::PastePanel(plot, "trajectory, top view: truth (green), estimate (red), ATE " + Format("%.5f", ate), at,
                  canvas);
}

// With a result: input | bicubic | restored | ground truth, and below the
// trajectory and the estimated depth beside the ground-truth depth.
void WriteResultFigure(const dsm::Sequence& sequence, const std::string& sequence_dir,
                       const std::string& result_dir, const Frame& frame, const std::string& output) {
  const dsm::SequenceResult result = dsm::ReadResult(result_dir);
  const cv::Mat& truth = frame.truth;
  const int num_frames = static_cast<int>(sequence.frames.size());
  if (static_cast<int>(result.latent.size()) != num_frames ||
      result.latent[frame.index].size() != truth.size()) {
    throw dsm::InputError(result_dir + ": frames or HR size differ from " + sequence_dir);
  }
  cv::Mat restored = result.latent[frame.index];
  if (restored.channels() != truth.channels()) {
    cv::cvtColor(restored, restored, restored.channels() == 3 ? cv::COLOR_BGR2GRAY : cv::COLOR_GRAY2BGR);
  }
  const double psnr_restored = dsm::Psnr(restored, truth, 255.0);
  cv::Mat canvas(truth.rows * 2 + kGap, truth.cols * 4 + 3 * kGap, CV_8UC3, cv::Scalar::all(255));
  const int step = truth.cols + kGap;
  dsm::PastePanel(frame.input_big, InputTitle(frame), cv::Point(0, 0), &canvas);
  dsm::PastePanel(frame.bicubic8, BicubicTitle(frame), cv::Point(step, 0), &canvas);
  dsm::PastePanel(restored, "restored" + Format(": %.2f dB", psnr_restored), cv::Point(2 * step, 0), &canvas);
  dsm::PastePanel(truth, "ground-truth sharp HR", cv::Point(3 * step, 0), &canvas);
  if (result.HasDepth()) {
    PasteDepthPanels(result.depth[frame.index], sequence.ground_truth->depth[frame.index],
                     cv::Point(2 * step, truth.rows + kGap), step, &canvas);
  }
  if (result.HasPoses() && num_frames >= 3) {
    PasteTrajectoryPanel(result.poses, sequence.ground_truth->poses,
                         cv::Size(2 * truth.cols + kGap, truth.rows), cv::Point(0, truth.rows + kGap),
                         &canvas);
  }
  dsm::WriteImage(output, canvas);
  std::printf("%s: frame %d, PSNR vs ground truth: bicubic %.2f dB, restored %.2f dB\n", output.c_str(),
              frame.index, frame.psnr_bicubic, psnr_restored);
}

int Run(int argc, char** argv) {
  std::string sequence_dir, output, result_dir;
  int frame = -1;  // default: the middle frame
  dsm::ToolCommandLine cli("make_comparison_figure", kDescription);
  cli.add_option("--sequence", sequence_dir, "sequence folder with gt/")
      ->required()
      ->check(CLI::ExistingDirectory);
  cli.add_option("--output", output, "PNG file to write")->required();
  cli.add_option("--frame", frame, "frame index (default: the middle frame)")->check(dsm::FlagInt(0));
  cli.add_option("--result", result_dir, "result folder of estimate_sequence")->check(CLI::ExistingDirectory);
  if (!cli.Parse(argc, argv)) return 0;

  const dsm::Sequence sequence = dsm::ReadSequence(sequence_dir, /*read_ground_truth=*/true);
  if (!sequence.ground_truth) throw dsm::InputError(sequence_dir + ": no gt/ folder to compare with");
  const int num_frames = static_cast<int>(sequence.frames.size());
  if (frame < 0) frame = num_frames / 2;
  if (frame >= num_frames) {
    throw dsm::InputError("--frame " + std::to_string(frame) + " is out of range (sequence has " +
                          std::to_string(num_frames) + " frames)");
  }
  const Frame prepared = PrepareFrame(sequence, sequence_dir, frame);
  if (result_dir.empty()) {
    WriteInputFigure(sequence, prepared, output);
  } else {
    WriteResultFigure(sequence, sequence_dir, result_dir, prepared, output);
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  return deblur_sr_mvs::ToolMain("make_comparison_figure", Run, argc, argv);
}
