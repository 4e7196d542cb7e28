// Evaluates a result folder against a sequence folder's ground truth and
// prints the paper's tables in Markdown (docs/tools.md#evaluate_sequence):
// image PSNR beside bicubic (tab:quantBlur), depth PSNR / rel. and ATE RMSE
// (tab:quant).
// Usage: evaluate_sequence --result OUT --sequence SEQ [--crop F] [--json FILE]
//                          [--method NAME] [--confidence-threshold X [--recompute-confidence]]
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <string>
#include <system_error>

#include <opencv2/imgcodecs.hpp>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/estimation/depth_confidence.h"
#include "deblur_sr_mvs/core/evaluation/evaluation.h"
#include "deblur_sr_mvs/core/io/result_io.h"
#include "deblur_sr_mvs/core/io/sequence_io.h"
#include "tool_main.h"

namespace dsm = deblur_sr_mvs;
namespace fs = std::filesystem;

namespace {

constexpr char kDescription[] =
    "Compares a result folder with the ground truth (gt/) of the sequence folder\n"
    "it was computed from and prints Markdown tables like the paper's:\n"
    "image PSNR (8-bit, whole image) beside bicubic up-sampling of the input;\n"
    "depth PSNR and rel. error (per-frame median scale alignment; centre crop\n"
    "and full frame, with the coverage of finite estimated depth);\n"
    "ATE RMSE of the positions after Sim(3) alignment. Metrics the result has\n"
    "no data for (depth, poses) read n/a.";

void WriteTextFile(const std::string& path, const std::string& content) {
  std::error_code error;
  const fs::path parent = fs::path(path).parent_path();
  if (!parent.empty()) fs::create_directories(parent, error);
  if (error) throw dsm::InputError(path + ": cannot create folder: " + error.message());
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (!out) throw dsm::InputError(path + ": cannot open file for writing");
  out << content;
  out.close();
  if (!out) throw dsm::InputError(path + ": write error");
}

// The result's depth with NaN where RESULT/depth_confidence/<frame>.tiff
// (written by estimate_sequence) is below `threshold`: what
// estimate_sequence --depth-confidence-threshold would have written.
void MaskByConfidence(const std::string& result_dir, double threshold, dsm::SequenceResult* result) {
  if (!result->HasDepth()) throw dsm::InputError(result_dir + ": --confidence-threshold needs depth");
  for (size_t t = 0; t < result->depth.size(); ++t) {
    const std::string path =
        result_dir + "/depth_confidence/" + dsm::FrameStem(result->frames[t].index) + ".tiff";
    const cv::Mat confidence = cv::imread(path, cv::IMREAD_UNCHANGED);
    if (confidence.type() != CV_32FC1 || confidence.size() != result->depth[t].size()) {
      throw dsm::InputError(path + ": missing, or not a float32 map of the depth's size");
    }
    result->depth[t] = dsm::MaskUnconfidentDepth(result->depth[t], confidence, threshold);
  }
}

// The result's depth with NaN where a depth confidence recomputed now, with
// the default DepthConfidenceOptions, from the result's latent/ (8-bit),
// depth/ and poses.txt is below `threshold`: how the current code would mask
// a result written by an older build.
void MaskByRecomputedConfidence(const std::string& result_dir, double threshold,
                                dsm::SequenceResult* result) {
  if (!result->HasDepth() || !result->HasPoses()) {
    throw dsm::InputError(result_dir + ": --recompute-confidence needs depth and poses");
  }
  std::vector<cv::Mat> latent(result->latent.size());
  for (size_t t = 0; t < latent.size(); ++t) result->latent[t].convertTo(latent[t], CV_32F, 1.0 / 255.0);
  std::vector<dsm::SE3> T_world_cam;
  for (const dsm::StampedPose& pose : result->poses) T_world_cam.push_back(pose.T_world_cam);
  const std::vector<cv::Mat> confidence = dsm::ComputeDepthConfidence(
      result->calibration.camera, latent, result->depth, T_world_cam, dsm::DepthConfidenceOptions());
  for (size_t t = 0; t < result->depth.size(); ++t) {
    result->depth[t] = dsm::MaskUnconfidentDepth(result->depth[t], confidence[t], threshold);
  }
}

int Run(int argc, char** argv) {
  std::string result_dir, sequence_dir, json_path, method;
  dsm::EvaluationOptions options;
  dsm::ToolCommandLine cli("evaluate_sequence", kDescription);
  cli.add_option("--result", result_dir, "result folder (camera.yaml, frames.csv, latent/, ...)")
      ->required()
      ->check(CLI::ExistingDirectory);
  cli.add_option("--sequence", sequence_dir, "sequence folder with gt/")
      ->required()
      ->check(CLI::ExistingDirectory);
  cli.add_option("--crop", options.crop_fraction,
                 "depth centre-crop fraction in (0, 1] (default 0.7, as the paper)")
      ->check(dsm::FlagNumber(1e-6, 1.0));
  bool metric = false;
  cli.add_flag(
      "--metric", metric,
      "the result is metric in the ground truth's frame (e.g. aligned to a pose prior): compare depth "
      "and positions as they are, without the per-frame depth scale or the Sim(3) alignment");
  double confidence_threshold = 0.0;
  cli.add_option("--confidence-threshold", confidence_threshold,
                 "evaluate the result's depth with NaN where its depth_confidence/ map is below this "
                 "(as estimate_sequence --depth-confidence-threshold writes it); 0 = as written")
      ->check(dsm::FlagNumber(0.0, 1.0));
  bool recompute_confidence = false;
  cli.add_flag(
      "--recompute-confidence", recompute_confidence,
      "with --confidence-threshold: recompute the confidence from the result's latent/, depth/ and "
      "poses.txt with this build's defaults instead of reading depth_confidence/ (to compare builds)");
  cli.add_option("--json", json_path, "also write the numbers as JSON");
  cli.add_option("--method", method, "row label (default: the result folder's name)");
  if (!cli.Parse(argc, argv)) return 0;
  options.align_depth_scale = options.align_trajectory = !metric;
  if (method.empty()) {
    fs::path name = fs::path(result_dir).lexically_normal();
    if (name.filename().empty()) name = name.parent_path();  // "out/"
    method = name.filename().string();
  }

  dsm::SequenceResult result = dsm::ReadResult(result_dir);
  if (recompute_confidence && confidence_threshold <= 0.0) {
    throw dsm::InputError("--recompute-confidence needs --confidence-threshold above 0");
  }
  if (recompute_confidence) {
    MaskByRecomputedConfidence(result_dir, confidence_threshold, &result);
  } else if (confidence_threshold > 0.0) {
    MaskByConfidence(result_dir, confidence_threshold, &result);
  }
  const dsm::Sequence sequence = dsm::ReadSequence(sequence_dir, /*read_ground_truth=*/true);
  if (!sequence.ground_truth) {
    throw dsm::InputError(sequence_dir + ": no gt/ folder (ground truth) to evaluate against");
  }
  dsm::EvaluationReport report;
  try {
    report = dsm::EvaluateResult(result, sequence, options);
  } catch (const dsm::InputError& error) {
    // The checks of the pair name no file themselves; name both folders.
    throw dsm::InputError(result_dir + " vs " + sequence_dir + ": " + error.what());
  }
  std::cout << dsm::ToMarkdown(report, method);
  if (!json_path.empty()) WriteTextFile(json_path, dsm::ToJson(report, method));
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  return deblur_sr_mvs::ToolMain("evaluate_sequence", Run, argc, argv);
}
