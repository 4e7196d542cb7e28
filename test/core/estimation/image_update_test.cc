// The linear algebra of the image update (eq:imgUpdate): the one-pass
// products with A^T W A against the two-pass form through a transposed
// copy, the Jacobi-preconditioned CG against plain CG and a direct solve.
#include "deblur_sr_mvs/core/estimation/image_update.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <functional>
#include <random>
#include <utility>
#include <vector>

#include <gtest/gtest.h>
#include <Eigen/Dense>

#include "../support/random_values.h"
#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/imaging/capture_operator.h"
#include "deblur_sr_mvs/core/imaging/normal_product.h"

namespace deblur_sr_mvs {
namespace {

// A random rows x cols operator with up to `per_row` taps per row (merged),
// positive like a capture operator's taps.
SparseMatrixRM RandomOperator(int rows, int cols, int per_row, std::mt19937* rng) {
  std::uniform_int_distribution<int> column(0, cols - 1);
  std::uniform_real_distribution<float> value(0.01f, 1.0f);
  std::vector<Eigen::Triplet<float>> taps;
  for (int r = 0; r < rows; ++r) {
    for (int k = 0; k < per_row; ++k) taps.emplace_back(r, column(*rng), value(*rng));
  }
  SparseMatrixRM a(rows, cols);
  a.setFromTriplets(taps.begin(), taps.end());
  a.makeCompressed();
  return a;
}

// Largest |a - b| relative to the largest |b|.
double RelativeMaxDifference(const cv::Mat& a, const cv::Mat& b) {
  return cv::norm(a, b, cv::NORM_INF) / cv::norm(b, cv::NORM_INF);
}

// A^T (W (A x)) in two passes through a transposed copy (the former form).
cv::Mat TwoPassNormalProduct(const SparseMatrixRM& a, const cv::Mat& weight, const cv::Mat& x) {
  SparseMatrixRM at;
  TransposeSparse(a, &at, 1);
  cv::Mat ax, back;
  MultiplySparse(a, x, &ax, 1);
  cv::multiply(ax, weight, ax);
  MultiplySparse(at, ax, &back, 1);
  return back;
}

class NormalProduct : public ::testing::TestWithParam<std::tuple<int, int>> {};

TEST_P(NormalProduct, OnePassEqualsTwoPassesToFloatRounding) {
  const auto [channels, threads] = GetParam();
  std::mt19937 rng(7 + channels);
  const int rows = 300, cols = 1200;
  const SparseMatrixRM a = RandomOperator(rows, cols, 40, &rng);
  const cv::Mat x = RandomValues(cols, channels, -1.0f, 1.0f, &rng);
  cv::Mat weight = RandomValues(rows, channels, 0.0f, 10.0f, &rng);
  weight.rowRange(0, 30).setTo(0.0);  // masked rows are skipped: still exact
  cv::Mat out = cv::Mat::zeros(cols, 1, CV_32FC(channels));
  AddWeightedNormalProduct(a, weight, x, &out, threads);
  const cv::Mat expected = TwoPassNormalProduct(a, weight, x);
  EXPECT_LT(RelativeMaxDifference(out, expected), 1e-5);

  // It adds to the output: a second call doubles it.
  cv::Mat twice = out.clone();
  AddWeightedNormalProduct(a, weight, x, &twice, threads);
  EXPECT_LT(RelativeMaxDifference(twice, 2.0 * expected), 1e-5);
}

TEST_P(NormalProduct, AdjointAndDiagonalMatchTheDenseMatrix) {
  const auto [channels, threads] = GetParam();
  std::mt19937 rng(11 + channels);
  const int rows = 80, cols = 200;
  const SparseMatrixRM a = RandomOperator(rows, cols, 12, &rng);
  const Eigen::MatrixXd dense = Eigen::MatrixXd(a.cast<double>());
  const cv::Mat y = RandomValues(rows, channels, -1.0f, 1.0f, &rng);
  const cv::Mat weight = RandomValues(rows, channels, 0.0f, 5.0f, &rng);
  cv::Mat adjoint = cv::Mat::zeros(cols, 1, CV_32FC(channels));
  cv::Mat diagonal = cv::Mat::zeros(cols, 1, CV_32FC(channels));
  AddAdjointProduct(a, y, &adjoint, threads);
  AddWeightedNormalDiagonal(a, weight, &diagonal, threads);
  for (int c = 0; c < channels; ++c) {
    Eigen::VectorXd yc(rows), wc(rows);
    for (int r = 0; r < rows; ++r) {
      yc[r] = y.ptr<float>()[r * channels + c];
      wc[r] = weight.ptr<float>()[r * channels + c];
    }
    const Eigen::VectorXd expected_adjoint = dense.transpose() * yc;
    const Eigen::MatrixXd normal = dense.transpose() * wc.asDiagonal() * dense;
    for (int j = 0; j < cols; ++j) {
      EXPECT_NEAR(adjoint.ptr<float>()[j * channels + c], expected_adjoint[j], 1e-4);
      EXPECT_NEAR(diagonal.ptr<float>()[j * channels + c], normal(j, j), 1e-4 * (1.0 + normal(j, j)));
    }
  }
}

INSTANTIATE_TEST_SUITE_P(ChannelsAndThreads, NormalProduct,
                         ::testing::Combine(::testing::Values(1, 3), ::testing::Values(1, 3)));

// A small SPD system N = B^T B + I with badly scaled unknowns (D N D).
struct SmallSystem {
  Eigen::MatrixXd normal;
  Eigen::VectorXd rhs;
};

SmallSystem BadlyScaledSystem(int n) {
  std::mt19937 rng(3);
  std::normal_distribution<double> gaussian;
  Eigen::MatrixXd b(2 * n, n);
  for (int i = 0; i < b.size(); ++i) b.data()[i] = gaussian(rng);
  Eigen::VectorXd scale(n);
  for (int i = 0; i < n; ++i) scale[i] = std::pow(10.0, 2.0 * i / (n - 1));  // 1 .. 100
  SmallSystem system;
  system.normal =
      scale.asDiagonal() * (b.transpose() * b + Eigen::MatrixXd::Identity(n, n)) * scale.asDiagonal();
  system.rhs = Eigen::VectorXd(n);
  for (int i = 0; i < n; ++i) system.rhs[i] = gaussian(rng);
  return system;
}

// Runs SolveJacobiPcg from x = 0 with the given diagonal; returns x and the steps.
std::pair<Eigen::VectorXd, int> SolveSmall(const SmallSystem& system, const cv::Mat& diagonal, int max_steps,
                                           double tolerance) {
  const int n = static_cast<int>(system.rhs.size());
  const Eigen::MatrixXf normal = system.normal.cast<float>();
  const auto apply = [&normal, n](const cv::Mat& x, cv::Mat* out) {
    out->create(n, 1, CV_32FC1);
    Eigen::Map<const Eigen::VectorXf> in(x.ptr<float>(), n);
    Eigen::Map<Eigen::VectorXf>(out->ptr<float>(), n) = normal * in;
  };
  cv::Mat x = cv::Mat::zeros(n, 1, CV_32FC1);
  cv::Mat residual(n, 1, CV_32FC1);
  for (int i = 0; i < n; ++i) residual.at<float>(i) = static_cast<float>(system.rhs[i]);
  const int steps = SolveJacobiPcg(apply, diagonal, residual, max_steps, tolerance, 1, &x);
  Eigen::VectorXd solution(n);
  for (int i = 0; i < n; ++i) solution[i] = x.at<float>(i);
  return {solution, steps};
}

TEST(JacobiPcg, ConvergesToTheSameSolutionAsPlainCgInFewerSteps) {
  const int n = 40;
  const SmallSystem system = BadlyScaledSystem(n);
  const Eigen::VectorXd exact = system.normal.ldlt().solve(system.rhs);
  cv::Mat jacobi(n, 1, CV_32FC1), ones(n, 1, CV_32FC1, cv::Scalar(1.0));
  for (int i = 0; i < n; ++i) jacobi.at<float>(i) = static_cast<float>(system.normal(i, i));
  const auto [preconditioned, pcg_steps] = SolveSmall(system, jacobi, 2000, 1e-5);
  const auto [plain, cg_steps] = SolveSmall(system, ones, 2000, 1e-5);  // M = I: plain CG
  EXPECT_LT((preconditioned - exact).norm() / exact.norm(), 1e-3);
  EXPECT_LT((plain - exact).norm() / exact.norm(), 1e-3);
  EXPECT_LT((preconditioned - plain).norm() / exact.norm(), 1e-3);
  EXPECT_LT(pcg_steps, cg_steps);
}

TEST(JacobiPcg, StopsAtTheRelativeResidualOrTheCap) {
  const int n = 40;
  const SmallSystem system = BadlyScaledSystem(n);
  cv::Mat jacobi(n, 1, CV_32FC1);
  for (int i = 0; i < n; ++i) jacobi.at<float>(i) = static_cast<float>(system.normal(i, i));
  const auto [loose, loose_steps] = SolveSmall(system, jacobi, 2000, 0.1);
  EXPECT_LE((system.rhs - system.normal * loose).norm(), 0.1 * system.rhs.norm() * (1.0 + 1e-4));
  EXPECT_EQ(SolveSmall(system, jacobi, 3, 0.0).second, 3);
  EXPECT_LT(loose_steps, SolveSmall(system, jacobi, 2000, 1e-5).second);
}

// PCG as SolvePcg took its steps before its vector updates were fused:
// x += alpha d and r -= alpha N d as two Axpy passes, d = z + beta d as
// OpenCV's d *= beta then an Axpy; sums in double as SolvePcg forms them
// (CgDot, tested below).
int UnfusedPcg(const std::function<void(const cv::Mat&, cv::Mat*)>& apply, const cv::Mat& inverse_diagonal,
               cv::Mat residual, int max_steps, cv::Mat* x) {
  const auto dot = [](const cv::Mat& a, const cv::Mat& b) { return CgDot(a, b, 1); };
  const auto axpy = [](double alpha, const cv::Mat& in, cv::Mat* out) {
    const float a = static_cast<float>(alpha);
    for (size_t i = 0; i < in.total(); ++i) out->ptr<float>()[i] += a * in.ptr<float>()[i];
  };
  cv::Mat z, normal_direction;
  cv::multiply(residual, inverse_diagonal, z);
  cv::Mat direction = z.clone();
  double rz = dot(residual, z);
  int steps = 0;
  for (; steps < max_steps; ++steps) {
    apply(direction, &normal_direction);
    const double alpha = rz / dot(direction, normal_direction);
    axpy(alpha, direction, x);
    axpy(-alpha, normal_direction, &residual);
    cv::multiply(residual, inverse_diagonal, z);
    const double rz_next = dot(residual, z);
    const double beta = rz_next / rz;
    rz = rz_next;
    direction *= beta;
    axpy(1.0, z, &direction);
  }
  return steps;
}

// The CG's sums: four interleaved partial sums in double, the n mod 4 last
// values in the first, added as (s0 + s1) + (s2 + s3), bit for bit; the
// one-pass pair equals the two sums; both within double rounding of the
// exact sum.
TEST(CgReductions, SumInFourInterleavedPartialSums) {
  std::mt19937 rng(31);
  std::uniform_real_distribution<float> value(-1.0f, 1.0f);
  for (const int n : {0, 1, 3, 4, 5, 7, 8, 13, 1001, 30000}) {
    cv::Mat a(std::max(n, 1), 1, CV_32FC1), b(std::max(n, 1), 1, CV_32FC1);
    for (int i = 0; i < a.rows; ++i) {
      a.at<float>(i) = value(rng);
      b.at<float>(i) = value(rng);
    }
    if (n == 0) a = b = cv::Mat(0, 1, CV_32FC1);
    double s[4] = {0.0, 0.0, 0.0, 0.0}, exact = 0.0, magnitude = 0.0;
    for (int i = 0; i < n; ++i) {
      const double term = static_cast<double>(a.at<float>(i)) * b.at<float>(i);
      s[i < n - n % 4 ? i % 4 : 0] += term;
      exact += term;  // products of floats are exact in double
      magnitude += std::abs(term);
    }
    const double expected = (s[0] + s[1]) + (s[2] + s[3]);
    const double got = CgDot(a, b, 1);
    EXPECT_EQ(std::memcmp(&got, &expected, sizeof(got)), 0) << n;
    EXPECT_NEAR(got, exact, (n + 2) * std::ldexp(1.0, -53) * magnitude) << n;
    const auto [aa, ab] = CgSquaredNormAndDot(a, b, 1);
    const double aa_expected = CgDot(a, a, 1);
    EXPECT_EQ(std::memcmp(&aa, &aa_expected, sizeof(aa)), 0) << n;
    EXPECT_EQ(std::memcmp(&ab, &got, sizeof(ab)), 0) << n;
  }
}

// SolvePcg's fused vector updates (one pass for x and r, one for d) give
// the unfused steps' iterates bit for bit.
TEST(JacobiPcg, FusedVectorUpdatesEqualTheUnfusedStepsBitForBit) {
  const int n = 40;
  const SmallSystem system = BadlyScaledSystem(n);
  const Eigen::MatrixXf normal = system.normal.cast<float>();
  const auto apply = [&normal, n](const cv::Mat& x, cv::Mat* out) {
    out->create(n, 1, CV_32FC1);
    Eigen::Map<const Eigen::VectorXf> in(x.ptr<float>(), n);
    Eigen::Map<Eigen::VectorXf>(out->ptr<float>(), n) = normal * in;
  };
  cv::Mat inverse_diagonal(n, 1, CV_32FC1), residual(n, 1, CV_32FC1);
  for (int i = 0; i < n; ++i) {
    inverse_diagonal.at<float>(i) = static_cast<float>(1.0 / static_cast<float>(system.normal(i, i)));
    residual.at<float>(i) = static_cast<float>(system.rhs[i]);
  }
  const auto jacobi = [&inverse_diagonal](const cv::Mat& r, cv::Mat* z) {
    cv::multiply(r, inverse_diagonal, *z);
  };
  cv::Mat fused = cv::Mat::zeros(n, 1, CV_32FC1), unfused = cv::Mat::zeros(n, 1, CV_32FC1);
  ASSERT_EQ(SolvePcg(apply, jacobi, residual.clone(), 12, 0.0, 1, &fused), 12);
  ASSERT_EQ(UnfusedPcg(apply, inverse_diagonal, residual.clone(), 12, &unfused), 12);
  EXPECT_EQ(std::memcmp(fused.data, unfused.data, n * sizeof(float)), 0);
  EXPECT_GT(cv::norm(fused, cv::NORM_INF), 0.0);
}

// The dense matrix of x -> diag(data) x + scale * D^T diag(v) D x on a
// rows x cols image with `channels` interleaved channels.
Eigen::MatrixXd DenseTvSystem(const cv::Mat& data_diagonal, const cv::Mat& v, double scale) {
  const int n = static_cast<int>(data_diagonal.total() * data_diagonal.channels());
  Eigen::MatrixXd dense(n, n);
  cv::Mat unit(data_diagonal.size(), data_diagonal.type()),
      column(data_diagonal.size(), data_diagonal.type());
  for (int j = 0; j < n; ++j) {
    unit.setTo(0.0);
    unit.ptr<float>()[j] = 1.0f;
    column.setTo(0.0);
    AddWeightedLaplacian(unit, v, scale, &column, 1);
    for (int i = 0; i < n; ++i) dense(i, j) = column.ptr<float>()[i];
    dense(j, j) += data_diagonal.ptr<float>()[j];
  }
  return dense;
}

// out += scale * D^T diag(v) D x pixel by pixel: the four edges of a pixel
// (right, left, down, up; an edge's weight is v at its left or upper end)
// summed in that order where the neighbour exists, as AddWeightedLaplacian
// did before its interior loop lost the checks.
void CheckedWeightedLaplacian(const cv::Mat& x, const cv::Mat& v, double scale, cv::Mat* out) {
  const int channels = x.channels();
  for (int y = 0; y < x.rows; ++y) {
    for (int col = 0; col < x.cols; ++col) {
      const int neighbour_x[4] = {col + 1, col - 1, col, col};
      const int neighbour_y[4] = {y, y, y + 1, y - 1};
      for (int c = 0; c < channels; ++c) {
        const auto at = [channels, c](const cv::Mat& m, int yy, int xx) {
          return m.ptr<float>(yy)[xx * channels + c];
        };
        float sum = 0.0f;
        for (int k = 0; k < 4; ++k) {
          const int nx = neighbour_x[k], ny = neighbour_y[k];
          if (nx < 0 || ny < 0 || nx >= x.cols || ny >= x.rows) continue;
          const float weight = k % 2 == 0 ? at(v, y, col) : at(v, ny, nx);
          sum += weight * (at(x, y, col) - at(x, ny, nx));
        }
        out->ptr<float>(y)[col * channels + c] += static_cast<float>(scale) * sum;
      }
    }
  }
}

// The row kernels without per-pixel checks add the same terms in the same
// order: bit for bit the checked stencil, on grids with and without
// interior, 1 and 3 channels, on one and two threads.
TEST(WeightedLaplacian, EqualsTheCheckedStencilBitForBit) {
  std::mt19937 rng(29);
  for (const cv::Size size :
       {cv::Size(1, 1), cv::Size(5, 1), cv::Size(1, 4), cv::Size(2, 2), cv::Size(9, 7)}) {
    for (const int channels : {1, 3}) {
      for (const int threads : {1, 2}) {
        const int n = size.area();
        const cv::Mat x = RandomValues(n, channels, -1.0f, 1.0f, &rng).reshape(channels, size.height);
        const cv::Mat v = RandomValues(n, channels, 0.1f, 20.0f, &rng).reshape(channels, size.height);
        const cv::Mat start = RandomValues(n, channels, -1.0f, 1.0f, &rng).reshape(channels, size.height);
        cv::Mat fast = start.clone(), checked = start.clone();
        AddWeightedLaplacian(x, v, 0.45, &fast, threads);
        CheckedWeightedLaplacian(x, v, 0.45, &checked);
        ASSERT_EQ(std::memcmp(fast.data, checked.data, fast.total() * fast.elemSize()), 0)
            << size << " channels " << channels << " threads " << threads;
      }
    }
  }
}

class LaplacianGaussSeidel : public ::testing::TestWithParam<int> {};

INSTANTIATE_TEST_SUITE_P(Channels, LaplacianGaussSeidel, ::testing::Values(1, 3));

// z = M^-1 r with M = (D + L) D^-1 (D + L^T) of the dense system, L its
// strictly lower part in the order of the values (raster, channels
// interleaved).
TEST_P(LaplacianGaussSeidel, IsTheSymmetricGaussSeidelInverseOfTheDenseSystem) {
  const int channels = GetParam();
  std::mt19937 rng(13 + channels);
  const int rows = 5, cols = 6, n = rows * cols * channels;
  const cv::Mat data = RandomValues(rows * cols, channels, 0.0f, 2.0f, &rng).reshape(channels, rows);
  const cv::Mat v = RandomValues(rows * cols, channels, 0.1f, 20.0f, &rng).reshape(channels, rows);
  const double scale = 0.45;
  const Eigen::MatrixXd dense = DenseTvSystem(data, v, scale);
  cv::Mat diagonal = data.clone();
  AddWeightedLaplacianDiagonal(v, scale, &diagonal);
  for (int i = 0; i < n; ++i) ASSERT_NEAR(diagonal.ptr<float>()[i], dense(i, i), 1e-4 * dense(i, i));
  const Eigen::MatrixXd lower = dense.triangularView<Eigen::StrictlyLower>();
  const Eigen::VectorXd d = dense.diagonal();
  const Eigen::MatrixXd m = (Eigen::MatrixXd(d.asDiagonal()) + lower) * d.cwiseInverse().asDiagonal() *
                            (Eigen::MatrixXd(d.asDiagonal()) + lower.transpose());
  ASSERT_LT((m - m.transpose()).norm(), 1e-9 * m.norm());  // symmetric, as PCG needs
  const cv::Mat r = RandomValues(rows * cols, channels, -1.0f, 1.0f, &rng).reshape(channels, rows);
  cv::Mat z;
  ApplyLaplacianGaussSeidel(diagonal, v, scale, r, &z);
  Eigen::VectorXd rv(n);
  for (int i = 0; i < n; ++i) rv[i] = r.ptr<float>()[i];
  const Eigen::VectorXd expected = m.ldlt().solve(rv);
  for (int i = 0; i < n; ++i)
    EXPECT_NEAR(z.ptr<float>()[i], expected[i], 1e-4 * expected.cwiseAbs().maxCoeff());
}

// The symmetric Gauss-Seidel sweeps in plain raster order (the form before
// the wavefront), with the inverse diagonal as ApplyLaplacianGaussSeidel
// forms it.
cv::Mat RasterGaussSeidel(const cv::Mat& diagonal, const cv::Mat& v, double scale, const cv::Mat& r) {
  const int channels = r.channels(), width = r.cols, height = r.rows, stride = width * channels;
  const float s = static_cast<float>(scale);
  cv::Mat inverse(diagonal.size(), diagonal.type());
  for (size_t i = 0; i < diagonal.total() * channels; ++i) {
    const float d = diagonal.ptr<float>()[i];
    inverse.ptr<float>()[i] = d > 0.0f ? 1.0f / d : 1.0f;
  }
  const float* pinv = inverse.ptr<float>();
  const float* pv = v.ptr<float>();
  const float* pr = r.ptr<float>();
  cv::Mat z(r.size(), r.type());
  float* pz = z.ptr<float>();
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      for (int c = 0; c < channels; ++c) {
        const long i = static_cast<long>(y) * stride + x * channels + c;
        float acc = pr[i];
        if (x > 0) acc += s * pv[i - channels] * pz[i - channels];
        if (y > 0) acc += s * pv[i - stride] * pz[i - stride];
        pz[i] = acc * pinv[i];
      }
    }
  }
  for (int y = height - 1; y >= 0; --y) {
    for (int x = width - 1; x >= 0; --x) {
      for (int c = channels - 1; c >= 0; --c) {
        const long i = static_cast<long>(y) * stride + x * channels + c;
        float acc = 0.0f;
        if (x + 1 < width) acc += pz[i + channels];
        if (y + 1 < height) acc += pz[i + stride];
        pz[i] += s * pv[i] * acc * pinv[i];
      }
    }
  }
  return z;
}

