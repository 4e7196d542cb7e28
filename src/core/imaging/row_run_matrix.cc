#include "deblur_sr_mvs/core/imaging/row_run_matrix.h"

#include <algorithm>
#include <limits>

#include "deblur_sr_mvs/core/common/errors.h"

namespace deblur_sr_mvs {
namespace {

// Calls run(first_column, length) for each run of the taps
// [begin, end) of one row.
template <typename Run>
void ForEachRun(const int* columns, size_t begin, size_t end, const Run& run) {
  size_t k = begin;
  while (k < end) {
    size_t next = k + 1;
    while (next < end && next - k < static_cast<size_t>(RowRunMatrix::kMaxRunLength) &&
           columns[next] == columns[next - 1] + 1)
      ++next;
    run(columns[k], static_cast<int>(next - k));
    k = next;
  }
}

}  // namespace

RowRunMatrix RowRunMatrix::FromCsr(const SparseMatrixRM& csr) {
  if (!csr.isCompressed()) throw InputError("row-run matrix: the CSR matrix must be compressed");
  const int rows = static_cast<int>(csr.rows());
  std::vector<int> row_taps(rows);
  for (int r = 0; r < rows; ++r) row_taps[r] = csr.outerIndexPtr()[r + 1] - csr.outerIndexPtr()[r];
  return FromPieces(static_cast<int>(csr.cols()), row_taps, {csr.innerIndexPtr()}, {csr.valuePtr()},
                    {static_cast<size_t>(csr.nonZeros())});
}

RowRunMatrix RowRunMatrix::FromPieces(int cols, const std::vector<int>& row_taps,
                                      const std::vector<const int*>& piece_columns,
                                      const std::vector<const float*>& piece_values,
                                      const std::vector<size_t>& piece_sizes) {
  if (piece_columns.size() != piece_sizes.size() || piece_values.size() != piece_sizes.size()) {
    throw InputError("row-run matrix: one column array, value array and size per piece");
  }
  size_t taps = 0;
  for (size_t size : piece_sizes) taps += size;
  size_t row_taps_sum = 0;
  for (int n : row_taps) row_taps_sum += static_cast<size_t>(n);
  if (row_taps_sum != taps) throw InputError("row-run matrix: the rows' taps do not add up to the pieces'");
  if (taps > static_cast<size_t>(std::numeric_limits<int>::max())) {
    throw InputError("row-run matrix: more than 2^31 - 1 non-zeros");
  }
  RowRunMatrix m;
  m.rows_ = static_cast<int>(row_taps.size());
  m.cols_ = cols;
  m.row_first_value_.resize(row_taps.size() + 1);
  m.row_first_run_.resize(row_taps.size() + 1);
  // Visits the rows piece by piece (a row lies within one piece).
  auto for_each_row = [&](const auto& visit) {
    size_t piece = 0, in_piece = 0;
    for (size_t r = 0; r < row_taps.size(); ++r) {
      while (piece < piece_sizes.size() && in_piece == piece_sizes[piece] && row_taps[r] > 0) {
        ++piece;
        in_piece = 0;
      }
      const size_t end = in_piece + static_cast<size_t>(row_taps[r]);
      if (row_taps[r] > 0 && (piece >= piece_sizes.size() || end > piece_sizes[piece])) {
        throw InputError("row-run matrix: a row spans two pieces");
      }
      visit(r, piece, in_piece, end);
      in_piece = end;
    }
  };
  // Counts the runs, then fills the arrays at their exact sizes.
  size_t runs = 0;
  for_each_row([&](size_t, size_t piece, size_t begin, size_t end) {
    if (begin < end) ForEachRun(piece_columns[piece], begin, end, [&](int, int) { ++runs; });
  });
  if (runs > static_cast<size_t>(std::numeric_limits<int>::max())) {
    throw InputError("row-run matrix: more than 2^31 - 1 runs");
  }
  m.run_first_column_.resize(runs);
  m.run_length_.resize(runs);
  m.values_.resize(taps);
  int value = 0, run = 0;
  for_each_row([&](size_t r, size_t piece, size_t begin, size_t end) {
    m.row_first_value_[r] = value;
    m.row_first_run_[r] = run;
    if (begin == end) return;
    const int* columns = piece_columns[piece];
    ForEachRun(columns, begin, end, [&](int first_column, int length) {
      if (first_column < 0 || first_column + length > cols) {
        throw InputError("row-run matrix: a column index is outside the matrix");
      }
      m.run_first_column_[run] = first_column;
      m.run_length_[run] = static_cast<uint16_t>(length);
      ++run;
    });
    std::copy(piece_values[piece] + begin, piece_values[piece] + end, m.values_.begin() + value);
    value += static_cast<int>(end - begin);
  });
  m.row_first_value_[row_taps.size()] = value;
  m.row_first_run_[row_taps.size()] = run;
  return m;
}

void RowRunMatrix::RowBlock::Clear() {
  row_runs_.clear();
  run_first_column_.clear();
  run_length_.clear();
  values_.clear();
}

void RowRunMatrix::RowBlock::AppendRow(const int* columns, const float* values, int taps) {
  const size_t runs_before = run_first_column_.size();
  ForEachRun(columns, 0, static_cast<size_t>(std::max(taps, 0)), [&](int first_column, int length) {
    run_first_column_.push_back(first_column);
    run_length_.push_back(static_cast<uint16_t>(length));
  });
  row_runs_.push_back(static_cast<int>(run_first_column_.size() - runs_before));
  if (taps > 0) values_.insert(values_.end(), values, values + taps);
}

RowRunMatrix RowRunMatrix::FromBlocks(int cols, const std::vector<const RowBlock*>& blocks) {
  size_t rows = 0, runs = 0, taps = 0;
  for (const RowBlock* block : blocks) {
    rows += block->row_runs_.size();
    runs += block->run_first_column_.size();
    taps += block->values_.size();
  }
  if (taps > static_cast<size_t>(std::numeric_limits<int>::max()) ||
      runs > static_cast<size_t>(std::numeric_limits<int>::max())) {
    throw InputError("row-run matrix: more than 2^31 - 1 non-zeros or runs");
  }
  RowRunMatrix m;
  m.rows_ = static_cast<int>(rows);
  m.cols_ = cols;
  m.row_first_value_.resize(rows + 1);
  m.row_first_run_.resize(rows + 1);
  // Reserved and appended block by block: not zero-filled first (these are
  // operator-sized, and a fresh block of memory would be touched twice).
  m.run_first_column_.reserve(runs);
  m.run_length_.reserve(runs);
  m.values_.reserve(taps);
  int row = 0, run = 0, value = 0;
  for (const RowBlock* block : blocks) {
    const int block_runs = static_cast<int>(block->run_first_column_.size());
    for (int k = 0; k < block_runs; ++k) {
      const int first_column = block->run_first_column_[k];
      if (first_column < 0 || first_column + block->run_length_[k] > cols) {
        throw InputError("row-run matrix: a column index is outside the matrix");
      }
    }
    m.run_first_column_.insert(m.run_first_column_.end(), block->run_first_column_.begin(),
                               block->run_first_column_.end());
    m.run_length_.insert(m.run_length_.end(), block->run_length_.begin(), block->run_length_.end());
    m.values_.insert(m.values_.end(), block->values_.begin(), block->values_.end());
    int block_run = 0;
    for (int row_runs : block->row_runs_) {
      m.row_first_value_[row] = value;
      m.row_first_run_[row] = run;
      for (int k = 0; k < row_runs; ++k) value += block->run_length_[block_run + k];
      block_run += row_runs;
      run += row_runs;
      ++row;
    }
  }
  m.row_first_value_[rows] = value;
  m.row_first_run_[rows] = run;
  return m;
}

SparseMatrixRM RowRunMatrix::ToCsr() const {
  SparseMatrixRM csr(rows_, cols_);
  csr.resizeNonZeros(nonZeros());
  int* outer = csr.outerIndexPtr();
  int* inner = csr.innerIndexPtr();
  for (int r = 0; r <= rows_; ++r) outer[r] = row_first_value_.empty() ? 0 : row_first_value_[r];
  for (int r = 0; r < rows_; ++r) {
    int k = row_first_value_[r];
    for (int run = row_first_run_[r]; run < row_first_run_[r + 1]; ++run) {
      for (int i = 0; i < run_length_[run]; ++i) inner[k++] = run_first_column_[run] + i;
    }
  }
  std::copy(values_.begin(), values_.end(), csr.valuePtr());
  return csr;
}

CsrRowSpans RowSpansOf(const SparseMatrixRM& a) {
  if (!a.isCompressed()) throw InputError("sparse product: the CSR matrix must be compressed");
  return {a.outerIndexPtr(), a.innerIndexPtr(), a.valuePtr()};
}

RunRowSpans RowSpansOf(const RowRunMatrix& a) {
  return {a.row_first_value(), a.row_first_run(), a.run_first_column(), a.run_length(), a.values()};
}

size_t RowRunMatrix::Bytes() const {
  return (row_first_value_.size() + row_first_run_.size() + run_first_column_.size()) * sizeof(int) +
         run_length_.size() * sizeof(uint16_t) + values_.size() * sizeof(float);
}

}  // namespace deblur_sr_mvs
