#include "deblur_sr_mvs/core/estimation/image_update.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <tuple>
#include <utility>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/common/options_check.h"
#include "deblur_sr_mvs/core/common/runtime.h"
#include "deblur_sr_mvs/core/imaging/normal_product.h"

namespace deblur_sr_mvs {
namespace {

size_t NumValues(const cv::Mat& m) {
  return m.total() * m.channels();
}

// a . b and, with kSquare, a . a of n values: four interleaved partial sums
// each (value i to sum i mod 4, the last n mod 4 values to sum 0, added as
// (s0 + s1) + (s2 + s3)), i.e. four independent chains of double adds
// instead of one, which bounded the CG's reductions by the add latency.
// Same values up to double rounding as one running sum.
template <bool kSquare>
void InterleavedSums(const cv::Mat& a, const cv::Mat& b, int threads, double* ab, double* aa) {
  const float* pa = a.ptr<float>();
  const float* pb = b.ptr<float>();
  const long n = static_cast<long>(NumValues(a)), blocks = n / 4;
  double ab0 = 0.0, ab1 = 0.0, ab2 = 0.0, ab3 = 0.0, aa0 = 0.0, aa1 = 0.0, aa2 = 0.0, aa3 = 0.0;
  const auto add = [pa, pb](long i, double& ab_sum, double& aa_sum) {
    ab_sum += static_cast<double>(pa[i]) * pb[i];
    if (kSquare) aa_sum += static_cast<double>(pa[i]) * pa[i];
  };
#pragma omp parallel for reduction(+ : ab0, ab1, ab2, ab3, aa0, aa1, aa2, aa3) num_threads(threads) \
    schedule(static)
  for (long k = 0; k < blocks; ++k) {
    add(4 * k, ab0, aa0);
    add(4 * k + 1, ab1, aa1);
    add(4 * k + 2, ab2, aa2);
    add(4 * k + 3, ab3, aa3);
  }
  for (long i = 4 * blocks; i < n; ++i) add(i, ab0, aa0);
  *ab = (ab0 + ab1) + (ab2 + ab3);
  if (aa != nullptr) *aa = (aa0 + aa1) + (aa2 + aa3);
}

}  // namespace

double CgDot(const cv::Mat& a, const cv::Mat& b, int threads) {
  double ab = 0.0;
  InterleavedSums<false>(a, b, threads, &ab, nullptr);
  return ab;
}

std::pair<double, double> CgSquaredNormAndDot(const cv::Mat& a, const cv::Mat& b, int threads) {
  double ab = 0.0, aa = 0.0;
  InterleavedSums<true>(a, b, threads, &ab, &aa);
  return {aa, ab};
}

namespace {

// x += alpha * d and r -= alpha * q in one pass (each value as Axpy forms it).
void StepSolutionAndResidual(double alpha, const cv::Mat& d, const cv::Mat& q, cv::Mat* x, cv::Mat* r,
                             int threads) {
  const float* __restrict pd = d.ptr<float>();
  const float* __restrict pq = q.ptr<float>();
  float* __restrict px = x->ptr<float>();
  float* __restrict pr = r->ptr<float>();
  const long n = static_cast<long>(NumValues(d));
  const float a = static_cast<float>(alpha), minus_a = static_cast<float>(-alpha);
#pragma omp parallel for num_threads(threads) schedule(static)
  for (long i = 0; i < n; ++i) {
    px[i] += a * pd[i];
    pr[i] += minus_a * pq[i];
  }
}

// d = z + beta d in one pass, each value as `d *= beta` (OpenCV: d * (float)
// beta + 0) followed by Axpy(1, z, d) formed it.
void NextDirection(double beta, const cv::Mat& z, cv::Mat* d, int threads) {
  const float* __restrict pz = z.ptr<float>();
  float* __restrict pd = d->ptr<float>();
  const long n = static_cast<long>(NumValues(z));
  const float b = static_cast<float>(beta), one = 1.0f;
#pragma omp parallel for num_threads(threads) schedule(static)
  for (long i = 0; i < n; ++i) {
    const float scaled = pd[i] * b + 0.0f;
    pd[i] = scaled + one * pz[i];
  }
}

// Per-channel TV weights v = 1 / max(|grad I|, eps) on the HR grid.
void TvWeights(const cv::Mat& image, double epsilon, cv::Mat* weights) {
  const int channels = image.channels();
  const int width = image.cols, height = image.rows;
  weights->create(image.size(), image.type());
  for (int y = 0; y < height; ++y) {
    const float* row = image.ptr<float>(y);
    const float* next = image.ptr<float>(std::min(y + 1, height - 1));
    float* out = weights->ptr<float>(y);
    for (int x = 0; x < width; ++x) {
      const int right = std::min(x + 1, width - 1);
      for (int c = 0; c < channels; ++c) {
        const float gx = row[right * channels + c] - row[x * channels + c];
        const float gy = next[x * channels + c] - row[x * channels + c];
        out[x * channels + c] =
            static_cast<float>(1.0 / std::max(std::sqrt(gx * gx + gy * gy), static_cast<float>(epsilon)));
      }
    }
  }
}

struct TermState {
  cv::Mat residual;  // LR
  cv::Mat weight;    // LR, per value: term weight * mask / max(|r|, eps)
};

}  // namespace

void ImageUpdateOptions::Check() const {
  CheckAtLeast("image update: lambda_i", lambda_i, 0.0);
  CheckAtLeast("image update: irls_iterations", irls_iterations, 1);
  CheckAtLeast("image update: cg_iterations", cg_iterations, 1);
  CheckAtLeast("image update: refine_irls_iterations", refine_irls_iterations, 1);
  CheckAtLeast("image update: refine_cg_iterations", refine_cg_iterations, 1);
  CheckAtLeast("image update: first_irls_iterations", first_irls_iterations, 1);
  CheckAtLeast("image update: final_irls_iterations", final_irls_iterations, 1);
  CheckAtLeast("image update: final_cg_iterations", final_cg_iterations, 1);
  CheckInRange("image update: cg_tolerance", cg_tolerance, 0.0, 1.0);
  CheckAbove("image update: residual_epsilon", residual_epsilon, 0.0);
  CheckAbove("image update: tv_epsilon", tv_epsilon, 0.0);
}

namespace {

// One row of AddWeightedLaplacian: kUp / kDown say whether the rows above
// and below exist. The terms are added in the same order at every pixel
// (right, left, down, up), so the interior loop, free of branches, gives the
// same sums as the border pixels' checked form.
template <bool kUp, bool kDown>
void AddWeightedLaplacianRow(const float* __restrict px, const float* __restrict pv, float s, int width,
                             int channels, int stride, float* __restrict po) {
  const auto pixel = [&](int xx, int c) {
    const long i = static_cast<long>(xx) * channels + c;
    float acc = 0.0f;
    if (xx + 1 < width) acc += pv[i] * (px[i] - px[i + channels]);
    if (xx > 0) acc += pv[i - channels] * (px[i] - px[i - channels]);
    if (kDown) acc += pv[i] * (px[i] - px[i + stride]);
    if (kUp) acc += pv[i - stride] * (px[i] - px[i - stride]);
    po[i] += s * acc;
  };
  for (int c = 0; c < channels; ++c) pixel(0, c);
  const long interior_end = static_cast<long>(width - 1) * channels;
  for (long i = channels; i < interior_end; ++i) {
    float acc = 0.0f;
    acc += pv[i] * (px[i] - px[i + channels]);
    acc += pv[i - channels] * (px[i] - px[i - channels]);
    if (kDown) acc += pv[i] * (px[i] - px[i + stride]);
    if (kUp) acc += pv[i - stride] * (px[i] - px[i - stride]);
    po[i] += s * acc;
  }
  if (width > 1)
    for (int c = 0; c < channels; ++c) pixel(width - 1, c);
}

}  // namespace

void AddWeightedLaplacian(const cv::Mat& x, const cv::Mat& v, double scale, cv::Mat* out, int threads) {
  const int channels = x.channels();
  const int width = x.cols, height = x.rows;
  const int stride = width * channels;
  const float s = static_cast<float>(scale);
  const float* px = x.ptr<float>();
  const float* pv = v.ptr<float>();
  float* po = out->ptr<float>();
#pragma omp parallel for num_threads(threads) schedule(static)
  for (int y = 0; y < height; ++y) {
    const long offset = static_cast<long>(y) * stride;
    const bool up = y > 0, down = y + 1 < height;
    if (up && down) {
      AddWeightedLaplacianRow<true, true>(px + offset, pv + offset, s, width, channels, stride, po + offset);
    } else if (up) {
      AddWeightedLaplacianRow<true, false>(px + offset, pv + offset, s, width, channels, stride, po + offset);
    } else if (down) {
      AddWeightedLaplacianRow<false, true>(px + offset, pv + offset, s, width, channels, stride, po + offset);
    } else {
      AddWeightedLaplacianRow<false, false>(px + offset, pv + offset, s, width, channels, stride,
                                            po + offset);
    }
  }
}

void AddWeightedLaplacianDiagonal(const cv::Mat& v, double scale, cv::Mat* out) {
  const int channels = v.channels();
  const int width = v.cols, height = v.rows;
  const int stride = width * channels;
  const float s = static_cast<float>(scale);
  const float* pv = v.ptr<float>();
  float* po = out->ptr<float>();
  for (int y = 0; y < height; ++y) {
    for (int xx = 0; xx < width; ++xx) {
      for (int c = 0; c < channels; ++c) {
        const long i = static_cast<long>(y) * stride + xx * channels + c;
        float acc = 0.0f;
        if (xx + 1 < width) acc += pv[i];
        if (xx > 0) acc += pv[i - channels];
        if (y + 1 < height) acc += pv[i];
        if (y > 0) acc += pv[i - stride];
        po[i] += s * acc;
      }
    }
  }
}

double TotalVariation(const cv::Mat& image) {
  const int channels = image.channels();
  double sum = 0.0;
  for (int y = 0; y < image.rows; ++y) {
    const float* row = image.ptr<float>(y);
    const float* next = image.ptr<float>(std::min(y + 1, image.rows - 1));
    for (int x = 0; x < image.cols; ++x) {
      const int right = std::min(x + 1, image.cols - 1);
      for (int c = 0; c < channels; ++c) {
        const double gx = row[right * channels + c] - row[x * channels + c];
        const double gy = next[x * channels + c] - row[x * channels + c];
        sum += std::sqrt(gx * gx + gy * gy);
      }
    }
  }
  return sum;
}

double ImageEnergy(const std::vector<LinearL1Term>& terms, double lambda_i, const cv::Mat& image) {
  double energy = lambda_i * TotalVariation(image);
  cv::Mat predicted;
  for (const LinearL1Term& term : terms) {
    term.op->Apply(image, &predicted);
    const int channels = predicted.channels();
    double sum = 0.0;
    for (int y = 0; y < predicted.rows; ++y) {
      const float* p = predicted.ptr<float>(y);
      const float* b = term.observation->ptr<float>(y);
      const uchar* m = term.mask.empty() ? nullptr : term.mask.ptr<uchar>(y);
      for (int x = 0; x < predicted.cols; ++x) {
        if (m != nullptr && m[x] == 0) continue;
        for (int c = 0; c < channels; ++c) sum += std::abs(p[x * channels + c] - b[x * channels + c]);
      }
    }
    energy += term.weight * sum;
  }
  return energy;
}

namespace {

// The Jacobi preconditioner M^-1 = 1 / diag(N) where the diagonal is
// positive (1 elsewhere).
void InverseDiagonal(const cv::Mat& diagonal, cv::Mat* inverse) {
  inverse->create(diagonal.size(), diagonal.type());
  const float* pd = diagonal.ptr<float>();
  float* pi = inverse->ptr<float>();
  const size_t n = NumValues(diagonal);
  for (size_t i = 0; i < n; ++i) pi[i] = pd[i] > 0.0f ? 1.0f / pd[i] : 1.0f;
}

void ApplyLaplacianGaussSeidelInverse(const cv::Mat& inverse_diagonal, const cv::Mat& v, double scale,
                                      const cv::Mat& r, cv::Mat* z);

// The reweighted least-squares problem of one IRLS step of eq:imgUpdate at
// the current image x: with W_k = weight_k * mask_k / max(|A_k x - b_k|, eps)
// and V = 1 / max(|grad x|, eps), the normal operator is
//   N y = sum_k A_k^T W_k A_k y + lambda_i D^T V D y
// and the right-hand side sum_k A_k^T W_k b_k. Every product streams the
// rows of A_k once (normal_product.h): no transposed copies.
class ReweightedImageSystem {
 public:
  ReweightedImageSystem(const std::vector<LinearL1Term>& terms, const ImageUpdateOptions& options,
                        int threads, const QuadraticAnchor* anchor)
      : terms_(terms), options_(options), threads_(threads), states_(terms.size()), anchor_(anchor) {}