// The wavefront sweeps (blocks of rows as interleaved chains) give the
// raster sweeps' values bit for bit, at sizes that are and are not multiples
// of the block, down to one row or one column.
TEST(LaplacianGaussSeidel, WavefrontEqualsRasterSweeps) {
  std::mt19937 rng(29);
  for (const cv::Size size : {cv::Size(1, 1), cv::Size(1, 7), cv::Size(9, 1), cv::Size(2, 3), cv::Size(13, 8),
                              cv::Size(17, 11), cv::Size(40, 23)}) {
    for (int channels = 1; channels <= 4; ++channels) {
      const int n = size.area();
      const cv::Mat v = RandomValues(n, channels, 0.1f, 20.0f, &rng).reshape(channels, size.height);
      cv::Mat diagonal = RandomValues(n, channels, 0.0f, 2.0f, &rng).reshape(channels, size.height);
      AddWeightedLaplacianDiagonal(v, 0.45, &diagonal);
      diagonal.ptr<float>()[0] = 0.0f;  // a value without a diagonal (inverse 1)
      const cv::Mat r = RandomValues(n, channels, -1.0f, 1.0f, &rng).reshape(channels, size.height);
      cv::Mat z;
      ApplyLaplacianGaussSeidel(diagonal, v, 0.45, r, &z);
      const cv::Mat expected = RasterGaussSeidel(diagonal, v, 0.45, r);
      ASSERT_EQ(std::memcmp(z.data, expected.data, z.total() * z.elemSize()), 0)
          << size << " channels " << channels;
      EXPECT_GT(cv::norm(z, cv::NORM_INF), 0.0);
    }
  }
}

