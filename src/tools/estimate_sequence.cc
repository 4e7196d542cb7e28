// estimate_sequence: sequence folder -> result folder (SPEC sections 3-4).
// Runs the joint estimator (or the baseline) and writes the HR latent images,
// HR depth maps, poses and report.json. A progress bar is drawn when stderr
// is a terminal. Bad input: one line on stderr, exit code 2.
#include <sys/resource.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <sstream>
#include <limits>
#include <string>

#include "tool_main.h"
#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/estimation/estimator.h"
#include "deblur_sr_mvs/core/imaging/image_ops.h"
#include "deblur_sr_mvs/core/io/result_io.h"
#include "deblur_sr_mvs/core/io/sequence_io.h"

namespace dsm = deblur_sr_mvs;

namespace {

constexpr char kUsage[] =
    "usage: estimate_sequence --input SEQ --output OUT [--mode joint|baseline] [--scale S]\n"
    "                         [--iterations N] [--samples M] [--lambda-s X] [--lambda-d X]\n"
    "                         [--lambda-i X] [--threads N] [--neighbours R] [--pose-neighbours R]\n"
    "                         [--fixed-poses] [--structure-matching both|restored|blurred]\n"
    "                         [--output-scale K] [--quiet]\n"
    "Defaults are the paper's: joint, scale 2, 3 iterations, M 50, lambda_s 30,\n"
    "lambda_d 0.1 (see README), lambda_i 0.45, neighbours 1; pose-neighbours 2,\n"
    "structure-matching both (see README); threads 0 = all cores.\n";

double PeakMemoryMiB() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return usage.ru_maxrss / 1024.0;  // Linux: KiB
}

std::string JsonNumber(double value) {
  if (!std::isfinite(value)) return "null";
  std::ostringstream out;
  out.precision(10);
  out << value;
  return out.str();
}

std::string Report(const dsm::EstimatorOptions& options, const std::string& input,
                   const dsm::EstimatorResult& result, double wall_seconds) {
  std::ostringstream json;
  json << "{\n  \"input\": \"" << input << "\",\n";
  json << "  \"parameters\": {\"mode\": \"" << dsm::ToString(options.mode) << "\", \"scale\": "
       << options.scale << ", \"iterations\": " << options.max_iterations
       << ", \"samples\": " << options.samples << ", \"lambda_s\": " << JsonNumber(options.lambda_s)
       << ", \"lambda_d\": " << JsonNumber(options.structure.lambda_d)
       << ", \"lambda_i\": " << JsonNumber(options.image.lambda_i)
       << ", \"neighbour_radius\": " << options.neighbour_radius
       << ", \"pose_neighbour_radius\": " << options.pose_neighbour_radius
       << ", \"update_poses\": " << (options.update_poses ? "true" : "false")
       << ", \"structure_matching\": \"" << dsm::ToString(options.structure_matching) << "\""
       << ", \"threads\": " << options.num_threads << "},\n";
  json << "  \"energies\": [\n";
  for (size_t i = 0; i < result.energies.size(); ++i) {
    const dsm::EnergyRecord& e = result.energies[i];
    json << "    {\"iteration\": " << e.iteration << ", \"stage\": \"" << e.stage
         << "\", \"total\": " << JsonNumber(e.total) << ", \"matching\": " << JsonNumber(e.matching)
         << ", \"self_consistency\": " << JsonNumber(e.self_consistency)
         << ", \"image_tv\": " << JsonNumber(e.image_tv) << ", \"depth_tv\": " << JsonNumber(e.depth_tv)
         << "}" << (i + 1 < result.energies.size() ? "," : "") << "\n";
  }
  json << "  ],\n  \"stage_seconds\": {";
  for (size_t i = 0; i < result.timings.size(); ++i) {
    json << (i ? ", " : "") << "\"" << result.timings[i].stage << "\": " << JsonNumber(result.timings[i].seconds);
  }
  json << "},\n  \"wall_seconds\": " << JsonNumber(wall_seconds)
       << ",\n  \"peak_memory_mib\": " << JsonNumber(PeakMemoryMiB()) << ",\n";
  std::string summary = result.initializer_summary;
  for (char& c : summary) {
    if (c == '"' || c == '\\') c = '\'';
    if (c == '\n') c = ';';
  }
  json << "  \"initializer\": \"" << summary << "\",\n";
  json << "  \"solver_notes\": [";
  for (size_t i = 0; i < result.notes.size(); ++i) json << (i ? ", " : "") << "\"" << result.notes[i] << "\"";
  json << "],\n";
  json << "  \"monocular_scale\": \"arbitrary: the first two cameras are 1 unit apart\"\n}\n";
  return json.str();
}