  // W_k, V and the Jacobi diagonal diag(N) at `image`, and `residual` =
  // rhs - N x there: sum_k A_k^T W_k (b_k - A_k x) - lambda_i D^T V D x.
  // On one thread each term takes one pass over its rows (L1ReweightPass:
  // A_k x, W_k, and the term's shares of the diagonal and the residual,
  // bit for bit the separate passes below, which more threads take).
  void Reweight(const cv::Mat& image, cv::Mat* residual) {
    TvWeights(image, options_.tv_epsilon, &tv_weights_);
    diagonal_.create(image.size(), image.type());
    diagonal_.setTo(0.0);
    residual->create(image.size(), image.type());
    residual->setTo(0.0);
    if (threads_ == 1) {
      for (size_t k = 0; k < terms_.size(); ++k) {
        const LinearL1Term& term = terms_[k];
        L1ReweightPass(term.op->matrix(), image, *term.observation, term.mask, term.weight,
                       options_.residual_epsilon, &states_[k].residual, &states_[k].weight, &diagonal_,
                       residual);
      }
    } else {
      for (size_t k = 0; k < terms_.size(); ++k) ReweightTerm(terms_[k], image, &states_[k]);
      for (size_t k = 0; k < terms_.size(); ++k) {
        AddWeightedNormalDiagonal(terms_[k].op->matrix(), states_[k].weight, &diagonal_, threads_);
      }
      for (size_t k = 0; k < terms_.size(); ++k) {
        cv::multiply(states_[k].residual, states_[k].weight, temp_lr_, -1.0);
        AddAdjointProduct(terms_[k].op->matrix(), temp_lr_, residual, threads_);
      }
    }
    if (options_.lambda_i > 0.0) AddWeightedLaplacianDiagonal(tv_weights_, options_.lambda_i, &diagonal_);
    if (anchor_ != nullptr) {  // + weight (anchor - x) to the residual, + weight to diag(N)
      diagonal_ += cv::Scalar::all(anchor_->weight);
      cv::scaleAdd(*anchor_->anchor, anchor_->weight, *residual, *residual);
      cv::scaleAdd(image, -anchor_->weight, *residual, *residual);
    }
    InverseDiagonal(diagonal_, &inverse_diagonal_);
    if (options_.lambda_i > 0.0)
      AddWeightedLaplacian(image, tv_weights_, -options_.lambda_i, residual, threads_);
  }

