// The 8-lane forms of the colour row-run kernels (rgb_run_kernels.h).
//
// Gather: the four partial sums of GatherRow (tap i of a run to chain
// i mod 4, one 4-lane pixel vector each) live in two 8-lane vectors,
// (chain 0 | chain 2) and (chain 1 | chain 3), so one multiply and one add
// take two taps; a tail tap adds to one half only (a blend keeps the other
// half's bits). The row's value is (s0 + s1) + (s2 + s3) as before: the two
// vectors' sum is (s0 + s1 | s2 + s3), then its halves are added.
// Scatter: 8 taps give 24 contiguous outputs as three 8-lane vectors, then
// one 4-tap block and single taps as in ScatterRow.
// Each output still gets one float multiply and one add in the same order:
// the results are the 4-lane forms' bits (test RgbRunKernels.*).
//
// Compiled for AVX2 through __attribute__((target("avx2"))) on these
// functions only (not -mavx2 for the file: the header's inline functions
// keep their portable out-of-line copies). AVX2 does not include FMA, so
// the compiler cannot contract a multiply and an add into one rounding.
#include <atomic>
#include <stdexcept>

#include "deblur_sr_mvs/core/imaging/rgb_run_kernels.h"

#ifdef __x86_64__
#ifdef __GNUC__  // GCC and Clang
#define DSM_RGB_RUNS_8_LANES 1
#include <immintrin.h>
#endif
#endif

