// Writes a side-by-side picture of one frame of a sequence folder with ground
// truth: the blurry LR input (pixel-replicated to HR size), its bicubic
// up-sampling and the sharp ground truth, with PSNRs against the ground truth,
// plus the ground-truth depth preview.
// Usage: make_comparison_figure --sequence SEQ --output PNG [--frame N]
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <string>

#include <opencv2/imgproc.hpp>

#include "deblur_sr_mvs/core/tool_main.h"
#include "deblur_sr_mvs/core/errors.h"
#include "deblur_sr_mvs/core/image_ops.h"
#include "deblur_sr_mvs/core/metrics.h"
#include "deblur_sr_mvs/core/sequence_io.h"

namespace dsm = deblur_sr_mvs;

namespace {

constexpr char kUsage[] =
    "usage: make_comparison_figure --sequence SEQ --output PNG [--frame N]\n";

std::string Format(const char* format, double value) {
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), format, value);
  return buffer;
}

int Run(int argc, char** argv) {
  std::string sequence_dir, output;
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
    } else if (flag == "--output") {
      output = value;
    } else if (flag == "--frame") {
      char* end = nullptr;
      frame = static_cast<int>(std::strtol(value.c_str(), &end, 10));
      if (end == value.c_str() || *end != '\0' || frame < 0) {
        throw dsm::InputError("--frame must be a non-negative integer, got '" + value + "'");
      }
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

}  // namespace

int main(int argc, char** argv) {
  return deblur_sr_mvs::ToolMain("make_comparison_figure", Run, argc, argv);
}
