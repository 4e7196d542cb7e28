// The row-run layout of the capture operator: a lossless round trip with
// CSR, and products over the runs bit-identical to the same products over
// the CSR arrays (the layout changes the memory traffic, not the arithmetic).
#include "deblur_sr_mvs/core/imaging/row_run_matrix.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <random>
#include <tuple>
#include <vector>

#include <gtest/gtest.h>

#include <opencv2/core.hpp>

#include "../support/random_values.h"
#include "../support/same_bits.h"
#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/imaging/capture_operator.h"
#include "deblur_sr_mvs/core/imaging/normal_product.h"
#include "deblur_sr_mvs/core/imaging/rgb_run_kernels.h"

namespace deblur_sr_mvs {
namespace {

// Rows like a capture operator's: a few runs of neighbouring columns (some
// of length 1), at random places; some rows empty; every 11th row ends at
// the last column (the colour kernels read that pixel differently).
SparseMatrixRM RandomRunOperator(int rows, int cols, std::mt19937* rng) {
  std::uniform_int_distribution<int> runs_per_row(0, 6), length(1, 20), start(0, cols - 20);
  std::uniform_real_distribution<float> value(-1.0f, 1.0f);
  std::vector<Eigen::Triplet<float>> taps;
  for (int r = 0; r < rows; ++r) {
    const int runs = r % 7 == 3 ? 0 : runs_per_row(*rng);
    for (int k = 0; k < runs; ++k) {
      const int first = start(*rng), n = length(*rng);
      for (int i = 0; i < n; ++i) taps.emplace_back(r, first + i, value(*rng));
    }
    if (r % 11 == 5) {
      const int n = length(*rng);
      for (int i = cols - n; i < cols; ++i) taps.emplace_back(r, i, value(*rng));
    }
  }
  SparseMatrixRM a(rows, cols);
  a.setFromTriplets(taps.begin(), taps.end());
  a.makeCompressed();
  return a;
}

void ExpectSameCsr(const SparseMatrixRM& a, const SparseMatrixRM& b) {
  ASSERT_EQ(a.rows(), b.rows());
  ASSERT_EQ(a.cols(), b.cols());
  ASSERT_EQ(a.nonZeros(), b.nonZeros());
  EXPECT_EQ(std::memcmp(a.outerIndexPtr(), b.outerIndexPtr(), sizeof(int) * (a.rows() + 1)), 0);
  EXPECT_EQ(std::memcmp(a.innerIndexPtr(), b.innerIndexPtr(), sizeof(int) * a.nonZeros()), 0);
  EXPECT_EQ(std::memcmp(a.valuePtr(), b.valuePtr(), sizeof(float) * a.nonZeros()), 0);
}

TEST(RowRunMatrix, RoundTripsThroughCsr) {
  std::mt19937 rng(3);
  const SparseMatrixRM csr = RandomRunOperator(200, 900, &rng);
  const RowRunMatrix runs = RowRunMatrix::FromCsr(csr);
  EXPECT_EQ(runs.rows(), 200);
  EXPECT_EQ(runs.cols(), 900);
  EXPECT_EQ(runs.nonZeros(), csr.nonZeros());
  EXPECT_LT(runs.runs(), csr.nonZeros() / 3);  // runs were found
  EXPECT_LT(runs.Bytes(), csr.nonZeros() * (sizeof(float) + sizeof(int)));
  ExpectSameCsr(runs.ToCsr(), csr);
}

// A span of consecutive columns longer than a run may be (16-bit lengths)
// is split; the matrix is unchanged.
TEST(RowRunMatrix, SplitsRunsLongerThanTheLengthLimit) {
  const int cols = RowRunMatrix::kMaxRunLength + 1000;
  std::vector<Eigen::Triplet<float>> taps;
  for (int c = 0; c < cols; ++c) taps.emplace_back(0, c, 1.0f + c % 5);
  taps.emplace_back(1, 7, 2.0f);
  SparseMatrixRM csr(2, cols);
  csr.setFromTriplets(taps.begin(), taps.end());
  csr.makeCompressed();
  const RowRunMatrix runs = RowRunMatrix::FromCsr(csr);
  EXPECT_EQ(runs.runs(), 3);
  ExpectSameCsr(runs.ToCsr(), csr);
}

// The builder's form: rows in per-thread pieces (one may be empty).
TEST(RowRunMatrix, FromPiecesEqualsFromTheConcatenatedCsr) {
  std::mt19937 rng(5);
  const SparseMatrixRM csr = RandomRunOperator(60, 300, &rng);
  std::vector<int> row_taps(60);
  for (int r = 0; r < 60; ++r) row_taps[r] = csr.outerIndexPtr()[r + 1] - csr.outerIndexPtr()[r];
  const int split = csr.outerIndexPtr()[25];
  const RowRunMatrix pieces = RowRunMatrix::FromPieces(
      300, row_taps, {csr.innerIndexPtr(), csr.innerIndexPtr() + split, csr.innerIndexPtr()},
      {csr.valuePtr(), csr.valuePtr() + split, csr.valuePtr()},
      {static_cast<size_t>(split), static_cast<size_t>(csr.nonZeros() - split), 0});
  ExpectSameCsr(pieces.ToCsr(), csr);
  row_taps[0] += 1;
  EXPECT_THROW(RowRunMatrix::FromPieces(300, row_taps, {csr.innerIndexPtr()}, {csr.valuePtr()},
                                        {static_cast<size_t>(csr.nonZeros())}),
               InputError);
}

// The capture-operator builder's form: rows appended one at a time to
// blocks of consecutive rows (one block empty, one row longer than a run
// may be) give the matrix of FromPieces over the same CSR arrays bit for
// bit: the same runs (maximal, split at kMaxRunLength), row offsets and
// values.
TEST(RowRunMatrix, FromBlocksEqualsFromPiecesBitForBit) {
  std::mt19937 rng(7);
  const int long_row = RowRunMatrix::kMaxRunLength + 500;
  const int cols = long_row + 40;
  SparseMatrixRM csr = RandomRunOperator(90, cols, &rng);
  // Row 40 becomes one span longer than a run (plus a separate tap).
  std::vector<Eigen::Triplet<float>> taps;
  for (int r = 0; r < csr.rows(); ++r) {
    if (r == 40) continue;
    for (SparseMatrixRM::InnerIterator it(csr, r); it; ++it) taps.emplace_back(r, it.col(), it.value());
  }
  for (int c = 10; c < 10 + long_row; ++c) taps.emplace_back(40, c, 0.5f + c % 3);
  taps.emplace_back(40, cols - 1, 3.0f);
  csr.setFromTriplets(taps.begin(), taps.end());
  csr.makeCompressed();
  const int* outer = csr.outerIndexPtr();
  std::vector<RowRunMatrix::RowBlock> blocks(3);
  blocks[0].AppendRow(csr.innerIndexPtr(), csr.valuePtr(), 0);  // reused: cleared below
  for (RowRunMatrix::RowBlock& block : blocks) block.Clear();
  const int split = 50;  // rows [0, 50) in block 0, none in block 1, the rest in block 2
  for (int r = 0; r < csr.rows(); ++r) {
    blocks[r < split ? 0 : 2].AppendRow(csr.innerIndexPtr() + outer[r], csr.valuePtr() + outer[r],
                                        outer[r + 1] - outer[r]);
  }
  EXPECT_EQ(blocks[0].rows(), split);
  EXPECT_EQ(blocks[1].rows(), 0);
  const RowRunMatrix built = RowRunMatrix::FromBlocks(cols, {&blocks[0], &blocks[1], &blocks[2]});
  const RowRunMatrix reference = RowRunMatrix::FromCsr(csr);
  ASSERT_EQ(built.rows(), reference.rows());
  ASSERT_EQ(built.cols(), reference.cols());
  ASSERT_EQ(built.runs(), reference.runs());
  ASSERT_EQ(built.nonZeros(), reference.nonZeros());
  EXPECT_GT(reference.runs(), csr.rows());  // several runs per row, the long one split
  const size_t rows1 = static_cast<size_t>(built.rows()) + 1;
  EXPECT_EQ(std::memcmp(built.row_first_value(), reference.row_first_value(), sizeof(int) * rows1), 0);
  EXPECT_EQ(std::memcmp(built.row_first_run(), reference.row_first_run(), sizeof(int) * rows1), 0);
  EXPECT_EQ(std::memcmp(built.run_first_column(), reference.run_first_column(), sizeof(int) * built.runs()),
            0);
  EXPECT_EQ(std::memcmp(built.run_length(), reference.run_length(), sizeof(uint16_t) * built.runs()), 0);
  EXPECT_EQ(std::memcmp(built.values(), reference.values(), sizeof(float) * built.nonZeros()), 0);
  // A column past the matrix is refused.
  EXPECT_THROW(RowRunMatrix::FromBlocks(cols - 1, {&blocks[0], &blocks[1], &blocks[2]}), InputError);
}

class RowRunProducts : public ::testing::TestWithParam<std::tuple<int, int>> {};

// A^T W A x, A^T y, diag(A^T W A) and A x over the runs equal the same
// passes over the CSR arrays bit for bit (same multiply-adds in the same
// order; with 3 channels the runs take the 4-lane kernels of
// rgb_run_kernels.h, the CSR form the scalar ones), and the adjoint is the
// adjoint.
TEST_P(RowRunProducts, EqualTheCsrProductsBitForBitAndAreAdjoint) {
  const auto [channels, threads] = GetParam();
  std::mt19937 rng(17 + channels);
  const int rows = 400, cols = 1500;
  const SparseMatrixRM csr = RandomRunOperator(rows, cols, &rng);
  const RowRunMatrix runs = RowRunMatrix::FromCsr(csr);
  const cv::Mat x = RandomValues(cols, channels, -1.0f, 1.0f, &rng);
  const cv::Mat y = RandomValues(rows, channels, -1.0f, 1.0f, &rng);
  cv::Mat weight = RandomValues(rows, channels, 0.0f, 10.0f, &rng);
  weight.rowRange(0, 40).setTo(0.0);  // masked rows
  auto zeros = [&] { return cv::Mat(cv::Mat::zeros(cols, 1, CV_32FC(channels))); };
  cv::Mat normal_csr = zeros(), normal_runs = zeros();
  AddWeightedNormalProduct(csr, weight, x, &normal_csr, threads);
  AddWeightedNormalProduct(runs, weight, x, &normal_runs, threads);
  EXPECT_TRUE(SameBits(normal_runs, normal_csr));
  EXPECT_GT(cv::norm(normal_csr, cv::NORM_INF), 0.0);
  cv::Mat adjoint_csr = zeros(), adjoint_runs = zeros();
  AddAdjointProduct(csr, y, &adjoint_csr, threads);
  AddAdjointProduct(runs, y, &adjoint_runs, threads);
  EXPECT_TRUE(SameBits(adjoint_runs, adjoint_csr));
  cv::Mat diagonal_csr = zeros(), diagonal_runs = zeros();
  AddWeightedNormalDiagonal(csr, weight, &diagonal_csr, threads);
  AddWeightedNormalDiagonal(runs, weight, &diagonal_runs, threads);
  EXPECT_TRUE(SameBits(diagonal_runs, diagonal_csr));
  cv::Mat apply_csr, apply_runs;
  MultiplySparse(csr, x, &apply_csr, threads);
  MultiplySparse(runs, x, &apply_runs, threads);
  EXPECT_TRUE(SameBits(apply_runs, apply_csr));
  EXPECT_GT(cv::norm(apply_csr, cv::NORM_INF), 0.0);

  // The adjoint over the runs is the adjoint: <A x, y> = <x, A^T y>, with A x
  // summed from the CSR entries (an independent product).
  double lhs = 0.0, rhs = 0.0;
  for (int r = 0; r < rows; ++r) {
    for (SparseMatrixRM::InnerIterator it(csr, r); it; ++it) {
      for (int c = 0; c < channels; ++c) {
        lhs +=
            double(it.value()) * x.ptr<float>()[it.col() * channels + c] * y.ptr<float>()[r * channels + c];
      }
    }
  }
  for (int i = 0; i < cols * channels; ++i) rhs += double(x.ptr<float>()[i]) * adjoint_runs.ptr<float>()[i];
  EXPECT_NEAR(lhs, rhs, 1e-5 * std::abs(lhs));
}

// A x row by row as GatherRowChains defines it, written out from the CSR
// arrays: tap i of a run of consecutive columns goes to partial sum i mod 4,
// and the row is (s0 + s1) + (s2 + s3).
cv::Mat ChainedProduct(const SparseMatrixRM& a, const cv::Mat& x, int channels) {
  cv::Mat y = cv::Mat::zeros(static_cast<int>(a.rows()), 1, CV_32FC(channels));
  const int* outer = a.outerIndexPtr();
  const int* inner = a.innerIndexPtr();
  const float* value = a.valuePtr();
  for (int r = 0; r < a.rows(); ++r) {
    float s[4][4] = {};
    int position = 0;  // in the current run
    for (int k = outer[r]; k < outer[r + 1]; ++k) {
      if (k > outer[r] && inner[k] != inner[k - 1] + 1) position = 0;
      for (int c = 0; c < channels; ++c) {
        s[position % 4][c] += value[k] * x.ptr<float>()[inner[k] * channels + c];
      }
      ++position;
    }
    for (int c = 0; c < channels; ++c) {
      y.ptr<float>()[r * channels + c] = (s[0][c] + s[1][c]) + (s[2][c] + s[3][c]);
    }
  }
  return y;
}

// The gathers (A x; A^T W A x gathers the same way) sum in four partial sums
// in the order above, bit for bit, over both layouts and 1-4 channels (3:
// the 4-lane colour kernel over runs); against the exact sum they differ by
// float rounding only.
TEST(RowGather, SumsInFourPartialSumsOverTheRuns) {
  for (int channels = 1; channels <= 4; ++channels) {
    std::mt19937 rng(41 + channels);
    const int rows = 300, cols = 1200;
    const SparseMatrixRM csr = RandomRunOperator(rows, cols, &rng);
    const RowRunMatrix runs = RowRunMatrix::FromCsr(csr);
    const cv::Mat x = RandomValues(cols, channels, -1.0f, 1.0f, &rng);
    const cv::Mat expected = ChainedProduct(csr, x, channels);
    cv::Mat apply_csr, apply_runs;
    MultiplySparse(csr, x, &apply_csr, 1);
    MultiplySparse(runs, x, &apply_runs, 1);
    EXPECT_TRUE(SameBits(apply_runs, expected)) << channels << " channels";
    EXPECT_TRUE(SameBits(apply_csr, expected)) << channels << " channels";
    int differs = 0;
    for (int r = 0; r < rows; ++r) {
      for (int c = 0; c < channels; ++c) {
        double exact = 0.0, magnitude = 0.0;
        const int taps = csr.outerIndexPtr()[r + 1] - csr.outerIndexPtr()[r];
        for (SparseMatrixRM::InnerIterator it(csr, r); it; ++it) {
          const double term = double(it.value()) * x.ptr<float>()[it.col() * channels + c];
          exact += term;
          magnitude += std::abs(term);
        }
        const float got = apply_runs.ptr<float>()[r * channels + c];
        // A priori bound of a float sum: (taps + 3) unit roundoffs of the sum of |terms|.
        EXPECT_NEAR(got, exact, (taps + 3) * std::ldexp(1.0, -24) * magnitude) << "row " << r << " channel " << c;
        float single = 0.0f;  // one running sum
        for (SparseMatrixRM::InnerIterator it(csr, r); it; ++it) {
          single += it.value() * x.ptr<float>()[it.col() * channels + c];
        }
        differs += got != single;
      }
    }
    EXPECT_GT(differs, 0) << "the four partial sums should round differently from one sum somewhere";
  }
}

INSTANTIATE_TEST_SUITE_P(ChannelsAndThreads, RowRunProducts,
                         ::testing::Combine(::testing::Values(1, 2, 3, 4), ::testing::Values(1, 3)));

class L1ReweightPassTest : public ::testing::TestWithParam<int> {};

// The image update's fused reweighting (one pass over the rows) gives, bit
// for bit, what the separate passes give one after the other on one thread:
// A x (MultiplySparse), A x - b, the L1 weights scale / max(|r|, eps) (0
// outside the mask), diag(A^T W A) and A^T (-(W r)) added to what the
// outputs held. 1-4 channels (3: the colour kernels).
TEST_P(L1ReweightPassTest, EqualsTheSeparatePassesBitForBit) {
  const int channels = GetParam();
  std::mt19937 rng(29 + channels);
  const int rows = 500, cols = 1600;
  const RowRunMatrix a = RowRunMatrix::FromCsr(RandomRunOperator(rows, cols, &rng));
  const cv::Mat x = RandomValues(cols, channels, -1.0f, 1.0f, &rng);
  const cv::Mat b = RandomValues(rows, channels, -2.0f, 2.0f, &rng);
  cv::Mat mask(rows, 1, CV_8UC1);
  for (int r = 0; r < rows; ++r) mask.at<uchar>(r) = r % 9 == 4 ? 0 : 255;
  const cv::Mat diagonal0 = RandomValues(cols, channels, 0.0f, 1.0f, &rng);
  const cv::Mat adjoint0 = RandomValues(cols, channels, -1.0f, 1.0f, &rng);
  const double scale = 0.7, epsilon = 1e-3;
  for (const cv::Mat& used : {mask, cv::Mat()}) {
    // The separate passes.
    cv::Mat ax, residual_ref, weight_ref, temp;
    MultiplySparse(a, x, &ax, 1);
    residual_ref = ax - b;
    weight_ref.create(b.size(), b.type());
    for (int r = 0; r < rows; ++r) {
      for (int c = 0; c < channels; ++c) {
        const float value = residual_ref.ptr<float>()[r * channels + c];
        weight_ref.ptr<float>()[r * channels + c] =
            used.empty() || used.at<uchar>(r) != 0
                ? static_cast<float>(scale / std::max<double>(std::abs(value), epsilon))
                : 0.0f;
      }
    }
    cv::Mat diagonal_ref = diagonal0.clone(), adjoint_ref = adjoint0.clone();
    AddWeightedNormalDiagonal(a, weight_ref, &diagonal_ref, 1);
    cv::multiply(residual_ref, weight_ref, temp, -1.0);
    AddAdjointProduct(a, temp, &adjoint_ref, 1);
    // The fused pass.
    cv::Mat residual, weight, diagonal = diagonal0.clone(), adjoint = adjoint0.clone();
    L1ReweightPass(a, x, b, used, scale, epsilon, &residual, &weight, &diagonal, &adjoint);
    EXPECT_TRUE(SameBits(residual, residual_ref));
    EXPECT_TRUE(SameBits(weight, weight_ref));
    EXPECT_TRUE(SameBits(diagonal, diagonal_ref));
    EXPECT_TRUE(SameBits(adjoint, adjoint_ref));
    EXPECT_FALSE(SameBits(adjoint, adjoint0));  // it added something
  }
  cv::Mat residual, weight, diagonal = diagonal0.clone(), adjoint = adjoint0.clone();
  EXPECT_THROW(L1ReweightPass(a, x, b, cv::Mat(rows + 1, 1, CV_8UC1, cv::Scalar(255)), scale, epsilon,
                              &residual, &weight, &diagonal, &adjoint),
               InputError);
}

INSTANTIATE_TEST_SUITE_P(Channels, L1ReweightPassTest, ::testing::Values(1, 2, 3, 4));


// The colour products with the 8-lane kernels (rgb_run_kernels_avx2.cc, which
// the dispatch takes where the CPU has AVX2) and with the 4-lane ones, one
// call each.
struct RgbProducts {
  cv::Mat normal, adjoint, diagonal, apply, residual, weight, l1_diagonal, l1_adjoint;
};

RgbProducts RunRgbProducts(const RowRunMatrix& a, const cv::Mat& x, const cv::Mat& y, const cv::Mat& w,
                           const cv::Mat& start, int threads) {
  RgbProducts p{start.clone(), start.clone(), start.clone(), {}, {}, {}, start.clone(), start.clone()};
  AddWeightedNormalProduct(a, w, x, &p.normal, threads);
  AddAdjointProduct(a, y, &p.adjoint, threads);
  AddWeightedNormalDiagonal(a, w, &p.diagonal, threads);
  MultiplySparse(a, x, &p.apply, threads);
  L1ReweightPass(a, x, y, cv::Mat(), 0.7, 1e-3, &p.residual, &p.weight, &p.l1_diagonal, &p.l1_adjoint);
  return p;
}

// The 8-lane forms give the 4-lane forms' bits on random colour operators
// (runs of 1-20 columns: the 8-tap, 4-tap and single-tap paths; rows ending
// at the image's last pixel; masked rows; some inputs +-0), through the
// dispatched products (1 and 3 threads) and called row by row directly.
TEST(RgbRunKernels, EightLanesEqualFourLanesBitForBit) {
  if (!rgb_runs::Use8LaneKernels()) GTEST_SKIP() << "no 8-lane kernels on this CPU or compiler";
  for (int seed = 0; seed < 4; ++seed) {
    std::mt19937 rng(101 + seed);
    const int rows = 450, cols = 1700;
    const RowRunMatrix a = RowRunMatrix::FromCsr(RandomRunOperator(rows, cols, &rng));
    cv::Mat x = RandomValues(cols, 3, -1.0f, 1.0f, &rng);
    for (int i = 0; i < cols * 3; i += 37) x.ptr<float>()[i] = i % 2 == 0 ? 0.0f : -0.0f;
    const cv::Mat y = RandomValues(rows, 3, -2.0f, 2.0f, &rng);
    cv::Mat w = RandomValues(rows, 3, 0.0f, 10.0f, &rng);
    w.rowRange(0, 30).setTo(0.0);
    const cv::Mat start = RandomValues(cols, 3, -1.0f, 1.0f, &rng);
    for (const int threads : {1, 3}) {
      const RgbProducts eight = RunRgbProducts(a, x, y, w, start, threads);
      rgb_runs::Allow8LaneKernels(false);
      const RgbProducts four = RunRgbProducts(a, x, y, w, start, threads);
      rgb_runs::Allow8LaneKernels(true);
      const auto expect_same = [&](const cv::Mat& e, const cv::Mat& f) {
        EXPECT_TRUE(SameBits(e, f));
        EXPECT_GT(cv::norm(e, cv::NORM_INF), 0.0);
      };
      expect_same(eight.normal, four.normal);
      expect_same(eight.adjoint, four.adjoint);
      expect_same(eight.diagonal, four.diagonal);
      expect_same(eight.apply, four.apply);
      expect_same(eight.residual, four.residual);
      expect_same(eight.weight, four.weight);
      expect_same(eight.l1_diagonal, four.l1_diagonal);
      expect_same(eight.l1_adjoint, four.l1_adjoint);
      EXPECT_FALSE(SameBits(eight.normal, start));  // it added something
    }
    // Row by row, the exported kernels against the header's 4-lane ones.
    const RunRowSpans spans = RowSpansOf(a);
    cv::Mat out8 = start.clone(), out4 = start.clone();
    for (int r = 0; r < rows; ++r) {
      const rgb_runs::Float4 g8 = rgb_runs::GatherRow8(spans, r, x.ptr<float>(), cols);
      const rgb_runs::Float4 g4 = rgb_runs::GatherRow(spans, r, x.ptr<float>(), cols);
      ASSERT_EQ(std::memcmp(&g8, &g4, 3 * sizeof(float)), 0) << "row " << r;
      rgb_runs::ScatterRow8(spans, r, g8, out8.ptr<float>());
      rgb_runs::ScatterRow(spans, r, g4, out4.ptr<float>());
      rgb_runs::ScatterSquaredRow8(spans, r, g8, out8.ptr<float>());
      rgb_runs::ScatterRow<true>(spans, r, g4, out4.ptr<float>());
    }
    EXPECT_TRUE(SameBits(out8, out4));
    cv::Mat rows8 = start.clone(), rows4 = start.clone();
    rgb_runs::NormalProductRows8(spans, cols, w.ptr<float>(), x.ptr<float>(), 0, rows, rows8.ptr<float>());
    rgb_runs::Allow8LaneKernels(false);
    AddWeightedNormalProduct(a, w, x, &rows4, 1);
    rgb_runs::Allow8LaneKernels(true);
    EXPECT_TRUE(SameBits(rows8, rows4));
  }
}
}  // namespace
}  // namespace deblur_sr_mvs
