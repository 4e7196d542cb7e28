// Products with the weighted normal operator A^T W A of a linear capture
// operator A (a row-major sparse matrix: one row per observed pixel, one
// column per latent pixel, interleaved channels sharing it; W diagonal, one
// weight per observed value), as the IRLS solvers of eq:imgUpdate and of the
// depth update need them. Each streams the rows of A once and scatters into
// the latent grid, so no transposed copy of A is made: for row r it forms
// (A x)_r, weighs it and adds a_r^T times it to the output. On more than one
// thread, contiguous blocks of rows go to per-thread latent accumulators that
// are summed at the end (a fixed order for a given thread count).
#pragma once

#include <opencv2/core.hpp>

#include "deblur_sr_mvs/core/imaging/row_run_matrix.h"

namespace deblur_sr_mvs {

// out += A^T diag(weight) A x. `x` and `out`: CV_32FC(C) with one pixel per
// column of A (any shape, continuous); `weight`: CV_32FC(C), one pixel per
// row of A. Rows whose weights are all zero are skipped. The row-run and the
// CSR forms of one matrix give bit-identical results.
void AddWeightedNormalProduct(const RowRunMatrix& a, const cv::Mat& weight, const cv::Mat& x, cv::Mat* out,
                              int threads);
void AddWeightedNormalProduct(const SparseMatrixRM& a, const cv::Mat& weight, const cv::Mat& x, cv::Mat* out,
                              int threads);

// out += A^T y (the adjoint, by scattering the rows of A); `y` has one pixel
// per row of A, `out` one per column.
void AddAdjointProduct(const RowRunMatrix& a, const cv::Mat& y, cv::Mat* out, int threads);
void AddAdjointProduct(const SparseMatrixRM& a, const cv::Mat& y, cv::Mat* out, int threads);

// out += diag(A^T diag(weight) A) per channel: out_j += sum_r weight_r a_rj^2
// (the Jacobi preconditioner of the normal equations).
void AddWeightedNormalDiagonal(const RowRunMatrix& a, const cv::Mat& weight, cv::Mat* out, int threads);
void AddWeightedNormalDiagonal(const SparseMatrixRM& a, const cv::Mat& weight, cv::Mat* out, int threads);

// One IRLS reweighting of an L1 data term |A x - b| in ONE pass over the
// rows of A (each row's taps are read once, for its gather and its two
// scatters, instead of once per pass), on one thread. Per observed value:
//   residual = (A x) - b,
//   weight = mask ? scale / max(|residual|, epsilon) : 0 (in double, stored
//            as float; an empty mask: every value),
// and, added over the rows,
//   diagonal += diag(A^T diag(weight) A)   (AddWeightedNormalDiagonal),
//   adjoint  += A^T (-(weight .* residual)) (AddAdjointProduct).
// `residual` and `weight` take b's shape (CV_32FC(C)); `x`, `diagonal` and
// `adjoint` have one pixel per column of A. Every value is bit for bit what
// MultiplySparse, the subtraction, the weighting and the one-thread
// AddWeightedNormalDiagonal and AddAdjointProduct give one after the other
// (test L1ReweightPassTest.EqualsTheSeparatePassesBitForBit).
void L1ReweightPass(const RowRunMatrix& a, const cv::Mat& x, const cv::Mat& b, const cv::Mat& mask,
                    double scale, double epsilon, cv::Mat* residual, cv::Mat* weight, cv::Mat* diagonal,
                    cv::Mat* adjoint);

}  // namespace deblur_sr_mvs