// On a TV-dominated system (large TV weights on a flat image, a weak data
// term), CG with the Gauss-Seidel preconditioner reaches the same solution
// as Jacobi-CG, in fewer steps.
TEST(LaplacianGaussSeidelPcg, ReachesTheJacobiSolutionInFewerSteps) {
  std::mt19937 rng(17);
  const int rows = 16, cols = 20, n = rows * cols;
  const cv::Mat data = RandomValues(n, 1, 0.01f, 0.1f, &rng).reshape(1, rows);
  const cv::Mat v = RandomValues(n, 1, 100.0f, 1000.0f, &rng).reshape(1, rows);
  const double scale = 0.45;
  const Eigen::MatrixXd dense = DenseTvSystem(data, v, scale);
  Eigen::VectorXd rhs(n);
  std::normal_distribution<double> gaussian;
  for (int i = 0; i < n; ++i) rhs[i] = gaussian(rng);
  const Eigen::VectorXd exact = dense.ldlt().solve(rhs);
  cv::Mat diagonal = data.clone();
  AddWeightedLaplacianDiagonal(v, scale, &diagonal);
  const auto apply = [&data, &v, scale](const cv::Mat& x, cv::Mat* out) {
    cv::multiply(x, data, *out);
    AddWeightedLaplacian(x, v, scale, out, 1);
  };
  const auto solve = [&](const std::function<void(const cv::Mat&, cv::Mat*)>& precondition) {
    cv::Mat x = cv::Mat::zeros(rows, cols, CV_32FC1);
    cv::Mat residual(rows, cols, CV_32FC1);
    for (int i = 0; i < n; ++i) residual.ptr<float>()[i] = static_cast<float>(rhs[i]);
    const int steps = SolvePcg(apply, precondition, residual, 5000, 1e-5, 1, &x);
    Eigen::VectorXd solution(n);
    for (int i = 0; i < n; ++i) solution[i] = x.ptr<float>()[i];
    return std::make_pair(solution, steps);
  };
  const auto [jacobi, jacobi_steps] =
      solve([&diagonal](const cv::Mat& r, cv::Mat* z) { cv::divide(r, diagonal, *z); });
  const auto [gauss_seidel, gauss_seidel_steps] = solve([&diagonal, &v, scale](const cv::Mat& r, cv::Mat* z) {
    ApplyLaplacianGaussSeidel(diagonal, v, scale, r, z);
  });
  EXPECT_LT((jacobi - exact).norm() / exact.norm(), 1e-3);
  EXPECT_LT((gauss_seidel - exact).norm() / exact.norm(), 1e-3);
  EXPECT_LT(gauss_seidel_steps, jacobi_steps);
}

