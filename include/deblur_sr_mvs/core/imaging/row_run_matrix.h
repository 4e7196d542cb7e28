// A row-major sparse float matrix stored as runs of consecutive columns.
//
// A capture operator's row (one LR pixel) holds the merged bilinear taps of
// its M x scale^2 samples: a few short spans of neighbouring HR pixels (about
// 5 runs of 13 columns at 640x480 HR). CSR stores one 32-bit column index per
// tap; this layout stores one first column and one 16-bit length per run, so
// a row costs about 4.5 bytes per tap instead of 8 and a product reads the
// latent image contiguously along each run. The values are kept in the order
// of the taps, so a product over the runs does the same multiply-adds in the
// same order as one over the CSR arrays (bit-identical results; see
// CsrRowSpans and GatherRowChains).
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include <Eigen/SparseCore>

namespace deblur_sr_mvs {

using SparseMatrixRM = Eigen::SparseMatrix<float, Eigen::RowMajor, int>;

class RowRunMatrix {
 public:
  // A run is at most this long; a longer span of consecutive columns is split.
  static constexpr int kMaxRunLength = 65535;

  RowRunMatrix() = default;

  // From a compressed row-major matrix; the taps of a row keep their order
  // (consecutive increasing columns form a run).
  static RowRunMatrix FromCsr(const SparseMatrixRM& csr);
  // From rows given in order as contiguous pieces of CSR arrays: piece p
  // holds piece_sizes[p] taps (piece_columns[p], piece_values[p]) of the next
  // rows; row r has row_taps[r] taps.
  static RowRunMatrix FromPieces(int cols, const std::vector<int>& row_taps,
                                 const std::vector<const int*>& piece_columns,
                                 const std::vector<const float*>& piece_values,
                                 const std::vector<size_t>& piece_sizes);
  // Rows appended one at a time (a builder's block of consecutive rows, e.g.
  // one thread's): each row's columns are split into runs as FromPieces
  // splits them (maximal spans of consecutive columns, at most
  // kMaxRunLength long), so that FromBlocks gives FromPieces' matrix bit for
  // bit without a column array of the whole block. Keeps its capacity
  // across Clear() (a builder reuses it from build to build).
  class RowBlock {
   public:
    void Clear();
    // Appends a row of `taps` taps; its columns must increase.
    void AppendRow(const int* columns, const float* values, int taps);
    int rows() const { return static_cast<int>(row_runs_.size()); }

   private:
    friend class RowRunMatrix;
    std::vector<int> row_runs_;  // per row
    std::vector<int> run_first_column_;
    std::vector<uint16_t> run_length_;
    std::vector<float> values_;
  };
  // The rows of the blocks in order (block b's after block b - 1's); throws
  // InputError for a run outside [0, cols).
  static RowRunMatrix FromBlocks(int cols, const std::vector<const RowBlock*>& blocks);

  // The same matrix in CSR form (for callers that need Eigen or a transpose).
  SparseMatrixRM ToCsr() const;

  int rows() const { return rows_; }
  int cols() const { return cols_; }
  long nonZeros() const { return static_cast<long>(values_.size()); }
  long runs() const { return static_cast<long>(run_first_column_.size()); }
  // Heap bytes of the arrays.
  size_t Bytes() const;

  // Row r: taps [row_first_value()[r], row_first_value()[r + 1]) of values(),
  // runs [row_first_run()[r], row_first_run()[r + 1]). Run k covers columns
  // run_first_column()[k] .. + run_length()[k] - 1, its values following the
  // previous run's.
  const int* row_first_value() const { return row_first_value_.data(); }
  const int* row_first_run() const { return row_first_run_.data(); }
  const int* run_first_column() const { return run_first_column_.data(); }
  const uint16_t* run_length() const { return run_length_.data(); }
  const float* values() const { return values_.data(); }

 private:
  int rows_ = 0;
  int cols_ = 0;
  std::vector<int> row_first_value_;  // rows + 1
  std::vector<int> row_first_run_;    // rows + 1
  std::vector<int> run_first_column_;
  std::vector<uint16_t> run_length_;
  std::vector<float> values_;
};

// The rows of a matrix in either layout as spans of consecutive columns, for
// product kernels written once for both: ForEachSpan(r, span) calls
// span(values, first_column, length) for the taps of row r in their stored
// order. Both layouts give the same spans: the runs of RowRunMatrix (a CSR
// row is split where its columns stop being consecutive, and after
// kMaxRunLength taps), so a kernel does the same multiply-adds in the same
// order for both layouts.
struct CsrRowSpans {
  const int* outer;
  const int* inner;
  const float* values;

  template <typename Span>
  void ForEachSpan(int r, const Span& span) const {
    const int end = outer[r + 1];
    for (int k = outer[r]; k < end;) {
      int next = k + 1;
      while (next < end && next - k < RowRunMatrix::kMaxRunLength && inner[next] == inner[next - 1] + 1) ++next;
      span(values + k, inner[k], next - k);
      k = next;
    }
  }
};

struct RunRowSpans {
  const int* row_first_value;
  const int* row_first_run;
  const int* run_first_column;
  const uint16_t* run_length;
  const float* values;
  template <typename Span>
  void ForEachSpan(int r, const Span& span) const {
    const float* v = values + row_first_value[r];
    for (int run = row_first_run[r]; run < row_first_run[r + 1]; ++run) {
      const int length = run_length[run];
      span(v, run_first_column[run], length);
      v += length;
    }
  }
};

// The gathers of the products (A x, and the first half of A^T W A x) sum a
// row's taps in kGatherChains partial sums: tap i of a span adds to partial
// sum i mod kGatherChains, and the row's value is (s0 + s1) + (s2 + s3).
// One running sum would make every tap wait for the previous tap's float
// add (a latency-bound chain); four independent chains let the CPU overlap
// them. The order is fixed by the spans, which both layouts share, so CSR
// and row runs give the same values bit for bit; against one running sum
// the values differ by float rounding only (RowGather.* tests).
constexpr int kGatherChains = 4;
static_assert(kGatherChains == 4, "the gathers' tails and final sums are written for four chains");

// out[c] = sum_k a(r, k) x(k * kChannels + c), c < kChannels, in the
// partial sums above.
template <int kChannels, typename Rows>
inline void GatherRowChains(const Rows& a, int r, const float* __restrict x, float* out) {
  float s[kGatherChains][kChannels] = {};
  a.ForEachSpan(r, [&](const float* __restrict v, int column, int length) {
    const float* __restrict px = x + static_cast<std::ptrdiff_t>(column) * kChannels;
    const auto add = [&](int chain, int i) {
      for (int c = 0; c < kChannels; ++c) s[chain][c] += v[i] * px[i * kChannels + c];
    };
    int i = 0;
    for (; i + kGatherChains <= length; i += kGatherChains) {
      for (int k = 0; k < kGatherChains; ++k) add(k, i + k);
    }
    const int tail = length - i;
    if (tail > 0) add(0, i);
    if (tail > 1) add(1, i + 1);
    if (tail > 2) add(2, i + 2);
  });
  for (int c = 0; c < kChannels; ++c) out[c] = (s[0][c] + s[1][c]) + (s[2][c] + s[3][c]);
}

// Throws InputError for an uncompressed CSR matrix.
CsrRowSpans RowSpansOf(const SparseMatrixRM& a);
RunRowSpans RowSpansOf(const RowRunMatrix& a);

}  // namespace deblur_sr_mvs
