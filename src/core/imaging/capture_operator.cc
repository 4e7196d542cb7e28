#include "deblur_sr_mvs/core/imaging/capture_operator.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <optional>
#include <sstream>
#include <type_traits>

#include <opencv2/imgproc.hpp>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/common/options_check.h"
#include "deblur_sr_mvs/core/common/runtime.h"
#include "deblur_sr_mvs/core/geometry/warp.h"
#include "deblur_sr_mvs/core/imaging/normal_product.h"
#include "deblur_sr_mvs/core/imaging/rgb_run_kernels.h"

namespace deblur_sr_mvs {
namespace {

// Fractions within 1e-4 px of 0 or 1 (float rounding) are snapped, so an exact integer warp
// (zero motion) yields single taps instead of 1e-13 neighbours.
constexpr float kSnap = 1e-4f;
constexpr float kInsideTolerance = 1e-4f;

// Merging taps through a local dense grid is O(grid area); above this area
// (extreme blur) a scatter array plus a sort is cheaper.
constexpr int kMaxLocalGrid = 4096;

// y = A x for a row-major sparse A (CSR or row runs, see RowSpansOf) and
// interleaved C-channel images; each row in the partial sums of
// GatherRowChains.
template <int kChannels, typename Rows>
void MultiplyFixed(const Rows& a, int rows, const float* x, float* y, int threads) {
#pragma omp parallel for schedule(static) num_threads(threads)
  for (int r = 0; r < rows; ++r) {
    GatherRowChains<kChannels>(a, r, x, y + static_cast<std::ptrdiff_t>(r) * kChannels);
  }
}

// MultiplyFixed<3> over row runs with one 4-lane vector per pixel, or two
// taps per 8-lane vector where the CPU has them (rgb_run_kernels.h): the
// same values, bit for bit.
void MultiplyRgbRuns(const RunRowSpans& a, int rows, int cols, const float* x, float* y, int threads) {
  const bool eight = rgb_runs::Use8LaneKernels();
#pragma omp parallel for schedule(static) num_threads(threads)
  for (int r = 0; r < rows; ++r) {
    const rgb_runs::Float4 sum = eight ? rgb_runs::GatherRow8(a, r, x, cols) : rgb_runs::GatherRow(a, r, x, cols);
    float* py = y + static_cast<std::ptrdiff_t>(r) * 3;
    for (int c = 0; c < 3; ++c) py[c] = sum[c];
  }
}

// at = a^T (both row-major, compressed) with `threads` threads: per-thread
// column histograms of contiguous row blocks, one prefix sum, then each thread
// scatters its block to disjoint slots. Row indices come out sorted.
}  // namespace

void TransposeSparse(const SparseMatrixRM& a, SparseMatrixRM* at, int threads) {
  const int rows = static_cast<int>(a.rows());
  const int cols = static_cast<int>(a.cols());
  const int* outer = a.outerIndexPtr();
  const int* inner = a.innerIndexPtr();
  const float* values = a.valuePtr();
  std::vector<int> slots(static_cast<size_t>(threads) * cols, 0);
  at->resize(cols, rows);
  at->resizeNonZeros(a.nonZeros());
  int* at_outer = at->outerIndexPtr();
  int* at_inner = at->innerIndexPtr();
  float* at_values = at->valuePtr();
#pragma omp parallel num_threads(threads)
  {
    const int thread = omp_get_thread_num();
    const int first = static_cast<int>(static_cast<long long>(rows) * thread / threads);
    const int last = static_cast<int>(static_cast<long long>(rows) * (thread + 1) / threads);
    int* count = slots.data() + static_cast<size_t>(thread) * cols;
    for (int k = outer[first]; k < outer[last]; ++k) ++count[inner[k]];
#pragma omp barrier
#pragma omp single
    {
      int running = 0;
      for (int c = 0; c < cols; ++c) {
        at_outer[c] = running;
        for (int t = 0; t < threads; ++t) {
          int& slot = slots[static_cast<size_t>(t) * cols + c];
          const int n = slot;
          slot = running;
          running += n;
        }
      }
      at_outer[cols] = running;
    }  // implicit barrier
    for (int r = first; r < last; ++r) {
      for (int k = outer[r]; k < outer[r + 1]; ++k) {
        const int position = count[inner[k]]++;
        at_inner[position] = r;
        at_values[position] = values[k];
      }
    }
  }
}

namespace {

template <typename Matrix>
void MultiplyAnyChannels(const Matrix& a, const float* x, float* y, int channels, int threads) {
  const auto rows = RowSpansOf(a);
  const int n = static_cast<int>(a.rows());
  switch (channels) {
    case 1:
      MultiplyFixed<1>(rows, n, x, y, threads);
      return;
    case 2:
      MultiplyFixed<2>(rows, n, x, y, threads);
      return;
    case 3:
      if constexpr (std::is_same_v<Matrix, RowRunMatrix>) {
        MultiplyRgbRuns(rows, n, static_cast<int>(a.cols()), x, y, threads);
      } else {
        MultiplyFixed<3>(rows, n, x, y, threads);
      }
      return;
    case 4:
      MultiplyFixed<4>(rows, n, x, y, threads);
      return;
    default:
      break;
  }
  throw InputError("capture operator: images must have 1 to 4 channels");
}

template <typename Matrix>
void Multiply(const Matrix& a, const cv::Size& in_size, const cv::Size& out_size, const cv::Mat& in,
              cv::Mat* out, int threads, const char* what) {
  if (in.depth() != CV_32F || in.size() != in_size) {
    std::ostringstream message;
    message << "capture operator " << what << ": expected a float image of " << in_size.width << "x"
            << in_size.height << ", got " << in.cols << "x" << in.rows << " (depth " << in.depth() << ")";
    throw InputError(message.str());
  }
  const int channels = in.channels();
  const cv::Mat source = in.isContinuous() ? in : in.clone();
  out->create(out_size, CV_32FC(channels));
  MultiplyAnyChannels(a, source.ptr<float>(), out->ptr<float>(), channels, threads);
}

}  // namespace

SE3 PoseAtTime(const CaptureGeometry& geometry, double tau) {
  if (geometry.T_world_second_neighbour.has_value()) {
    std::vector<TimedPose> nodes = {{geometry.T_world_neighbour, geometry.neighbour_stamp},
                                    {*geometry.T_world_second_neighbour, geometry.second_neighbour_stamp}};
    if (geometry.T_world_third_neighbour.has_value()) {
      nodes.push_back({*geometry.T_world_third_neighbour, geometry.third_neighbour_stamp});
    }
    return PoseOnPolynomialPath(nodes, geometry.T_world_cam, geometry.stamp, tau);
  }
  // eq:interpolatingP: alpha = (tau - s) / (t - s) also extrapolates
  // backwards when s follows t, and forwards past t.
  return PoseAtTime(geometry.T_world_neighbour, geometry.neighbour_stamp, geometry.T_world_cam,
                    geometry.stamp, tau);
}

std::vector<int> BlurPathFrames(int t, int num_frames) {
  if (num_frames < 2 || t < 0 || t >= num_frames) {
    throw InputError("BlurPathFrames: needs >= 2 frames and a frame inside them");
  }
  if (num_frames == 2) return {1 - t};
  if (t == 0) return {1, 2};
  if (t == num_frames - 1) return {t - 1, t - 2};
  if (num_frames == 3) return {0, 2};
  if (t == 1) return {0, 2, 3};
  return {t - 1, t + 1, t - 2};
}

void SetBlurPath(const std::vector<SE3>& T_world_cam, const std::vector<double>& stamps, int t,
                 CaptureGeometry* geometry) {
  if (T_world_cam.size() != stamps.size()) throw InputError("SetBlurPath: poses and stamps differ in number");
  const std::vector<int> path = BlurPathFrames(t, static_cast<int>(stamps.size()));
  geometry->T_world_cam = T_world_cam[t];
  geometry->stamp = stamps[t];
  geometry->T_world_neighbour = T_world_cam[path[0]];
  geometry->neighbour_stamp = stamps[path[0]];
  geometry->T_world_second_neighbour.reset();
  geometry->second_neighbour_stamp = 0.0;
  geometry->T_world_third_neighbour.reset();
  geometry->third_neighbour_stamp = 0.0;
  if (path.size() > 1) {
    geometry->T_world_second_neighbour = T_world_cam[path[1]];
    geometry->second_neighbour_stamp = stamps[path[1]];
  }
  if (path.size() > 2) {
    geometry->T_world_third_neighbour = T_world_cam[path[2]];
    geometry->third_neighbour_stamp = stamps[path[2]];
  }
}

void MoveBlurPath(const SE3& T_world_target, double target_stamp, CaptureGeometry* geometry) {
  const SE3 T_target_cam = T_world_target * geometry->T_world_cam.Inverse();
  const double shift = target_stamp - geometry->stamp;
  geometry->T_world_neighbour = T_target_cam * geometry->T_world_neighbour;
  geometry->neighbour_stamp += shift;
  if (geometry->T_world_second_neighbour.has_value()) {
    geometry->T_world_second_neighbour = T_target_cam * *geometry->T_world_second_neighbour;
    geometry->second_neighbour_stamp += shift;
  }
  if (geometry->T_world_third_neighbour.has_value()) {
    geometry->T_world_third_neighbour = T_target_cam * *geometry->T_world_third_neighbour;
    geometry->third_neighbour_stamp += shift;
  }
  geometry->T_world_cam = T_world_target;
  geometry->stamp = target_stamp;
}

namespace {

// tau_m of the rows that open `row_delay` after row 0.
double SampleTime(const CaptureGeometry& geometry, int samples, double row_delay, int m) {
  return geometry.stamp - geometry.exposure + row_delay + (m + 0.5) / samples * geometry.exposure;
}

}  // namespace

std::vector<SE3> VirtualCameraPoses(const CaptureGeometry& geometry, int samples, double row_delay) {
  // tau_m = t_o + ((m - 1/2)/M)(t_c - t_o), m = 1..M, on the path of
  // eq:interpolatingP. eq:blurOperator takes m/M, the right end of each of
  // the M slices of the exposure: its mean instant is then (M + 1)/(2M) of
  // the way, not the middle, so the modelled blur sits half a slice late and
  // the restored image shifts to compensate (0.13 HR px on average at 14 px
  // of blur and M 50 on the synthetic scenes). The midpoint of each slice
  // integrates the exposure without that bias (0.03 px).
  std::vector<SE3> poses;
  poses.reserve(samples);
  for (int m = 0; m < samples; ++m)
    poses.push_back(PoseAtTime(geometry, SampleTime(geometry, samples, row_delay, m)));
  return poses;
}

double RowDelay(const CaptureGeometry& geometry, int lr_row, int lr_rows) {
  return geometry.readout_time * lr_row / lr_rows;
}

void RecentreOnShutterClose(const CaptureGeometry& geometry, int scale, const cv::Mat& inverse_depth,
                            const cv::Mat& image, cv::Mat* out, cv::Mat* valid) {
  const PinholeCamera& camera = geometry.camera_hr;
  const int width = inverse_depth.cols, height = inverse_depth.rows;
  const int lr_rows = std::max(1, height / scale);
  cv::Mat map_x(inverse_depth.size(), CV_32FC1), map_y(inverse_depth.size(), CV_32FC1);
  valid->create(inverse_depth.size(), CV_8UC1);
  int transfer_row = -1;
  std::optional<PixelTransfer> close_to_mid;
  for (int y = 0; y < height; ++y) {
    // The mid-exposure camera of this row's LR row (one per image with a
    // global shutter).
    const int lr_row = geometry.readout_time > 0.0 ? std::min(y / scale, lr_rows - 1) : 0;
    if (lr_row != transfer_row) {
      const double tau = geometry.stamp - 0.5 * geometry.exposure + RowDelay(geometry, lr_row, lr_rows);
      close_to_mid.emplace(camera, PoseAtTime(geometry, tau).Inverse() * geometry.T_world_cam);
      transfer_row = lr_row;
    }
    const float* rho = inverse_depth.ptr<float>(y);
    float* u_out = map_x.ptr<float>(y);
    float* v_out = map_y.ptr<float>(y);
    uint8_t* ok = valid->ptr<uint8_t>(y);
    for (int x = 0; x < width; ++x) {
      u_out[x] = static_cast<float>(x);
      v_out[x] = static_cast<float>(y);
      ok[x] = 0;
      Eigen::Vector2d uv;
      if (!(rho[x] > 0.0f && std::isfinite(rho[x])) || !close_to_mid->Warp(x, y, 1.0 / rho[x], &uv)) continue;
      u_out[x] = static_cast<float>(uv.x());
      v_out[x] = static_cast<float>(uv.y());
      if (uv.x() >= 1.0 && uv.y() >= 1.0 && uv.x() <= width - 2.0 && uv.y() <= height - 2.0) ok[x] = 255;
    }
  }
  cv::remap(image, *out, map_x, map_y, cv::INTER_LINEAR, cv::BORDER_REPLICATE);
}

void CaptureOperatorOptions::Check() const {
  CheckInRange("capture operator: samples (M)", samples, 1, 10000);
  CheckInRange("capture operator: samples_per_pixel", samples_per_pixel, 0.01, 100.0);
  CheckInRange("capture operator: min_samples", min_samples, 1, 10000);
  CheckInRange("capture operator: scale", scale, 1, 8);
  CheckAtLeast("capture operator: num_threads", num_threads, 0);
}

void CaptureOperator::Apply(const cv::Mat& hr, cv::Mat* lr) const {
  Multiply(forward_, hr_size_, lr_size_, hr, lr, num_threads_, "Apply");
}

namespace {

template <typename Matrix>
void MultiplyMatrix(const Matrix& a, const cv::Mat& in, cv::Mat* out, int threads) {
  if (in.depth() != CV_32F || in.rows * in.cols != a.cols()) {
    throw InputError("MultiplySparse: input must be a float image with one pixel per column");
  }
  const int channels = in.channels();
  const cv::Mat source = in.isContinuous() ? in : in.clone();
  out->create(static_cast<int>(a.rows()), 1, CV_32FC(channels));
  MultiplyAnyChannels(a, source.ptr<float>(), out->ptr<float>(), channels, ResolveThreads(threads));
}

}  // namespace

void MultiplySparse(const SparseMatrixRM& a, const cv::Mat& in, cv::Mat* out, int threads) {
  MultiplyMatrix(a, in, out, threads);
}

void MultiplySparse(const RowRunMatrix& a, const cv::Mat& in, cv::Mat* out, int threads) {
  MultiplyMatrix(a, in, out, threads);
}

void CaptureOperator::ApplyAdjoint(const cv::Mat& lr, cv::Mat* hr) const {
  if (adjoint_.nonZeros() > 0 || forward_.nonZeros() == 0) {
    Multiply(adjoint_, lr_size_, hr_size_, lr, hr, num_threads_, "ApplyAdjoint");
    return;
  }
  // No transposed copy: scatter each row of Psi into the HR image.
  if (lr.depth() != CV_32F || lr.size() != lr_size_) {
    throw InputError("capture operator ApplyAdjoint: expected a float image of the LR size");
  }
  const int channels = lr.channels();
  if (channels < 1 || channels > 4) throw InputError("capture operator: images must have 1 to 4 channels");
  const cv::Mat source = lr.isContinuous() ? lr : lr.clone();
  hr->create(hr_size_, CV_32FC(channels));
  hr->setTo(0.0);
  AddAdjointProduct(forward_, source, hr, 1);
}

namespace {

// Throws InputError unless the geometry fits an operator of factor `scale`.
void CheckCaptureGeometry(const CaptureGeometry& geometry, int scale) {
  const PinholeCamera& camera = geometry.camera_hr;
  {
    const std::string problem = camera.Problem();
    if (!problem.empty()) throw InputError("capture operator: " + problem);
  }
  if (camera.width < 2 || camera.height < 2 || camera.width % scale != 0 || camera.height % scale != 0) {
    throw InputError("capture operator: HR size " + std::to_string(camera.width) + "x" +
                     std::to_string(camera.height) + " must be at least 2x2 and divisible by scale " +
                     std::to_string(scale));
  }
  if (geometry.depth_hr.type() != CV_32FC1 || geometry.depth_hr.cols != camera.width ||
      geometry.depth_hr.rows != camera.height) {
    throw InputError("capture operator: depth must be CV_32FC1 of the HR camera size");
  }
  if (!(geometry.exposure > 0.0) || !std::isfinite(geometry.exposure)) {
    throw InputError("capture operator: exposure must be > 0");
  }
  if (!(geometry.readout_time >= 0.0) || !std::isfinite(geometry.readout_time)) {
    throw InputError("capture operator: readout_time must be finite and >= 0");
  }
  const double frame_gap = geometry.stamp - geometry.neighbour_stamp;
  if (!std::isfinite(frame_gap) || frame_gap == 0.0) {
    throw InputError("capture operator: the neighbour's stamp must differ from the frame's");
  }
  if (geometry.T_world_second_neighbour.has_value()) {
    const double s2 = geometry.second_neighbour_stamp;
    if (!std::isfinite(s2) || s2 == geometry.stamp || s2 == geometry.neighbour_stamp) {
      throw InputError("capture operator: the second neighbour's stamp must differ from the other two");
    }
  }
}

// Everything the rows of one operator share: sizes, the M warps
// W^{tau_m -> src} (eq:warpingFunction) as structure-of-arrays over m so that
// the per-sample loop vectorises, with their row-constant parts precomputed
// per HR row, and the depth D_tau_m each virtual camera sees. A global
// shutter has one set of M warps; a rolling shutter one set per LR row
// (`transfers` and `depth` hold sets * M entries, set-major).
struct AssemblyContext {
  int hr_width = 0, hr_height = 0, lr_width = 0, lr_height = 0;
  int scale = 1, samples = 1, samples_per_pixel = 1;
  bool per_row = false;  // one set of warps per LR row (rolling shutter)
  float sample_weight = 1.0f;
  float max_u = 0.0f, max_v = 0.0f;
  std::vector<const float*> virtual_depth;    // D_tau_m, row-major HR, [set * samples + m]
  std::vector<float> h0, h3, h6, t0, t1, t2;  // [set * samples + m]
  std::vector<float> row_bases;               // [(y * 3 + k) * samples + m]

