// synthesize_sequence: a blurred, low-resolution sequence with ground truth
// from a Middlebury scene (docs/tools.md#synthesize_sequence).
//
//   synthesize_sequence --scene DIR --output SEQ [--frames N] [--scale S]
//                       [--exposure-ratio R]
//                       [--path lateral|arc|forward|handheld|rotate]
//                       [--noise SIGMA] [--seed N] [--readout-ratio R]
//                       [--gain-jitter G] [--blur-px PX]
//                       [--subframes S] [--fps F] [--arc-fixation F]
//                       [--forward-cap F] [--hr-width W --hr-height H]
//
// Exit code 0 on success, 2 with one line on stderr on bad input.
#include <algorithm>
#include <cctype>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <iterator>
#include <string>

#include "deblur_sr_mvs/core/evaluation/synthesizer.h"
#include "tool_main.h"

namespace {

namespace dsm = deblur_sr_mvs;
using deblur_sr_mvs::InputError;

constexpr char kDescription[] =
    "Renders a camera path through a Middlebury scene (view1/view5, disp1/disp5,\n"
    "dmin.txt), averages sub-frames over each exposure, box-downsamples by the\n"
    "scale and writes a sequence folder with gt/ (docs/file_formats.md).";

// --seed: a non-negative integer of up to 64 bits.
CLI::Validator SeedValidator() {
  return CLI::Validator(
      [](std::string& text) -> std::string {
        std::size_t used = 0;
        if (!text.empty() && text[0] != '-') {
          try {
            std::stoull(text, &used);
          } catch (const std::exception&) {
            used = 0;
          }
        }
        if (used == 0 || used != text.size()) return "expected a non-negative integer, got \"" + text + "\"";
        return std::string();
      },
      "SEED");
}

struct Flags {
  std::string scene_folder, output_folder;
  std::string path = "lateral";
  double scene_zoom = 1.0;
};

// Parses the command line into flags and options; false after --help.
bool ParseCommandLine(int argc, char** argv, Flags* flags, dsm::SynthesisOptions* options) {
  dsm::ToolCommandLine cli("synthesize_sequence", kDescription);
  cli.add_option("--scene", flags->scene_folder, "Middlebury scene folder (third-size images)")
      ->required()
      ->check(CLI::ExistingDirectory);
  cli.add_option("--output", flags->output_folder, "sequence folder to write")->required();
  cli.add_option("--frames", options->num_frames, "number of frames (default 10)")->check(dsm::FlagInt());
  cli.add_option("--scale", options->scale, "super-resolution factor, LR = HR / S (default 2)")
      ->check(dsm::FlagInt());
  cli.add_option("--exposure-ratio", options->exposure_ratio,
                 "exposure / frame interval, in (0, 1] (default 0.8)")
      ->check(dsm::FlagNumber());
  cli.add_option("--path", flags->path, "lateral, arc, forward, handheld or rotate (default lateral)")
      ->check(CLI::IsMember({"lateral", "arc", "forward", "handheld", "rotate"}));
  cli.add_option("--noise", options->noise_sigma, "Gaussian noise on the LR frames, 8-bit units (default 0)")
      ->check(dsm::FlagNumber());
  cli.add_option("--seed", options->seed, "seed of the noise, the handheld path and the gains (default 0)")
      ->check(SeedValidator());
  cli.add_option("--readout-ratio", options->readout_ratio,
                 "rolling shutter: readout time = R x frame interval, in [0, 1] (default 0: global); "
                 "writes sensor.yaml")
      ->check(dsm::FlagNumber());
  cli.add_option("--gain-jitter", options->gain_jitter,
                 "per-frame gain drawn from [1-G, 1+G] on the frame and its gt latent, G in [0, 0.5] "
                 "(default 0)")
      ->check(dsm::FlagNumber());
  cli.add_option("--blur-px", options->blur_px, "median HR image motion per exposure (default 14)")
      ->check(dsm::FlagNumber());
  cli.add_option("--subframes", options->subframes, "renders per exposure, > 50 (default 200)")
      ->check(dsm::FlagInt());
  cli.add_option("--fps", options->fps, "frame rate, stamps are (i + 1) / F (default 30)")
      ->check(dsm::FlagNumber());
  cli.add_option("--arc-fixation", options->arc_fixation_factor,
                 "arc: fixation point at F x the median depth (default 2)")
      ->check(dsm::FlagNumber());
  cli.add_option("--forward-cap", options->forward_travel_cap,
                 "forward, handheld: total depth travel <= F x the nearest depth (default 0.4)")
      ->check(dsm::FlagNumber());
  cli.add_option("--hr-width", options->hr_width, "HR width (default: automatic covered crop)")
      ->check(dsm::FlagInt());
  cli.add_option("--hr-height", options->hr_height, "HR height (default: automatic covered crop)")
      ->check(dsm::FlagInt());
  cli.add_option("--scene-zoom", flags->scene_zoom,
                 "see the scene with Z times the focal length and size (1-4, default 1; bicubic "
                 "texture), e.g. for 640x480 HR")
      ->check(dsm::FlagNumber());
  if (!cli.Parse(argc, argv)) return false;
  options->path = dsm::ParseCameraPathType(flags->path);
  options->Check();
  return true;
}

// Rewriting a sequence folder with fewer frames must not leave the old
// frames behind: remove the frame files (6-digit stems) of a folder that is a
// sequence folder (has frames.csv). Nothing else is touched.
void RemoveStaleFrames(const std::string& folder) {
  namespace fs = std::filesystem;
  const fs::path root(folder);
  if (!fs::exists(root / "frames.csv")) return;
  for (const char* sub : {"images", "gt/latent", "gt/depth"}) {
    std::error_code error;
    if (!fs::is_directory(root / sub, error)) continue;
    for (const fs::directory_entry& entry : fs::directory_iterator(root / sub, error)) {
      const std::string stem = entry.path().stem().string();
      const std::string extension = entry.path().extension().string();
      if (stem.size() == 6 && std::all_of(stem.begin(), stem.end(), ::isdigit) &&
          (extension == ".png" || extension == ".tiff") && entry.is_regular_file(error)) {
        fs::remove(entry.path(), error);
      }
    }
  }
}

// What was written, the blur and the holes the renderer had to fill.
void PrintSummary(const std::string& output_folder, const deblur_sr_mvs::StereoScene& scene,
                  const deblur_sr_mvs::SynthesisOptions& options,
                  const deblur_sr_mvs::SynthesisResult& result) {
  double blur_min = 1e30, blur_max = 0.0, holes_max = 0.0, holes_mean = 0.0;
  for (const auto& stats : result.frame_stats) {
    blur_min = std::min(blur_min, stats.blur.median_px);
    blur_max = std::max(blur_max, stats.blur.median_px);
    holes_max = std::max(holes_max, stats.hole_fraction_max);
    holes_mean += stats.hole_fraction_latent / result.frame_stats.size();
  }
  std::cout << std::fixed << std::setprecision(2) << "wrote " << output_folder << ": " << options.num_frames
            << " frames, " << CameraPathName(options.path) << " path, LR " << result.lr_camera.width << "x"
            << result.lr_camera.height << ", HR " << result.hr_camera.width << "x" << result.hr_camera.height
            << " (scale " << options.scale << ")\n"
            << "  depth " << scene.min_depth << "-" << scene.max_depth << " m (median " << scene.median_depth
            << "), camera speed " << result.path.speed
            << (options.path == deblur_sr_mvs::CameraPathType::kRotate ? " rad/s" : " m/s")
            << (result.speed_capped ? " (capped)" : "") << "\n"
            << "  blur per exposure (median HR px): target " << options.blur_px
            << (options.path == deblur_sr_mvs::CameraPathType::kHandheld ? ", median of the frames "
                                                                         : ", middle frame ")
            << result.achieved_blur_px << ", frames " << blur_min << "-" << blur_max << "\n"
            << "  holes before filling: latent mean " << 100.0 * holes_mean << " %, worst sub-frame "
            << 100.0 * holes_max << " %\n"
            << "  " << options.subframes << " sub-frames per exposure, " << std::setprecision(1)
            << result.seconds << " s\n";
  if (holes_max > 0.02) {
    std::cout << "warning: up to " << std::setprecision(1) << 100.0 * holes_max
              << " % of the pixels of a sub-frame were seen by neither view and were filled "
                 "from their background (unknown disparity, or a path reaching far beyond the "
                 "views: fewer frames or less blur help)\n";
  }
}

int Run(int argc, char** argv) {
  Flags flags;
  deblur_sr_mvs::SynthesisOptions options;
  if (!ParseCommandLine(argc, argv, &flags, &options)) return 0;
  const std::string& output_folder = flags.output_folder;
  const double scene_zoom = flags.scene_zoom;

  deblur_sr_mvs::StereoScene scene = deblur_sr_mvs::LoadMiddleburyScene(flags.scene_folder);
  if (scene_zoom != 1.0) scene = deblur_sr_mvs::ZoomScene(scene, scene_zoom);
  {
    // Fail before the rendering, not after it, when the output cannot be made.
    std::error_code error;
    std::filesystem::create_directories(output_folder, error);
    if (error) throw InputError(output_folder + ": cannot create the folder: " + error.message());
  }
  const deblur_sr_mvs::SynthesisResult result = deblur_sr_mvs::SynthesizeSequence(scene, options, &std::cout);
  RemoveStaleFrames(output_folder);
  deblur_sr_mvs::WriteSequence(output_folder, result.sequence);
  deblur_sr_mvs::WriteSynthesisYaml(output_folder + "/gt/synthesis.yaml", scene, options, result);

  PrintSummary(output_folder, scene, options, result);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  return deblur_sr_mvs::ToolMain("synthesize_sequence", Run, argc, argv);
}