namespace deblur_sr_mvs {
namespace rgb_runs {
namespace {

std::atomic<bool> allow_8_lanes{true};

#if DSM_RGB_RUNS_8_LANES

#define DSM_AVX2 __attribute__((target("avx2")))

DSM_AVX2 inline __m256 Halves(__m128 low, __m128 high) {
  return _mm256_insertf128_ps(_mm256_castps128_ps256(low), high, 1);
}

// One pixel's 3 values and, where `full`, the next pixel's first (else 0).
DSM_AVX2 inline __m128 Pixel(const float* p, bool full) {
  return full ? _mm_loadu_ps(p) : _mm_setr_ps(p[0], p[1], p[2], 0.0f);
}

// Adds v[k] * pixel k to half `high` of *s (the other half unchanged).
DSM_AVX2 inline void AddTap(const float* v, const float* px, int k, bool full, bool high, __m256* s) {
  const __m128 t = _mm_mul_ps(_mm_set1_ps(v[k]), Pixel(px + 3 * k, full));
  const __m256 sum = _mm256_add_ps(*s, Halves(t, t));
  *s = high ? _mm256_blend_ps(*s, sum, 0xF0) : _mm256_blend_ps(*s, sum, 0x0F);
}

// Adds (v[k] * pixel k | v[k + 2] * pixel k + 2) to *s (both pixels full).
DSM_AVX2 inline void AddTapPair(const float* v, const float* px, int k, __m256* s) {
  const __m256 f = Halves(_mm_set1_ps(v[k]), _mm_set1_ps(v[k + 2]));
  const __m256 p = Halves(_mm_loadu_ps(px + 3 * k), _mm_loadu_ps(px + 3 * (k + 2)));
  *s = _mm256_add_ps(*s, _mm256_mul_ps(f, p));
}

// GatherRun (rgb_run_kernels.h) into (chain 0 | chain 2) and (chain 1 |
// chain 3). Pixel i's 4-value load is safe for i < safe.
DSM_AVX2 inline void GatherRun8(const float* __restrict v, const float* __restrict x, int column, int length,
                                int cols, __m256* s02, __m256* s13) {
  const float* __restrict px = x + static_cast<std::ptrdiff_t>(column) * 3;
  const int safe = column + length == cols ? length - 1 : length;
  const __m256i even = _mm256_setr_epi32(0, 0, 0, 0, 2, 2, 2, 2);
  const __m256i odd = _mm256_setr_epi32(1, 1, 1, 1, 3, 3, 3, 3);
  int i = 0;
  for (; i + 4 <= safe; i += 4) {
    const __m256 f = _mm256_castps128_ps256(_mm_loadu_ps(v + i));
    const float* p = px + 3 * i;
    const __m256 p02 = Halves(_mm_loadu_ps(p), _mm_loadu_ps(p + 6));
    const __m256 p13 = Halves(_mm_loadu_ps(p + 3), _mm_loadu_ps(p + 9));
    *s02 = _mm256_add_ps(*s02, _mm256_mul_ps(_mm256_permutevar8x32_ps(f, even), p02));
    *s13 = _mm256_add_ps(*s13, _mm256_mul_ps(_mm256_permutevar8x32_ps(f, odd), p13));
  }
  // At most four taps are left; tap i + k goes to chain k.
  const int tail = length - i;
  v += i;
  px += 3 * i;
  if (tail > 2 && i + 2 < safe) {
    AddTapPair(v, px, 0, s02);
  } else {
    if (tail > 0) AddTap(v, px, 0, i < safe, false, s02);
    if (tail > 2) AddTap(v, px, 2, i + 2 < safe, true, s02);
  }
  if (tail > 3 && i + 3 < safe) {
    AddTapPair(v, px, 1, s13);
  } else {
    if (tail > 1) AddTap(v, px, 1, i + 1 < safe, false, s13);
    if (tail > 3) AddTap(v, px, 3, i + 3 < safe, true, s13);
  }
}

DSM_AVX2 inline Float4 GatherRowAvx2(const RunRowSpans& a, int r, const float* __restrict x, int cols) {
  __m256 s02 = _mm256_setzero_ps(), s13 = _mm256_setzero_ps();
  const float* v = a.values + a.row_first_value[r];
  for (int run = a.row_first_run[r]; run < a.row_first_run[r + 1]; ++run) {
    const int length = a.run_length[run];
    GatherRun8(v, x, a.run_first_column[run], length, cols, &s02, &s13);
    v += length;
  }
  const __m256 pairs = _mm256_add_ps(s02, s13);  // (s0 + s1 | s2 + s3)
  return _mm_add_ps(_mm256_castps256_ps128(pairs), _mm256_extractf128_ps(pairs, 1));
}

// ScatterRow (rgb_run_kernels.h) with 8 taps at a time: the 24 outputs are
// f0 f0 f0 f1 f1 f1 f2 f2 | f2 f3 f3 f3 f4 f4 f4 f5 | f5 f5 f6 f6 f6 f7 f7 f7
// times s r g b r g b r g | b r g b r g b r | g b r g b r g b.
template <bool kSquare>
DSM_AVX2 inline void ScatterRowAvx2(const RunRowSpans& a, int r, Float4 s, float* __restrict out) {
  const ScatterFactors factors(s);
  const __m256 s3 = _mm256_castps128_ps256(s);
  const __m256 s0 = _mm256_permutevar8x32_ps(s3, _mm256_setr_epi32(0, 1, 2, 0, 1, 2, 0, 1));
  const __m256 s1 = _mm256_permutevar8x32_ps(s3, _mm256_setr_epi32(2, 0, 1, 2, 0, 1, 2, 0));
  const __m256 s2 = _mm256_permutevar8x32_ps(s3, _mm256_setr_epi32(1, 2, 0, 1, 2, 0, 1, 2));
  const __m256i f0 = _mm256_setr_epi32(0, 0, 0, 1, 1, 1, 2, 2);
  const __m256i f1 = _mm256_setr_epi32(2, 3, 3, 3, 4, 4, 4, 5);
  const __m256i f2 = _mm256_setr_epi32(5, 5, 6, 6, 6, 7, 7, 7);
  const float* v = a.values + a.row_first_value[r];
  for (int run = a.row_first_run[r]; run < a.row_first_run[r + 1]; ++run) {
    const int length = a.run_length[run];
    float* __restrict po = out + static_cast<std::ptrdiff_t>(a.run_first_column[run]) * 3;
    int i = 0;
    for (; i + 8 <= length; i += 8) {
      __m256 f = _mm256_loadu_ps(v + i);
      if (kSquare) f = _mm256_mul_ps(f, f);
      float* q = po + 3 * i;
      const __m256 o0 = _mm256_add_ps(_mm256_loadu_ps(q), _mm256_mul_ps(_mm256_permutevar8x32_ps(f, f0), s0));
      const __m256 o1 =
          _mm256_add_ps(_mm256_loadu_ps(q + 8), _mm256_mul_ps(_mm256_permutevar8x32_ps(f, f1), s1));
      const __m256 o2 =
          _mm256_add_ps(_mm256_loadu_ps(q + 16), _mm256_mul_ps(_mm256_permutevar8x32_ps(f, f2), s2));
      _mm256_storeu_ps(q, o0);
      _mm256_storeu_ps(q + 8, o1);
      _mm256_storeu_ps(q + 16, o2);
    }
    if (i + 4 <= length) {
      ScatterQuad<kSquare>(v + i, factors, po + 3 * i);
      i += 4;
    }
    ScatterTail<kSquare>(v, i, length, s, po);
    v += length;
  }
}

bool CpuHasAvx2() {
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx2");
}

#endif  // DSM_RGB_RUNS_8_LANES

}  // namespace

bool Use8LaneKernels() {
#if DSM_RGB_RUNS_8_LANES
  static const bool cpu = CpuHasAvx2();
  return cpu && allow_8_lanes.load(std::memory_order_relaxed);
#else
  return false;
#endif
}

void Allow8LaneKernels(bool allow) {
  allow_8_lanes.store(allow, std::memory_order_relaxed);
}

#if DSM_RGB_RUNS_8_LANES

DSM_AVX2 Float4 GatherRow8(const RunRowSpans& a, int r, const float* __restrict x, int cols) {
  return GatherRowAvx2(a, r, x, cols);
}

DSM_AVX2 void ScatterRow8(const RunRowSpans& a, int r, Float4 s, float* __restrict out) {
  ScatterRowAvx2<false>(a, r, s, out);
}

DSM_AVX2 void ScatterSquaredRow8(const RunRowSpans& a, int r, Float4 s, float* __restrict out) {
  ScatterRowAvx2<true>(a, r, s, out);
}

DSM_AVX2 void NormalProductRows8(const RunRowSpans& a, int cols, const float* __restrict weight,
                                 const float* __restrict x, int first, int last, float* __restrict out) {
  for (int r = first; r < last; ++r) {
    const float* w = weight + static_cast<std::ptrdiff_t>(r) * 3;
    if (w[0] == 0.0f && w[1] == 0.0f && w[2] == 0.0f) continue;
    const Float4 sum = GatherRowAvx2(a, r, x, cols);
    ScatterRowAvx2<false>(a, r, sum * Float4{w[0], w[1], w[2], 0.0f}, out);
  }
}

DSM_AVX2 void AdjointRows8(const RunRowSpans& a, const float* __restrict y, int first, int last,
                           float* __restrict out) {
  for (int r = first; r < last; ++r) {
    const float* py = y + static_cast<std::ptrdiff_t>(r) * 3;
    ScatterRowAvx2<false>(a, r, Float4{py[0], py[1], py[2], 0.0f}, out);
  }
}

DSM_AVX2 void NormalDiagonalRows8(const RunRowSpans& a, const float* __restrict weight, int first, int last,
                                  float* __restrict out) {
  for (int r = first; r < last; ++r) {
    const float* w = weight + static_cast<std::ptrdiff_t>(r) * 3;
    ScatterRowAvx2<true>(a, r, Float4{w[0], w[1], w[2], 0.0f}, out);
  }
}

#else  // Not compiled in: Use8LaneKernels() is false, the callers take the 4-lane forms.

Float4 GatherRow8(const RunRowSpans& a, int r, const float* __restrict x, int cols) {
  return GatherRow(a, r, x, cols);
}

void ScatterRow8(const RunRowSpans& a, int r, Float4 s, float* __restrict out) {
  ScatterRow<false>(a, r, s, out);
}

void ScatterSquaredRow8(const RunRowSpans& a, int r, Float4 s, float* __restrict out) {
  ScatterRow<true>(a, r, s, out);
}

void NormalProductRows8(const RunRowSpans&, int, const float* __restrict, const float* __restrict, int, int,
                        float* __restrict) {
  throw std::logic_error("rgb_runs: the 8-lane kernels are not compiled in");
}

void AdjointRows8(const RunRowSpans&, const float* __restrict, int, int, float* __restrict) {
  throw std::logic_error("rgb_runs: the 8-lane kernels are not compiled in");
}

void NormalDiagonalRows8(const RunRowSpans&, const float* __restrict, int, int, float* __restrict) {
  throw std::logic_error("rgb_runs: the 8-lane kernels are not compiled in");
}

#endif  // DSM_RGB_RUNS_8_LANES

}  // namespace rgb_runs
}  // namespace deblur_sr_mvs