  AssemblyContext(const PinholeCamera& camera, int scale_in, int samples_in,
                  const std::vector<PixelTransferF>& transfers, const std::vector<const cv::Mat*>& depth)
      : hr_width(camera.width),
        hr_height(camera.height),
        lr_width(camera.width / scale_in),
        lr_height(camera.height / scale_in),
        scale(scale_in),
        samples(samples_in),
        samples_per_pixel(samples_in * scale_in * scale_in),
        per_row(static_cast<int>(transfers.size()) != samples_in),
        sample_weight(1.0f / static_cast<float>(samples_in * scale_in * scale_in)),
        max_u(static_cast<float>(camera.width - 1)),
        max_v(static_cast<float>(camera.height - 1)),
        virtual_depth(transfers.size()),
        h0(transfers.size()),
        h3(transfers.size()),
        h6(transfers.size()),
        t0(transfers.size()),
        t1(transfers.size()),
        t2(transfers.size()),
        row_bases(static_cast<size_t>(camera.height) * 3 * samples_in) {
    for (size_t i = 0; i < transfers.size(); ++i) {
      virtual_depth[i] = depth[i]->ptr<float>();
      h0[i] = transfers[i].h[0];
      h3[i] = transfers[i].h[3];
      h6[i] = transfers[i].h[6];
      t0[i] = transfers[i].t[0];
      t1[i] = transfers[i].t[1];
      t2[i] = transfers[i].t[2];
    }
    for (int y = 0; y < hr_height; ++y) {
      const int set = SetOfRow(y);
      for (int m = 0; m < samples; ++m) {
        float base[3];
        transfers[set * samples + m].RowBase(static_cast<float>(y), base);
        for (int k = 0; k < 3; ++k) row_bases[(static_cast<size_t>(y) * 3 + k) * samples + m] = base[k];
      }
    }
  }
  // The set of warps of HR row y.
  int SetOfRow(int y) const { return per_row ? y / scale : 0; }
};

// Per-thread scratch of one LR pixel: its M * scale^2 bilinear taps
// (structure of arrays) and the buffers that merge them.
struct PixelScratch {
  std::vector<float> depth;
  std::vector<int> tap_x, tap_y;
  std::vector<float> frac_x, frac_y;
  std::vector<float> cells;       // the local grid with a zero row above and column to the left
  std::vector<int> grid_columns;  // a grid's non-zero taps before they are appended
  std::vector<float> grid_values;
  std::vector<float> scatter;  // fallback for huge footprints
  std::vector<int> touched;
  std::vector<float> touched_values;

