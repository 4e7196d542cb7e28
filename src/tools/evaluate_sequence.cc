// Evaluates a result folder against a sequence folder's ground truth and
// prints the paper's tables in Markdown (SPEC section 4):
// image PSNR beside bicubic (tab:quantBlur), depth PSNR / rel. and ATE RMSE
// (tab:quant).
// Usage: evaluate_sequence --result OUT --sequence SEQ [--crop F] [--json FILE]
//                          [--method NAME]
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <string>
#include <system_error>

#include "tool_main.h"
#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/evaluation/evaluation.h"
#include "deblur_sr_mvs/core/io/result_io.h"
#include "deblur_sr_mvs/core/io/sequence_io.h"

namespace dsm = deblur_sr_mvs;
namespace fs = std::filesystem;

namespace {

constexpr char kUsage[] =
    "usage: evaluate_sequence --result OUT --sequence SEQ [--crop F] [--json FILE]\n"
    "                         [--method NAME]\n"
    "\n"
    "Compares a result folder with the ground truth (gt/) of the sequence folder\n"
    "it was computed from and prints Markdown tables like the paper's:\n"
    "image PSNR (8-bit, whole image) beside bicubic up-sampling of the input;\n"
    "depth PSNR and rel. error (per-frame median scale alignment, centre crop);\n"
    "ATE RMSE of the positions after Sim(3) alignment. Metrics the result has\n"
    "no data for (depth, poses) read n/a.\n"
    "\n"
    "  --result OUT     result folder (camera.yaml, frames.csv, latent/, ...)\n"
    "  --sequence SEQ   sequence folder with gt/\n"
    "  --crop F         depth centre-crop fraction in (0, 1] (default 0.7, as the paper)\n"
    "  --json FILE      also write the numbers as JSON\n"
    "  --method NAME    row label (default: the result folder's name)\n"
    "  --help           this text\n";

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

int Run(int argc, char** argv) {
  std::string result_dir, sequence_dir, json_path, method;
  dsm::EvaluationOptions options;
  for (int i = 1; i < argc; ++i) {
    const std::string flag = argv[i];
    if (flag == "--help" || flag == "-h") {
      std::cout << kUsage;
      return 0;
    }
    if (flag != "--result" && flag != "--sequence" && flag != "--crop" && flag != "--json" &&
        flag != "--method") {
      throw dsm::InputError("unknown flag " + flag + " (see --help)");
    }
    if (i + 1 >= argc) throw dsm::InputError("flag " + flag + " needs a value");
    const std::string value = argv[++i];
    if (flag == "--result") {
      result_dir = value;
    } else if (flag == "--sequence") {
      sequence_dir = value;
    } else if (flag == "--crop") {
      options.crop_fraction = dsm::ParseFlagNumber(flag, value, 1e-6, 1.0);
    } else if (flag == "--json") {
      json_path = value;
    } else {
      method = value;
    }
  }
  if (result_dir.empty() || sequence_dir.empty()) {
    throw dsm::InputError("--result and --sequence are required (see --help)");
  }
  if (method.empty()) {
    fs::path name = fs::path(result_dir).lexically_normal();
    if (name.filename().empty()) name = name.parent_path();  // "out/"
    method = name.filename().string();
  }

  const dsm::SequenceResult result = dsm::ReadResult(result_dir);
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
