// The multi-frame super-resolution peer method for the benchmarks: OpenCV's
// BTV-L1 (cv::superres, Farsiu et al. 2004 with the Mitzel et al. 2009 flow
// registration; the method the paper cites) run over the frames of a
// sequence folder. Writes an image-only result folder (latent/, camera.yaml at
// the HR size, frames.csv, report.json; no depth, no poses).
// Usage: superres_btvl1 --input SEQ --output OUT [--scale S] [--iterations N]
//                       [--temporal-radius R] [--threads N] [--no-centre-shift]
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <string>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/core/ocl.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/superres.hpp>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/imaging/image_ops.h"
#include "deblur_sr_mvs/core/io/result_io.h"
#include "deblur_sr_mvs/core/io/sequence_io.h"
#include "report_json.h"
#include "tool_main.h"

namespace dsm = deblur_sr_mvs;

namespace {

constexpr char kDescription[] =
    "Multi-frame super-resolution of every frame of a sequence folder with OpenCV's\n"
    "BTV-L1 (cv::superres; Farsiu et al. 2004), the peer method of the benchmarks.\n"
    "Writes an image-only result folder (latent/, camera.yaml, frames.csv,\n"
    "report.json) for evaluate_sequence. Parameters are OpenCV's defaults except\n"
    "the scale.";

struct Flags {
  std::string input_dir, output_dir;
  int scale = 2;
  int iterations = -1;       // -1: OpenCV's default
  int temporal_radius = -1;  // -1: OpenCV's default
  int threads = -1;          // -1: OpenCV's default
  bool no_centre_shift = false;
};

// Serves the sequence's images to cv::superres in order; empty at the end.
class InMemoryFrameSource : public cv::superres::FrameSource {
 public:
  explicit InMemoryFrameSource(const std::vector<cv::Mat>& frames) : frames_(frames) {}

  void nextFrame(cv::OutputArray frame) override {
    if (next_ < frames_.size()) {
      frames_[next_++].copyTo(frame);
    } else {
      frame.release();
    }
  }
  void reset() override { next_ = 0; }

