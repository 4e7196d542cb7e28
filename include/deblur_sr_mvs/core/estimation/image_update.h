// The latent-image update of eq:imgUpdate: L1 data terms through linear
// capture operators plus isotropic TV, solved by IRLS with a warm-started
// conjugate-gradient inner solver.
//
// Why IRLS + CG rather than a primal-dual method: every term is a sparse
// linear operator we can apply and transpose in milliseconds, IRLS converges
// in a handful of reweightings from the previous iterate (the outer loop warm
// starts it), and each reweighted problem is a well-conditioned SPD system
// that CG reduces monotonically; a primal-dual method on the same energy
// needs hundreds of operator applications and step sizes tied to ||Psi||.
#pragma once

#include <functional>
#include <utility>
#include <vector>

#include <opencv2/core.hpp>

#include "deblur_sr_mvs/core/imaging/capture_operator.h"

namespace deblur_sr_mvs {

// The preconditioner of the image update's CG.
enum class ImagePreconditioner {
  kJacobi,  // 1 / diag(N)
  // One symmetric Gauss-Seidel sweep on diag(N) + the off-diagonal TV
  // stencil: the IRLS TV weights are large on flat areas, where Jacobi-CG
  // moves information one pixel per step; the sweeps carry it across the
  // image in one application.
  kTvGaussSeidel,
};

struct ImageUpdateOptions {
  double lambda_i = 0.45;   // weight of the image TV (paper: 0.3 - 0.6)
  int irls_iterations = 4;  // reweightings per update
  // Preconditioned CG per reweighted system: at most cg_iterations
  // steps, fewer once the residual of the normal equations is below
  // cg_tolerance x its value at the warm start (0: always cg_iterations).
  int cg_iterations = 10;
  double cg_tolerance = 0.05;
  ImagePreconditioner preconditioner = ImagePreconditioner::kTvGaussSeidel;
  // The estimator's image phases between the first and the last (which
  // gives the output images) start from the latent the previous phase
  // restored (only the structure moved): they use these counts instead of
  // irls_iterations and cg_iterations. With the Gauss-Seidel preconditioner
  // 2 x 5 keep the accuracy of 4 x 10 (1.56x fewer operator passes over a
  // 3-iteration run); with Jacobi they lost up to 0.55 dB (BENCHMARKS.md
  // "A Gauss-Seidel preconditioner: the middle image phases at 2 x 5").
  int refine_irls_iterations = 2;
  int refine_cg_iterations = 5;
  // The estimator's first image phase (from the bicubic frames or the given
  // latents) runs first_irls_iterations reweightings of up to cg_iterations
  // steps; its last phase (the output images), when refinement phases came
  // before it, runs final_irls_iterations of up to final_cg_iterations. A
  // phase that is both first and last, and a last phase right after the
  // first (one iteration), run irls_iterations x cg_iterations. 3 x 10
  // first and 2 x 13 last keep the accuracy of 4 x 10 in both on lateral,
  // arc, forward and hand-held paths with 24 % fewer operator passes over a
  // 3-iteration run (BENCHMARKS.md "Fewer reweightings in the first and the
  // last image phase").
  int first_irls_iterations = 3;
  int final_irls_iterations = 2;
  int final_cg_iterations = 13;
  double residual_epsilon = 1e-3;  // L1 smoothing: weights 1 / max(|r|, eps) (intensity in [0, 1])
  double tv_epsilon = 1e-3;        // TV smoothing: 1 / max(|grad I|, eps)
  int num_threads = 0;             // 0: OpenMP default
  void Check() const;
};

// One L1 term  weight * sum_{x in mask} |(op * I)(x) - observation(x)|_1.
struct LinearL1Term {
  const CaptureOperator* op = nullptr;
  const cv::Mat* observation = nullptr;  // LR, CV_32FC(C)
  cv::Mat mask;                          // LR CV_8UC1 (non-zero = used); empty = all
  double weight = 1.0;
};

// Value of sum(terms) + lambda_i * TV(image) (isotropic TV per channel);
// for reports and tests (the update does not need it).
double ImageEnergy(const std::vector<LinearL1Term>& terms, double lambda_i, const cv::Mat& image);

// Isotropic total variation sum_x |grad I(x)|_2 with forward differences
// (Neumann boundary), summed over channels.
double TotalVariation(const cv::Mat& image);

// out += scale * D^T diag(v) D x per channel: the weighted Laplacian of
// forward differences with Neumann boundary, the IRLS form of a TV term with
// weights v (same size and channels as x).
void AddWeightedLaplacian(const cv::Mat& x, const cv::Mat& v, double scale, cv::Mat* out, int threads);
// out += scale * diag(D^T diag(v) D): the diagonal of the operator above.
void AddWeightedLaplacianDiagonal(const cv::Mat& v, double scale, cv::Mat* out);

// a . b of two float images of the same size (all channels), in double:
// four interleaved partial sums (value i to sum i mod 4; the last n mod 4
// values to sum 0), added as (s0 + s1) + (s2 + s3); with threads > 1 each
// thread sums its share so. The CG's reductions (SolvePcg).
double CgDot(const cv::Mat& a, const cv::Mat& b, int threads);
// (a . a, a . b) in one pass, each summed as CgDot sums.
std::pair<double, double> CgSquaredNormAndDot(const cv::Mat& a, const cv::Mat& b, int threads);

// Preconditioned conjugate gradients on N x = b from the current *x, given
// residual = b - N x there (consumed): at most max_iterations steps, stopping
// once ||r||_2 <= relative_tolerance * ||r_0||_2. apply_preconditioner(r, z)
// sets z = M^-1 r for a symmetric positive definite M. Returns the steps taken.
int SolvePcg(const std::function<void(const cv::Mat&, cv::Mat*)>& apply_normal,
             const std::function<void(const cv::Mat&, cv::Mat*)>& apply_preconditioner, cv::Mat residual,
             int max_iterations, double relative_tolerance, int threads, cv::Mat* x);

// z = M^-1 r for the symmetric Gauss-Seidel preconditioner
// M = (D + L) D^-1 (D + L^T) of the matrix diag(diagonal) + the off-diagonal
// part of scale * D^T diag(v) D (AddWeightedLaplacian): L its strictly
// lower part in raster order. `diagonal` must include the stencil's own
// diagonal (entries <= 0 count as 1).
void ApplyLaplacianGaussSeidel(const cv::Mat& diagonal, const cv::Mat& v, double scale, const cv::Mat& r,
                               cv::Mat* z);

// The same M^-1 for the many applications of one CG solve: the diagonal is
// inverted once, at construction; `v` is shared (a cv::Mat header), not copied.
class LaplacianGaussSeidelPreconditioner {
 public:
  LaplacianGaussSeidelPreconditioner(const cv::Mat& diagonal, const cv::Mat& v, double scale);
  void Apply(const cv::Mat& r, cv::Mat* z) const;

