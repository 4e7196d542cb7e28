// Times building Psi_t and applying Psi_t / Psi_t^T (issue: operator
// benchmark). Scene: 640x480 HR -> 320x240 LR, M = 50, a camera translating
// sideways past a bumpy surface with a depth edge, ~15 HR px of blur.
// Usage: benchmark_capture_operator [--repeats N] [--samples M] [--readout-ratio R]
//        [--row-layout] [--shared-depths] [--normal-product]
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <omp.h>

#include "deblur_sr_mvs/core/imaging/capture_operator.h"
#include "deblur_sr_mvs/core/imaging/normal_product.h"
#include "deblur_sr_mvs/core/imaging/rgb_run_kernels.h"
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

// Operator options with M = `samples` on one thread (the estimator's
// configuration has no transposed copy).
dsm::CaptureOperatorOptions OneThreadOptions(int samples, bool transposed_copy) {
  dsm::CaptureOperatorOptions options;
  options.samples = samples;
  options.num_threads = 1;
  options.transposed_copy = transposed_copy;
  return options;
}

// Times two forms of one computation alternately (a, b, a, b, ...) so that a
// change of the machine's load hits both; returns their median times (ms).
template <typename A, typename B>
std::pair<double, double> InterleavedMedianMs(int repeats, A&& a, B&& b) {
  std::vector<double> times_a, times_b;
  for (int i = 0; i < repeats; ++i) {
    double start = Seconds();
    a();
    times_a.push_back((Seconds() - start) * 1e3);
    start = Seconds();
    b();
    times_b.push_back((Seconds() - start) * 1e3);
  }
  std::sort(times_a.begin(), times_a.end());
  std::sort(times_b.begin(), times_b.end());
  return {times_a[times_a.size() / 2], times_b[times_b.size() / 2]};
}

bool SameBits(const cv::Mat& a, const cv::Mat& b) {
  return a.size() == b.size() && a.type() == b.type() &&
         std::memcmp(a.data, b.data, a.total() * a.elemSize()) == 0;
}

// The estimator's configuration (one thread, no transposed copy): Psi_t x
// and the scattered Psi_t^T y over the operator's row runs against the same
// products over its CSR form, interleaved; the results are compared bit for
// bit.
void BenchmarkRunLayout(const dsm::CaptureGeometry& geometry, int samples, int repeats) {
  const dsm::CaptureOperatorOptions options = OneThreadOptions(samples, /*transposed_copy=*/false);
  const dsm::CaptureOperator op = dsm::BuildCaptureOperator(geometry, options);
  const dsm::RowRunMatrix& runs = op.matrix();
  const dsm::SparseMatrixRM csr = runs.ToCsr();
  const cv::Size hr = op.hr_size();
  const int apply_repeats = repeats * 5;
  for (int channels : {1, 3}) {
    cv::Mat x(hr, CV_32FC(channels)), y_csr, y_runs;
    cv::randu(x, 0.0f, 1.0f);
    const auto [apply_csr, apply_runs] = InterleavedMedianMs(
        apply_repeats, [&] { dsm::MultiplySparse(csr, x, &y_csr, 1); }, [&] { op.Apply(x, &y_runs); });
    y_csr = y_csr.reshape(channels, op.lr_size().height);
    cv::Mat back_csr(hr, CV_32FC(channels)), back_runs(hr, CV_32FC(channels));
    const auto [adjoint_csr, adjoint_runs] = InterleavedMedianMs(
        apply_repeats,
        [&] {
          back_csr.setTo(0.0);
          dsm::AddAdjointProduct(csr, y_csr, &back_csr, 1);
        },
        [&] {
          back_runs.setTo(0.0);
          dsm::AddAdjointProduct(runs, y_csr, &back_runs, 1);
        });
    std::printf(
        "row layout, 1 thread, %d channel(s): %.2f runs per row (%.1f columns per run), %.1f MiB runs / %.1f "
        "MiB CSR | apply CSR %.2f ms, runs %.2f ms (x%.2f) | adjoint (scatter) CSR %.2f ms, runs %.2f ms "
        "(x%.2f) | bit-identical: %s, %s\n",
        channels, double(runs.runs()) / runs.rows(), double(runs.nonZeros()) / runs.runs(),
        runs.Bytes() / double(1 << 20), (csr.nonZeros() * 8.0 + (csr.rows() + 1) * 4.0) / (1 << 20),
        apply_csr, apply_runs, apply_csr / apply_runs, adjoint_csr, adjoint_runs, adjoint_csr / adjoint_runs,
        SameBits(y_csr, y_runs) ? "yes" : "no", SameBits(back_csr, back_runs) ? "yes" : "no");
  }
}