  // out = N x.
  void ApplyNormal(const cv::Mat& x, cv::Mat* out) {
    out->create(x.size(), x.type());
    out->setTo(0.0);
    for (size_t k = 0; k < terms_.size(); ++k) {
      AddWeightedNormalProduct(terms_[k].op->matrix(), states_[k].weight, x, out, threads_);
    }
    if (options_.lambda_i > 0.0) AddWeightedLaplacian(x, tv_weights_, options_.lambda_i, out, threads_);
    if (anchor_ != nullptr) cv::scaleAdd(x, anchor_->weight, *out, *out);
  }

  const cv::Mat& diagonal() const { return diagonal_; }

  // z = M^-1 r with the options' preconditioner.
  void Precondition(const cv::Mat& r, cv::Mat* z) {
    if (options_.preconditioner == ImagePreconditioner::kTvGaussSeidel && options_.lambda_i > 0.0) {
      ApplyLaplacianGaussSeidelInverse(inverse_diagonal_, tv_weights_, options_.lambda_i, r, z);
      return;
    }
    cv::multiply(r, inverse_diagonal_, *z);
  }

 private:
  // W = weight * mask / max(|A x - b|, eps) of one term at `image`.
  void ReweightTerm(const LinearL1Term& term, const cv::Mat& image, TermState* state) const {
    term.op->Apply(image, &state->residual);
    state->residual -= *term.observation;
    state->weight.create(state->residual.size(), state->residual.type());
    const int channels = state->residual.channels();
    for (int y = 0; y < state->residual.rows; ++y) {
      const float* r = state->residual.ptr<float>(y);
      float* w = state->weight.ptr<float>(y);
      const uchar* m = term.mask.empty() ? nullptr : term.mask.ptr<uchar>(y);
      for (int x = 0; x < state->residual.cols; ++x) {
        const bool used = m == nullptr || m[x] != 0;
        for (int c = 0; c < channels; ++c) {
          const int i = x * channels + c;
          w[i] = used ? static_cast<float>(term.weight /
                                           std::max<double>(std::abs(r[i]), options_.residual_epsilon))
                      : 0.0f;
        }
      }
    }
  }