 private:
  const std::vector<cv::Mat>& frames_;
  std::size_t next_ = 0;
};

// BTV-L1 returns only the interior of the HR image (it crops its BTV kernel
// size on every side, where the regulariser is undefined) and models LR pixel
// x as HR pixel s*x (nearest down-sampling), whereas docs/file_formats.md#scaling-rule puts it at
// the centre of its s x s block, s*x + (s-1)/2. Its estimate therefore comes
// out shifted by (s-1)/2 HR pixels (measured: +0.5 px on x2 shift sequences,
// ~6 dB PSNR). This puts the interior back on the package's pixel grid and fills the
// cropped border from the bicubic up-sampling of the input frame.
cv::Mat ToFullFrame(const cv::Mat& interior, const cv::Mat& input, int scale, int border, bool centre_shift) {
  cv::Mat full = dsm::ToImage8(dsm::UpsampleBicubic(dsm::ToFloat01(input), scale));
  if (interior.type() != full.type() || interior.cols != full.cols - 2 * border ||
      interior.rows != full.rows - 2 * border) {
    throw std::runtime_error("BTV-L1 returned a " + std::to_string(interior.cols) + "x" +
                             std::to_string(interior.rows) + " image for a " + std::to_string(full.cols) +
                             "x" + std::to_string(full.rows) + " frame with a " + std::to_string(border) +
                             " px border");
  }
  cv::Mat placed = interior;
  if (centre_shift) {
    const double shift = (scale - 1) / 2.0;  // dst(X) = interior(X - shift)
    const cv::Matx23d translation(1.0, 0.0, shift, 0.0, 1.0, shift);
    cv::warpAffine(interior, placed, translation, interior.size(), cv::INTER_CUBIC, cv::BORDER_REPLICATE);
  }
  placed.copyTo(full(cv::Rect(border, border, interior.cols, interior.rows)));
  return full;
}

// Parses the command line; false after --help.
bool ParseCommandLine(int argc, char** argv, Flags* flags) {
  dsm::ToolCommandLine cli("superres_btvl1", kDescription);
  cli.add_option("--input", flags->input_dir, "sequence folder (camera.yaml, frames.csv, images/)")
      ->required()
      ->check(CLI::ExistingDirectory);
  cli.add_option("--output", flags->output_dir, "result folder to write")->required();
  cli.add_option("--scale", flags->scale, "up-sampling factor, 2..8 (default 2)")
      ->check(dsm::FlagInt(2, 8));  // BTV-L1 asserts scale > 1
  cli.add_option("--iterations", flags->iterations, "BTV-L1 iterations per frame (default 180, OpenCV's)")
      ->check(dsm::FlagInt(1, 100000));
  cli.add_option("--temporal-radius", flags->temporal_radius,
                 "frames on each side used per output (default 4, OpenCV's; capped at frames - 1)")
      ->check(dsm::FlagInt(0, 1000));
  cli.add_option("--threads", flags->threads, "OpenCV worker threads (default: OpenCV's choice)")
      ->check(dsm::FlagInt(1, 1024));
  cli.add_flag("--no-centre-shift", flags->no_centre_shift, "keep OpenCV's pixel grid (see report.json)");
  return cli.Parse(argc, argv);
}

// BTV-L1 reads radius frames ahead, then emits one output per input in
// input order (output k is frame k; checked on shifted synthetic frames).
// Returns the wall time in seconds.
double SuperResolve(cv::superres::SuperResolution* btv, const dsm::Sequence& sequence, int scale,
                    bool centre_shift, dsm::SequenceResult* result) {
  const int num_frames = static_cast<int>(sequence.frames.size());
  const int border = btv->getKernelSize();
  result->latent.reserve(num_frames);
  const auto start = std::chrono::steady_clock::now();
  cv::Mat interior;
  for (;;) {
    btv->nextFrame(interior);
    if (interior.empty()) break;
    const int k = static_cast<int>(result->latent.size());
    if (k >= num_frames) throw std::runtime_error("BTV-L1 returned more frames than it was given");
    result->latent.push_back(ToFullFrame(interior, sequence.images[k], scale, border, centre_shift));
    const double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    std::printf("frame %d/%d  %.1f s\n", k + 1, num_frames, elapsed);
    std::fflush(stdout);
  }
  if (static_cast<int>(result->latent.size()) != num_frames) {
    throw std::runtime_error("BTV-L1 returned " + std::to_string(result->latent.size()) + " frames for " +
                             std::to_string(num_frames) + " inputs");
  }
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

dsm::Json Report(const cv::superres::SuperResolution& btv, const Flags& flags, int requested_radius,
                 int num_frames, double wall_time) {
  const int scale = btv.getScale();
  dsm::Json report;
  report["method"] = "btvl1";
  report["implementation"] =
      std::string("OpenCV ") + CV_VERSION + " cv::superres::createSuperResolution_BTVL1 (CPU)";
  report["input"] = flags.input_dir;
  report["parameters"] = {{"scale", scale},
                          {"iterations", btv.getIterations()},
                          {"tau", dsm::JsonNumber(btv.getTau())},
                          {"lambda", dsm::JsonNumber(btv.getLambda())},
                          {"alpha", dsm::JsonNumber(btv.getAlpha())},
                          {"btv_kernel_size", btv.getKernelSize()},
                          {"blur_kernel_size", btv.getBlurKernelSize()},
                          {"blur_sigma", dsm::JsonNumber(btv.getBlurSigma())},
                          {"temporal_radius", btv.getTemporalAreaRadius()},
                          {"temporal_radius_requested", requested_radius},
                          {"optical_flow", "Farneback (OpenCV default)"},
                          {"threads", cv::getNumThreads()}};
  report["border_px"] = btv.getKernelSize();
  report["border_fill"] = "bicubic up-sampling of the input frame";
  report["centre_shift_px"] = dsm::JsonNumber(flags.no_centre_shift ? 0.0 : (scale - 1) / 2.0);
  report["frames"] = num_frames;
  report["wall_time_s"] = dsm::JsonNumber(wall_time);
  report["wall_time_per_frame_s"] = dsm::JsonNumber(wall_time / num_frames);
  return report;
}

int Run(int argc, char** argv) {
  Flags flags;
  if (!ParseCommandLine(argc, argv, &flags)) return 0;
  const int scale = flags.scale;
  const dsm::Sequence sequence = dsm::ReadSequence(flags.input_dir, /*read_ground_truth=*/false);
  const int num_frames = static_cast<int>(sequence.frames.size());
  const dsm::PinholeCamera hr_camera = sequence.calibration.camera.Upscaled(scale);

  cv::ocl::setUseOpenCL(false);  // the CPU path; results independent of the GPU driver
  if (flags.threads > 0) cv::setNumThreads(flags.threads);
  cv::Ptr<cv::superres::SuperResolution> btv = cv::superres::createSuperResolution_BTVL1();
  btv->setScale(scale);
  if (flags.iterations > 0) btv->setIterations(flags.iterations);
  const int requested_radius =
      flags.temporal_radius >= 0 ? flags.temporal_radius : btv->getTemporalAreaRadius();
  // OpenCV's BTV-L1 indexes past its frame cache (and crashes) when the
  // sequence is shorter than radius + 1 frames.
  btv->setTemporalAreaRadius(std::min(requested_radius, num_frames - 1));
  const int border = btv->getKernelSize();
  if (hr_camera.width <= 2 * border + 2 || hr_camera.height <= 2 * border + 2) {
    throw dsm::InputError(flags.input_dir + "/camera.yaml: the HR frame " + std::to_string(hr_camera.width) +
                          "x" + std::to_string(hr_camera.height) + " is too small for BTV-L1 (it crops " +
                          std::to_string(border) + " px on every side)");
  }
  btv->setInput(cv::makePtr<InMemoryFrameSource>(sequence.images));

  dsm::SequenceResult result;
  result.calibration = dsm::CameraCalibration::FromCamera(hr_camera, sequence.calibration.camera_name);
  result.frames = sequence.frames;
  const double wall_time = SuperResolve(btv.get(), sequence, scale, !flags.no_centre_shift, &result);
  result.report_json = dsm::JsonText(Report(*btv, flags, requested_radius, num_frames, wall_time));
  dsm::WriteResult(flags.output_dir, result);
  std::printf("%s: %d frames x%d (%dx%d) in %.1f s (%.2f s/frame)\n", flags.output_dir.c_str(), num_frames,
              scale, hr_camera.width, hr_camera.height, wall_time, wall_time / num_frames);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  return deblur_sr_mvs::ToolMain("superres_btvl1", Run, argc, argv);
}
