#include "deblur_sr_mvs/core/imaging/normal_product.h"

#include <omp.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <string>
#include <type_traits>
#include <vector>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/common/runtime.h"
#include "deblur_sr_mvs/core/imaging/rgb_run_kernels.h"

namespace deblur_sr_mvs {
namespace {

// The three row kernels for 3-channel images over row runs, with one 4-lane
// vector per pixel (rgb_run_kernels.h), or their 8-lane forms where the CPU
// has them: the same values, bit for bit, as the scalar kernels below,
// which call them for such images.
void NormalProductRowsRgb(const RunRowSpans& a, int cols, const float* __restrict weight,
                          const float* __restrict x, int first, int last, float* __restrict out) {
  if (rgb_runs::Use8LaneKernels()) return rgb_runs::NormalProductRows8(a, cols, weight, x, first, last, out);
  for (int r = first; r < last; ++r) {
    const float* w = weight + static_cast<std::ptrdiff_t>(r) * 3;
    if (w[0] == 0.0f && w[1] == 0.0f && w[2] == 0.0f) continue;
    const rgb_runs::Float4 sum = rgb_runs::GatherRow(a, r, x, cols);
    rgb_runs::ScatterRow(a, r, sum * rgb_runs::Float4{w[0], w[1], w[2], 0.0f}, out);
  }
}

void AdjointRowsRgb(const RunRowSpans& a, const float* __restrict y, int first, int last,
                    float* __restrict out) {
  if (rgb_runs::Use8LaneKernels()) return rgb_runs::AdjointRows8(a, y, first, last, out);
  for (int r = first; r < last; ++r) {
    const float* py = y + static_cast<std::ptrdiff_t>(r) * 3;
    rgb_runs::ScatterRow(a, r, rgb_runs::Float4{py[0], py[1], py[2], 0.0f}, out);
  }
}

void NormalDiagonalRowsRgb(const RunRowSpans& a, const float* __restrict weight, int first, int last,
                           float* __restrict out) {
  if (rgb_runs::Use8LaneKernels()) return rgb_runs::NormalDiagonalRows8(a, weight, first, last, out);
  for (int r = first; r < last; ++r) {
    const float* w = weight + static_cast<std::ptrdiff_t>(r) * 3;
    rgb_runs::ScatterRow</*kSquare=*/true>(a, r, rgb_runs::Float4{w[0], w[1], w[2], 0.0f}, out);
  }
}

// Whether a kernel over `Rows` with kChannels channels takes the ones above.
template <int kChannels, typename Rows>
constexpr bool kRgbRuns = kChannels == 3 && std::is_same_v<Rows, RunRowSpans>;

// The three row kernels over rows [first, last) of A, scattering into `out`
// (interleaved kChannels values per column). The output never aliases the
// operator or the inputs (__restrict): the scatter then need not reload the
// taps after each store.
template <int kChannels, typename Rows>
void NormalProductRows(const Rows& a, int cols, const float* __restrict weight, const float* __restrict x,
                       int first, int last, float* __restrict out) {
  if constexpr (kRgbRuns<kChannels, Rows>) return NormalProductRowsRgb(a, cols, weight, x, first, last, out);
  for (int r = first; r < last; ++r) {
    const float* w = weight + static_cast<std::ptrdiff_t>(r) * kChannels;
    bool used = false;
    for (int c = 0; c < kChannels; ++c) used = used || w[c] != 0.0f;
    if (!used) continue;
    float acc[kChannels];
    GatherRowChains<kChannels>(a, r, x, acc);
    for (int c = 0; c < kChannels; ++c) acc[c] *= w[c];
    a.ForEachSpan(r, [&](const float* __restrict v, int column, int length) {
      float* __restrict po = out + static_cast<std::ptrdiff_t>(column) * kChannels;
      for (int i = 0; i < length; ++i) {
        for (int c = 0; c < kChannels; ++c) po[i * kChannels + c] += v[i] * acc[c];
      }
    });
  }
}

template <int kChannels, typename Rows>
void AdjointRows(const Rows& a, const float* __restrict y, int first, int last, float* __restrict out) {
  if constexpr (kRgbRuns<kChannels, Rows>) return AdjointRowsRgb(a, y, first, last, out);
  for (int r = first; r < last; ++r) {
    const float* py = y + static_cast<std::ptrdiff_t>(r) * kChannels;
    a.ForEachSpan(r, [&](const float* __restrict v, int column, int length) {
      float* __restrict po = out + static_cast<std::ptrdiff_t>(column) * kChannels;
      for (int i = 0; i < length; ++i) {
        for (int c = 0; c < kChannels; ++c) po[i * kChannels + c] += v[i] * py[c];
      }
    });
  }
}

template <int kChannels, typename Rows>
void NormalDiagonalRows(const Rows& a, const float* __restrict weight, int first, int last,
                        float* __restrict out) {
  if constexpr (kRgbRuns<kChannels, Rows>) return NormalDiagonalRowsRgb(a, weight, first, last, out);
  for (int r = first; r < last; ++r) {
    const float* w = weight + static_cast<std::ptrdiff_t>(r) * kChannels;
    a.ForEachSpan(r, [&](const float* __restrict v, int column, int length) {
      float* __restrict po = out + static_cast<std::ptrdiff_t>(column) * kChannels;
      for (int i = 0; i < length; ++i) {
        const float squared = v[i] * v[i];
        for (int c = 0; c < kChannels; ++c) po[i * kChannels + c] += squared * w[c];
      }
    });
  }
}

// Per-thread latent accumulators of ScatterRowBlocks, kept between calls
// (the OpenMP threads persist): a call zeroes them but allocates only when
// the latent grid grew.
std::vector<float>& ThreadScratch() {
  thread_local std::vector<float> scratch;
  return scratch;
}

// Runs kernel(first, last, target) over contiguous row blocks, one per
// thread: block 0 scatters into `out`, the others into their thread's
// zeroed scratch, which is then added to `out`.
template <typename Kernel>
void ScatterRowBlocks(int rows, size_t out_values, int threads, float* out, const Kernel& kernel) {
  if (threads <= 1) {
    kernel(0, rows, out);
    return;
  }
  constexpr int kMaxThreads = 256;
  threads = std::min(threads, kMaxThreads);
  std::array<float*, kMaxThreads> partial{};
  int used_threads = 1;
#pragma omp parallel num_threads(threads)
  {
    const int thread = omp_get_thread_num();
    const int used = omp_get_num_threads();
    const int first = static_cast<int>(static_cast<long long>(rows) * thread / used);
    const int last = static_cast<int>(static_cast<long long>(rows) * (thread + 1) / used);
    float* target = out;
    if (thread > 0) {
      std::vector<float>& scratch = ThreadScratch();
      if (scratch.size() < out_values) scratch.resize(out_values);
      std::fill(scratch.begin(), scratch.begin() + static_cast<std::ptrdiff_t>(out_values), 0.0f);
      target = scratch.data();
      partial[thread] = target;
    } else {
      used_threads = used;
    }
    kernel(first, last, target);
  }
  const long n = static_cast<long>(out_values);
#pragma omp parallel for num_threads(threads) schedule(static)
  for (long i = 0; i < n; ++i) {
    for (int thread = 1; thread < used_threads; ++thread) out[i] += partial[thread][i];
  }
}

// Checks the shapes and dispatches on the channel count.
template <template <int> class Pass, typename... Args>
void Dispatch(int channels, Args&&... args) {
  switch (channels) {
    case 1:
      return Pass<1>::Run(args...);
    case 2:
      return Pass<2>::Run(args...);
    case 3:
      return Pass<3>::Run(args...);
    case 4:
      return Pass<4>::Run(args...);
    default:
      throw InputError("normal product: images must have 1 to 4 channels");
  }
}

void CheckGrid(const cv::Mat& image, long pixels, int channels, const char* what) {
  if (image.depth() != CV_32F || !image.isContinuous() || static_cast<long>(image.total()) != pixels ||
      image.channels() != channels) {
    throw InputError(std::string("normal product: ") + what + " does not match the operator");
  }
}

template <int kChannels>
struct NormalProductPass {
  template <typename Matrix>
  static void Run(const Matrix& a, const float* weight, const float* x, float* out, int threads) {
    const auto rows = RowSpansOf(a);
    ScatterRowBlocks(static_cast<int>(a.rows()), static_cast<size_t>(a.cols()) * kChannels, threads, out,
                     [&](int first, int last, float* target) {
                       NormalProductRows<kChannels>(rows, static_cast<int>(a.cols()), weight, x, first, last,
                                                    target);
                     });
  }
};

template <int kChannels>
struct AdjointPass {
  template <typename Matrix>
  static void Run(const Matrix& a, const float* y, float* out, int threads) {
    const auto rows = RowSpansOf(a);
    ScatterRowBlocks(
        static_cast<int>(a.rows()), static_cast<size_t>(a.cols()) * kChannels, threads, out,
        [&](int first, int last, float* target) { AdjointRows<kChannels>(rows, y, first, last, target); });
  }
};

template <int kChannels>
struct NormalDiagonalPass {
  template <typename Matrix>
  static void Run(const Matrix& a, const float* weight, float* out, int threads) {
    const auto rows = RowSpansOf(a);
    ScatterRowBlocks(static_cast<int>(a.rows()), static_cast<size_t>(a.cols()) * kChannels, threads, out,
                     [&](int first, int last, float* target) {
                       NormalDiagonalRows<kChannels>(rows, weight, first, last, target);
                     });
  }
};

template <typename Matrix>
void WeightedNormalProduct(const Matrix& a, const cv::Mat& weight, const cv::Mat& x, cv::Mat* out,
                           int threads) {
  const int channels = x.channels();
  CheckGrid(x, a.cols(), channels, "the input");
  CheckGrid(*out, a.cols(), channels, "the output");
  CheckGrid(weight, a.rows(), channels, "the weight");
  Dispatch<NormalProductPass>(channels, a, weight.ptr<float>(), x.ptr<float>(), out->ptr<float>(),
                              ResolveThreads(threads));
}

template <typename Matrix>
void AdjointProduct(const Matrix& a, const cv::Mat& y, cv::Mat* out, int threads) {
  const int channels = y.channels();
  CheckGrid(y, a.rows(), channels, "the input");
  CheckGrid(*out, a.cols(), channels, "the output");
  Dispatch<AdjointPass>(channels, a, y.ptr<float>(), out->ptr<float>(), ResolveThreads(threads));
}

template <typename Matrix>
void WeightedNormalDiagonal(const Matrix& a, const cv::Mat& weight, cv::Mat* out, int threads) {
  const int channels = weight.channels();
  CheckGrid(weight, a.rows(), channels, "the weight");
  CheckGrid(*out, a.cols(), channels, "the output");
  Dispatch<NormalDiagonalPass>(channels, a, weight.ptr<float>(), out->ptr<float>(), ResolveThreads(threads));
}

// The rows of L1ReweightPass: per row, (A x)_r by the gather of Psi x
// (MultiplySparse: GatherRow for colour row runs, else GatherRowChains),
// then the row's residual and weights, then the row's scatters as
// NormalDiagonalRows and AdjointRows do them (the colour kernels for 3
// channels, the scalar loops otherwise).
struct L1Reweighting {
  const float* b;
  const uchar* mask;  // one per row; nullptr: every row
  double scale, epsilon;
  float* residual;
  float* weight;
};

// Row r's residual, weights and adjoint factors -(w r) of L1ReweightPass.
template <int kChannels>
inline void L1RowWeights(const L1Reweighting& l1, int r, const float* ax, float* y) {
  const bool used = l1.mask == nullptr || l1.mask[r] != 0;
  const std::ptrdiff_t i0 = static_cast<std::ptrdiff_t>(r) * kChannels;
  for (int c = 0; c < kChannels; ++c) {
    const float residual = ax[c] - l1.b[i0 + c];
    const float w =
        used ? static_cast<float>(l1.scale / std::max<double>(std::abs(residual), l1.epsilon)) : 0.0f;
    l1.residual[i0 + c] = residual;
    l1.weight[i0 + c] = w;
    y[c] = -(residual * w);
  }
}

// L1ReweightRows<3>'s gather and scatters, 4-lane or (k8Lanes) 8-lane.
template <bool k8Lanes>
struct RgbRowKernels {
  static rgb_runs::Float4 Gather(const RunRowSpans& a, int r, const float* __restrict x, int cols) {
    return k8Lanes ? rgb_runs::GatherRow8(a, r, x, cols) : rgb_runs::GatherRow(a, r, x, cols);
  }
  template <bool kSquare>
  static void Scatter(const RunRowSpans& a, int r, rgb_runs::Float4 s, float* __restrict out) {
    if (!k8Lanes) return rgb_runs::ScatterRow<kSquare>(a, r, s, out);
    if (kSquare) return rgb_runs::ScatterSquaredRow8(a, r, s, out);
    rgb_runs::ScatterRow8(a, r, s, out);
  }
};

template <int kChannels, bool k8Lanes = false>
void L1ReweightRows(const RunRowSpans& a, int rows, int cols, const float* __restrict x,
                    const L1Reweighting& l1, float* __restrict diagonal, float* __restrict adjoint) {
  if constexpr (kChannels == 3 && !k8Lanes) {
    if (rgb_runs::Use8LaneKernels()) return L1ReweightRows<3, true>(a, rows, cols, x, l1, diagonal, adjoint);
  }
  using Rgb = RgbRowKernels<k8Lanes>;
  for (int r = 0; r < rows; ++r) {
    float ax[kChannels], y[kChannels];
    if constexpr (kChannels == 3) {
      const rgb_runs::Float4 sum = Rgb::Gather(a, r, x, cols);
      for (int c = 0; c < 3; ++c) ax[c] = sum[c];
    } else {
      GatherRowChains<kChannels>(a, r, x, ax);
    }
    L1RowWeights<kChannels>(l1, r, ax, y);
    const float* w = l1.weight + static_cast<std::ptrdiff_t>(r) * kChannels;
    if constexpr (kChannels == 3) {
      Rgb::template Scatter</*kSquare=*/true>(a, r, rgb_runs::Float4{w[0], w[1], w[2], 0.0f}, diagonal);
      Rgb::template Scatter<false>(a, r, rgb_runs::Float4{y[0], y[1], y[2], 0.0f}, adjoint);
    } else {
      a.ForEachSpan(r, [&](const float* __restrict v, int column, int length) {
        float* __restrict pd = diagonal + static_cast<std::ptrdiff_t>(column) * kChannels;
        float* __restrict pa = adjoint + static_cast<std::ptrdiff_t>(column) * kChannels;
        for (int i = 0; i < length; ++i) {
          const float squared = v[i] * v[i];
          for (int c = 0; c < kChannels; ++c) pd[i * kChannels + c] += squared * w[c];
        }
        for (int i = 0; i < length; ++i) {
          for (int c = 0; c < kChannels; ++c) pa[i * kChannels + c] += v[i] * y[c];
        }
      });
    }
  }
}

template <int kChannels>
struct L1ReweightPassOf {
  static void Run(const RowRunMatrix& a, const float* x, const L1Reweighting& l1, float* diagonal,
                  float* adjoint) {
    L1ReweightRows<kChannels>(RowSpansOf(a), static_cast<int>(a.rows()), static_cast<int>(a.cols()), x, l1,
                              diagonal, adjoint);
  }
};

}  // namespace

void AddWeightedNormalProduct(const RowRunMatrix& a, const cv::Mat& weight, const cv::Mat& x, cv::Mat* out,
                              int threads) {
  WeightedNormalProduct(a, weight, x, out, threads);
}

void AddWeightedNormalProduct(const SparseMatrixRM& a, const cv::Mat& weight, const cv::Mat& x, cv::Mat* out,
                              int threads) {
  WeightedNormalProduct(a, weight, x, out, threads);
}

void AddAdjointProduct(const RowRunMatrix& a, const cv::Mat& y, cv::Mat* out, int threads) {
  AdjointProduct(a, y, out, threads);
}

void AddAdjointProduct(const SparseMatrixRM& a, const cv::Mat& y, cv::Mat* out, int threads) {
  AdjointProduct(a, y, out, threads);
}

void AddWeightedNormalDiagonal(const RowRunMatrix& a, const cv::Mat& weight, cv::Mat* out, int threads) {
  WeightedNormalDiagonal(a, weight, out, threads);
}

void AddWeightedNormalDiagonal(const SparseMatrixRM& a, const cv::Mat& weight, cv::Mat* out, int threads) {
  WeightedNormalDiagonal(a, weight, out, threads);
}

void L1ReweightPass(const RowRunMatrix& a, const cv::Mat& x, const cv::Mat& b, const cv::Mat& mask,
                    double scale, double epsilon, cv::Mat* residual, cv::Mat* weight, cv::Mat* diagonal,
                    cv::Mat* adjoint) {
  const int channels = x.channels();
  CheckGrid(x, a.cols(), channels, "the input");
  CheckGrid(*diagonal, a.cols(), channels, "the diagonal");
  CheckGrid(*adjoint, a.cols(), channels, "the adjoint");
  const cv::Mat observed = b.isContinuous() ? b : b.clone();
  CheckGrid(observed, a.rows(), channels, "the observation");
  const cv::Mat used = mask.empty() || mask.isContinuous() ? mask : mask.clone();
  if (!used.empty() && (used.type() != CV_8UC1 || static_cast<long>(used.total()) != a.rows())) {
    throw InputError("normal product: the mask does not match the operator");
  }
  residual->create(b.size(), b.type());
  weight->create(b.size(), b.type());
  const L1Reweighting l1{observed.ptr<float>(),
                         used.empty() ? nullptr : used.ptr<uchar>(),
                         scale,
                         epsilon,
                         residual->ptr<float>(),
                         weight->ptr<float>()};
  Dispatch<L1ReweightPassOf>(channels, a, x.ptr<float>(), l1, diagonal->ptr<float>(), adjoint->ptr<float>());
}

}  // namespace deblur_sr_mvs
