// Times building Psi_t and applying Psi_t / Psi_t^T (issue: operator
// benchmark). Scene: 640x480 HR -> 320x240 LR, M = 50, a camera translating
// sideways past a bumpy surface with a depth edge, ~15 HR px of blur.
// Usage: benchmark_capture_operator [--repeats N] [--samples M] [--readout-ratio R]
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include <omp.h>

#include "deblur_sr_mvs/core/imaging/capture_operator.h"
#include "tool_main.h"

namespace dsm = deblur_sr_mvs;

namespace {

double Seconds() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

template <typename Function>
double MedianMs(int repeats, Function&& function) {
  std::vector<double> times;
  for (int i = 0; i < repeats; ++i) {
    const double start = Seconds();
    function();
    times.push_back((Seconds() - start) * 1e3);
  }
  std::sort(times.begin(), times.end());
  return times[times.size() / 2];
}

// 640x480 HR: a bumpy surface at ~2 m with a box at 1.3 m, the camera
// translating sideways.
dsm::CaptureGeometry BenchmarkGeometry() {
  const int width = 640, height = 480;
  dsm::CaptureGeometry geometry;
  geometry.camera_hr = dsm::PinholeCamera(width, height, 525.0, 525.0, 319.5, 239.5);
  geometry.depth_hr = cv::Mat(height, width, CV_32FC1);
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      float d = 2.0f + 0.4f * std::sin(0.02f * x) * std::cos(0.03f * y);
      if (x > 200 && x < 360 && y > 150 && y < 330) d = 1.3f;
      geometry.depth_hr.at<float>(y, x) = d;
    }
  }
  // 0.07 m per frame and exposure 0.8 frame: ~15 px at 2 m, ~23 px at 1.3 m.
  geometry.T_world_neighbour = dsm::SE3();
  geometry.T_world_cam = dsm::SE3::Exp((dsm::Vector6d() << 0.07, 0.01, 0.0, 0.0, 0.004, 0.001).finished());
  geometry.neighbour_stamp = 0.0;
  geometry.stamp = 1.0 / 30.0;
  geometry.exposure = 0.8 / 30.0;
  return geometry;
}

// Times the build, Psi_t and Psi_t^T with one thread count and prints them.
void BenchmarkThreads(const dsm::CaptureGeometry& geometry, int threads, int samples, int repeats) {
  const int width = geometry.camera_hr.width, height = geometry.camera_hr.height;
  dsm::CaptureOperatorOptions options;
  options.samples = samples;
  options.scale = 2;
  options.num_threads = threads;
  dsm::CaptureOperatorBuilder builder(options);
  dsm::CaptureOperator op;
  builder.Build(geometry, &op);  // warm-up: allocates the scratch buffers
  const double build_ms = MedianMs(repeats, [&] { builder.Build(geometry, &op); });
  cv::Mat gray_hr(height, width, CV_32FC1), color_hr(height, width, CV_32FC3);
  cv::randu(gray_hr, 0.0f, 1.0f);
  cv::randu(color_hr, 0.0f, 1.0f);
  cv::Mat gray_lr, color_lr, back;
  op.Apply(gray_hr, &gray_lr);
  op.Apply(color_hr, &color_lr);
  op.ApplyAdjoint(gray_lr, &back);
  const int apply_repeats = repeats * 5;
  const double apply_gray = MedianMs(apply_repeats, [&] { op.Apply(gray_hr, &gray_lr); });
  const double adjoint_gray = MedianMs(apply_repeats, [&] { op.ApplyAdjoint(gray_lr, &back); });
  const double apply_color = MedianMs(apply_repeats, [&] { op.Apply(color_hr, &color_lr); });
  const double adjoint_color = MedianMs(apply_repeats, [&] { op.ApplyAdjoint(color_lr, &back); });
  const dsm::CaptureOperatorBuilder::Timings& stages = builder.last_timings();
  std::printf(
      "threads %d: build stages (last run): reprojection %.1f ms, assembly %.1f ms, "
      "adjoint copy %.1f ms\n",
      threads, stages.reprojection_ms, stages.assembly_ms, stages.adjoint_ms);
  const double nnz = static_cast<double>(op.matrix().nonZeros());
  std::printf(
      "threads %d: build %.1f ms | apply %.2f ms (gray) %.2f ms (rgb) | adjoint %.2f ms "
      "(gray) %.2f ms (rgb) | nnz %.2f M (%.1f per LR pixel), %.0f MiB for Psi and Psi^T\n",
      threads, build_ms, apply_gray, apply_color, adjoint_gray, adjoint_color, nnz / 1e6,
      nnz / op.matrix().rows(), 2.0 * nnz * 8.0 / (1 << 20));
}

int Run(int argc, char** argv) {
  int repeats = 7;
  int samples = 50;
  double readout_ratio = 0.0;
  dsm::ToolCommandLine cli("benchmark_capture_operator",
                           "Times building Psi_t and applying Psi_t / Psi_t^T: 640x480 HR -> 320x240 LR, "
                           "a camera translating past a bumpy surface, 1 and 2 threads.");
  cli.add_option("--repeats", repeats, "timed runs per measurement, the median is shown (default 7)")
      ->check(dsm::FlagInt(1));
  cli.add_option("--samples", samples, "M, sub-exposure samples (default 50)")->check(dsm::FlagInt(1, 10000));
  cli.add_option("--readout-ratio", readout_ratio,
                 "rolling shutter: readout time = R x frame interval (default 0: global shutter)")
      ->check(dsm::FlagNumber(0.0, 1.0));
  if (!cli.Parse(argc, argv)) return 0;
  dsm::CaptureGeometry geometry = BenchmarkGeometry();
  geometry.readout_time = readout_ratio * (geometry.stamp - geometry.neighbour_stamp);
  std::printf(
      "capture operator benchmark: 640x480 -> 320x240, M = %d, scale 2, readout %.2f x frame interval, "
      "median of %d\n",
      samples, readout_ratio, repeats);
  std::printf("machine threads available: %d\n", omp_get_max_threads());
  for (int threads : {1, 2}) BenchmarkThreads(geometry, threads, samples, repeats);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  return deblur_sr_mvs::ToolMain("benchmark_capture_operator", Run, argc, argv);
}