// A small deblurring problem: a capture operator with motion blur and 2x
// down-sampling, observing a random image.
struct SmallDeblurProblem {
  CaptureOperator op;
  cv::Mat truth, observation;
};

SmallDeblurProblem MakeSmallDeblurProblem() {
  std::mt19937 rng(5);
  const int hr_rows = 24, hr_cols = 32;
  CaptureGeometry geometry;
  geometry.camera_hr = PinholeCamera(hr_cols, hr_rows, 30.0, 30.0, hr_cols / 2.0, hr_rows / 2.0);
  geometry.depth_hr = cv::Mat(hr_rows, hr_cols, CV_32FC1, cv::Scalar(2.0));
  geometry.T_world_cam = SE3(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0.0, 0.0, 0.0));
  geometry.T_world_neighbour = SE3(Eigen::Matrix3d::Identity(), Eigen::Vector3d(-0.05, 0.0, 0.0));
  geometry.stamp = 1.0;
  geometry.neighbour_stamp = 0.9;
  geometry.exposure = 0.08;
  CaptureOperatorOptions op_options;
  op_options.samples = 10;
  SmallDeblurProblem problem;
  problem.op = BuildCaptureOperator(geometry, op_options);
  problem.truth = RandomValues(hr_rows * hr_cols, 1, 0.0f, 1.0f, &rng).reshape(1, hr_rows);
  problem.op.Apply(problem.truth, &problem.observation);
  return problem;
}

