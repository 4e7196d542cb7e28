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
#include <vector>
#include <cstdlib>
#include <iostream>
#include <string>

#include <Eigen/Core>
#include <opencv2/imgproc.hpp>

#include "tool_main.h"
#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/imaging/image_ops.h"
#include "deblur_sr_mvs/core/evaluation/metrics.h"
#include "deblur_sr_mvs/core/io/result_io.h"
#include "deblur_sr_mvs/core/io/sequence_io.h"

namespace dsm = deblur_sr_mvs;

namespace {

constexpr char kUsage[] =
    "usage: make_comparison_figure --sequence SEQ --output PNG [--frame N] [--result OUT]\n";

std::string Format(const char* format, double value) {
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), format, value);
  return buffer;
}

int Run(int argc, char** argv) {
  std::string sequence_dir, output, result_dir;
  int frame = -1;  // default: the middle frame
  for (int i = 1; i < argc; ++i) {
    const std::string flag = argv[i];
    if (flag == "--help" || flag == "-h") {
      std::cout << kUsage;
      return 0;
    }
    if (i + 1 >= argc) throw dsm::InputError("flag " + flag + " needs a value");
    const std::string value = argv[++i];
    if (flag == "--sequence") {
      sequence_dir = value;
    } else if (flag == "--result") {
      result_dir = value;
    } else if (flag == "--output") {
      output = value;
    } else if (flag == "--frame") {
      frame = dsm::ParseFlagInt(flag, value, 0);
    } else {
      throw dsm::InputError("unknown flag " + flag);
    }
  }
  if (sequence_dir.empty() || output.empty()) throw dsm::InputError("--sequence and --output are required");

  const dsm::Sequence sequence = dsm::ReadSequence(sequence_dir, /*read_ground_truth=*/true);
  if (!sequence.ground_truth) throw dsm::InputError(sequence_dir + ": no gt/ folder to compare with");
  const int num_frames = static_cast<int>(sequence.frames.size());
  if (frame < 0) frame = num_frames / 2;
  if (frame >= num_frames) {
    throw dsm::InputError("--frame " + std::to_string(frame) + " is out of range (sequence has " +
                          std::to_string(num_frames) + " frames)");
  }
  const cv::Mat& input = sequence.images[frame];
  const cv::Mat& truth = sequence.ground_truth->latent[frame];
  const int scale = truth.cols / input.cols;
  if (scale < 1 || truth.cols != input.cols * scale || truth.rows != input.rows * scale) {
    throw dsm::InputError(sequence_dir + ": gt size is not an integer multiple of the input size");
  }
  cv::Mat input_big, bicubic8;
  cv::resize(input, input_big, truth.size(), 0, 0, cv::INTER_NEAREST);
  bicubic8 = dsm::ToImage8(dsm::UpsampleBicubic(dsm::ToFloat01(input), scale));
  cv::Mat truth_matched = truth;
  if (truth.channels() != bicubic8.channels()) {
    cv::cvtColor(truth, truth_matched, truth.channels() == 3 ? cv::COLOR_BGR2GRAY : cv::COLOR_GRAY2BGR);
  }
  const double psnr_bicubic = dsm::Psnr(bicubic8, truth_matched, 255.0);
  const cv::Mat depth_preview = dsm::ColorizeDepth(sequence.ground_truth->depth[frame]);

  const int gap = 4;
  if (result_dir.empty()) {
    cv::Mat canvas(truth.rows * 2 + gap, truth.cols * 2 + gap, CV_8UC3, cv::Scalar::all(255));
    dsm::PastePanel(input_big, "blurry LR input (frame " + std::to_string(frame) + ")",
                    cv::Point(0, 0), &canvas);
    dsm::PastePanel(bicubic8, "bicubic x" + std::to_string(scale) + Format(": %.2f dB", psnr_bicubic),
                    cv::Point(truth.cols + gap, 0), &canvas);
    dsm::PastePanel(truth_matched, "ground-truth sharp HR", cv::Point(0, truth.rows + gap), &canvas);
    dsm::PastePanel(depth_preview, "ground-truth depth", cv::Point(truth.cols + gap, truth.rows + gap),
                    &canvas);
    dsm::WriteImage(output, canvas);
    std::printf("%s: frame %d, bicubic PSNR %.2f dB vs ground truth\n", output.c_str(), frame,
                psnr_bicubic);
    return 0;
  }
  // With a result: input | bicubic | restored | ground truth, and below the
  // estimated depth beside the ground-truth depth (same colour range).
  const dsm::SequenceResult result = dsm::ReadResult(result_dir);
  if (static_cast<int>(result.latent.size()) != num_frames || result.latent[frame].size() != truth.size()) {
    throw dsm::InputError(result_dir + ": frames or HR size differ from " + sequence_dir);
  }
  cv::Mat restored = result.latent[frame];
  if (restored.channels() != truth_matched.channels()) {
    cv::cvtColor(restored, restored, restored.channels() == 3 ? cv::COLOR_BGR2GRAY : cv::COLOR_GRAY2BGR);
  }
  const double psnr_restored = dsm::Psnr(restored, truth_matched, 255.0);
  cv::Mat canvas(truth.rows * 2 + gap, truth.cols * 4 + 3 * gap, CV_8UC3, cv::Scalar::all(255));
  const int step = truth.cols + gap;
  dsm::PastePanel(input_big, "blurry LR input (frame " + std::to_string(frame) + ")", cv::Point(0, 0), &canvas);
  dsm::PastePanel(bicubic8, "bicubic x" + std::to_string(scale) + Format(": %.2f dB", psnr_bicubic),
                  cv::Point(step, 0), &canvas);
  dsm::PastePanel(restored, "restored" + Format(": %.2f dB", psnr_restored), cv::Point(2 * step, 0), &canvas);
  dsm::PastePanel(truth_matched, "ground-truth sharp HR", cv::Point(3 * step, 0), &canvas);
  if (result.HasDepth()) {
    const cv::Mat& gt_depth = sequence.ground_truth->depth[frame];
    // Estimated depth in its own (monocular) units: scale it to the truth by
    // the median ratio so that one colour range fits both.
    std::vector<float> ratios;
    const cv::Mat& estimated = result.depth[frame];
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
                    "estimated depth (median-scaled)", cv::Point(2 * step, truth.rows + gap), &canvas);
    dsm::PastePanel(dsm::ColorizeDepth(gt_depth, min_depth, max_depth), "ground-truth depth",
                    cv::Point(3 * step, truth.rows + gap), &canvas);
  }
  if (result.HasPoses() && num_frames >= 3) {
    // Trajectory, top view (x right, z up the panel), estimate Sim(3)-aligned
    // onto the ground truth: ground truth green, estimate red.
    std::vector<Eigen::Vector3d> estimate, truth_positions;
    for (int t = 0; t < num_frames; ++t) {
      estimate.push_back(result.poses[t].T_world_cam.translation());
      truth_positions.push_back(sequence.ground_truth->poses[t].T_world_cam.translation());
    }
    const dsm::Sim3 sim3 = dsm::UmeyamaAlignment(estimate, truth_positions, true);
    for (Eigen::Vector3d& p : estimate) p = sim3.scale * sim3.rotation * p + sim3.translation;
    cv::Mat plot(truth.rows, 2 * truth.cols + gap, CV_8UC3, cv::Scalar::all(255));
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
    for (int t = 0; t < num_frames; ++t) {
      if (t > 0) {
        cv::line(plot, to_pixel(truth_positions[t - 1]), to_pixel(truth_positions[t]), cv::Scalar(0, 160, 0), 2, cv::LINE_AA);
        cv::line(plot, to_pixel(estimate[t - 1]), to_pixel(estimate[t]), cv::Scalar(0, 0, 220), 1, cv::LINE_AA);
      }
      cv::circle(plot, to_pixel(truth_positions[t]), 4, cv::Scalar(0, 160, 0), 2, cv::LINE_AA);
      cv::circle(plot, to_pixel(estimate[t]), 2, cv::Scalar(0, 0, 220), -1, cv::LINE_AA);
    }
    const double ate = dsm::AbsoluteTrajectoryRmse(estimate, truth_positions);
    dsm::PastePanel(plot, "trajectory, top view: truth (green), estimate (red), ATE " + Format("%.5f", ate),
                    cv::Point(0, truth.rows + gap), &canvas);
  }
  dsm::WriteImage(output, canvas);
  std::printf("%s: frame %d, PSNR vs ground truth: bicubic %.2f dB, restored %.2f dB\n", output.c_str(),
              frame, psnr_bicubic, psnr_restored);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  return deblur_sr_mvs::ToolMain("make_comparison_figure", Run, argc, argv);
}