  explicit PixelScratch(const AssemblyContext& context)
      : depth(context.samples),
        tap_x(context.samples_per_pixel),
        tap_y(context.samples_per_pixel),
        frac_x(context.samples_per_pixel),
        frac_y(context.samples_per_pixel),
        cells(4 * (2 * kMaxLocalGrid + 2)),
        grid_columns(kMaxLocalGrid),
        grid_values(kMaxLocalGrid) {}
};

// Bounding box of the taps (the top-left taps of the bilinear stencils; the
// right and bottom taps are added by Include()).
struct TapBox {
  int min_x, max_x, min_y, max_y;
  int Width() const { return max_x - min_x + 1; }
  int Height() const { return max_y - min_y + 1; }
  // The empty box of an image.
  static TapBox Empty(const AssemblyContext& context) {
    return {context.hr_width, -1, context.hr_height, -1};
  }
  // The box of the taps whose top-left taps span `top_left`.
  void Include(const TapBox& top_left) {
    min_x = std::min(min_x, top_left.min_x);
    max_x = std::max(max_x, top_left.max_x + 1);
    min_y = std::min(min_y, top_left.min_y);
    max_y = std::max(max_y, top_left.max_y + 1);
  }
};

// The taps of HR pixel (x, y) for every virtual camera, written at `offset`
// of the scratch, and the box of their top-left taps (`top_left`, grown);
// returns how many samples missed the source image.
inline int WarpHrPixel(const AssemblyContext& context, int x, int y, int offset, PixelScratch* scratch,
                       TapBox* top_left) {
  const int samples = context.samples;
  const float* base0 = &context.row_bases[(static_cast<size_t>(y) * 3 + 0) * samples];
  const float* base1 = base0 + samples;
  const float* base2 = base1 + samples;
  const size_t pixel = static_cast<size_t>(y) * context.hr_width + x;
  const size_t set_offset = static_cast<size_t>(context.SetOfRow(y)) * samples;
  const float* const* virtual_depth = context.virtual_depth.data() + set_offset;
  for (int m = 0; m < samples; ++m) scratch->depth[m] = virtual_depth[m][pixel];
  int* out_x = scratch->tap_x.data() + offset;
  int* out_y = scratch->tap_y.data() + offset;
  float* out_fx = scratch->frac_x.data() + offset;
  float* out_fy = scratch->frac_y.data() + offset;
  const float xf = static_cast<float>(x);
  const float yf = static_cast<float>(y);
  const float max_u = context.max_u;
  const float max_v = context.max_v;
  const int hr_width = context.hr_width;
  const int hr_height = context.hr_height;
  // W^{tau_m -> src}(x) for every virtual camera (eq:warpingFunction);
  // unknown depth or a point behind the camera samples x itself, and
  // samples outside the image are clamped (border replicated); both
  // count as misses in the coverage.
  const float* __restrict depth_m = scratch->depth.data();
  const float* __restrict c_h0 = context.h0.data() + set_offset;
  const float* __restrict c_h3 = context.h3.data() + set_offset;
  const float* __restrict c_h6 = context.h6.data() + set_offset;
  const float* __restrict c_t0 = context.t0.data() + set_offset;
  const float* __restrict c_t1 = context.t1.data() + set_offset;
  const float* __restrict c_t2 = context.t2.data() + set_offset;
  int misses = 0;
  int min_x = top_left->min_x, max_x = top_left->max_x, min_y = top_left->min_y, max_y = top_left->max_y;
#pragma omp simd reduction(+ : misses) reduction(min : min_x, min_y) reduction(max : max_x, max_y)
  for (int m = 0; m < samples; ++m) {
    const float d = depth_m[m];
    const float z = d * (c_h6[m] * xf + base2[m]) + c_t2[m];
    const float inv_z = 1.0f / z;
    float u = (d * (c_h0[m] * xf + base0[m]) + c_t0[m]) * inv_z;
    float v = (d * (c_h3[m] * xf + base1[m]) + c_t1[m]) * inv_z;
    // Bitwise & (no short-circuit branches) keeps the loop vectorisable.
    const bool usable = (d > 0.0f) & (d < 1e30f) & (z > 1e-9f);
    u = usable ? u : xf;
    v = usable ? v : yf;
    const bool inside = usable & (u >= -kInsideTolerance) & (v >= -kInsideTolerance) &
                        (u <= max_u + kInsideTolerance) & (v <= max_v + kInsideTolerance);
    misses += inside ? 0 : 1;
    u = std::min(std::max(u, 0.0f), max_u);
    v = std::min(std::max(v, 0.0f), max_v);
    const int ix = std::min(static_cast<int>(u), hr_width - 2);
    const int iy = std::min(static_cast<int>(v), hr_height - 2);
    float fx = u - static_cast<float>(ix);
    float fy = v - static_cast<float>(iy);
    fx = fx < kSnap ? 0.0f : (fx > 1.0f - kSnap ? 1.0f : fx);
    fy = fy < kSnap ? 0.0f : (fy > 1.0f - kSnap ? 1.0f : fy);
    out_x[m] = ix;
    out_y[m] = iy;
    out_fx[m] = fx;
    out_fy[m] = fy;
    min_x = std::min(min_x, ix);
    max_x = std::max(max_x, ix);
    min_y = std::min(min_y, iy);
    max_y = std::max(max_y, iy);
  }
  *top_left = {min_x, max_x, min_y, max_y};
  return misses;
}

// Merges the taps in a local dense grid. Each sample adds its four bilinear
// weights to ONE cell as a 4-vector (top-left, top-right, bottom-left,
// bottom-right); the stencil is unfolded when the grid is emitted. Emitting
// in raster order gives sorted column indices. The grid has a zero row
// above and a zero column to the left, so every cell adds its four parts
// (the missing neighbours' are +0: the same sums, as the weights are never
// negative) without branches, and the non-zero cells are kept by a
// branch-free compaction.
void MergeTapsInGrid(const AssemblyContext& context, const TapBox& box, PixelScratch* scratch,
                     RowRunMatrix::RowBlock* block) {
  const int grid_width = box.Width();
  const int grid_height = box.Height();
  const int stride = grid_width + 1;  // in cells
  const float sample_weight = context.sample_weight;
  std::fill(scratch->cells.begin(), scratch->cells.begin() + 4 * stride * (grid_height + 1), 0.0f);
  float* __restrict c = scratch->cells.data();
  for (int k = 0; k < context.samples_per_pixel; ++k) {
    const float wy1 = scratch->frac_y[k] * sample_weight;
    const float wy0 = sample_weight - wy1;
    const float fx = scratch->frac_x[k];
    float* cell =
        c + 4 * ((scratch->tap_y[k] - box.min_y + 1) * stride + (scratch->tap_x[k] - box.min_x + 1));
    cell[0] += (1.0f - fx) * wy0;
    cell[1] += fx * wy0;
    cell[2] += (1.0f - fx) * wy1;
    cell[3] += fx * wy1;
  }
  int* __restrict out_columns = scratch->grid_columns.data();
  float* __restrict out_values = scratch->grid_values.data();
  int count = 0;
  for (int gy = 0; gy < grid_height; ++gy) {
    const float* here = c + 4 * ((gy + 1) * stride + 1);
    const float* above = here - 4 * stride;
    const int base = (box.min_y + gy) * context.hr_width + box.min_x;
    for (int gx = 0; gx < grid_width; ++gx) {
      const float value = here[4 * gx] + here[4 * gx - 3] + above[4 * gx + 2] + above[4 * gx - 1];
      out_columns[count] = base + gx;
      out_values[count] = value;
      count += value != 0.0f ? 1 : 0;
    }
  }
  block->AppendRow(out_columns, out_values, count);
}

// Merges the taps of a footprint too large for a local grid (extreme blur)
// through an image-sized scatter array and a sort of the touched columns.
void MergeTapsScattered(const AssemblyContext& context, PixelScratch* scratch,
                        RowRunMatrix::RowBlock* block) {
  const int hr_width = context.hr_width;
  const float sample_weight = context.sample_weight;
  std::vector<float>& scatter = scratch->scatter;
  std::vector<int>& touched = scratch->touched;
  if (scatter.empty()) scatter.assign(static_cast<size_t>(hr_width) * context.hr_height, 0.0f);
  auto add = [&](int index, float w) {
    if (w == 0.0f) return;
    if (scatter[index] == 0.0f) touched.push_back(index);
    scatter[index] += w;
  };
  for (int k = 0; k < context.samples_per_pixel; ++k) {
    const int index = scratch->tap_y[k] * hr_width + scratch->tap_x[k];
    const float wy1 = scratch->frac_y[k] * sample_weight;
    const float wy0 = sample_weight - wy1;
    const float fx = scratch->frac_x[k];
    add(index, (1.0f - fx) * wy0);
    add(index + 1, fx * wy0);
    add(index + hr_width, (1.0f - fx) * wy1);
    add(index + hr_width + 1, fx * wy1);
  }
  std::sort(touched.begin(), touched.end());
  std::vector<float>& touched_values = scratch->touched_values;
  touched_values.clear();
  for (int index : touched) {
    touched_values.push_back(scatter[index]);
    scatter[index] = 0.0f;
  }
  block->AppendRow(touched.data(), touched_values.data(), static_cast<int>(touched.size()));
  touched.clear();
}

// The rows [first_row, last_row) of Psi (LR rows) into one thread's block
// of row runs: per LR pixel, the taps of its scale^2 HR pixels for every
// virtual camera, merged into one sparse row; and its coverage.
void AssembleRows(const AssemblyContext& context, int first_row, int last_row, std::vector<float>* coverage,
                  RowRunMatrix::RowBlock* block) {
  const int scale = context.scale;
  const int lr_width = context.lr_width;
  block->Clear();
  PixelScratch scratch(context);
  for (int lr_y = first_row; lr_y < last_row; ++lr_y) {
    for (int lr_x = 0; lr_x < lr_width; ++lr_x) {
      const int row = lr_y * lr_width + lr_x;
      int misses = 0;
      TapBox top_left = TapBox::Empty(context);
      for (int sub_y = 0; sub_y < scale; ++sub_y) {
        for (int sub_x = 0; sub_x < scale; ++sub_x) {
          misses += WarpHrPixel(context, lr_x * scale + sub_x, lr_y * scale + sub_y,
                                (sub_y * scale + sub_x) * context.samples, &scratch, &top_left);
        }
      }
      TapBox box = TapBox::Empty(context);
      box.Include(top_left);
      (*coverage)[row] = 1.0f - static_cast<float>(misses) / context.samples_per_pixel;
      if (box.Width() * box.Height() <= kMaxLocalGrid) {
        MergeTapsInGrid(context, box, &scratch, block);
      } else {
        MergeTapsScattered(context, &scratch, block);
      }
    }
  }
}

// The instants of the virtual cameras whose depth is reprojected from D_t.
// A global shutter: tau_m itself. A rolling shutter has M * H virtual cameras
// but only K reprojected depths (DepthCameraCount), at instants evenly spread
// from the first row's first sample to the last row's last; each virtual
// camera reads the nearest (D_tau changes only where the motion between the
// two instants crosses a depth edge).
struct DepthInstants {
  double first = 0.0;
  double step = 1.0;
  // The depth camera nearest to instant `tau`.
  int Nearest(double tau, int samples) const {
    return std::clamp(static_cast<int>(std::lround((tau - first) / step)), 0, samples - 1);
  }
};

DepthInstants PlanDepthInstants(const CaptureGeometry& geometry, int scale, int samples, int depth_count) {
  const int lr_rows = geometry.camera_hr.height / scale;
  DepthInstants instants;
  instants.first = SampleTime(geometry, samples, 0.0, 0);
  const double last = SampleTime(geometry, samples, RowDelay(geometry, lr_rows - 1, lr_rows), samples - 1);
  instants.step = depth_count > 1 ? (last - instants.first) / (depth_count - 1) : 1.0;
  return instants;
}

// T_tau_t of the cameras whose depth D_tau is reprojected from D_t: the M
// virtual cameras of a global shutter, the K depth cameras of a rolling one.
std::vector<SE3> DepthCameras(const CaptureGeometry& geometry, int scale, int samples, int depth_count) {
  std::vector<SE3> T_depth_t;
  if (geometry.readout_time == 0.0) {
    for (const SE3& T_world_tau : VirtualCameraPoses(geometry, samples))
      T_depth_t.push_back(T_world_tau.Inverse() * geometry.T_world_cam);
    return T_depth_t;
  }
  const DepthInstants instants = PlanDepthInstants(geometry, scale, samples, depth_count);
  for (int k = 0; k < depth_count; ++k) {
    T_depth_t.push_back(PoseAtTime(geometry, instants.first + k * instants.step).Inverse() *
                        geometry.T_world_cam);
  }
  return T_depth_t;
}

// The virtual cameras of one operator: their warps into the source camera
// (one set of M for a global shutter, one per LR row for a rolling shutter)
// and, for each, the depth camera (DepthCameras) it reads.
struct VirtualCameras {
  std::vector<PixelTransferF> transfers;  // [set * samples + m]
  std::vector<int> depth_index;           // the entry of DepthCameras each one reads
};

VirtualCameras PlanVirtualCameras(const CaptureGeometry& geometry, int scale, int samples, int depth_count) {
  const PinholeCamera& camera = geometry.camera_hr;
  const SE3 T_t_world = geometry.T_world_cam.Inverse();
  const SE3 T_source_world = geometry.T_world_source ? geometry.T_world_source->Inverse() : T_t_world;
  VirtualCameras cameras;
  if (geometry.readout_time == 0.0) {
    for (const SE3& T_world_tau : VirtualCameraPoses(geometry, samples)) {
      cameras.depth_index.push_back(static_cast<int>(cameras.transfers.size()));
      cameras.transfers.emplace_back(PixelTransfer(camera, T_source_world * T_world_tau));
    }
    return cameras;
  }
  const int lr_rows = camera.height / scale;
  const DepthInstants instants = PlanDepthInstants(geometry, scale, samples, depth_count);
  for (int y = 0; y < lr_rows; ++y) {
    const double delay = RowDelay(geometry, y, lr_rows);
    for (int m = 0; m < samples; ++m) {
      const double tau = SampleTime(geometry, samples, delay, m);
      cameras.transfers.emplace_back(PixelTransfer(camera, T_source_world * PoseAtTime(geometry, tau)));
      cameras.depth_index.push_back(instants.Nearest(tau, depth_count));
    }
  }
  return cameras;
}

bool SamePose(const SE3& a, const SE3& b) {
  return a.rotation() == b.rotation() && a.translation() == b.translation();
}

// Every 8th HR pixel and the last one of [0, size).
constexpr int kBlurGridStep = 8;
int NextGridPoint(int i, int size) {
  return i == size - 1 ? size : std::min(i + kBlurGridStep, size - 1);
}

// The opening time of LR row `lr_row`'s exposure window (its closing is
// `exposure` later).
double RowOpening(const CaptureGeometry& geometry, int lr_row, int lr_rows) {
  return geometry.stamp - geometry.exposure + RowDelay(geometry, lr_row, lr_rows);
}

// The poses, from the frame of the points (T_world_points) into the camera,
// at the opening and the closing of every LR row's exposure window: one
// entry for a global shutter (every row alike).
struct RowExposureEnds {
  std::vector<SE3> T_open_points, T_close_points;
  RowExposureEnds(const CaptureGeometry& geometry, int lr_rows, const SE3& T_world_points) {
    const int rows = geometry.readout_time > 0.0 ? lr_rows : 1;
    for (int y = 0; y < rows; ++y) {
      const double open = RowOpening(geometry, y, lr_rows);
      T_open_points.push_back(PoseAtTime(geometry, open).Inverse() * T_world_points);
      T_close_points.push_back(PoseAtTime(geometry, open + geometry.exposure).Inverse() * T_world_points);
    }
  }
  // The blur vector (opening minus closing position, HR pixels) of a point
  // seen in LR row `lr_row`; false when it is behind the camera.
  bool Blur(const PinholeCamera& camera, const Eigen::Vector3d& point, int lr_row, Eigen::Vector2d* blur) const {
    const size_t row = std::min<size_t>(static_cast<size_t>(std::max(lr_row, 0)), T_open_points.size() - 1);
    const Eigen::Vector3d at_open = T_open_points[row] * point;
    const Eigen::Vector3d at_close = T_close_points[row] * point;
    if (!(at_open.z() > 1e-9 && at_close.z() > 1e-9)) return false;
    *blur = camera.Project(at_open) - camera.Project(at_close);
    return true;
  }
};

}  // namespace

double BlurLengthHr(const CaptureGeometry& geometry, int scale) {
  CheckCaptureGeometry(geometry, scale);
  const PinholeCamera& camera = geometry.camera_hr;
  const RowExposureEnds ends(geometry, camera.height / scale, geometry.T_world_cam);
  double longest = 0.0;
  Eigen::Vector2d blur;
  for (int y = 0; y < camera.height; y = NextGridPoint(y, camera.height)) {
    const float* depth = geometry.depth_hr.ptr<float>(y);
    for (int x = 0; x < camera.width; x = NextGridPoint(x, camera.width)) {
      const double d = depth[x];
      if (!(d > 0.0 && d < 1e30)) continue;  // unknown depth: the operator samples x itself
      if (ends.Blur(camera, d * camera.Ray(x, y), y / scale, &blur)) longest = std::max(longest, blur.norm());
    }
  }
  return longest;
}

double BlurDifferenceHr(const CaptureGeometry& a, const CaptureGeometry& b, int scale) {
  CheckCaptureGeometry(a, scale);
  CheckCaptureGeometry(b, scale);
  if (a.camera_hr.width != b.camera_hr.width || a.camera_hr.height != b.camera_hr.height) {
    throw InputError("BlurDifferenceHr: the frames' HR sizes differ");
  }
  const PinholeCamera& camera = a.camera_hr;
  const int lr_rows = camera.height / scale;
  const RowExposureEnds ends_a(a, lr_rows, SE3()), ends_b(b, lr_rows, SE3());
  const SE3 T_b_world = b.T_world_cam.Inverse();
  double sum = 0.0;
  int count = 0;
  for (int y = 0; y < camera.height; y = NextGridPoint(y, camera.height)) {
    const float* depth = a.depth_hr.ptr<float>(y);
    for (int x = 0; x < camera.width; x = NextGridPoint(x, camera.width)) {
      const double d = depth[x];
      if (!(d > 0.0 && d < 1e30)) continue;  // unknown depth: no blur to compare
      const Eigen::Vector3d world = a.T_world_cam * (d * camera.Ray(x, y));
      const Eigen::Vector3d in_b = T_b_world * world;
      if (!(in_b.z() > 1e-9)) continue;
      const Eigen::Vector2d pixel_b = camera.Project(in_b);
      if (!(pixel_b.x() >= 0.0 && pixel_b.y() >= 0.0 && pixel_b.x() < camera.width && pixel_b.y() < camera.height)) {
        continue;  // b does not see it
      }
      Eigen::Vector2d blur_a, blur_b;
      if (!ends_a.Blur(camera, world, y / scale, &blur_a) ||
          !ends_b.Blur(camera, world, static_cast<int>(pixel_b.y()) / scale, &blur_b)) {
        continue;
      }
      sum += (blur_a - blur_b).norm();
      ++count;
    }
  }
  return count > 0 ? sum / count : std::numeric_limits<double>::quiet_NaN();
}

namespace {

// About options.samples_per_pixel samples per HR pixel of `motion`, clamped
// to [min(min_samples, samples), samples].
int SamplesForMotion(double motion_hr, const CaptureOperatorOptions& options) {
  const double wanted = std::ceil(motion_hr * options.samples_per_pixel);
  const int floor = std::min(options.min_samples, options.samples);
  return static_cast<int>(
      std::clamp(wanted, static_cast<double>(floor), static_cast<double>(options.samples)));
}

// M and K of a frame (CaptureSamples, DepthCameraCount) from one
// measurement of its blur.
struct SampleCounts {
  int samples = 1;        // M, virtual cameras per exposure window
  int depth_cameras = 1;  // K, depths reprojected from D_t
};

SampleCounts CountSamples(const CaptureGeometry& geometry, const CaptureOperatorOptions& options) {
  if (!options.adaptive_samples) return {options.samples, options.samples};
  // Each row's M samples span its own exposure window, so M follows the blur
  // (BlurLengthHr: the longest over the rows' windows) for either shutter.
  const double blur = BlurLengthHr(geometry, options.scale);
  const int samples = SamplesForMotion(blur, options);
  if (geometry.readout_time == 0.0) return {samples, samples};
  // A rolling shutter's reprojected depths span every row's window (the
  // exposure plus the readout): K follows the motion over that span, at
  // twice the samples' density, since each virtual camera reads the nearest
  // depth instant (at one per pixel the model-agreement test's rolling
  // frames lost 0.02-0.16 dB against M = 50; at two, 0.02-0.08 dB, as the
  // global shutter's 0.03-0.09 dB).
  const int lr_rows = geometry.camera_hr.height / options.scale;
  const double span = geometry.exposure + RowDelay(geometry, lr_rows - 1, lr_rows);
  return {samples, SamplesForMotion(2.0 * blur * span / geometry.exposure, options)};
}

}  // namespace

int CaptureSamples(const CaptureGeometry& geometry, const CaptureOperatorOptions& options) {
  return CountSamples(geometry, options).samples;
}

int DepthCameraCount(const CaptureGeometry& geometry, const CaptureOperatorOptions& options) {
  return CountSamples(geometry, options).depth_cameras;
}

void VirtualDepths::Compute(const CaptureGeometry& geometry, const CaptureOperatorOptions& options) {
  options.Check();
  CheckCaptureGeometry(geometry, options.scale);
  const double start = NowMs();
  const SampleCounts counts = CountSamples(geometry, options);
  samples_ = counts.samples;
  scale_ = options.scale;
  reprojected_ = options.reproject_depth;
  depth_t_ = geometry.depth_hr;
  T_depth_t_ = DepthCameras(geometry, options.scale, samples_, counts.depth_cameras);
  if (reprojected_) {
    // D_tau by reprojecting D_t into each depth camera (paper Sec. 3).
    const int num_depths = static_cast<int>(T_depth_t_.size());
    depths_.resize(num_depths);
    const int threads = ResolveThreads(options.num_threads);
#pragma omp parallel for schedule(dynamic, 1) num_threads(threads)
    for (int k = 0; k < num_depths; ++k) {
      ReprojectDepth(geometry.camera_hr, geometry.depth_hr, T_depth_t_[k], /*fill_from_source=*/true,
                     &depths_[k]);
    }
  }
  compute_ms_ = NowMs() - start;
}

size_t VirtualDepths::Bytes() const {
  if (!reprojected_) return 0;
  size_t bytes = 0;
  for (size_t k = 0; k < T_depth_t_.size() && k < depths_.size(); ++k)
    bytes += depths_[k].total() * sizeof(float);
  return bytes;
}

CaptureOperatorBuilder::CaptureOperatorBuilder(const CaptureOperatorOptions& options) : options_(options) {
  options_.Check();
}

void CaptureOperatorBuilder::Build(const CaptureGeometry& geometry, CaptureOperator* op) {
  own_depths_.Compute(geometry, options_);
  Assemble(geometry, own_depths_, op);
  timings_.reprojection_ms = own_depths_.compute_ms();
}

void CaptureOperatorBuilder::Build(const CaptureGeometry& geometry, const VirtualDepths& shared,
                                   CaptureOperator* op) {
  CheckCaptureGeometry(geometry, options_.scale);
  const SampleCounts counts = CountSamples(geometry, options_);
  bool same = shared.samples_ == counts.samples && shared.scale_ == options_.scale &&
              shared.reprojected_ == options_.reproject_depth &&
              shared.depth_t_.data == geometry.depth_hr.data;
  const std::vector<SE3> T_depth_t =
      same ? DepthCameras(geometry, options_.scale, counts.samples, counts.depth_cameras)
           : std::vector<SE3>();
  for (size_t k = 0; same && k < T_depth_t.size(); ++k) same = SamePose(T_depth_t[k], shared.T_depth_t_[k]);
  if (!same || T_depth_t.size() != shared.T_depth_t_.size()) {
    throw InputError("capture operator: the shared virtual depths were computed for another frame structure");
  }
  Assemble(geometry, shared, op);
  timings_.reprojection_ms = 0.0;
}

void CaptureOperatorBuilder::Assemble(const CaptureGeometry& geometry, const VirtualDepths& depths,
                                      CaptureOperator* op) {
  const PinholeCamera& camera = geometry.camera_hr;
  const int scale = options_.scale;
  const int samples = depths.samples_;
  const int threads = ResolveThreads(options_.num_threads);
  const VirtualCameras cameras =
      PlanVirtualCameras(geometry, scale, samples, static_cast<int>(depths.T_depth_t_.size()));
  std::vector<const cv::Mat*> virtual_depth(cameras.depth_index.size(), &geometry.depth_hr);
  if (depths.reprojected_) {
    for (size_t i = 0; i < virtual_depth.size(); ++i)
      virtual_depth[i] = &depths.depths_[cameras.depth_index[i]];
  }
  const double stage_start = NowMs();
  const AssemblyContext context(camera, scale, samples, cameras.transfers, virtual_depth);
  const int lr_pixels = context.lr_width * context.lr_height;
  op->lr_size_ = cv::Size(context.lr_width, context.lr_height);
  op->hr_size_ = cv::Size(context.hr_width, context.hr_height);
  op->num_threads_ = threads;
  op->coverage_.assign(lr_pixels, 1.0f);
  // Each thread assembles a contiguous block of LR rows into its own row
  // runs; the blocks are concatenated in order afterwards.
  blocks_.resize(std::max<size_t>(blocks_.size(), threads));
  const int lr_height = context.lr_height;
#pragma omp parallel num_threads(threads)
  {
    const int thread = omp_get_thread_num();
    const int first_row = static_cast<int>(static_cast<long long>(lr_height) * thread / threads);
    const int last_row = static_cast<int>(static_cast<long long>(lr_height) * (thread + 1) / threads);
    AssembleRows(context, first_row, last_row, &op->coverage_, &blocks_[thread]);
  }
  std::vector<const RowRunMatrix::RowBlock*> blocks;
  for (int t = 0; t < threads; ++t) blocks.push_back(&blocks_[t]);
  op->forward_ = RowRunMatrix::FromBlocks(context.hr_width * context.hr_height, blocks);
  timings_.assembly_ms = NowMs() - stage_start;
  const double adjoint_start = NowMs();
  if (options_.transposed_copy) {
    TransposeSparse(op->forward_.ToCsr(), &op->adjoint_, threads);
  } else {
    op->adjoint_ = SparseMatrixRM();
  }
  timings_.adjoint_ms = NowMs() - adjoint_start;
}

CaptureOperator BuildCaptureOperator(const CaptureGeometry& geometry, const CaptureOperatorOptions& options) {
  CaptureOperatorBuilder builder(options);
  CaptureOperator op;
  builder.Build(geometry, &op);
  return op;
}

namespace {

bool SameCamera(const PinholeCamera& a, const PinholeCamera& b) {
  return a.width == b.width && a.height == b.height && a.fx == b.fx && a.fy == b.fy && a.cx == b.cx &&
         a.cy == b.cy;
}

bool SameBytes(const cv::Mat& a, const cv::Mat& b) {
  if (a.size() != b.size() || a.type() != b.type()) return false;
  const size_t row_bytes = a.cols * a.elemSize();
  for (int y = 0; y < a.rows; ++y) {
    if (std::memcmp(a.ptr(y), b.ptr(y), row_bytes) != 0) return false;
  }
  return true;
}

}  // namespace

bool SameCaptureGeometry(const CaptureGeometry& a, const CaptureGeometry& b) {
  if (!SameCamera(a.camera_hr, b.camera_hr) || a.stamp != b.stamp || a.neighbour_stamp != b.neighbour_stamp ||
      a.exposure != b.exposure || a.readout_time != b.readout_time ||
      !SamePose(a.T_world_cam, b.T_world_cam) || !SamePose(a.T_world_neighbour, b.T_world_neighbour) ||
      a.T_world_source.has_value() != b.T_world_source.has_value() ||
      a.T_world_second_neighbour.has_value() != b.T_world_second_neighbour.has_value() ||
      a.T_world_third_neighbour.has_value() != b.T_world_third_neighbour.has_value()) {
    return false;
  }
  if (a.T_world_source.has_value() && !SamePose(*a.T_world_source, *b.T_world_source)) return false;
  if (a.T_world_second_neighbour.has_value() &&
      (a.second_neighbour_stamp != b.second_neighbour_stamp ||
       !SamePose(*a.T_world_second_neighbour, *b.T_world_second_neighbour)))
    return false;
  if (a.T_world_third_neighbour.has_value() &&
      (a.third_neighbour_stamp != b.third_neighbour_stamp ||
       !SamePose(*a.T_world_third_neighbour, *b.T_world_third_neighbour)))
    return false;
  return SameBytes(a.depth_hr, b.depth_hr);
}

bool SameOperatorModel(const CaptureOperatorOptions& a, const CaptureOperatorOptions& b) {
  return a.samples == b.samples && a.adaptive_samples == b.adaptive_samples &&
         a.samples_per_pixel == b.samples_per_pixel && a.min_samples == b.min_samples && a.scale == b.scale &&
         a.reproject_depth == b.reproject_depth;
}

}  // namespace deblur_sr_mvs