 private:
  cv::Mat inverse_diagonal_;
  cv::Mat v_;
  double scale_;
};

// Jacobi-preconditioned conjugate gradients on N x = b from the current *x,
// given residual = b - N x there (consumed): at most max_iterations steps,
// stopping once ||r||_2 <= relative_tolerance * ||r_0||_2. `diagonal` is
// diag(N) (entries <= 0 are left unscaled). Returns the steps taken.
int SolveJacobiPcg(const std::function<void(const cv::Mat&, cv::Mat*)>& apply_normal, const cv::Mat& diagonal,
                   cv::Mat residual, int max_iterations, double relative_tolerance, int threads, cv::Mat* x);

// The work an update did. Operator passes count the streams over the rows
// of one data term's operator: an apply, an adjoint or a diagonal pass is 1,
// a one-pass normal product A^T W A x is 2 (it does the multiply-adds of an
// apply and an adjoint).
struct ImageUpdateStats {
  int reweightings = 0;
  int cg_steps = 0;
  long operator_passes = 0;
  ImageUpdateStats& operator+=(const ImageUpdateStats& other) {
    reweightings += other.reweightings;
    cg_steps += other.cg_steps;
    operator_passes += other.operator_passes;
    return *this;
  }
};

// A quadratic proximity term (weight / 2) ||I - anchor||^2 over every HR
// value (the plug-and-play step of DenoisedAnchorOptions).
struct QuadraticAnchor {
  const cv::Mat* anchor = nullptr;  // HR, the image's size and type
  double weight = 0.0;
};

// Minimises the energy over `image` (HR, CV_32FC(C), updated in place from
// its current value); ImageEnergy gives the energy reached. With `anchor`
// (non-null, weight > 0) the energy also holds its proximity term.
ImageUpdateStats UpdateImage(const std::vector<LinearL1Term>& terms, const ImageUpdateOptions& options,
                             cv::Mat* image, const QuadraticAnchor* anchor = nullptr);

}  // namespace deblur_sr_mvs