// The update lowers the energy of the small deblurring problem from a flat
// start, and reports the work it did.
TEST(ImageUpdate, LowersTheEnergyOfARandomProblem) {
  const SmallDeblurProblem problem = MakeSmallDeblurProblem();
  std::vector<LinearL1Term> terms{{&problem.op, &problem.observation, cv::Mat(), 1.0}};
  ImageUpdateOptions options;
  options.lambda_i = 0.01;
  cv::Mat image(problem.truth.size(), CV_32FC1, cv::Scalar(0.5));
  const double before = ImageEnergy(terms, options.lambda_i, image);
  const ImageUpdateStats stats = UpdateImage(terms, options, &image);
  const double after = ImageEnergy(terms, options.lambda_i, image);
  EXPECT_LT(after, 0.5 * before);
  ASSERT_EQ(12, problem.observation.rows);
  ASSERT_EQ(16, problem.observation.cols);
  EXPECT_EQ(stats.reweightings, options.irls_iterations);
  EXPECT_GE(stats.cg_steps, options.irls_iterations);
  EXPECT_LE(stats.cg_steps, options.irls_iterations * options.cg_iterations);
  EXPECT_EQ(stats.operator_passes, 3L * stats.reweightings + 2L * stats.cg_steps);  // one term
}

// The proximity term (QuadraticAnchor): weight 0 is the update of before,
// bit for bit; a wrong-sized anchor throws.
TEST(QuadraticAnchor, ZeroWeightIsTheUpdateOfBefore) {
  const SmallDeblurProblem problem = MakeSmallDeblurProblem();
  const std::vector<LinearL1Term> terms{{&problem.op, &problem.observation, cv::Mat(), 1.0}};
  ImageUpdateOptions options;
  options.lambda_i = 0.01;
  options.num_threads = 1;
  const cv::Mat start(problem.truth.size(), CV_32FC1, cv::Scalar(0.5));
  cv::Mat plain = start.clone(), anchored = start.clone();
  UpdateImage(terms, options, &plain);
  const cv::Mat anchor_image = problem.truth.clone();
  const QuadraticAnchor zero{&anchor_image, 0.0};
  UpdateImage(terms, options, &anchored, &zero);
  EXPECT_EQ(cv::norm(plain, anchored, cv::NORM_INF), 0.0);
  const QuadraticAnchor wrong{&problem.observation, 1.0};  // LR size
  EXPECT_THROW(UpdateImage(terms, options, &anchored, &wrong), InputError);
}