  const std::vector<LinearL1Term>& terms_;
  const ImageUpdateOptions& options_;
  const int threads_;
  std::vector<TermState> states_;
  const QuadraticAnchor* anchor_;  // null: none
  cv::Mat tv_weights_, diagonal_, inverse_diagonal_, temp_lr_;
};

}  // namespace

int SolvePcg(const std::function<void(const cv::Mat&, cv::Mat*)>& apply_normal,
             const std::function<void(const cv::Mat&, cv::Mat*)>& apply_preconditioner, cv::Mat residual,
             int max_iterations, double relative_tolerance, int threads, cv::Mat* x) {
  cv::Mat preconditioned, direction, normal_direction;
  apply_preconditioner(residual, &preconditioned);
  direction = preconditioned.clone();
  auto [rr, rz] = CgSquaredNormAndDot(residual, preconditioned, threads);
  const double rr0 = rr;
  const double stop = relative_tolerance * relative_tolerance * rr0;
  int steps = 0;
  for (; steps < max_iterations && rr > stop && rr > 0.0; ++steps) {
    apply_normal(direction, &normal_direction);
    const double dnd = CgDot(direction, normal_direction, threads);
    if (!(dnd > 0.0) || !(rz > 0.0)) break;
    const double alpha = rz / dnd;
    StepSolutionAndResidual(alpha, direction, normal_direction, x, &residual, threads);
    apply_preconditioner(residual, &preconditioned);
    double rz_next = 0.0;
    std::tie(rr, rz_next) = CgSquaredNormAndDot(residual, preconditioned, threads);
    const double beta = rz_next / rz;
    rz = rz_next;
    NextDirection(beta, preconditioned, &direction, threads);
  }
  return steps;
}

int SolveJacobiPcg(const std::function<void(const cv::Mat&, cv::Mat*)>& apply_normal, const cv::Mat& diagonal,
                   cv::Mat residual, int max_iterations, double relative_tolerance, int threads, cv::Mat* x) {
  cv::Mat inverse_diagonal;
  InverseDiagonal(diagonal, &inverse_diagonal);
  const auto jacobi = [&inverse_diagonal](const cv::Mat& r, cv::Mat* z) {
    cv::multiply(r, inverse_diagonal, *z);
  };
  return SolvePcg(apply_normal, jacobi, std::move(residual), max_iterations, relative_tolerance, threads, x);
}

namespace {

// The sweeps of ApplyLaplacianGaussSeidelInverse. Pixel (x, y) of the
// forward sweep needs (x - 1, y) and (x, y - 1); a raster sweep is one chain
// of dependent float operations per channel. The sweeps therefore go over
// blocks of kSweepRows rows as a wavefront: row j of a block runs j pixels
// behind row j - 1, so the block's rows are independent chains that the CPU
// overlaps. Every value gets the same operations, in the same order, from
// the same (final) neighbours as in the raster sweep: the results are
// bit for bit the raster sweep's (LaplacianGaussSeidel.WavefrontEqualsRasterSweeps).
constexpr int kSweepRows = 4;

struct SweepImages {
  const float* __restrict inverse_diagonal;
  const float* __restrict v;
  const float* __restrict r;
  float* __restrict z;
  float s;
  int width, height;
};

// One value of the forward sweep, (D + L) y = r: the earlier neighbours are
// the left one (edge weight v there) and the one above (v there).
template <int kChannels>
inline void ForwardValue(const SweepImages& m, long i, bool left, bool up) {
  const long stride = static_cast<long>(m.width) * kChannels;
  float acc = m.r[i];
  if (left) acc += m.s * m.v[i - kChannels] * m.z[i - kChannels];
  if (up) acc += m.s * m.v[i - stride] * m.z[i - stride];
  m.z[i] = acc * m.inverse_diagonal[i];
}

// One value of the backward sweep, (D + U) z = D y, i.e. z = y + D^-1
// (lambda v (z_right + z_down)).
template <int kChannels>
inline void BackwardValue(const SweepImages& m, long i, bool right, bool down) {
  const long stride = static_cast<long>(m.width) * kChannels;
  float acc = 0.0f;
  if (right) acc += m.z[i + kChannels];
  if (down) acc += m.z[i + stride];
  m.z[i] += m.s * m.v[i] * acc * m.inverse_diagonal[i];
}

// The forward sweep over rows [y0, y0 + rows), row j of the block j pixels
// behind row j - 1 (wavefront step k: row j at x = k - j). While every row
// of the block is inside the image (rows - 1 <= k < width) the x checks
// are known.
template <int kChannels>
void ForwardSweepBlock(const SweepImages& m, int y0, int rows) {
  const auto step = [&](int k, bool edges) {
    for (int j = 0; j < rows; ++j) {
      const int xx = k - j, y = y0 + j;
      if (edges && (xx < 0 || xx >= m.width)) continue;
      const long pixel = (static_cast<long>(y) * m.width + xx) * kChannels;
      for (int c = 0; c < kChannels; ++c) ForwardValue<kChannels>(m, pixel + c, !edges || xx > 0, y > 0);
    }
  };
  const int steady_end = std::max(rows, m.width);
  for (int k = 0; k < m.width + rows - 1; ++k) step(k, k < rows || k >= steady_end);
}

// The backward sweep over rows (y0 - rows, y0], bottom-up: row y0 - j at
// x = width - 1 - (k - j).
template <int kChannels>
void BackwardSweepBlock(const SweepImages& m, int y0, int rows) {
  const auto step = [&](int k, bool edges) {
    for (int j = 0; j < rows; ++j) {
      const int xx = m.width - 1 - (k - j), y = y0 - j;
      if (edges && (xx < 0 || xx >= m.width)) continue;
      const long pixel = (static_cast<long>(y) * m.width + xx) * kChannels;
      for (int c = kChannels - 1; c >= 0; --c) {
        BackwardValue<kChannels>(m, pixel + c, !edges || xx + 1 < m.width, y + 1 < m.height);
      }
    }
  };
  const int steady_end = std::max(rows, m.width);
  for (int k = 0; k < m.width + rows - 1; ++k) step(k, k < rows || k >= steady_end);
}

template <int kChannels>
void SymmetricGaussSeidelSweeps(const SweepImages& m) {
  for (int y0 = 0; y0 < m.height; y0 += kSweepRows) {
    ForwardSweepBlock<kChannels>(m, y0, std::min(kSweepRows, m.height - y0));
  }
  for (int y0 = m.height - 1; y0 >= 0; y0 -= kSweepRows) {
    BackwardSweepBlock<kChannels>(m, y0, std::min(kSweepRows, y0 + 1));
  }
}

// ApplyLaplacianGaussSeidel with the diagonal given by its inverse
// (InverseDiagonal): the sweeps multiply by it instead of dividing.
void ApplyLaplacianGaussSeidelInverse(const cv::Mat& inverse_diagonal, const cv::Mat& v, double scale,
                                      const cv::Mat& r, cv::Mat* z) {
  z->create(r.size(), r.type());
  SweepImages m{inverse_diagonal.ptr<float>(), v.ptr<float>(), r.ptr<float>(), z->ptr<float>(), 0.0f, 0, 0};
  m.s = static_cast<float>(scale);
  m.width = r.cols;
  m.height = r.rows;
  switch (r.channels()) {
    case 1:
      return SymmetricGaussSeidelSweeps<1>(m);
    case 2:
      return SymmetricGaussSeidelSweeps<2>(m);
    case 3:
      return SymmetricGaussSeidelSweeps<3>(m);
    case 4:
      return SymmetricGaussSeidelSweeps<4>(m);
    default:
      throw InputError("image update: images must have 1 to 4 channels");
  }
}

}  // namespace

void ApplyLaplacianGaussSeidel(const cv::Mat& diagonal, const cv::Mat& v, double scale, const cv::Mat& r,
                               cv::Mat* z) {
  LaplacianGaussSeidelPreconditioner(diagonal, v, scale).Apply(r, z);
}

LaplacianGaussSeidelPreconditioner::LaplacianGaussSeidelPreconditioner(const cv::Mat& diagonal,
                                                                       const cv::Mat& v, double scale)
    : v_(v), scale_(scale) {
  InverseDiagonal(diagonal, &inverse_diagonal_);
}

void LaplacianGaussSeidelPreconditioner::Apply(const cv::Mat& r, cv::Mat* z) const {
  ApplyLaplacianGaussSeidelInverse(inverse_diagonal_, v_, scale_, r, z);
}

namespace {

void CheckTermsMatchImage(const std::vector<LinearL1Term>& terms, const cv::Mat& image) {
  if (image.depth() != CV_32F || !image.isContinuous()) {
    throw InputError("image update: the image must be a continuous float image");
  }
  for (const LinearL1Term& term : terms) {
    if (term.op == nullptr || term.observation == nullptr || term.op->hr_size() != image.size() ||
        term.observation->size() != term.op->lr_size() || term.observation->type() != image.type() ||
        (!term.mask.empty() && term.mask.size() != term.op->lr_size())) {
      throw InputError("image update: a data term does not match the image (sizes or channels)");
    }
  }
}

}  // namespace

// IRLS on eq:imgUpdate: reweight at the current image, then CG on the
// reweighted system from it (each solve warm starts from the last).
ImageUpdateStats UpdateImage(const std::vector<LinearL1Term>& terms, const ImageUpdateOptions& options,
                             cv::Mat* image, const QuadraticAnchor* anchor) {
  options.Check();
  const int threads = ResolveThreads(options.num_threads);
  CheckTermsMatchImage(terms, *image);
  const bool anchored = anchor != nullptr && anchor->weight > 0.0;
  if (anchored && (anchor->anchor == nullptr || anchor->anchor->size() != image->size() ||
                   anchor->anchor->type() != image->type() || !std::isfinite(anchor->weight))) {
    throw InputError("image update: the anchor must match the image and have a finite weight");
  }
  ReweightedImageSystem system(terms, options, threads, anchored ? anchor : nullptr);
  const auto apply_normal = [&system](const cv::Mat& x, cv::Mat* out) { system.ApplyNormal(x, out); };
  const auto precondition = [&system](const cv::Mat& r, cv::Mat* z) { system.Precondition(r, z); };
  ImageUpdateStats stats;
  const long terms_count = static_cast<long>(terms.size());
  cv::Mat residual;
  for (int irls = 0; irls < options.irls_iterations; ++irls) {
    system.Reweight(*image, &residual);
    const int steps = SolvePcg(apply_normal, precondition, residual, options.cg_iterations,
                               options.cg_tolerance, threads, image);
    ++stats.reweightings;
    stats.cg_steps += steps;
    // Reweight: 1 apply + 1 diagonal pass; initial residual: 1 adjoint;
    // each CG step: 1 normal product (2).
    stats.operator_passes += terms_count * (3 + 2L * steps);
  }
  return stats;
}

}  // namespace deblur_sr_mvs
