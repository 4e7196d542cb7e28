// synthesize_sequence: a blurred, low-resolution sequence with ground truth
// from a Middlebury scene (SPEC section 4).
//
//   synthesize_sequence --scene DIR --output SEQ [--frames N] [--scale S]
//                       [--exposure-ratio R] [--path lateral|arc|forward]
//                       [--noise SIGMA] [--seed N] [--blur-px PX]
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

#include "tool_main.h"
#include "deblur_sr_mvs/core/evaluation/synthesizer.h"

namespace {

using deblur_sr_mvs::InputError;
using deblur_sr_mvs::ParseFlagInt;
using deblur_sr_mvs::ParseFlagNumber;

constexpr char kUsage[] =
    "usage: synthesize_sequence --scene DIR --output SEQ [--frames N] [--scale S]\n"
    "                           [--exposure-ratio R] [--path lateral|arc|forward]\n"
    "                           [--noise SIGMA] [--seed N] [--blur-px PX] [--subframes S]\n"
    "                           [--fps F] [--arc-fixation F] [--forward-cap F]\n"
    "                           [--hr-width W --hr-height H] [--scene-zoom Z]\n"
    "\n"
    "Renders a camera path through a Middlebury scene (view1/view5, disp1/disp5,\n"
    "dmin.txt), averages sub-frames over each exposure, box-downsamples by the\n"
    "scale and writes a sequence folder with gt/ (SPEC section 3).\n"
    "\n"
    "  --scene DIR           Middlebury scene folder (third-size images)\n"
    "  --output SEQ          sequence folder to write\n"
    "  --frames N            number of frames (default 10)\n"
    "  --scale S             super-resolution factor, LR = HR / S (default 2)\n"
    "  --exposure-ratio R    exposure / frame interval, in (0, 1] (default 0.8)\n"
    "  --path P              lateral, arc or forward (default lateral)\n"
    "  --noise SIGMA         Gaussian noise on the LR frames, 8-bit units (default 0)\n"
    "  --seed N              noise seed (default 0)\n"
    "  --blur-px PX          median HR image motion per exposure (default 14)\n"
    "  --subframes S         renders per exposure, > 50 (default 200)\n"
    "  --fps F               frame rate, stamps are (i + 1) / F (default 30)\n"
    "  --arc-fixation F      arc: fixation point at F x the median depth (default 2)\n"
    "  --forward-cap F       forward: total travel <= F x the nearest depth (default 0.4)\n"
    "  --scene-zoom Z          see the scene with Z times the focal length and size\n"
    "                          (1-4, default 1; bicubic texture), e.g. for 640x480 HR\n"
    "  --hr-width W, --hr-height H\n"
    "                        HR size (default: automatic covered crop)\n"
    "  --help                this text\n";

std::uint64_t ParseSeed(const std::string& flag, const std::string& text) {
  std::size_t used = 0;
  unsigned long long value = 0;
  if (!text.empty() && text[0] != '-') {
    try {
      value = std::stoull(text, &used);
    } catch (const std::exception&) {
      used = 0;
    }
  }
  if (used == 0 || used != text.size()) {
    throw InputError(flag + ": expected a non-negative integer, got \"" + text + "\"");
  }
  return value;
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

int Run(int argc, char** argv) {
  deblur_sr_mvs::SynthesisOptions options;
  std::string scene_folder, output_folder;
  double scene_zoom = 1.0;  // --scene-zoom
  for (int i = 1; i < argc; ++i) {
    const std::string flag = argv[i];
    if (flag == "--help" || flag == "-h") {
      std::cout << kUsage;
      return 0;
    }
    if (flag.rfind("--", 0) != 0) throw InputError("unexpected argument \"" + flag + "\"");
    static const char* const kFlags[] = {
        "--scene", "--output", "--frames", "--scale", "--exposure-ratio", "--path",
        "--noise", "--seed", "--blur-px", "--subframes", "--fps", "--arc-fixation",
        "--forward-cap", "--hr-width", "--hr-height", "--scene-zoom"};
    if (std::find(std::begin(kFlags), std::end(kFlags), flag) == std::end(kFlags)) {
      throw InputError("unknown flag " + flag + " (see --help)");
    }
    if (i + 1 >= argc) throw InputError(flag + ": missing value");
    const std::string value = argv[++i];
    if (flag == "--scene") {
      scene_folder = value;
    } else if (flag == "--output") {
      output_folder = value;
    } else if (flag == "--frames") {
      options.num_frames = ParseFlagInt(flag, value);
    } else if (flag == "--scale") {
      options.scale = ParseFlagInt(flag, value);
    } else if (flag == "--exposure-ratio") {
      options.exposure_ratio = ParseFlagNumber(flag, value);
    } else if (flag == "--path") {
      options.path = deblur_sr_mvs::ParseCameraPathType(value);
    } else if (flag == "--noise") {
      options.noise_sigma = ParseFlagNumber(flag, value);
    } else if (flag == "--seed") {
      options.seed = ParseSeed(flag, value);
    } else if (flag == "--blur-px") {
      options.blur_px = ParseFlagNumber(flag, value);
    } else if (flag == "--subframes") {
      options.subframes = ParseFlagInt(flag, value);
    } else if (flag == "--fps") {
      options.fps = ParseFlagNumber(flag, value);
    } else if (flag == "--arc-fixation") {
      options.arc_fixation_factor = ParseFlagNumber(flag, value);
    } else if (flag == "--forward-cap") {
      options.forward_travel_cap = ParseFlagNumber(flag, value);
    } else if (flag == "--hr-width") {
      options.hr_width = ParseFlagInt(flag, value);
    } else if (flag == "--hr-height") {
      options.hr_height = ParseFlagInt(flag, value);
    } else if (flag == "--scene-zoom") {
      scene_zoom = ParseFlagNumber(flag, value);
    } else {
      throw InputError("unknown flag " + flag + " (see --help)");
    }
  }
  if (scene_folder.empty()) throw InputError("--scene is required (see --help)");
  if (output_folder.empty()) throw InputError("--output is required (see --help)");
  options.Check();

  deblur_sr_mvs::StereoScene scene = deblur_sr_mvs::LoadMiddleburyScene(scene_folder);
  if (scene_zoom != 1.0) scene = deblur_sr_mvs::ZoomScene(scene, scene_zoom);
  {
    // Fail before the rendering, not after it, when the output cannot be made.
    std::error_code error;
    std::filesystem::create_directories(output_folder, error);
    if (error) throw InputError(output_folder + ": cannot create the folder: " + error.message());
  }
  const deblur_sr_mvs::SynthesisResult result =
      deblur_sr_mvs::SynthesizeSequence(scene, options, &std::cout);
  RemoveStaleFrames(output_folder);
  deblur_sr_mvs::WriteSequence(output_folder, result.sequence);
  deblur_sr_mvs::WriteSynthesisYaml(output_folder + "/gt/synthesis.yaml", scene, options, result);

  double blur_min = 1e30, blur_max = 0.0, holes_max = 0.0, holes_mean = 0.0;
  for (const auto& stats : result.frame_stats) {
    blur_min = std::min(blur_min, stats.blur.median_px);
    blur_max = std::max(blur_max, stats.blur.median_px);
    holes_max = std::max(holes_max, stats.hole_fraction_max);
    holes_mean += stats.hole_fraction_latent / result.frame_stats.size();
  }
  std::cout << std::fixed << std::setprecision(2) << "wrote " << output_folder << ": "
            << options.num_frames << " frames, " << CameraPathName(options.path) << " path, LR "
            << result.lr_camera.width << "x" << result.lr_camera.height << ", HR "
            << result.hr_camera.width << "x" << result.hr_camera.height << " (scale "
            << options.scale << ")\n"
            << "  depth " << scene.min_depth << "-" << scene.max_depth << " m (median "
            << scene.median_depth << "), camera speed " << result.path.speed << " m/s"
            << (result.speed_capped ? " (capped)" : "") << "\n"
            << "  blur per exposure (median HR px): target " << options.blur_px
            << ", middle frame " << result.achieved_blur_px << ", frames " << blur_min << "-"
            << blur_max << "\n"
            << "  holes before filling: latent mean " << 100.0 * holes_mean
            << " %, worst sub-frame " << 100.0 * holes_max << " %\n"
            << "  " << options.subframes << " sub-frames per exposure, "
            << std::setprecision(1) << result.seconds << " s\n";
  if (holes_max > 0.02) {
    std::cout << "warning: up to " << std::setprecision(1) << 100.0 * holes_max
              << " % of the pixels of a sub-frame were seen by neither view and were filled "
                 "from their background (unknown disparity, or a path reaching far beyond the "
                 "views: fewer frames or less blur help)\n";
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  return deblur_sr_mvs::ToolMain("synthesize_sequence", Run, argc, argv);
}