// The operators of one frame for its own and two neighbours' latent images
// (the estimator's N(t) = 2), one thread: each build reprojecting D_t itself
// against one set of virtual depths shared by the three; then adaptive M.
void BenchmarkSharedDepths(const dsm::CaptureGeometry& geometry, int samples, int repeats) {
  const dsm::CaptureOperatorOptions options = OneThreadOptions(samples, /*transposed_copy=*/false);
  const std::vector<std::optional<dsm::SE3>> sources = {
      std::nullopt, geometry.T_world_neighbour,
      geometry.T_world_cam * (geometry.T_world_neighbour.Inverse() * geometry.T_world_cam)};
  auto time_builds = [&](const dsm::CaptureOperatorOptions& build_options, bool shared) {
    dsm::CaptureOperatorBuilder builder(build_options);
    dsm::CaptureOperator op;
    dsm::CaptureGeometry source_geometry = geometry;
    return MedianMs(repeats, [&] {
      dsm::VirtualDepths depths;
      if (shared) depths.Compute(geometry, build_options);
      for (const auto& source : sources) {
        source_geometry.T_world_source = source;
        if (shared)
          builder.Build(source_geometry, depths, &op);
        else
          builder.Build(source_geometry, &op);
      }
    });
  };
  const double alone = time_builds(options, false);
  const double shared = time_builds(options, true);
  dsm::CaptureOperatorOptions adaptive = options;
  adaptive.adaptive_samples = true;
  const double adaptive_shared = time_builds(adaptive, true);
  std::printf(
      "3 operators of one frame, 1 thread: each reprojecting %.1f ms, shared virtual depths %.1f ms (x%.2f); "
      "adaptive M = %d (blur %.1f HR px) with shared depths %.1f ms (x%.2f against the first)\n",
      alone, shared, alone / shared, dsm::CaptureSamples(geometry, adaptive), dsm::BlurLengthHr(geometry, 2),
      adaptive_shared, alone / adaptive_shared);
}

// The colour normal product, diagonal pass and A x over the row runs with
// the 4-lane kernels against the 8-lane ones (rgb_run_kernels.h),
// interleaved.
void BenchmarkRgbLanes(const dsm::RowRunMatrix& runs, const cv::Mat& weight, const cv::Mat& x, int repeats) {
  cv::Mat four(x.size(), x.type()), eight(x.size(), x.type());
  const auto timed = [&](bool eight_lanes, cv::Mat* out, bool diagonal) {
    return [&, eight_lanes, out, diagonal] {
      dsm::rgb_runs::Allow8LaneKernels(eight_lanes);
      out->setTo(0.0);
      if (diagonal) {
        dsm::AddWeightedNormalDiagonal(runs, weight, out, 1);
      } else {
        dsm::AddWeightedNormalProduct(runs, weight, x, out, 1);
      }
      dsm::rgb_runs::Allow8LaneKernels(true);
    };
  };
  const auto [four_ms, eight_ms] = InterleavedMedianMs(repeats, timed(false, &four, false), timed(true, &eight, false));
  const bool same = SameBits(four, eight);
  const auto [four_diagonal_ms, eight_diagonal_ms] =
      InterleavedMedianMs(repeats, timed(false, &four, true), timed(true, &eight, true));
  const bool same_diagonal = SameBits(four, eight);
  cv::Mat four_ax, eight_ax;
  const auto gather = [&](bool eight_lanes, cv::Mat* ax) {
    return [&, eight_lanes, ax] {
      dsm::rgb_runs::Allow8LaneKernels(eight_lanes);
      dsm::MultiplySparse(runs, x, ax, 1);
      dsm::rgb_runs::Allow8LaneKernels(true);
    };
  };
  const auto [four_ax_ms, eight_ax_ms] =
      InterleavedMedianMs(repeats, gather(false, &four_ax), gather(true, &eight_ax));
  std::printf(
      "colour, row runs, 1 thread: A^T W A x 4-lane %.2f ms, 8-lane %.2f ms (x%.2f, bit-identical: %s) | "
      "diagonal pass 4-lane %.2f ms, 8-lane %.2f ms (x%.2f, bit-identical: %s) | A x 4-lane %.2f ms, 8-lane "
      "%.2f ms (x%.2f, bit-identical: %s)\n",
      four_ms, eight_ms, four_ms / eight_ms, same ? "yes" : "no", four_diagonal_ms, eight_diagonal_ms,
      four_diagonal_ms / eight_diagonal_ms, same_diagonal ? "yes" : "no", four_ax_ms, eight_ax_ms,
      four_ax_ms / eight_ax_ms, SameBits(four_ax, eight_ax) ? "yes" : "no");
}

