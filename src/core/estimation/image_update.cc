#include "deblur_sr_mvs/core/estimation/image_update.h"

#include <omp.h>

#include <algorithm>
#include <cmath>

#include "deblur_sr_mvs/core/common/errors.h"

namespace deblur_sr_mvs {
namespace {

int Threads(int requested) { return requested > 0 ? requested : omp_get_max_threads(); }

size_t NumValues(const cv::Mat& m) { return m.total() * m.channels(); }

double Dot(const cv::Mat& a, const cv::Mat& b, int threads) {
  const float* pa = a.ptr<float>();
  const float* pb = b.ptr<float>();
  const long n = static_cast<long>(NumValues(a));
  double sum = 0.0;
#pragma omp parallel for reduction(+ : sum) num_threads(threads) schedule(static)
  for (long i = 0; i < n; ++i) sum += static_cast<double>(pa[i]) * pb[i];
  return sum;
}

// y += alpha * x
void Axpy(double alpha, const cv::Mat& x, cv::Mat* y, int threads) {
  const float* px = x.ptr<float>();
  float* py = y->ptr<float>();
  const long n = static_cast<long>(NumValues(x));
  const float a = static_cast<float>(alpha);
#pragma omp parallel for num_threads(threads) schedule(static)
  for (long i = 0; i < n; ++i) py[i] += a * px[i];
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
  if (!(lambda_i >= 0.0)) throw InputError("image update: lambda_i must be >= 0");
  if (irls_iterations < 1 || cg_iterations < 1) {
    throw InputError("image update: irls_iterations and cg_iterations must be >= 1");
  }
  if (!(residual_epsilon > 0.0) || !(tv_epsilon > 0.0)) {
    throw InputError("image update: residual_epsilon and tv_epsilon must be > 0");
  }
}

void AddWeightedLaplacian(const cv::Mat& x, const cv::Mat& v, double scale, cv::Mat* out,
                          int threads) {
  const int channels = x.channels();
  const int width = x.cols, height = x.rows;
  const int stride = width * channels;
  const float s = static_cast<float>(scale);
  const float* px = x.ptr<float>();
  const float* pv = v.ptr<float>();
  float* po = out->ptr<float>();
#pragma omp parallel for num_threads(threads) schedule(static)
  for (int y = 0; y < height; ++y) {
    for (int xx = 0; xx < width; ++xx) {
      for (int c = 0; c < channels; ++c) {
        const long i = static_cast<long>(y) * stride + xx * channels + c;
        float acc = 0.0f;
        // Edge to the right (owned by this pixel) and from the left.
        if (xx + 1 < width) acc += pv[i] * (px[i] - px[i + channels]);
        if (xx > 0) acc += pv[i - channels] * (px[i] - px[i - channels]);
        if (y + 1 < height) acc += pv[i] * (px[i] - px[i + stride]);
        if (y > 0) acc += pv[i - stride] * (px[i] - px[i - stride]);
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

double UpdateImage(const std::vector<LinearL1Term>& terms, const ImageUpdateOptions& options,
                   cv::Mat* image) {
  options.Check();
  const int threads = Threads(options.num_threads);
  if (image->depth() != CV_32F || !image->isContinuous()) {
    throw InputError("image update: the image must be a continuous float image");
  }
  for (const LinearL1Term& term : terms) {
    if (term.op == nullptr || term.observation == nullptr ||
        term.op->hr_size() != image->size() || term.observation->size() != term.op->lr_size() ||
        term.observation->type() != image->type() ||
        (!term.mask.empty() && term.mask.size() != term.op->lr_size())) {
      throw InputError("image update: a data term does not match the image (sizes or channels)");
    }
  }
  std::vector<TermState> states(terms.size());
  // Psi^T as row-major copies made here, once per update: a gather is much
  // faster than scattering through Psi, and the copies live only as long as
  // this update (the operators' owners need not keep them).
  std::vector<SparseMatrixRM> adjoints(terms.size());
  for (size_t k = 0; k < terms.size(); ++k) TransposeSparse(terms[k].op->matrix(), &adjoints[k], threads);
  auto apply_adjoint = [&](size_t k, const cv::Mat& lr, cv::Mat* hr) {
    MultiplySparse(adjoints[k], lr, hr, threads);
    *hr = hr->reshape(lr.channels(), image->rows);
  };
  cv::Mat tv_weights, rhs, residual, direction, normal_direction, temp_lr, temp_hr;

  // Normal operator N x = sum_k A_k^T W_k A_k x + lambda_i D^T V D x.
  auto apply_normal = [&](const cv::Mat& x, cv::Mat* out) {
    out->create(x.size(), x.type());
    out->setTo(0.0);
    for (size_t k = 0; k < terms.size(); ++k) {
      terms[k].op->Apply(x, &temp_lr);
      cv::multiply(temp_lr, states[k].weight, temp_lr);
      apply_adjoint(k, temp_lr, &temp_hr);
      Axpy(1.0, temp_hr, out, threads);
    }
    if (options.lambda_i > 0.0) AddWeightedLaplacian(x, tv_weights, options.lambda_i, out, threads);
  };

  for (int irls = 0; irls < options.irls_iterations; ++irls) {
    // Reweight: W = weight * mask / max(|A x - b|, eps), V = 1 / max(|grad x|, eps).
    for (size_t k = 0; k < terms.size(); ++k) {
      const LinearL1Term& term = terms[k];
      TermState& state = states[k];
      term.op->Apply(*image, &state.residual);
      state.residual -= *term.observation;
      state.weight.create(state.residual.size(), state.residual.type());
      const int channels = state.residual.channels();
      for (int y = 0; y < state.residual.rows; ++y) {
        const float* r = state.residual.ptr<float>(y);
        float* w = state.weight.ptr<float>(y);
        const uchar* m = term.mask.empty() ? nullptr : term.mask.ptr<uchar>(y);
        for (int x = 0; x < state.residual.cols; ++x) {
          const bool used = m == nullptr || m[x] != 0;
          for (int c = 0; c < channels; ++c) {
            const int i = x * channels + c;
            w[i] = used ? static_cast<float>(term.weight /
                                             std::max<double>(std::abs(r[i]), options.residual_epsilon))
                        : 0.0f;
          }
        }
      }
    }
    TvWeights(*image, options.tv_epsilon, &tv_weights);

    // rhs = sum_k A_k^T W_k b_k; CG on N x = rhs from the current image.
    rhs.create(image->size(), image->type());
    rhs.setTo(0.0);
    for (size_t k = 0; k < terms.size(); ++k) {
      cv::multiply(*terms[k].observation, states[k].weight, temp_lr);
      apply_adjoint(k, temp_lr, &temp_hr);
      Axpy(1.0, temp_hr, &rhs, threads);
    }
    apply_normal(*image, &residual);
    residual = rhs - residual;  // r = b - N x
    direction = residual.clone();
    double rr = Dot(residual, residual, threads);
    const double rr0 = rr;
    for (int it = 0; it < options.cg_iterations && rr > 1e-12 * rr0 && rr > 0.0; ++it) {
      apply_normal(direction, &normal_direction);
      const double dnd = Dot(direction, normal_direction, threads);
      if (!(dnd > 0.0)) break;
      const double alpha = rr / dnd;
      Axpy(alpha, direction, image, threads);
      Axpy(-alpha, normal_direction, &residual, threads);
      const double rr_next = Dot(residual, residual, threads);
      const double beta = rr_next / rr;
      rr = rr_next;
      // d = r + beta d
      direction *= beta;
      Axpy(1.0, residual, &direction, threads);
    }
  }
  return ImageEnergy(terms, options.lambda_i, *image);
}

}  // namespace deblur_sr_mvs