// The proximity term pulls the solution to the anchor: a weight far above the
// data terms' curvature gives the anchor; a moderate one lands between the
// anchor-free solution and the anchor, and lowers the energy with the term.
TEST(QuadraticAnchor, PullsTheSolutionTowardsTheAnchor) {
  const SmallDeblurProblem problem = MakeSmallDeblurProblem();
  const std::vector<LinearL1Term> terms{{&problem.op, &problem.observation, cv::Mat(), 1.0}};
  ImageUpdateOptions options;
  options.lambda_i = 0.01;
  options.num_threads = 1;
  options.irls_iterations = 6;
  options.cg_iterations = 50;
  options.cg_tolerance = 0.0;
  const cv::Mat start(problem.truth.size(), CV_32FC1, cv::Scalar(0.5));
  const cv::Mat anchor_image(problem.truth.size(), CV_32FC1, cv::Scalar(0.3));
  cv::Mat plain = start.clone(), strong = start.clone();
  UpdateImage(terms, options, &plain);
  const QuadraticAnchor heavy{&anchor_image, 1e6};
  UpdateImage(terms, options, &strong, &heavy);
  EXPECT_LT(cv::norm(strong, anchor_image, cv::NORM_INF), 1e-3);
  cv::Mat moderate = start.clone();
  const QuadraticAnchor some{&anchor_image, 50.0};
  UpdateImage(terms, options, &moderate, &some);
  const double to_anchor = cv::norm(moderate, anchor_image), plain_to_anchor = cv::norm(plain, anchor_image);
  EXPECT_LT(to_anchor, plain_to_anchor);
  EXPECT_GT(to_anchor, cv::norm(strong, anchor_image));
}

}  // namespace
}  // namespace deblur_sr_mvs