int Run(int argc, char** argv) {
  std::string input, output;
  dsm::EstimatorOptions options;
  bool quiet = false;
  int output_scale = 1;  // bicubic up-sampling of the outputs ("w/o SR + Bic.")
  for (int i = 1; i < argc; ++i) {
    const std::string flag = argv[i];
    if (flag == "--help" || flag == "-h") {
      std::cout << kUsage;
      return 0;
    }
    if (flag == "--fixed-poses") {
      options.update_poses = false;
      continue;
    }
    if (flag == "--quiet") {
      quiet = true;
      continue;
    }
    if (i + 1 >= argc) throw dsm::InputError("flag " + flag + " needs a value");
    const std::string value = argv[++i];
    if (flag == "--input") input = value;
    else if (flag == "--output") output = value;
    else if (flag == "--mode") options.mode = dsm::ParseEstimatorMode(value);
    else if (flag == "--scale") options.scale = dsm::ParseFlagInt(flag, value);
    else if (flag == "--iterations") options.max_iterations = dsm::ParseFlagInt(flag, value);
    else if (flag == "--samples") options.samples = dsm::ParseFlagInt(flag, value);
    else if (flag == "--lambda-s") options.lambda_s = dsm::ParseFlagNumber(flag, value);
    else if (flag == "--lambda-d") options.structure.lambda_d = dsm::ParseFlagNumber(flag, value);
    else if (flag == "--lambda-i") options.image.lambda_i = dsm::ParseFlagNumber(flag, value);
    else if (flag == "--threads") options.num_threads = dsm::ParseFlagInt(flag, value);
    else if (flag == "--neighbours") options.neighbour_radius = dsm::ParseFlagInt(flag, value);
    else if (flag == "--pose-neighbours") options.pose_neighbour_radius = dsm::ParseFlagInt(flag, value);
    else if (flag == "--output-scale") output_scale = dsm::ParseFlagInt(flag, value);
    else if (flag == "--structure-matching") options.structure_matching = dsm::ParseStructureMatching(value);
    else throw dsm::InputError("unknown flag " + flag + " (see --help)");
  }
  if (input.empty() || output.empty()) throw dsm::InputError("--input and --output are required (see --help)");
  if (output_scale < 1 || output_scale > 4) throw dsm::InputError("--output-scale must be in [1, 4]");
  options.Check();

  const auto start = std::chrono::steady_clock::now();
  const dsm::Sequence sequence = dsm::ReadSequence(input, /*read_ground_truth=*/false);
  if (sequence.frames.size() < 2) throw dsm::InputError(input + ": needs at least 2 frames");
  if (sequence.calibration.HasDistortion()) {
    throw dsm::InputError(input + "/camera.yaml: distortion is not zero; rectify the frames first");
  }
  dsm::EstimatorInput estimator_input;
  estimator_input.camera = sequence.calibration.camera;
  estimator_input.frames = sequence.frames;
  for (const cv::Mat& image : sequence.images) estimator_input.images.push_back(dsm::ToFloat01(image));

  const bool draw = !quiet && isatty(STDERR_FILENO);
  dsm::ProgressCallback progress = [&](double fraction, const std::string& what) {
    if (!draw) return;
    const int width = 30;
    const int filled = static_cast<int>(fraction * width + 0.5);
    std::fprintf(stderr, "\r[%s%s] %3d%% %-40s", std::string(filled, '#').c_str(),
                 std::string(width - filled, '.').c_str(), static_cast<int>(fraction * 100 + 0.5),
                 what.c_str());
    std::fflush(stderr);
  };
  dsm::Estimator estimator(options);
  dsm::EstimatorResult result;
  try {
    result = estimator.Run(estimator_input, progress);
  } catch (const dsm::InitializationError& error) {
    if (draw) std::fprintf(stderr, "\n");
    throw dsm::InputError(input + ": initialisation failed: " + error.what());
  }
  if (draw) std::fprintf(stderr, "\n");
  const double wall =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

  dsm::SequenceResult out;
  out.calibration = dsm::CameraCalibration::FromCamera(result.camera_hr.Upscaled(output_scale),
                                                       sequence.calibration.camera_name);
  out.frames = sequence.frames;
  for (size_t t = 0; t < result.latent.size(); ++t) {
    if (output_scale > 1) {
      // "Proposed (w/o SR) + Bic.": the estimate at the input resolution,
      // bicubic up-sampled (depth as inverse depth, NaN kept out).
      out.latent.push_back(dsm::ToImage8(dsm::UpsampleBicubic(result.latent[t], output_scale)));
      cv::Mat inverse;
      cv::divide(1.0, result.depth[t], inverse);
      cv::patchNaNs(inverse, 0.0);
      cv::Mat inverse_up = dsm::UpsampleBicubic(inverse, output_scale), depth_up;
      cv::divide(1.0, inverse_up, depth_up);
      depth_up.setTo(std::numeric_limits<float>::quiet_NaN(), inverse_up <= 0.0f);
      out.depth.push_back(depth_up);
    } else {
      out.latent.push_back(dsm::ToImage8(result.latent[t]));
      out.depth.push_back(result.depth[t]);
    }
    out.poses.push_back({sequence.frames[t].stamp, result.T_world_cam[t]});
  }
  out.report_json = Report(options, input, result, wall);
  dsm::WriteResult(output, out);
  if (!quiet) {
    std::printf("estimate_sequence: %zu frames, %s, %.1f s, peak %.0f MiB, energy %.4g -> %.4g; wrote %s\n",
                result.latent.size(), dsm::ToString(options.mode), wall, PeakMemoryMiB(),
                result.energies.front().total, result.energies.back().total, output.c_str());
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  return deblur_sr_mvs::ToolMain("estimate_sequence", Run, argc, argv);
}