// One product with the weighted normal operator A^T W A, as a CG step of
// the image update makes it, and the diagonal pass of its preconditioner
// (one thread): streaming the operator's row runs once (gather, weigh,
// scatter) against the same pass over its CSR form, interleaved; and the
// CSR pass against two gathers, A x through the rows of A and A^T (W A x)
// through the rows of a transposed copy (also the time to make that copy).
void BenchmarkNormalProduct(const dsm::CaptureGeometry& geometry, int samples, int repeats) {
  const dsm::CaptureOperatorOptions options = OneThreadOptions(samples, /*transposed_copy=*/true);
  const dsm::CaptureOperator op = dsm::BuildCaptureOperator(geometry, options);
  const dsm::RowRunMatrix& runs = op.matrix();
  const dsm::SparseMatrixRM csr = runs.ToCsr();
  const int apply_repeats = repeats * 5;
  const double transpose_ms = MedianMs(repeats, [&] {
    dsm::SparseMatrixRM copy = csr.transpose();
    copy.makeCompressed();
  });
  for (int channels : {1, 3}) {
    cv::Mat x(op.hr_size(), CV_32FC(channels)), weight(op.lr_size(), CV_32FC(channels));
    cv::randu(x, 0.0f, 1.0f);
    cv::randu(weight, 0.5f, 2.0f);
    cv::Mat one_pass_csr(op.hr_size(), CV_32FC(channels)), one_pass_runs(op.hr_size(), CV_32FC(channels));
    const auto [csr_ms, runs_ms] = InterleavedMedianMs(
        apply_repeats,
        [&] {
          one_pass_csr.setTo(0.0);
          dsm::AddWeightedNormalProduct(csr, weight, x, &one_pass_csr, 1);
        },
        [&] {
          one_pass_runs.setTo(0.0);
          dsm::AddWeightedNormalProduct(runs, weight, x, &one_pass_runs, 1);
        });
    cv::Mat diagonal_csr(op.hr_size(), CV_32FC(channels)), diagonal_runs(op.hr_size(), CV_32FC(channels));
    const auto [diagonal_csr_ms, diagonal_runs_ms] = InterleavedMedianMs(
        apply_repeats,
        [&] {
          diagonal_csr.setTo(0.0);
          dsm::AddWeightedNormalDiagonal(csr, weight, &diagonal_csr, 1);
        },
        [&] {
          diagonal_runs.setTo(0.0);
          dsm::AddWeightedNormalDiagonal(runs, weight, &diagonal_runs, 1);
        });
    cv::Mat lr, two_gathers;
    const double two_gathers_ms = MedianMs(apply_repeats, [&] {
      dsm::MultiplySparse(csr, x, &lr, 1);
      lr = lr.reshape(channels, op.lr_size().height).mul(weight);
      op.ApplyAdjoint(lr, &two_gathers);
    });
    std::printf(
        "normal product A^T W A x, 1 thread, %d channel(s): one pass over the row runs %.2f ms, over CSR "
        "%.2f "
        "ms (CSR / runs x%.2f, bit-identical: %s) | diagonal pass runs %.2f ms, CSR %.2f ms (x%.2f, "
        "bit-identical: %s) | CSR: two gathers through a transposed copy %.2f ms (one pass / two gathers "
        "x%.2f; the copy %.1f ms; max difference %.1e)\n",
        channels, runs_ms, csr_ms, csr_ms / runs_ms, SameBits(one_pass_runs, one_pass_csr) ? "yes" : "no",
        diagonal_runs_ms, diagonal_csr_ms, diagonal_csr_ms / diagonal_runs_ms,
        SameBits(diagonal_runs, diagonal_csr) ? "yes" : "no", two_gathers_ms, csr_ms / two_gathers_ms,
        transpose_ms, cv::norm(one_pass_csr, two_gathers, cv::NORM_INF));
    if (channels == 3 && dsm::rgb_runs::Use8LaneKernels()) BenchmarkRgbLanes(runs, weight, x, apply_repeats);
  }
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
      "(gray) %.2f ms (rgb) | nnz %.2f M (%.1f per LR pixel), %.0f MiB for Psi (row runs) and Psi^T (CSR)\n",
      threads, build_ms, apply_gray, apply_color, adjoint_gray, adjoint_color, nnz / 1e6,
      nnz / op.matrix().rows(), (op.matrix().Bytes() + nnz * 8.0) / (1 << 20));
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
  bool row_layout = false, shared_depths = false, normal_product = false;
  cli.add_flag("--row-layout", row_layout,
               "also time Psi_t and Psi_t^T over the operator's row runs against its CSR form");
  cli.add_flag("--shared-depths", shared_depths,
               "also time building the operators of 3 sources of one frame with and without shared virtual "
               "depths, and adaptive M");
  cli.add_flag(
      "--normal-product", normal_product,
      "also time A^T W A x and its diagonal in one pass over the row runs against CSR, and against two "
      "gathers through a transposed copy");
  if (!cli.Parse(argc, argv)) return 0;
  dsm::CaptureGeometry geometry = BenchmarkGeometry();
  geometry.readout_time = readout_ratio * (geometry.stamp - geometry.neighbour_stamp);
  std::printf(
      "capture operator benchmark: 640x480 -> 320x240, M = %d, scale 2, readout %.2f x frame interval, "
      "median of %d\n",
      samples, readout_ratio, repeats);
  std::printf("machine threads available: %d\n", omp_get_max_threads());
  for (int threads : {1, 2}) BenchmarkThreads(geometry, threads, samples, repeats);
  if (row_layout) BenchmarkRunLayout(geometry, samples, repeats);
  if (shared_depths) BenchmarkSharedDepths(geometry, samples, repeats);
  if (normal_product) BenchmarkNormalProduct(geometry, samples, repeats);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  return deblur_sr_mvs::ToolMain("benchmark_capture_operator", Run, argc, argv);
}
