// Row-run kernels for interleaved 3-channel (colour) images: one 4-lane
// vector per pixel instead of three scalar chains.
//
// The colour products of the image update (Psi x, A^T W A x, A^T y, the
// diagonal of A^T W A) spend most of their time in the per-tap scalar work of
// three channels. Here a gather adds v * (r, g, b, next r) to one of four
// 4-lane partial sums (the fourth lane is never used; the partial sums are
// those of GatherRowChains in row_run_matrix.h), and a scatter adds v * (a_r,
// a_g, a_b) to the 3 * length contiguous outputs of a run as 4-lane vectors,
// four taps (12 values) at a time. Each output value still gets the same
// float multiply and add, in the same order, as in the scalar kernels: the
// results are bit for bit those of the scalar form (test RowRunProducts.*).
// GCC / Clang vector extensions: portable, SSE2 on x86-64, NEON on ARM.
#pragma once

#include <cstddef>
#include <cstring>

#include "deblur_sr_mvs/core/imaging/row_run_matrix.h"

namespace deblur_sr_mvs {
namespace rgb_runs {

using Float4 = float __attribute__((vector_size(16)));

inline Float4 Load4(const float* p) {
  Float4 v;
  std::memcpy(&v, p, sizeof(v));
  return v;
}

inline void Store4(float* p, Float4 v) {
  std::memcpy(p, &v, sizeof(v));
}

// The 3 values of one pixel (fourth lane 0): no read past the pixel.
inline Float4 LoadPixel(const float* p) {
  return Float4{p[0], p[1], p[2], 0.0f};
}

// sum_i v[i] * x(column + i) for one run added to the partial sums of
// GatherRowChains (row_run_matrix.h): tap i to s[i mod 4], each lane in tap
// order. x is an interleaved 3-channel image of `cols` pixels. The full
// 4-value load reads the next pixel's first channel into the unused lane,
// except at the image's last pixel.
inline void GatherRun(const float* __restrict v, const float* __restrict x, int column, int length, int cols,
                      Float4* __restrict s) {
  const float* __restrict px = x + static_cast<std::ptrdiff_t>(column) * 3;
  const int safe = column + length == cols ? length - 1 : length;
  int i = 0;
  for (; i + 4 <= safe; i += 4) {
    s[0] += v[i] * Load4(px + 3 * i);
    s[1] += v[i + 1] * Load4(px + 3 * (i + 1));
    s[2] += v[i + 2] * Load4(px + 3 * (i + 2));
    s[3] += v[i + 3] * Load4(px + 3 * (i + 3));
  }
  // At most four taps are left (three, or four when the last is the image's
  // last pixel); tap i + k goes to chain k.
  const auto tap = [&](int k) {
    const float* p = px + 3 * (i + k);
    return v[i + k] * (i + k < safe ? Load4(p) : LoadPixel(p));
  };
  const int tail = length - i;
  if (tail > 0) s[0] += tap(0);
  if (tail > 1) s[1] += tap(1);
  if (tail > 2) s[2] += tap(2);
  if (tail > 3) s[3] += tap(3);
}

// sum_k a(r, k) x(k) over row r (lanes 0-2; lane 3 is junk), in the four
// partial sums of GatherRowChains and added as (s0 + s1) + (s2 + s3).
inline Float4 GatherRow(const RunRowSpans& a, int r, const float* __restrict x, int cols) {
  Float4 s[4] = {};
  const float* v = a.values + a.row_first_value[r];
  for (int run = a.row_first_run[r]; run < a.row_first_run[r + 1]; ++run) {
    const int length = a.run_length[run];
    GatherRun(v, x, a.run_first_column[run], length, cols, s);
    v += length;
  }
  return (s[0] + s[1]) + (s[2] + s[3]);
}

// The scatter's factor vectors (s_r, s_g, s_b, s_r), (s_g, s_b, s_r, s_g),
// (s_b, s_r, s_g, s_b): four taps' 12 contiguous outputs, channel by channel.
struct ScatterFactors {
  explicit ScatterFactors(Float4 s)
      : s0{s[0], s[1], s[2], s[0]}, s1{s[1], s[2], s[0], s[1]}, s2{s[2], s[0], s[1], s[2]}, s(s) {}
  Float4 s0, s1, s2, s;
};

// q[3 j + c] += f(v[j]) * s_c for the four taps j < 4 at v (12 outputs at q,
// three vectors), f the identity or (kSquare) the square.
template <bool kSquare>
inline void ScatterQuad(const float* __restrict v, const ScatterFactors& s, float* __restrict q) {
  Float4 f = Load4(v);
  if (kSquare) f = f * f;
  const Float4 f0 = {f[0], f[0], f[0], f[1]};
  const Float4 f1 = {f[1], f[1], f[2], f[2]};
  const Float4 f2 = {f[2], f[3], f[3], f[3]};
  const Float4 o0 = Load4(q) + f0 * s.s0;
  const Float4 o1 = Load4(q + 4) + f1 * s.s1;
  const Float4 o2 = Load4(q + 8) + f2 * s.s2;
  Store4(q, o0);
  Store4(q + 4, o1);
  Store4(q + 8, o2);
}

// Taps [i, length) of a run one at a time (q: the run's first output).
template <bool kSquare>
inline void ScatterTail(const float* __restrict v, int i, int length, Float4 s, float* __restrict q) {
  for (; i < length; ++i) {
    const float f = kSquare ? v[i] * v[i] : v[i];
    for (int c = 0; c < 3; ++c) q[3 * i + c] += f * s[c];
  }
}

// out(k) += f(a(r, k)) * s (channels 0-2) over row r, f the identity or
// (kSquare) the square. Four taps at a time: 12 contiguous outputs as three
// vectors, the taps' factors laid out to match.
template <bool kSquare = false>
inline void ScatterRow(const RunRowSpans& a, int r, Float4 s, float* __restrict out) {
  const ScatterFactors factors(s);
  const float* v = a.values + a.row_first_value[r];
  for (int run = a.row_first_run[r]; run < a.row_first_run[r + 1]; ++run) {
    const int length = a.run_length[run];
    float* __restrict po = out + static_cast<std::ptrdiff_t>(a.run_first_column[run]) * 3;
    int i = 0;
    for (; i + 4 <= length; i += 4) ScatterQuad<kSquare>(v + i, factors, po + 3 * i);
    ScatterTail<kSquare>(v, i, length, s, po);
    v += length;
  }
}

// The 8-lane forms (rgb_run_kernels_avx2.cc): two taps per vector in the
// gathers, 24 outputs per 8 taps in the scatters, with each value's float
// operations and their order unchanged, so the results are bit for bit those
// of the 4-lane forms above (test RgbRunKernels.*). Compiled for AVX2
// through function attributes (the package is built without -march) and
// used where the CPU has AVX2 (runtime check); elsewhere the callers take
// the 4-lane forms (where the compiler is not an x86-64 GCC / Clang, the
// 8-lane functions are not compiled in: the row ones throw, the others are
// the 4-lane forms).
//
// Whether the 8-lane forms run: compiled in, the CPU has AVX2 (and the OS
// saves its registers) and Allow8LaneKernels(false) was not called.
bool Use8LaneKernels();
// Tests: lets (true, the default) or stops the dispatch from taking the
// 8-lane forms. Not thread-safe against running products.
void Allow8LaneKernels(bool allow);

// GatherRow, ScatterRow, ScatterRow<true>.
Float4 GatherRow8(const RunRowSpans& a, int r, const float* __restrict x, int cols);
void ScatterRow8(const RunRowSpans& a, int r, Float4 s, float* __restrict out);
void ScatterSquaredRow8(const RunRowSpans& a, int r, Float4 s, float* __restrict out);

// Rows [first, last) of the colour kernels of normal_product.cc
// (A^T W A x, A^T y, diag(A^T W A); weight, y: 3 values per row).
void NormalProductRows8(const RunRowSpans& a, int cols, const float* __restrict weight,
                        const float* __restrict x, int first, int last, float* __restrict out);
void AdjointRows8(const RunRowSpans& a, const float* __restrict y, int first, int last, float* __restrict out);
void NormalDiagonalRows8(const RunRowSpans& a, const float* __restrict weight, int first, int last,
                         float* __restrict out);

}  // namespace rgb_runs
}  // namespace deblur_sr_mvs
