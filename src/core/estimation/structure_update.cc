#include "deblur_sr_mvs/core/estimation/structure_update.h"

#include <omp.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <list>
#include <map>
#include <memory>

#include <Eigen/Dense>
#include <opencv2/imgproc.hpp>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/common/options_check.h"
#include "deblur_sr_mvs/core/common/runtime.h"
#include "deblur_sr_mvs/core/estimation/image_update.h"
#include "deblur_sr_mvs/core/imaging/normal_product.h"

namespace deblur_sr_mvs {
namespace {

// Central-difference gradients of a C-channel float image (one-sided at the border).
void Gradients(const cv::Mat& image, cv::Mat* gx, cv::Mat* gy) {
  const int channels = image.channels();
  gx->create(image.size(), image.type());
  gy->create(image.size(), image.type());
  const int w = image.cols, h = image.rows;
  for (int y = 0; y < h; ++y) {
    const float* row = image.ptr<float>(y);
    const float* up = image.ptr<float>(std::max(y - 1, 0));
    const float* down = image.ptr<float>(std::min(y + 1, h - 1));
    const float y_scale = (y == 0 || y == h - 1) ? 1.0f : 0.5f;
    float* ox = gx->ptr<float>(y);
    float* oy = gy->ptr<float>(y);
    for (int x = 0; x < w; ++x) {
      const int left = std::max(x - 1, 0), right = std::min(x + 1, w - 1);
      const float x_scale = (x == 0 || x == w - 1) ? 1.0f : 0.5f;
      for (int c = 0; c < channels; ++c) {
        ox[x * channels + c] = x_scale * (row[right * channels + c] - row[left * channels + c]);
        oy[x * channels + c] = y_scale * (down[x * channels + c] - up[x * channels + c]);
      }
    }
  }
}

// Bilinear read of C channels at (u, v), which must lie in [0, w-1] x [0, h-1].
inline void SampleBilinear(const cv::Mat& image, float u, float v, float* out) {
  const int channels = image.channels();
  const int x0 = std::min(static_cast<int>(u), image.cols - 2);
  const int y0 = std::min(static_cast<int>(v), image.rows - 2);
  const float fx = u - x0, fy = v - y0;
  const float* a = image.ptr<float>(y0) + x0 * channels;
  const float* b = image.ptr<float>(y0 + 1) + x0 * channels;
  for (int c = 0; c < channels; ++c) {
    const float top = a[c] + fx * (a[c + channels] - a[c]);
    const float bottom = b[c] + fx * (b[c + channels] - b[c]);
    out[c] = top + fy * (bottom - top);
  }
}

// Per-element IRLS weights of an L1 residual: 1 / max(|r|, eps) inside mask.
void L1Weights(const cv::Mat& residual, const cv::Mat& mask, double epsilon, cv::Mat* weights) {
  const int channels = residual.channels();
  weights->create(residual.size(), residual.type());
  for (int y = 0; y < residual.rows; ++y) {
    const float* r = residual.ptr<float>(y);
    const uchar* m = mask.empty() ? nullptr : mask.ptr<uchar>(y);
    float* w = weights->ptr<float>(y);
    for (int x = 0; x < residual.cols; ++x) {
      const bool used = m == nullptr || m[x] != 0;
      for (int c = 0; c < channels; ++c) {
        const int i = x * channels + c;
        w[i] = used ? static_cast<float>(1.0 / std::max<double>(std::abs(r[i]), epsilon)) : 0.0f;
      }
    }
  }
}

// Mask on the observation grid: the pair's mask and, for LR observations,
// only pixels whose whole HR footprint warped validly.
cv::Mat ObservationMask(const PairMatching& pair, const cv::Mat& valid_hr) {
  cv::Mat valid = valid_hr;
  if (pair.blur != nullptr) valid = DownscaleMaskAll(valid_hr, valid_hr.cols / pair.blur->lr_size().width);
  if (pair.mask.empty()) return valid;
  cv::Mat combined;
  cv::bitwise_and(valid, pair.mask, combined);
  return combined;
}

// The image a pair warps into t: its own source, or the latent image of s.
const cv::Mat& SourceImage(const PairMatching& pair, const std::vector<cv::Mat>& latents) {
  return pair.source != nullptr ? *pair.source : latents[pair.s];
}

// Predicted observation of a warped HR image: Psi * image, or the image itself.
void Predict(const PairMatching& pair, const cv::Mat& hr, cv::Mat* out) {
  if (pair.blur != nullptr) {
    pair.blur->Apply(hr, out);
  } else {
    hr.copyTo(*out);
  }
}
void PredictAdjoint(const PairMatching& pair, const cv::Mat& observation_grid, cv::Mat* out) {
  if (pair.blur != nullptr) {
    pair.blur->ApplyAdjoint(observation_grid, out);
  } else {
    observation_grid.copyTo(*out);
  }
}

double Dot1(const cv::Mat& a, const cv::Mat& b) {
  double sum = 0.0;
  const float* pa = a.ptr<float>();
  const float* pb = b.ptr<float>();
  const size_t n = a.total() * a.channels();
  for (size_t i = 0; i < n; ++i) sum += static_cast<double>(pa[i]) * pb[i];
  return sum;
}

// Box down-sampling (the capture operator's last step) and its adjoint.
void BoxDown(const cv::Mat& hr, int scale, cv::Mat* lr) {
  cv::resize(hr, *lr, cv::Size(hr.cols / scale, hr.rows / scale), 0, 0, cv::INTER_AREA);
}
void BoxAdjoint(const cv::Mat& lr, int scale, cv::Mat* hr) {
  cv::resize(lr, *hr, cv::Size(lr.cols * scale, lr.rows * scale), 0, 0, cv::INTER_NEAREST);
  *hr *= 1.0 / (scale * scale);
}

// out[i] = sum_c g[i, c] * in[i, c] (a C-channel image against its Jacobian).
void ContractChannels(const cv::Mat& g, const cv::Mat& in, cv::Mat* out, bool accumulate) {
  const int channels = g.channels();
  const int n = static_cast<int>(g.total());
  const float* pg = g.ptr<float>();
  const float* pi = in.ptr<float>();
  float* po = out->ptr<float>();
  for (int i = 0; i < n; ++i) {
    float acc = 0.0f;
    for (int c = 0; c < channels; ++c) acc += pg[i * channels + c] * pi[i * channels + c];
    po[i] = accumulate ? po[i] + acc : acc;
  }
}
// out[i, c] = g[i, c] * in[i].
void ExpandChannels(const cv::Mat& g, const cv::Mat& in, cv::Mat* out) {
  const int channels = g.channels();
  const int n = static_cast<int>(g.total());
  out->create(g.size(), g.type());
  const float* pg = g.ptr<float>();
  const float* pi = in.ptr<float>();
  float* po = out->ptr<float>();
  for (int i = 0; i < n; ++i) {
    for (int c = 0; c < channels; ++c) po[i * channels + c] = pg[i * channels + c] * pi[i];
  }
}

// The warp W^{t->s} of eq:warpingFunction for one pair of poses, per pixel.
class PairWarp {
 public:
  PairWarp(const PinholeCamera& camera, const SE3& T_world_t, const SE3& T_world_s)
      : camera_(camera), T_world_s_(T_world_s) {
    const SE3 T_s_t = T_world_s.Inverse() * T_world_t;
    const Eigen::Matrix3d k = camera.K();
    h_ = k * T_s_t.rotation() * k.inverse();
    kt_ = k * T_s_t.translation();
    R_s_world_ = T_world_s.rotation().transpose();
    max_u_ = camera.width - 1.0;
    max_v_ = camera.height - 1.0;
  }
  // Where pixel (x, y) of t lands in s.
  struct Projection {
    double u = 0.0, v = 0.0;       // pixel of s
    double du = 0.0, dv = 0.0;     // d(u, v) / d rho
    double inverse_depth_s = 0.0;  // 1 / z of the point in s
  };
  // (u, v) in s of pixel (x, y) of t at inverse depth rho and d(u, v)/d rho;
  // false when rho is unusable or the point falls behind or outside s.
  bool Project(int x, int y, double rho, Projection* p) const {
    if (!(rho > 0.0) || !std::isfinite(rho)) return false;
    // q ~ K X_s scaled by rho: q = H [x y 1] + rho K t, q_z = rho z_s.
    const Eigen::Vector3d q = h_ * Eigen::Vector3d(x, y, 1.0) + rho * kt_;
    if (!(q.z() > 1e-9)) return false;
    const double inverse_qz = 1.0 / q.z();
    p->u = q.x() * inverse_qz;
    p->v = q.y() * inverse_qz;
    if (p->u < 0.0 || p->v < 0.0 || p->u > max_u_ || p->v > max_v_) return false;
    p->du = (kt_.x() - p->u * kt_.z()) * inverse_qz;
    p->dv = (kt_.y() - p->v * kt_.z()) * inverse_qz;
    p->inverse_depth_s = rho * inverse_qz;
    return true;
  }
  bool Project(int x, int y, double rho, double* u, double* v, double* du, double* dv) const {
    Projection p;
    if (!Project(x, y, rho, &p)) return false;
    *u = p.u;
    *v = p.v;
    *du = p.du;
    *dv = p.dv;
    return true;
  }
  // d(u, v)/d eps_t for P_t = exp(eps_t) P_t0 (d/d eps_s is minus it) at a
  // projection of Project: X_w = P_t X_t, X_s = R_s^T (X_w - c_s),
  // d X_s / d eps_t = R_s^T [I, -[X_w]x].
  Eigen::Matrix<double, 2, 6> DPixelDPose(const Projection& p) const {
    // X_s from the pixel of s and its depth; d pixel / d X_s = [f/z, 0, -(u - c)/z] per row.
    const double z = 1.0 / p.inverse_depth_s;
    const double xn = (p.u - camera_.cx) / camera_.fx, yn = (p.v - camera_.cy) / camera_.fy;
    const Eigen::Vector3d point_w = T_world_s_ * Eigen::Vector3d(xn * z, yn * z, z);
    Eigen::Matrix<double, 2, 3> d_pixel;
    d_pixel << camera_.fx * p.inverse_depth_s, 0.0, -(p.u - camera_.cx) * p.inverse_depth_s, 0.0,
        camera_.fy * p.inverse_depth_s, -(p.v - camera_.cy) * p.inverse_depth_s;
    // d_pixel R_s^T DLeftPerturbedPointDEps(X_w) row by row: with m a row of
    // d_pixel R_s^T, m [I, -[X_w]x] = [m, (X_w x m)^T].
    const Eigen::Matrix<double, 2, 3> m = d_pixel * R_s_world_;
    Eigen::Matrix<double, 2, 6> jacobian;
    jacobian.leftCols<3>() = m;
    jacobian.block<1, 3>(0, 3) = point_w.cross(m.row(0).transpose()).transpose();
    jacobian.block<1, 3>(1, 3) = point_w.cross(m.row(1).transpose()).transpose();
    return jacobian;
  }
  // The same at pixel (x, y) of t, inverse depth rho (in front of s).
  Eigen::Matrix<double, 2, 6> DPixelDPose(int x, int y, double rho) const {
    const Eigen::Vector3d q = h_ * Eigen::Vector3d(x, y, 1.0) + rho * kt_;
    Projection p;
    p.u = q.x() / q.z();
    p.v = q.y() / q.z();
    p.inverse_depth_s = rho / q.z();
    return DPixelDPose(p);
  }

 private:
  PinholeCamera camera_;
  SE3 T_world_s_;
  Eigen::Matrix3d h_, R_s_world_;
  Eigen::Vector3d kt_;
  double max_u_ = 0.0, max_v_ = 0.0;
};

// Per pixel of a pair, from the source's gradients g_c at the warp: S =
// sum_c w_c g_c g_c^T and b = sum_c w_c r_c g_c (with J = d pixel / d eps_t,
// the pose terms J^T S J and J^T b).
struct GradientMoments {
  double s00 = 0.0, s01 = 0.0, s11 = 0.0, b0 = 0.0, b1 = 0.0;
  void Add(double w, double r, double gx, double gy) {
    s00 += w * gx * gx;
    s01 += w * gx * gy;
    s11 += w * gy * gy;
    b0 += w * r * gx;
    b1 += w * r * gy;
  }
};

// The pose sums of the pixels of one image row: per pixel J = d pixel /
// d eps_t, S J and b (GradientMoments) in float; AddTo adds sum J^T S J and
// sum J^T b over the row to double sums, one product per row.
class RowPoseSums {
 public:
  explicit RowPoseSums(int max_pixels) : j_(12, max_pixels), sj_(12, max_pixels), b_(2, max_pixels) {}
  // Every pixel's terms to zero.
  void Clear() {
    j_.setZero();
    sj_.setZero();
    b_.setZero();
  }
  // Pixel i of the row.
  void Set(int i, const Eigen::Matrix<double, 2, 6>& j, const GradientMoments& m) {
    for (int k = 0; k < 6; ++k) {
      j_(k, i) = static_cast<float>(j(0, k));
      j_(6 + k, i) = static_cast<float>(j(1, k));
      sj_(k, i) = static_cast<float>(m.s00 * j(0, k) + m.s01 * j(1, k));
      sj_(6 + k, i) = static_cast<float>(m.s01 * j(0, k) + m.s11 * j(1, k));
    }
    b_(0, i) = static_cast<float>(m.b0);
    b_(1, i) = static_cast<float>(m.b1);
  }
  // block += sum J^T S J, rhs += sum J^T b over pixels [0, pixels).
  void AddTo(int pixels, Eigen::Matrix<double, 6, 6>* block, Vector6d* rhs) const {
    const auto j0 = j_.topLeftCorner(6, pixels), j1 = j_.bottomLeftCorner(6, pixels);
    const Eigen::Matrix<float, 6, 6> row_block =
        j0 * sj_.topLeftCorner(6, pixels).transpose() + j1 * sj_.bottomLeftCorner(6, pixels).transpose();
    const Eigen::Matrix<float, 6, 1> row_rhs =
        j0 * b_.row(0).head(pixels).transpose() + j1 * b_.row(1).head(pixels).transpose();
    *block += row_block.cast<double>();
    *rhs += row_rhs.cast<double>();
  }

 private:
  Eigen::MatrixXf j_, sj_, b_;
};

}  // namespace

cv::Mat BlurDerivativeWrtInverseDepth(const CaptureGeometry& geometry, int samples, int scale,
                                      const cv::Mat& inverse_depth, const cv::Mat& latent, int max_samples) {
  const PinholeCamera& camera = geometry.camera_hr;
  const int channels = latent.channels();
  cv::Mat derivative = cv::Mat::zeros(latent.size(), latent.type());
  const int step = std::max(1, samples / std::max(1, max_samples));
  std::vector<int> used;
  for (int m = samples - 1; m >= 0; m -= step) used.push_back(m);
  // One set of virtual cameras, or one per LR row for a rolling shutter
  // (their windows open RowDelay later): h = K R K^-1 and K t of T_t_tau.
  const int lr_rows = camera.height / scale;
  const int num_sets = geometry.readout_time > 0.0 ? lr_rows : 1;
  const Eigen::Matrix3d k = camera.K();
  const Eigen::Matrix3d k_inv = k.inverse();
  std::vector<Eigen::Matrix3d> h(num_sets * used.size());
  std::vector<Eigen::Vector3d> kt(h.size());
  const SE3 T_t_world = geometry.T_world_cam.Inverse();
  for (int set = 0; set < num_sets; ++set) {
    const std::vector<SE3> T_world_tau =
        VirtualCameraPoses(geometry, samples, RowDelay(geometry, set, lr_rows));
    for (size_t i = 0; i < used.size(); ++i) {
      const SE3 T_t_tau = T_t_world * T_world_tau[used[i]];
      h[set * used.size() + i] = k * T_t_tau.rotation() * k_inv;
      kt[set * used.size() + i] = k * T_t_tau.translation();
    }
  }
  cv::Mat gx, gy;
  Gradients(latent, &gx, &gy);
  const float weight = 1.0f / used.size();
  const double max_u = camera.width - 1.0, max_v = camera.height - 1.0;
#pragma omp parallel for schedule(static)
  for (int y = 0; y < camera.height; ++y) {
    const float* rho_row = inverse_depth.ptr<float>(y);
    float* out = derivative.ptr<float>(y);
    std::vector<float> grad_x(channels), grad_y(channels);
    const size_t first = (num_sets > 1 ? std::min(y / scale, lr_rows - 1) : 0) * used.size();
    for (size_t i = first; i < first + used.size(); ++i) {
      for (int x = 0; x < camera.width; ++x) {
        const double rho = rho_row[x];
        if (!(rho > 0.0)) continue;
        const Eigen::Vector3d q = h[i] * Eigen::Vector3d(x, y, 1.0) + rho * kt[i];
        if (!(q.z() > 1e-9)) continue;
        const double u = std::clamp(q.x() / q.z(), 0.0, max_u);
        const double v = std::clamp(q.y() / q.z(), 0.0, max_v);
        SampleBilinear(gx, static_cast<float>(u), static_cast<float>(v), grad_x.data());
        SampleBilinear(gy, static_cast<float>(u), static_cast<float>(v), grad_y.data());
        const double du = (kt[i].x() - u * kt[i].z()) / q.z();
        const double dv = (kt[i].y() - v * kt[i].z()) / q.z();
        for (int c = 0; c < channels; ++c) {
          out[x * channels + c] += weight * static_cast<float>(grad_x[c] * du + grad_y[c] * dv);
        }
      }
    }
  }
  return derivative;
}

// ---- Blur as motion evidence (BlurPoseJacobian, LinearizeBlurInPoses).
namespace {

// The poses of a self-consistency geometry's blur path, in the order of
// BlurPoseJacobian's frames: P_t, P_neighbour, then P_second_neighbour and
// P_third_neighbour where set.
int PathPoseCount(const CaptureGeometry& geometry) {
  return 2 + (geometry.T_world_second_neighbour.has_value() ? 1 : 0) +
         (geometry.T_world_third_neighbour.has_value() ? 1 : 0);
}
SE3* PathPose(CaptureGeometry* geometry, int k) {
  if (k == 0) return &geometry->T_world_cam;
  if (k == 1) return &geometry->T_world_neighbour;
  if (k == 2) return &*geometry->T_world_second_neighbour;
  return &*geometry->T_world_third_neighbour;
}

// The basis of the path's pose derivative: powers of tau - t up to the
// cubic of the longest path (PoseOnPolynomialPath through four poses).
constexpr int kPathBasisSize = 3;
using PathBasisVector = Eigen::Matrix<double, kPathBasisSize, 1>;

// The instant tau of virtual camera m of M over the exposure of rows that
// open `row_delay` later (as the operator samples it), and the basis at tau:
// phi_1 = (tau - t) / exposure, phi_b = phi_1^b.
double VirtualCameraTime(const CaptureGeometry& geometry, int samples, double row_delay, int m) {
  return geometry.stamp - geometry.exposure + row_delay + (m + 0.5) / samples * geometry.exposure;
}
PathBasisVector PathBasis(const CaptureGeometry& geometry, double tau) {
  const double phi = (tau - geometry.stamp) / geometry.exposure;
  return {phi, phi * phi, phi * phi * phi};
}

// d delta(tau) / d eps (6 x 6F) of the virtual camera at tau relative to P_t,
// T_t_tau = P_t^-1 P(tau), with Exp(delta) T_t_tau(eps) ~ T_t_tau(eps + d eps)
// ... by central differences over the 6 axes of each path pose, at 8
// instants spanning the exposure and the readout, fitted by least squares as
// sum_b phi_b(tau) C_b (the path passes through P_t at t, so delta(t) = 0;
// exact for the polynomial paths of up to four poses). Returns [C_1; C_2;
// C_3] (6 kPathBasisSize x 6F).
Eigen::MatrixXd PathPoseChain(const CaptureGeometry& geometry) {
  const int frames = PathPoseCount(geometry);
  const int nodes = 8;
  const double first = geometry.stamp - geometry.exposure;
  const double span = geometry.exposure + geometry.readout_time;
  std::vector<double> taus(nodes);
  std::vector<SE3> T_tau_t(nodes);  // the inverse of T_t_tau at eps = 0
  const SE3 T_t_world = geometry.T_world_cam.Inverse();
  for (int i = 0; i < nodes; ++i) {
    taus[i] = first + span * i / (nodes - 1.0);
    T_tau_t[i] = (T_t_world * PoseAtTime(geometry, taus[i])).Inverse();
  }
  const double h = 1e-6;
  // y(i, 6F r + c): d delta_r(tau_i) / d eps_c.
  Eigen::MatrixXd y = Eigen::MatrixXd::Zero(nodes, 36 * frames);
  for (int k = 0; k < frames; ++k) {
    for (int j = 0; j < 6; ++j) {
      for (const double sign : {1.0, -1.0}) {
        CaptureGeometry moved = geometry;
        Vector6d eps = Vector6d::Zero();
        eps(j) = sign * h;
        *PathPose(&moved, k) = SE3::Exp(eps) * *PathPose(&moved, k);
        const SE3 T_t_world_moved = moved.T_world_cam.Inverse();
        for (int i = 0; i < nodes; ++i) {
          const Vector6d delta = (T_t_world_moved * PoseAtTime(moved, taus[i]) * T_tau_t[i]).Log();
          for (int r = 0; r < 6; ++r) y(i, 6 * frames * r + 6 * k + j) += sign * delta(r) / (2.0 * h);
        }
      }
    }
  }
  Eigen::MatrixXd phi(nodes, kPathBasisSize);
  for (int i = 0; i < nodes; ++i) phi.row(i) = PathBasis(geometry, taus[i]).transpose();
  const Eigen::MatrixXd fit = (phi.transpose() * phi).ldlt().solve(phi.transpose() * y);  // K x 36F
  Eigen::MatrixXd chain(6 * kPathBasisSize, 6 * frames);
  for (int b = 0; b < kPathBasisSize; ++b) {
    for (int r = 0; r < 6; ++r) chain.row(6 * b + r) = fit.block(b, 6 * frames * r, 1, 6 * frames);
  }
  return chain;
}

// One used virtual camera: the warp of its pixels into t (q = H [x y 1] +
// rho K t, as BlurDerivativeWrtInverseDepth) and its path basis.
struct BlurPoseCamera {
  Eigen::Matrix3d h;
  Eigen::Vector3d kt;
  PathBasisVector basis;
};

// At most max_samples of the M virtual cameras, evenly spread (the middle
// one of each of max_samples slices), per LR row for a rolling shutter.
std::vector<BlurPoseCamera> BlurPoseCameras(const CaptureGeometry& geometry, int samples, int max_samples,
                                            int num_sets, int lr_rows, int* used_per_set) {
  const int used = std::max(1, std::min(samples, max_samples));
  *used_per_set = used;
  const Eigen::Matrix3d k = geometry.camera_hr.K();
  const Eigen::Matrix3d k_inv = k.inverse();
  const SE3 T_t_world = geometry.T_world_cam.Inverse();
  std::vector<BlurPoseCamera> cameras;
  cameras.reserve(num_sets * used);
  for (int set = 0; set < num_sets; ++set) {
    const double delay = RowDelay(geometry, set, lr_rows);
    for (int i = 0; i < used; ++i) {
      const int m = static_cast<int>((i + 0.5) * samples / used);
      const double tau = VirtualCameraTime(geometry, samples, delay, m);
      const SE3 T_t_tau = T_t_world * PoseAtTime(geometry, tau);
      cameras.push_back({k * T_t_tau.rotation() * k_inv, k * T_t_tau.translation(), PathBasis(geometry, tau)});
    }
  }
  return cameras;
}

// Adds, for HR pixel (x, y) of t at inverse depth rho seen by `camera`,
// scale_weight x g^T d pixel / d delta x phi_b into moments[(K c + b) 6 + j]
// (g the gradient of channel c of I_t at the warp, delta the virtual
// camera's pose relative to P_t).
void AddBlurPoseMoments(const PinholeCamera& hr, const BlurPoseCamera& camera, int x, int y, double rho,
                        const cv::Mat& gx, const cv::Mat& gy, double scale_weight, float* grad_x, float* grad_y,
                        double* moments) {
  const Eigen::Vector3d q = camera.h * Eigen::Vector3d(x, y, 1.0) + rho * camera.kt;
  if (!(q.z() > 1e-9)) return;
  const double u = q.x() / q.z(), v = q.y() / q.z();
  if (u < 0.0 || v < 0.0 || u > hr.width - 1.0 || v > hr.height - 1.0) return;
  SampleBilinear(gx, static_cast<float>(u), static_cast<float>(v), grad_x);
  SampleBilinear(gy, static_cast<float>(u), static_cast<float>(v), grad_y);
  // X_t = z K^-1 [u v 1] with 1 / z = rho / q_z; d pixel / d delta = d pixel
  // / d X_t [I, -[X_t]x]: row m gives [m, (X_t x m)^T].
  const double iz = rho / q.z();
  const Eigen::Vector3d point = hr.Ray(u, v) / iz;
  const Eigen::Vector3d m0(hr.fx * iz, 0.0, -(u - hr.cx) * iz), m1(0.0, hr.fy * iz, -(v - hr.cy) * iz);
  Eigen::Matrix<double, 2, 6> jacobian;
  jacobian << m0.transpose(), point.cross(m0).transpose(), m1.transpose(), point.cross(m1).transpose();
  const int channels = gx.channels();
  for (int c = 0; c < channels; ++c) {
    const Eigen::Matrix<double, 1, 6> a =
        scale_weight * (grad_x[c] * jacobian.row(0) + grad_y[c] * jacobian.row(1));
    for (int b = 0; b < kPathBasisSize; ++b) {
      double* out = moments + (kPathBasisSize * c + b) * 6;
      for (int j = 0; j < 6; ++j) out[j] += camera.basis(b) * a(j);
    }
  }
}

// True for the LR pixels that blur_pose_stride uses.
bool UsedBlurPosePixel(int x, int y, int stride) {
  return y % stride == 0 && x % stride == (y / stride) % stride;
}

}  // namespace

cv::Mat BlurPoseJacobian(const CaptureGeometry& geometry, int samples, int scale, const cv::Mat& inverse_depth,
                         const cv::Mat& latent, int max_samples, int stride) {
  if (geometry.T_world_source.has_value()) {
    throw InputError("BlurPoseJacobian: needs the self-consistency geometry (no source camera)");
  }
  const PinholeCamera& hr = geometry.camera_hr;
  const int channels = latent.channels(), frames = PathPoseCount(geometry);
  const int lr_rows = hr.height / scale, lr_cols = hr.width / scale;
  const int num_sets = geometry.readout_time > 0.0 ? lr_rows : 1;
  int used = 0;
  const std::vector<BlurPoseCamera> cameras =
      BlurPoseCameras(geometry, samples, max_samples, num_sets, lr_rows, &used);
  const Eigen::MatrixXd chain = PathPoseChain(geometry);  // [C_1; C_2; C_3]
  cv::Mat gx, gy;
  Gradients(latent, &gx, &gy);
  cv::Mat jacobian = cv::Mat::zeros(lr_rows, lr_cols, CV_32FC(channels * frames * 6));
  const double scale_weight = 1.0 / (used * scale * scale);
#pragma omp parallel for schedule(static)
  for (int ly = 0; ly < lr_rows; ++ly) {
    std::vector<float> grad_x(channels), grad_y(channels);
    Eigen::VectorXd moments(channels * 6 * kPathBasisSize);
    const BlurPoseCamera* set = &cameras[(num_sets > 1 ? ly : 0) * used];
    float* out = jacobian.ptr<float>(ly);
    for (int lx = 0; lx < lr_cols; ++lx) {
      if (!UsedBlurPosePixel(lx, ly, stride)) continue;
      moments.setZero();
      for (int y = ly * scale; y < (ly + 1) * scale; ++y) {
        const float* rho_row = inverse_depth.ptr<float>(y);
        for (int x = lx * scale; x < (lx + 1) * scale; ++x) {
          const double rho = rho_row[x];
          if (!(rho > 0.0) || !std::isfinite(rho)) continue;
          for (int i = 0; i < used; ++i) {
            AddBlurPoseMoments(hr, set[i], x, y, rho, gx, gy, scale_weight, grad_x.data(), grad_y.data(),
                               moments.data());
          }
        }
      }
      // J_c = sum_b A_cb C_b (A_cb the 6 moments of channel c, basis b).
      for (int c = 0; c < channels; ++c) {
        Eigen::RowVectorXd row = Eigen::RowVectorXd::Zero(6 * frames);
        for (int b = 0; b < kPathBasisSize; ++b) {
          row += moments.segment<6>(6 * (kPathBasisSize * c + b)).transpose() * chain.middleRows<6>(6 * b);
        }
        for (int i = 0; i < 6 * frames; ++i) out[(lx * channels + c) * 6 * frames + i] = static_cast<float>(row(i));
      }
    }
  }
  return jacobian;
}

namespace {

// Adds weight x stride^2 x J^T W J and J^T W r0 of the used LR pixels
// (blur_pose_stride) inside `mask` (LR; empty: all) to `term`, J the rows of
// `jacobian` (BlurPoseJacobian's layout over the first columns of the term)
// plus, with `warp` (6 LR images: the warp's pose Jacobian through Psi_t),
// +warp in the columns of frame kt and -warp in those of frame ks.
void AccumulateBlurPoseTerm(const cv::Mat& jacobian, const cv::Mat& residual, const cv::Mat& mask,
                            const std::vector<cv::Mat>* warp, int kt, int ks, double weight,
                            const StructureUpdateOptions& options, BlurPoseTerm* term) {
  const int stride = options.blur_pose_stride, channels = residual.channels();
  const int blur_columns = jacobian.channels() / channels, unknowns = static_cast<int>(term->gradient.size());
  const double sampled_weight = weight * stride * stride;
  Eigen::VectorXd a(unknowns);
  for (int y = 0; y < jacobian.rows; ++y) {
    const float* r = residual.ptr<float>(y);
    const float* j = jacobian.ptr<float>(y);
    const uchar* m = mask.empty() ? nullptr : mask.ptr<uchar>(y);
    for (int x = 0; x < jacobian.cols; ++x) {
      if (!UsedBlurPosePixel(x, y, stride) || (m != nullptr && m[x] == 0)) continue;
      for (int c = 0; c < channels; ++c) {
        const int i = x * channels + c;
        const double r0 = r[i];
        const double w = sampled_weight / std::max(std::abs(r0), options.residual_epsilon);
        a.setZero();
        a.head(blur_columns) = Eigen::Map<const Eigen::VectorXf>(j + i * blur_columns, blur_columns).cast<double>();
        for (int e = 0; warp != nullptr && e < 6; ++e) {
          const double value = (*warp)[e].ptr<float>(y)[i];
          a(6 * kt + e) += value;
          a(6 * ks + e) -= value;
        }
        term->hessian.selfadjointView<Eigen::Upper>().rankUpdate(a, w);
        term->gradient += (w * r0) * a;
      }
    }
  }
}

BlurPoseTerm EmptyBlurPoseTerm(const std::vector<int>& frames) {
  BlurPoseTerm term;
  term.frames = frames;
  term.hessian = Eigen::MatrixXd::Zero(6 * frames.size(), 6 * frames.size());
  term.gradient = Eigen::VectorXd::Zero(6 * frames.size());
  return term;
}

}  // namespace

BlurPoseTerm LinearizeBlurInPoses(const CaptureGeometry& geometry, const std::vector<int>& frames, int samples,
                                  int scale, const cv::Mat& inverse_depth, const cv::Mat& latent,
                                  const cv::Mat& observation, const cv::Mat& predicted, double weight,
                                  const StructureUpdateOptions& options) {
  if (static_cast<int>(frames.size()) != PathPoseCount(geometry)) {
    throw InputError("LinearizeBlurInPoses: one frame index per pose of the blur path");
  }
  const cv::Mat jacobian = BlurPoseJacobian(geometry, samples, scale, inverse_depth, latent,
                                            options.blur_pose_samples, options.blur_pose_stride);
  BlurPoseTerm term = EmptyBlurPoseTerm(frames);
  AccumulateBlurPoseTerm(jacobian, observation - predicted, cv::Mat(), nullptr, 0, 0, weight, options, &term);
  term.hessian = term.hessian.selfadjointView<Eigen::Upper>();
  return term;
}

BlurPoseTerm LinearizeBlurredPairInPoses(const CaptureGeometry& geometry, const std::vector<int>& frames,
                                         int s, int samples, int scale, const cv::Mat& inverse_depth,
                                         const SE3& T_world_s, const cv::Mat& latent_s,
                                         const CaptureOperator& psi_t, const cv::Mat& observation, double weight,
                                         const StructureUpdateOptions& options) {
  if (static_cast<int>(frames.size()) != PathPoseCount(geometry)) {
    throw InputError("LinearizeBlurredPairInPoses: one frame index per pose of the blur path");
  }
  std::vector<int> all = frames;
  if (std::find(all.begin(), all.end(), s) == all.end()) all.push_back(s);
  const int ks = static_cast<int>(std::find(all.begin(), all.end(), s) - all.begin());
  std::vector<cv::Mat> jacobians, projected(6);
  const WarpLinearization lin = LinearizeWarp(geometry.camera_hr, inverse_depth, geometry.T_world_cam,
                                              T_world_s, latent_s, &jacobians);
  for (int e = 0; e < 6; ++e) psi_t.Apply(jacobians[e], &projected[e]);
  cv::Mat predicted;
  psi_t.Apply(lin.warped, &predicted);
  const cv::Mat blur = BlurPoseJacobian(geometry, samples, scale, inverse_depth, lin.warped,
                                        options.blur_pose_samples, options.blur_pose_stride);
  BlurPoseTerm term = EmptyBlurPoseTerm(all);
  AccumulateBlurPoseTerm(blur, observation - predicted, DownscaleMaskAll(lin.valid, scale), &projected, 0, ks,
                         weight, options, &term);
  term.hessian = term.hessian.selfadjointView<Eigen::Upper>();
  return term;
}

void StructureUpdateOptions::Check() const {
  CheckAtLeast("structure update: lambda_d", lambda_d, 0.0);
  CheckInRange("structure update: pose_pixel_stride", pose_pixel_stride, 1, 8);
  CheckAtLeast("structure update: depth_irls_iterations", depth_irls_iterations, 0);
  CheckAtLeast("structure update: depth_cg_iterations", depth_cg_iterations, 1);
  CheckInRange("structure update: depth_cg_tolerance", depth_cg_tolerance, 0.0, 1.0);
  CheckAtLeast("structure update: pose_iterations", pose_iterations, 0);
  CheckAbove("structure update: residual_epsilon", residual_epsilon, 0.0);
  CheckAbove("structure update: tv_epsilon", tv_epsilon, 0.0);
  CheckAtLeast("structure update: depth_damping", depth_damping, 0.0);
  CheckAtLeast("structure update: pose_damping", pose_damping, 0.0);
  CheckAtLeast("structure update: joint_cg_iterations", joint_cg_iterations, 1);
  CheckAtLeast("structure update: joint_irls_iterations", joint_irls_iterations, 1);
  CheckAtLeast("structure update: joint_pose_damping", joint_pose_damping, 0.0);
  CheckInRange("structure update: joint_coarse_levels", joint_coarse_levels, 0, 4);
  CheckInRange("structure update: blur_pose_samples", blur_pose_samples, 1, 1000);
  CheckInRange("structure update: blur_pose_stride", blur_pose_stride, 1, 8);
  CheckAtLeast("structure update: blur_pose_weight", blur_pose_weight, 0.0);
  edge_weight.Check();
}

namespace {

// LinearizeWarp, and with `warped_gradients` the source's gradients at the
// warp (HR, 2C channels: g_x of channel c at 2c, g_y at 2c + 1; zero where
// the warp is not valid), for the pose terms of HR pairs.
WarpLinearization LinearizeWarpSampled(const PinholeCamera& camera_hr, const cv::Mat& inverse_depth_t,
                                       const SE3& T_world_t, const SE3& T_world_s, const cv::Mat& latent_s,
                                       std::vector<cv::Mat>* pose_jacobians, cv::Mat* warped_gradients) {
  const int channels = latent_s.channels();
  const int width = camera_hr.width, height = camera_hr.height;
  // The outputs are not cleared first: every pixel is written, zeros
  // where the warp is not valid (WriteInvalid).
  WarpLinearization lin;
  lin.warped.create(height, width, latent_s.type());
  lin.d_inverse_depth.create(height, width, latent_s.type());
  lin.valid.create(height, width, CV_8UC1);
  if (pose_jacobians != nullptr) {
    pose_jacobians->assign(6, cv::Mat());
    for (cv::Mat& j : *pose_jacobians) j.create(height, width, latent_s.type());
  }
  if (warped_gradients != nullptr) warped_gradients->create(height, width, CV_32FC(2 * channels));
  const auto write_invalid = [&](int x, int y) {
    lin.valid.at<uchar>(y, x) = 0;
    std::fill_n(lin.warped.ptr<float>(y) + x * channels, channels, 0.0f);
    std::fill_n(lin.d_inverse_depth.ptr<float>(y) + x * channels, channels, 0.0f);
    if (warped_gradients != nullptr)
      std::fill_n(warped_gradients->ptr<float>(y) + x * 2 * channels, 2 * channels, 0.0f);
    if (pose_jacobians == nullptr) return;
    for (cv::Mat& j : *pose_jacobians) std::fill_n(j.ptr<float>(y) + x * channels, channels, 0.0f);
  };
  cv::Mat gx, gy;
  Gradients(latent_s, &gx, &gy);
  const PairWarp warp(camera_hr, T_world_t, T_world_s);
#pragma omp parallel for schedule(static)
  for (int y = 0; y < height; ++y) {
    const float* rho_row = inverse_depth_t.ptr<float>(y);
    std::vector<float> value(channels), grad_x(channels), grad_y(channels);
    for (int x = 0; x < width; ++x) {
      double u, v, du, dv;
      if (!warp.Project(x, y, rho_row[x], &u, &v, &du, &dv)) {
        write_invalid(x, y);
        continue;
      }
      lin.valid.at<uchar>(y, x) = 255;
      SampleBilinear(latent_s, static_cast<float>(u), static_cast<float>(v), value.data());
      SampleBilinear(gx, static_cast<float>(u), static_cast<float>(v), grad_x.data());
      SampleBilinear(gy, static_cast<float>(u), static_cast<float>(v), grad_y.data());
      float* warped = lin.warped.ptr<float>(y) + x * channels;
      float* d_rho = lin.d_inverse_depth.ptr<float>(y) + x * channels;
      for (int c = 0; c < channels; ++c) {
        warped[c] = value[c];
        d_rho[c] = static_cast<float>(grad_x[c] * du + grad_y[c] * dv);
      }
      if (warped_gradients != nullptr) {
        float* gradients = warped_gradients->ptr<float>(y) + x * 2 * channels;
        for (int c = 0; c < channels; ++c) {
          gradients[2 * c] = grad_x[c];
          gradients[2 * c + 1] = grad_y[c];
        }
      }
      if (pose_jacobians == nullptr) continue;
      const Eigen::Matrix<double, 2, 6> d_pixel_d_eps = warp.DPixelDPose(x, y, rho_row[x]);
      for (int j = 0; j < 6; ++j) {
        float* out = (*pose_jacobians)[j].ptr<float>(y) + x * channels;
        for (int c = 0; c < channels; ++c) {
          out[c] = static_cast<float>(grad_x[c] * d_pixel_d_eps(0, j) + grad_y[c] * d_pixel_d_eps(1, j));
        }
      }
    }
  }
  return lin;
}

}  // namespace

WarpLinearization LinearizeWarp(const PinholeCamera& camera_hr, const cv::Mat& inverse_depth_t,
                                const SE3& T_world_t, const SE3& T_world_s, const cv::Mat& latent_s,
                                std::vector<cv::Mat>* pose_jacobians) {
  return LinearizeWarpSampled(camera_hr, inverse_depth_t, T_world_t, T_world_s, latent_s, pose_jacobians,
                              nullptr);
}

namespace {

// Where a pair's depth-pose coupling C (6 values per pixel) is added: one of
// its frame's interleaved coupling images (CV_32FC(6)), with the sign of the
// pose column it stands for (+C for eps_t, -C for eps_s).
struct CouplingTarget {
  cv::Mat* images = nullptr;  // nullptr: not added
  float sign = 0.0f;
};
using CouplingTargets = std::array<CouplingTarget, 2>;

// One HR pair's share of HrPairPoseTerms: its images after LinearizeWarpSampled
// and the reweighting, where its coupling goes and its 6x6 sums.
struct HrPairPoseInputs {
  const cv::Mat* warped_gradients = nullptr;
  const cv::Mat* d_inverse_depth = nullptr;
  const cv::Mat* residual = nullptr;
  const cv::Mat* weight = nullptr;
  CouplingTargets targets;
  Eigen::Matrix<double, 6, 6>* block = nullptr;
  Vector6d* rhs = nullptr;
};

// The pose terms of HR pairs (no capture operator) in one pass over their
// pixels, without the six pose Jacobian images: channel c's row is A_c =
// g_c^T J (g_c the source's gradient at the warp, `warped_gradients` of
// LinearizeWarpSampled; J = d pixel / d eps_t), so
// with the IRLS weights w and the depth derivative g_rho,
//   coupling = sum_c w_c g_rho,c A_c^T = J^T q,  q = sum_c w_c g_rho,c g_c,
//   block = sum J^T S J,  S = sum_c w_c g_c g_c^T,  rhs = sum J^T sum_c w_c r0_c g_c.
// The coupling is added into `targets` as it is formed (no image per pair).
// The 6x6 sums go row by row (float within a row, double across rows).
// Every pair of `pairs` warps t's pixels into s at the same depth and poses
// (a restored pair and its input pair), so J is formed once per pixel for
// all of them; each pair's values get the operations, and each coupling
// value the additions in pair order, that one pair at a time gives.
void HrPairPoseTerms(const PinholeCamera& camera, const cv::Mat& inverse_depth, const SE3& T_world_t,
                     const SE3& T_world_s, const std::vector<HrPairPoseInputs>& pairs) {
  const int width = camera.width;
  const PairWarp warp(camera, T_world_t, T_world_s);
  std::vector<RowPoseSums> row_sums;  // per pair; per row, zero where every weight is zero
  for (const HrPairPoseInputs& pair : pairs) {
    pair.block->setZero();
    pair.rhs->setZero();
    row_sums.emplace_back(width);
  }
  for (int y = 0; y < camera.height; ++y) {
    const float* rho_row = inverse_depth.ptr<float>(y);
    for (size_t p = 0; p < pairs.size(); ++p) row_sums[p].Clear();
    for (int x = 0; x < width; ++x) {
      Eigen::Matrix<double, 2, 6> j;
      bool j_formed = false;
      for (size_t p = 0; p < pairs.size(); ++p) {
        const HrPairPoseInputs& pair = pairs[p];
        const int channels = pair.d_inverse_depth->channels();
        // A zero weight in every channel: masked, or the warp is not valid.
        const float* w = pair.weight->ptr<float>(y) + x * channels;
        if (std::all_of(w, w + channels, [](float value) { return value == 0.0f; })) continue;
        const float* r_row = pair.residual->ptr<float>(y);
        const float* g_row = pair.d_inverse_depth->ptr<float>(y);
        const float* gradient = pair.warped_gradients->ptr<float>(y) + x * 2 * channels;
        GradientMoments m;
        double q0 = 0.0, q1 = 0.0;
        for (int c = 0; c < channels; ++c) {
          const double g_rho = g_row[x * channels + c];
          const float grad_x = gradient[2 * c], grad_y = gradient[2 * c + 1];
          m.Add(w[c], r_row[x * channels + c], grad_x, grad_y);
          q0 += w[c] * g_rho * grad_x;
          q1 += w[c] * g_rho * grad_y;
        }
        if (!j_formed) {
          j = warp.DPixelDPose(x, y, rho_row[x]);
          j_formed = true;
        }
        for (int k = 0; k < 6; ++k) {
          const float coupling = static_cast<float>(j(0, k) * q0 + j(1, k) * q1);
          for (const CouplingTarget& target : pair.targets) {
            if (target.images != nullptr) target.images->ptr<float>(y)[6 * x + k] += target.sign * coupling;
          }
        }
        row_sums[p].Set(x, j, m);
      }
    }
    for (size_t p = 0; p < pairs.size(); ++p) row_sums[p].AddTo(width, pairs[p].block, pairs[p].rhs);
  }
  for (const HrPairPoseInputs& pair : pairs) *pair.block = 0.5 * (*pair.block + pair.block->transpose());
}

// The IRLS form of the depth update of one frame (eq:taylorExpansion, with
// the edge-weighted TV of eq:regularizingTerm on c * rho, c the parallax
// scale) at the current inverse depth rho:
//   N x = sum_p G_p^T Psi^T W_p Psi (G_p .* x) + lambda_s H^T Box^T W_s Box (H .* x)
//         + lambda_d c^2 L_v x + damping * x,
//   rhs = sum_p G_p^T Psi^T W_p r_p + lambda_s H^T Box^T W_s r_s - lambda_d c^2 L_v rho,
// G_p the warped images' derivatives in rho, H the self term's (Psi = I for
// HR pairs).
//
// Memory: a pair's images live only while it is linearised. The pairs'
// share of the right-hand side and the HR pairs' share of N (a diagonal) are
// summed then; only pairs with a capture operator keep G_p and W_p (their
// part of N is applied in every CG step). With pose coupling the pairs'
// depth-pose couplings are summed into one image per coupled pose column.
class DepthNormalEquations {
 public:
  // No pose coupling (the per-frame depth update).
  static constexpr int kNoPoseCoupling = -1;

  // `coupling_reference` (>= 0): the pairs' pose terms are formed too, and
  // the coupling of the pose column of that frame is left out (see
  // couplings()). `held_poses`: the leading frames whose pose increments
  // the caller holds at zero; with a held reference, their columns and the
  // pose terms of pairs between two of them are not formed (they multiply,
  // or enter, only held increments: StructureUpdateOptions::
  // skip_held_pose_work).
  DepthNormalEquations(const PinholeCamera& camera_hr, const std::vector<SE3>& T_world_cam,
                       const std::vector<cv::Mat>& latents, const std::vector<PairMatching>& pairs,
                       const SelfConsistencyLinearization* self, const cv::Mat& edge_weight,
                       double parallax_scale, const StructureUpdateOptions& options,
                       int coupling_reference = kNoPoseCoupling, int held_poses = 0)
      : camera_hr_(camera_hr),
        T_world_cam_(T_world_cam),
        latents_(latents),
        pairs_(pairs),
        self_(self),
        edge_weight_(edge_weight),
        parallax_scale_(parallax_scale),
        options_(options),
        coupling_reference_(coupling_reference),
        held_poses_(held_poses),
        width_(camera_hr.width),
        height_(camera_hr.height),
        c2_(parallax_scale * parallax_scale),
        states_(pairs.size()),
        tv_weight_(height_, width_, CV_32FC1),
        nd_self_(height_, width_, CV_32FC1),
        moved_(cv::Mat::zeros(height_, width_, CV_32FC1)),
        hr_diagonal_(height_, width_, CV_32FC1),
        data_rhs_(height_, width_, CV_32FC1) {}

  // Linearises every term at `inverse_depth` and reweights (IRLS).
  void Linearize(const cv::Mat& inverse_depth) {
    double diagonal_sum = LinearizePairs(inverse_depth);
    if (self_ != nullptr) diagonal_sum += LinearizeSelf();
    damping_ = options_.depth_damping * diagonal_sum / (width_ * height_) + 1e-12;
    ReweightTv(inverse_depth);
    FormDiagonal();
  }

  // Frees the scratch images of Linearize (kept otherwise for the next one).
  void ReleaseScratch() {
    squared_.release();
    expanded_.release();
    predicted_.release();
    back_.release();
  }

  // diag(N), the Jacobi preconditioner (after Linearize).
  const cv::Mat& diagonal() const { return diagonal_; }
  // The TV term of N is tv_scale() D^T diag(tv_weight()) D (after
  // Linearize; AddWeightedLaplacian).
  const cv::Mat& tv_weight() const { return tv_weight_; }
  double tv_scale() const { return options_.lambda_d * c2_; }

  // From now on Linearize also sums the pairs' absolute residuals over
  // their masks (the photometric scale of a pose prior's terms).
  void MeasureResiduals() { measure_residuals_ = true; }
  double absolute_residuals() const { return absolute_residuals_; }
  double residual_values() const { return residual_values_; }

  // With pose coupling, pair p's pose terms after Linearize: for r = r0 -
  // Psi(g .* d + A (eps_t - eps_s)), block = A^T Psi^T W Psi A and rhs =
  // A^T Psi^T W r0.
  struct PoseTerms {
    Eigen::Matrix<double, 6, 6> block = Eigen::Matrix<double, 6, 6>::Zero();
    Vector6d rhs = Vector6d::Zero();
  };
  const PoseTerms& pose_terms(size_t p) const { return states_[p].pose; }

  // With pose coupling, the columns of N_dp on this frame's pixels after
  // Linearize: pair p's coupling C_p = G^T Psi^T W Psi A_j (j = 0..5,
  // interleaved pixel by pixel, CV_32FC(6)) enters with +C_p for eps_t and
  // -C_p for eps_s, so the frame's columns sum to zero: the column of the
  // reference frame is minus the sum of the others and is not formed, and
  // the others multiply eps_frame - eps_reference.
  struct PoseColumn {
    int frame = 0;
    cv::Mat images;
  };
  const std::vector<PoseColumn>& couplings() const { return couplings_; }

  // rhs at `inverse_depth` (the linearisation point), without damping.
  void RightHandSide(const cv::Mat& inverse_depth, cv::Mat* rhs) {
    data_rhs_.copyTo(*rhs);
    if (self_ != nullptr) {
      cv::multiply(self_residual_, self_weight_, predicted_);
      BoxAdjoint(predicted_, self_->scale, &back_);
      ContractChannels(self_->derivative, back_, &nd_self_, false);
      cv::scaleAdd(nd_self_, self_->weight, *rhs, *rhs);
    }
    AddWeightedLaplacian(inverse_depth, tv_weight_, -options_.lambda_d * c2_, rhs, 1);
  }

  // out = N in.
  void ApplyNormal(const cv::Mat& in, cv::Mat* out) {
    cv::multiply(hr_diagonal_, in, *out);
    for (size_t p = 0; p < pairs_.size(); ++p) {
      if (pairs_[p].blur == nullptr) continue;
      ExpandChannels(states_[p].d_inverse_depth, in, &expanded_);
      back_ = cv::Mat::zeros(expanded_.size(), expanded_.type());
      AddWeightedNormalProduct(pairs_[p].blur->matrix(), states_[p].weight, expanded_, &back_, 1);
      ContractChannels(states_[p].d_inverse_depth, back_, out, true);
    }
    if (self_ != nullptr) {
      ExpandChannels(self_->derivative, in, &expanded_);
      BoxDown(expanded_, self_->scale, &predicted_);
      cv::multiply(predicted_, self_weight_, predicted_);
      BoxAdjoint(predicted_, self_->scale, &back_);
      ContractChannels(self_->derivative, back_, &nd_self_, false);
      cv::scaleAdd(nd_self_, self_->weight, *out, *out);
    }
    AddWeightedLaplacian(in, tv_weight_, options_.lambda_d * c2_, out, 1);
    cv::scaleAdd(in, damping_, *out, *out);
  }

  // rho += step, where a step may not shrink rho below a quarter (inverse
  // depth stays positive); remembers the change for the self term.
  void ApplyStep(const cv::Mat& step, cv::Mat* inverse_depth) {
    float* rho_out = inverse_depth->ptr<float>();
    const float* delta = step.ptr<float>();
    float* moved_out = moved_.ptr<float>();
    for (int i = 0; i < width_ * height_; ++i) {
      if (!(rho_out[i] > 0.0f)) continue;
      const float updated = std::max(rho_out[i] + delta[i], 0.25f * rho_out[i]);
      moved_out[i] += updated - rho_out[i];
      rho_out[i] = updated;
    }
  }

 private:
  // What a pair keeps after Linearize: G and W with a capture operator
  // (empty for HR pairs), and its pose terms.
  struct PairState {
    cv::Mat d_inverse_depth;  // HR, C channels
    cv::Mat weight;           // observation grid, C channels
    PoseTerms pose;           // with pose coupling
  };

  bool pose_coupling() const { return coupling_reference_ != kNoPoseCoupling; }
  bool held(int frame) const { return frame < held_poses_; }
  // Whether `frame`'s pose column is formed: not the reference's, nor, with
  // a held reference, a held frame's (its increment and the reference's
  // are both zero, so the column multiplies zero and its products land in
  // held rows).
  bool formed_column(int frame) const {
    return frame != coupling_reference_ && !(held(frame) && held(coupling_reference_));
  }
  // Whether pair p's pose terms are formed: not between two held frames.
  bool pose_terms_formed(const PairMatching& pair) const {
    return pose_coupling() && !(held(pair.t) && held(pair.s));
  }

  // The index in couplings_ of the pose column of `frame` (zero when new).
  size_t Column(int frame) {
    for (size_t i = 0; i < couplings_.size(); ++i) {
      if (couplings_[i].frame == frame) return i;
    }
    couplings_.push_back({frame, cv::Mat::zeros(height_, width_, CV_32FC(6))});
    return couplings_.size() - 1;
  }
  // Where pair (t <- s)'s coupling goes: +C to eps_t's column and -C to
  // eps_s's, leaving out the reference's (columns made first: pointers
  // into couplings_ last until it grows).
  CouplingTargets TargetsOf(const PairMatching& pair) {
    const bool with_t = formed_column(pair.t), with_s = formed_column(pair.s);
    const size_t column_t = with_t ? Column(pair.t) : 0, column_s = with_s ? Column(pair.s) : 0;
    CouplingTargets targets;
    if (with_t) targets[0] = {&couplings_[column_t].images, 1.0f};
    if (with_s) targets[1] = {&couplings_[column_s].images, -1.0f};
    return targets;
  }

  // Whether HR pair p with pose terms and the next pair warp the same
  // pixels (the same t and s: a restored pair and its input pair) and the
  // next forms its pose terms without a capture operator too.
  bool SharesHrWarp(size_t p) const {
    if (p + 1 >= pairs_.size()) return false;
    const PairMatching &a = pairs_[p], &b = pairs_[p + 1];
    return a.t == b.t && a.s == b.s && b.blur == nullptr && pose_terms_formed(b);
  }

  // Every pair at the current depth (eq:taylorExpansion), one at a time:
  // its share of the right-hand side, of the HR diagonal and, with pose
  // coupling, its pose terms; returns its share of the data diagonal's sum
  // (for the damping).
  double LinearizePairs(const cv::Mat& inverse_depth) {
    double diagonal_sum = 0.0;
    absolute_residuals_ = residual_values_ = 0.0;
    data_rhs_.setTo(0.0);
    // HR pairs (no capture operator) act pixel by pixel: their part of the
    // normal matrix is the diagonal sum_p sum_c w g^2, formed once per
    // reweighting instead of applied pair by pair in every CG step.
    hr_diagonal_.setTo(0.0);
    for (PoseColumn& column : couplings_) column.images.setTo(0.0);
    std::vector<cv::Mat> pose_jacobians;  // A_j of a pair with a capture operator
    // The source's gradients at an HR pair's warp: two buffers, as an HR
    // pair whose next pair shares its warp (SharesHrWarp) waits for it.
    std::array<cv::Mat, 2> warped_gradients;
    std::vector<HrPairPoseInputs> waiting;  // HR pairs whose pose terms wait for their partner
    std::vector<cv::Mat> waiting_images;    // and what they read (residual, weight, d rho)
    waiting_images.reserve(6);              // no reallocation: `waiting` points into it
    for (size_t p = 0; p < pairs_.size(); ++p) {
      const PairMatching& pair = pairs_[p];
      PairState& state = states_[p];
      // HR pairs form their pose terms in one pass (HrPairPoseTerms), without
      // the pose Jacobian images.
      const bool jacobian_images = pose_terms_formed(pair) && pair.blur != nullptr;
      const bool hr_pose_terms = pose_terms_formed(pair) && pair.blur == nullptr;
      cv::Mat& gradients = warped_gradients[waiting.size() % 2];
      const WarpLinearization lin = LinearizeWarpSampled(
          camera_hr_, inverse_depth, T_world_cam_[pair.t], T_world_cam_[pair.s], SourceImage(pair, latents_),
          jacobian_images ? &pose_jacobians : nullptr, hr_pose_terms ? &gradients : nullptr);
      Predict(pair, lin.warped, &predicted_);
      const cv::Mat residual = *pair.observation - predicted_;
      cv::Mat weight;
      const cv::Mat mask = ObservationMask(pair, lin.valid);
      L1Weights(residual, mask, options_.residual_epsilon, &weight);
      if (pair.weight != 1.0f) weight *= pair.weight;  // PairMatching::weight
      if (measure_residuals_) MeasureResidual(residual, mask);
      cv::multiply(residual, weight, predicted_);
      PredictAdjoint(pair, predicted_, &back_);
      ContractChannels(lin.d_inverse_depth, back_, &data_rhs_, true);
      if (pair.blur == nullptr) {
        cv::multiply(lin.d_inverse_depth, weight, squared_);
        ContractChannels(lin.d_inverse_depth, squared_, &hr_diagonal_, true);
      }
      if (jacobian_images) CouplePoses(pair, lin, residual, weight, pose_jacobians, &state.pose);
      if (hr_pose_terms) {
        waiting_images.insert(waiting_images.end(), {residual, weight, lin.d_inverse_depth});
        const cv::Mat* kept = &waiting_images[waiting_images.size() - 3];
        waiting.push_back({&gradients, kept + 2, kept, kept + 1, TargetsOf(pair), &state.pose.block,
                           &state.pose.rhs});
        // The pose terms of the pair and its partner in one pass (the
        // coupling images are touched by no other pair in between).
        if (waiting.size() == 2 || !SharesHrWarp(p)) {
          HrPairPoseTerms(camera_hr_, inverse_depth, T_world_cam_[pair.t], T_world_cam_[pair.s], waiting);
          waiting.clear();
          waiting_images.clear();
        }
      }
      diagonal_sum += Dot1(lin.d_inverse_depth, lin.d_inverse_depth) * cv::mean(weight)[0] /
                      std::max(1, weight.channels());
      if (pair.blur != nullptr) {
        state.d_inverse_depth = lin.d_inverse_depth;
        state.weight = weight;
      }
    }
    return diagonal_sum;
  }

  // Adds sum |r| and the count of values over the mask (empty: all).
  void MeasureResidual(const cv::Mat& residual, const cv::Mat& mask) {
    const cv::Scalar sums = cv::sum(cv::abs(residual));
    if (mask.empty()) {
      for (int c = 0; c < residual.channels(); ++c) absolute_residuals_ += sums[c];
      residual_values_ += static_cast<double>(residual.total() * residual.channels());
      return;
    }
    cv::Mat masked = cv::Mat::zeros(residual.size(), residual.type());
    residual.copyTo(masked, mask);
    const cv::Scalar masked_sums = cv::sum(cv::abs(masked));
    for (int c = 0; c < residual.channels(); ++c) absolute_residuals_ += masked_sums[c];
    residual_values_ += static_cast<double>(cv::countNonZero(mask)) * residual.channels();
  }

  // The pose terms of a linearised pair with a capture operator from the
  // pose Jacobians A_j of LinearizeWarp (eq:updateVariables): Psi A_j on the
  // observation grid, its weighted products with Psi A_k and W r0, and
  // G^T Psi^T W Psi A_j (added into the pair's coupling columns).
  void CouplePoses(const PairMatching& pair, const WarpLinearization& lin, const cv::Mat& residual,
                   const cv::Mat& weight, const std::vector<cv::Mat>& pose_jacobians, PoseTerms* pose) {
    std::array<cv::Mat, 6> projected, weighted, columns;
    cv::multiply(residual, weight, predicted_);
    for (int j = 0; j < 6; ++j) {
      Predict(pair, pose_jacobians[j], &projected[j]);
      cv::multiply(projected[j], weight, weighted[j]);
      PredictAdjoint(pair, weighted[j], &back_);
      columns[j].create(height_, width_, CV_32FC1);
      ContractChannels(lin.d_inverse_depth, back_, &columns[j], false);
    }
    cv::Mat coupling;
    cv::merge(columns.data(), columns.size(), coupling);
    for (const CouplingTarget& target : TargetsOf(pair)) {
      if (target.images != nullptr) cv::scaleAdd(coupling, target.sign, *target.images, *target.images);
    }
    PoseProducts(projected, weighted, predicted_, &pose->block, &pose->rhs);
  }

  // block(j, k) = sum a_j (w a_k) and rhs(j) = sum a_j (w r0) over every
  // value of the images (row by row: float within a row, double across
  // rows, so that the six images' rows stay in cache for the 27 products).
  static void PoseProducts(const std::array<cv::Mat, 6>& a, const std::array<cv::Mat, 6>& weighted_a,
                           const cv::Mat& weighted_residual, Eigen::Matrix<double, 6, 6>* block, Vector6d* rhs) {
    using Row = Eigen::Map<const Eigen::VectorXf>;
    block->setZero();
    rhs->setZero();
    const int n = a[0].cols * a[0].channels();
    for (int y = 0; y < a[0].rows; ++y) {
      const Row r(weighted_residual.ptr<float>(y), n);
      for (int j = 0; j < 6; ++j) {
        const Row a_j(a[j].ptr<float>(y), n), weighted_j(weighted_a[j].ptr<float>(y), n);
        (*rhs)(j) += a_j.dot(r);
        for (int k = 0; k <= j; ++k) (*block)(j, k) += weighted_j.dot(Row(a[k].ptr<float>(y), n));
      }
    }
    *block = block->selfadjointView<Eigen::Lower>();
  }

  // The self term (eq:IPterm): r = (B - Psi I) - Box(h .* moved), the linear
  // model since it was linearised; returns its share of the diagonal's sum.
  double LinearizeSelf() {
    ExpandChannels(self_->derivative, moved_, &expanded_);
    BoxDown(expanded_, self_->scale, &predicted_);
    self_residual_ = *self_->observation - self_->predicted - predicted_;
    L1Weights(self_residual_, cv::Mat(), options_.residual_epsilon, &self_weight_);
    return self_->weight * Dot1(self_->derivative, self_->derivative) * cv::mean(self_weight_)[0] /
           (self_->scale * self_->scale);
  }

  // diag(N): the HR pairs' diagonal, sum_c g_c^2 diag(Psi^T W Psi)_c per
  // pair with a capture operator, the self term's box (weights 1/s^2 per
  // tap), the TV stencil and the damping.
  void FormDiagonal() {
    hr_diagonal_.copyTo(diagonal_);
    for (size_t p = 0; p < pairs_.size(); ++p) {
      if (pairs_[p].blur == nullptr) continue;
      const cv::Mat& g = states_[p].d_inverse_depth;
      back_ = cv::Mat::zeros(g.size(), g.type());
      AddWeightedNormalDiagonal(pairs_[p].blur->matrix(), states_[p].weight, &back_, 1);
      cv::multiply(g, g, squared_);
      ContractChannels(squared_, back_, &diagonal_, true);
    }
    if (self_ != nullptr) {
      const double box = 1.0 / (self_->scale * self_->scale);
      BoxAdjoint(self_weight_, self_->scale, &back_);  // w / s^2 on each HR pixel of its LR pixel
      cv::multiply(self_->derivative, self_->derivative, squared_, box);
      ContractChannels(squared_, back_, &nd_self_, false);
      cv::scaleAdd(nd_self_, self_->weight, diagonal_, diagonal_);
    }
    AddWeightedLaplacianDiagonal(tv_weight_, options_.lambda_d * c2_, &diagonal_);
    diagonal_ += damping_;
  }

  // TV weights v = g / max(|grad (c rho)|, eps) (eq:regularizingTerm with g_t).
  void ReweightTv(const cv::Mat& inverse_depth) {
    const float* rho = inverse_depth.ptr<float>();
    for (int yy = 0; yy < height_; ++yy) {
      for (int xx = 0; xx < width_; ++xx) {
        const int i = yy * width_ + xx;
        const float gxv = xx + 1 < width_ ? rho[i + 1] - rho[i] : 0.0f;
        const float gyv = yy + 1 < height_ ? rho[i + width_] - rho[i] : 0.0f;
        const double magnitude = parallax_scale_ * std::sqrt(gxv * gxv + gyv * gyv);
        const float g = edge_weight_.empty() ? 1.0f : edge_weight_.ptr<float>()[i];
        tv_weight_.ptr<float>()[i] = static_cast<float>(g / std::max(magnitude, options_.tv_epsilon));
      }
    }
  }

  const PinholeCamera& camera_hr_;
  const std::vector<SE3>& T_world_cam_;
  const std::vector<cv::Mat>& latents_;
  const std::vector<PairMatching>& pairs_;
  const SelfConsistencyLinearization* self_;
  const cv::Mat& edge_weight_;
  const double parallax_scale_;
  const StructureUpdateOptions& options_;
  const int coupling_reference_;  // kNoPoseCoupling: no pose terms
  const int held_poses_;          // leading frames with held pose increments
  const int width_, height_;
  const double c2_;
  std::vector<PairState> states_;
  std::vector<PoseColumn> couplings_;  // with pose coupling
  cv::Mat tv_weight_, nd_self_;
  cv::Mat self_weight_, self_residual_;  // self term: IRLS weights and residual
  cv::Mat moved_;                        // inverse-depth change since the self term's linearisation
  cv::Mat hr_diagonal_, diagonal_;
  cv::Mat data_rhs_;                               // the pairs' share of the rhs
  cv::Mat squared_, expanded_, predicted_, back_;  // scratch
  double damping_ = 0.0;
  bool measure_residuals_ = false;
  double absolute_residuals_ = 0.0, residual_values_ = 0.0;  // of the pairs, with measure_residuals_
};

// CG on N step = rhs from a zero step with the options' preconditioner.
void SolveDepthStep(DepthNormalEquations* system, const cv::Mat& rhs, const StructureUpdateOptions& options,
                    cv::Mat* step) {
  step->setTo(0.0);
  const auto apply_normal = [system](const cv::Mat& x, cv::Mat* out) { system->ApplyNormal(x, out); };
  switch (options.depth_preconditioner) {
    case DepthPreconditioner::kTvGaussSeidel: {
      const LaplacianGaussSeidelPreconditioner sweeps(system->diagonal(), system->tv_weight(),
                                                      system->tv_scale());
      SolvePcg(
          apply_normal, [&sweeps](const cv::Mat& r, cv::Mat* z) { sweeps.Apply(r, z); }, rhs.clone(),
          options.depth_cg_iterations, options.depth_cg_tolerance, 1, step);
      return;
    }
    case DepthPreconditioner::kJacobi:
      SolveJacobiPcg(apply_normal, system->diagonal(), rhs.clone(), options.depth_cg_iterations,
                     options.depth_cg_tolerance, 1, step);
      return;
    case DepthPreconditioner::kNone:
      SolvePcg(
          apply_normal, [](const cv::Mat& r, cv::Mat* z) { r.copyTo(*z); }, rhs.clone(),
          options.depth_cg_iterations, options.depth_cg_tolerance, 1, step);
      return;
  }
}

}  // namespace

void UpdateDepth(const PinholeCamera& camera_hr, const std::vector<SE3>& T_world_cam,
                 const std::vector<cv::Mat>& latents, const std::vector<PairMatching>& pairs,
                 const SelfConsistencyLinearization* self, const cv::Mat& edge_weight, double parallax_scale,
                 const StructureUpdateOptions& options, cv::Mat* inverse_depth) {
  options.Check();
  if (pairs.empty() && self == nullptr) return;
  DepthNormalEquations system(camera_hr, T_world_cam, latents, pairs, self, edge_weight, parallax_scale,
                              options);
  cv::Mat rhs(camera_hr.height, camera_hr.width, CV_32FC1);
  cv::Mat step(camera_hr.height, camera_hr.width, CV_32FC1);
  for (int irls = 0; irls < options.depth_irls_iterations; ++irls) {
    system.Linearize(*inverse_depth);
    system.RightHandSide(*inverse_depth, &rhs);
    SolveDepthStep(&system, rhs, options, &step);
    system.ApplyStep(step, inverse_depth);
  }
}

namespace {

// A^T W A and A^T W r0 of one pair for the pose update, where
// r(eps) = r0 - A (eps_t - eps_s) and W holds the IRLS weights of r0.
struct PairNormalEquations {
  Eigen::Matrix<double, 6, 6> block = Eigen::Matrix<double, 6, 6>::Zero();
  Eigen::Matrix<double, 6, 1> rhs = Eigen::Matrix<double, 6, 1>::Zero();
  double absolute_residuals = 0.0;  // sum |r0| over the used values
  double values = 0.0;              // how many
};

// The images of one HR pair: its source I_s with its gradients and the
// observation of t.
struct HrPairImages {
  const cv::Mat* source;
  const cv::Mat* source_gx;
  const cv::Mat* source_gy;
  const cv::Mat* observation;
};

// HR pairs of the same frames t <- s and mask (e.g. the restored pair and
// the input pair), pixel by pixel, without intermediate images: the
// observations of t against the sources warped by W^{t->s}. Every pair of
// the group warps the same pixels, so each pixel's warp and J are computed
// once. Channel c of pair k has the row a_kc = g_kc^T J (J = d pixel /
// d eps_t), so the group's block = sum J^T S J and rhs = sum J^T b with S
// and b summed over the pairs' channels (GradientMoments). The 6x6 sums go
// row by row (RowPoseSums) over the used pixels.
PairNormalEquations HrPairNormalEquations(const PinholeCamera& camera_hr, const cv::Mat& inverse_depth_t,
                                          const SE3& T_world_t, const SE3& T_world_s,
                                          const std::vector<HrPairImages>& group, const cv::Mat& mask,
                                          double epsilon, int stride) {
  const int channels = group.front().source->channels();
  const PairWarp warp(camera_hr, T_world_t, T_world_s);
  PairNormalEquations eq;
  std::vector<float> value(channels), grad_x(channels), grad_y(channels);
  RowPoseSums row_sums((camera_hr.width + stride - 1) / stride);  // the used pixels, packed
  for (int y = 0; y < camera_hr.height; y += stride) {
    const float* rho_row = inverse_depth_t.ptr<float>(y);
    const uchar* mask_row = mask.empty() ? nullptr : mask.ptr<uchar>(y);
    int used = 0;
    for (int x = (y / stride) % stride; x < camera_hr.width; x += stride) {
      if (mask_row != nullptr && mask_row[x] == 0) continue;
      PairWarp::Projection p;
      if (!warp.Project(x, y, rho_row[x], &p)) continue;
      const float u = static_cast<float>(p.u), v = static_cast<float>(p.v);
      GradientMoments m;
      for (const HrPairImages& pair : group) {
        SampleBilinear(*pair.source, u, v, value.data());
        SampleBilinear(*pair.source_gx, u, v, grad_x.data());
        SampleBilinear(*pair.source_gy, u, v, grad_y.data());
        const float* observed = pair.observation->ptr<float>(y) + x * channels;
        for (int c = 0; c < channels; ++c) {
          const double r0 = observed[c] - value[c];
          m.Add(1.0 / std::max(std::abs(r0), epsilon), r0, grad_x[c], grad_y[c]);
          eq.absolute_residuals += std::abs(r0);
        }
        eq.values += channels;
      }
      row_sums.Set(used++, warp.DPixelDPose(p), m);
    }
    if (used > 0) row_sums.AddTo(used, &eq.block, &eq.rhs);
  }
  eq.block = 0.5 * (eq.block + eq.block.transpose());
  return eq;
}

// A pair through the capture operator (LR residuals): the HR Jacobian images
// are mapped by Psi_t.
PairNormalEquations BlurredPairNormalEquations(const PinholeCamera& camera_hr, const cv::Mat& inverse_depth_t,
                                               const SE3& T_world_t, const SE3& T_world_s,
                                               const cv::Mat& source, const PairMatching& pair,
                                               double epsilon) {
  std::vector<cv::Mat> jacobians, projected(6);
  const WarpLinearization lin =
      LinearizeWarp(camera_hr, inverse_depth_t, T_world_t, T_world_s, source, &jacobians);
  cv::Mat predicted, weight;
  Predict(pair, lin.warped, &predicted);
  const cv::Mat residual = *pair.observation - predicted;
  L1Weights(residual, ObservationMask(pair, lin.valid), epsilon, &weight);
  for (int j = 0; j < 6; ++j) Predict(pair, jacobians[j], &projected[j]);
  PairNormalEquations eq;
  const size_t values = residual.total() * residual.channels();
  const float* w = weight.ptr<float>();
  const float* r0 = residual.ptr<float>();
  for (size_t i = 0; i < values; ++i) {
    if (w[i] == 0.0f) continue;
    eq.absolute_residuals += std::abs(r0[i]);
    eq.values += 1.0;
    Eigen::Matrix<double, 6, 1> a;
    for (int j = 0; j < 6; ++j) a(j) = projected[j].ptr<float>()[i];
    eq.rhs += (w[i] * r0[i]) * a;
    eq.block.selfadjointView<Eigen::Upper>().rankUpdate(a, w[i]);
  }
  eq.block = eq.block.selfadjointView<Eigen::Upper>();
  return eq;
}

// The pairs in groups that UpdatePoses evaluates together: HR pairs of the
// same frames and mask (a restored pair and its input pair) share each
// pixel's warp (HrPairNormalEquations); a pair with a capture operator is a
// group of its own. Indices into `pairs`, in their order.
std::vector<std::vector<int>> GroupPairsByWarp(const std::vector<PairMatching>& pairs) {
  std::vector<std::vector<int>> groups;
  for (int p = 0; p < static_cast<int>(pairs.size()); ++p) {
    const PairMatching& pair = pairs[p];
    auto group = std::find_if(groups.begin(), groups.end(), [&](const std::vector<int>& members) {
      const PairMatching& first = pairs[members.front()];
      return pair.blur == nullptr && first.blur == nullptr && first.t == pair.t && first.s == pair.s &&
             first.mask.data == pair.mask.data;
    });
    if (group != groups.end()) {
      group->push_back(p);
    } else {
      groups.push_back({p});
    }
  }
  return groups;
}

// The normal equations of the free poses (frames from num_fixed on) from
// each group's r(eps) = r0 - A (eps_t - eps_s): its A^T W A enters the
// (t, t) and (s, s) blocks and, negated, (t, s) and (s, t); A^T W r0 enters
// t's gradient and, negated, s's. Fixed frames' rows and columns are left out.
void AssemblePoseSystem(const std::vector<PairMatching>& pairs, const std::vector<std::vector<int>>& groups,
                        const std::vector<PairNormalEquations>& equations, int num_fixed, int unknowns,
                        Eigen::MatrixXd* hessian, Eigen::VectorXd* gradient) {
  *hessian = Eigen::MatrixXd::Zero(unknowns, unknowns);
  *gradient = Eigen::VectorXd::Zero(unknowns);
  for (size_t g = 0; g < groups.size(); ++g) {
    const Eigen::Matrix<double, 6, 6>& block = equations[g].block;
    const Eigen::Matrix<double, 6, 1>& rhs = equations[g].rhs;
    // Block indices (negative: a fixed frame).
    const int bt = pairs[groups[g].front()].t - num_fixed, bs = pairs[groups[g].front()].s - num_fixed;
    if (bt >= 0) {
      hessian->block<6, 6>(6 * bt, 6 * bt) += block;
      gradient->segment<6>(6 * bt) += rhs;
    }
    if (bs >= 0) {
      hessian->block<6, 6>(6 * bs, 6 * bs) += block;
      gradient->segment<6>(6 * bs) -= rhs;
    }
    if (bt >= 0 && bs >= 0) {
      hessian->block<6, 6>(6 * bt, 6 * bs) -= block;
      hessian->block<6, 6>(6 * bs, 6 * bt) -= block;
    }
  }
}

// Adds the blur terms (blur as motion evidence) at the steps `taken` so far
// in this pose update: r = r0 - J taken, so the gradient is J^T W r0 -
// J^T W J taken; their blocks of the free frames enter as they are.
void AddBlurPoseTerms(const std::vector<BlurPoseTerm>& terms, const std::vector<Vector6d>& taken, int num_fixed,
                      Eigen::MatrixXd* hessian, Eigen::VectorXd* gradient) {
  for (const BlurPoseTerm& term : terms) {
    const int frames = static_cast<int>(term.frames.size());
    Eigen::VectorXd steps(6 * frames);
    for (int k = 0; k < frames; ++k) steps.segment<6>(6 * k) = taken[term.frames[k]];
    const Eigen::VectorXd g = term.gradient - term.hessian * steps;
    for (int k = 0; k < frames; ++k) {
      const int bk = term.frames[k] - num_fixed;  // negative: a fixed frame
      if (bk < 0) continue;
      gradient->segment<6>(6 * bk) += g.segment<6>(6 * k);
      for (int l = 0; l < frames; ++l) {
        const int bl = term.frames[l] - num_fixed;
        if (bl >= 0) hessian->block<6, 6>(6 * bk, 6 * bl) += term.hessian.block<6, 6>(6 * k, 6 * l);
      }
    }
  }
}

}  // namespace

bool PosePriorTerms::any() const {
  return std::any_of(centre_world.begin(), centre_world.end(),
                     [](const std::optional<Eigen::Vector3d>& centre) { return centre.has_value(); });
}

// Per frame with a prior: the centre residual e_c = c - c_prior (d e_c /
// d eps = [I, -Hat(c)], since Exp(eps) P moves c to c + rho + phi x c) and,
// with rotation_sigma, the orientation residual e_R = Log(R R_prior^T)
// (d e_R / d phi = J_l(e_R)^-1), each Huber-reweighted on |e| / sigma.
void AddPosePriorNormalEquations(const PosePriorTerms& prior, const std::vector<SE3>& T_world_cam,
                                 int num_fixed, int offset, double photometric_scale, Eigen::MatrixXd* hessian,
                                 Eigen::VectorXd* gradient) {
  const auto huber_weight = [&prior](double sigmas) {
    return sigmas <= prior.huber ? 1.0 : prior.huber / sigmas;
  };
  photometric_scale *= prior.weight;
  const int count = std::min(static_cast<int>(prior.centre_world.size()), static_cast<int>(T_world_cam.size()));
  for (int f = std::max(num_fixed, 0); f < count; ++f) {
    if (!prior.centre_world[f]) continue;
    const int block = 6 * (f - offset);
    const Eigen::Vector3d centre = T_world_cam[f].translation();
    const Eigen::Vector3d e_c = centre - *prior.centre_world[f];
    Eigen::Matrix<double, 3, 6> j_c;
    j_c << Eigen::Matrix3d::Identity(), -Hat(centre);
    const double inverse_variance_c = 1.0 / (prior.position_sigma * prior.position_sigma);
    const double w_c =
        photometric_scale * inverse_variance_c * huber_weight(e_c.norm() / prior.position_sigma);
    hessian->block<6, 6>(block, block) += w_c * j_c.transpose() * j_c;
    gradient->segment<6>(block) -= w_c * j_c.transpose() * e_c;
    if (!(prior.rotation_sigma > 0.0)) continue;
    const Eigen::Vector3d e_r = SO3Log(T_world_cam[f].rotation() * prior.R_world_cam[f].transpose());
    const Eigen::Matrix3d j_r = SO3LeftJacobianInverse(e_r);
    const double w_r = photometric_scale / (prior.rotation_sigma * prior.rotation_sigma) *
                       huber_weight(e_r.norm() / prior.rotation_sigma);
    hessian->block<3, 3>(block + 3, block + 3) += w_r * j_r.transpose() * j_r;
    gradient->segment<3>(block + 3) -= w_r * j_r.transpose() * e_r;
  }
}

namespace {

// One track linearised at the poses: its point re-triangulated (DLT, then
// Gauss-Newton), then per observation the residual (projection - pixel) and
// its Jacobians in the frame's tangent eps (the left perturbation of
// T_world_cam, which moves T_world_mid the same way) and in the point.
struct TrackLinearization {
  int first = 0;
  std::vector<Eigen::Matrix<double, 2, 6>> j_eps;
  std::vector<Eigen::Matrix<double, 2, 3>> j_point;
  std::vector<Eigen::Vector2d> residual;
};

bool LinearizeTrack(const FeatureTrack& track, const PinholeCamera& camera,
                    const std::vector<SE3>& T_seen_world, TrackLinearization* out) {
  const int count = static_cast<int>(T_seen_world.size());
  if (count < 2) return false;
  std::vector<Eigen::Vector3d> rays(count);
  for (int k = 0; k < count; ++k) rays[k] = camera.Ray(track.points[k].x(), track.points[k].y());
  Eigen::Vector3d point;
  if (!TriangulateRays(rays, T_seen_world, &point)) return false;
  out->first = track.first_frame;
  out->j_eps.resize(count);
  out->j_point.resize(count);
  out->residual.resize(count);
  constexpr int kPointIterations = 3;
  for (int iteration = 0; iteration <= kPointIterations; ++iteration) {
    if (!point.allFinite()) return false;
    Eigen::Matrix3d H = Eigen::Matrix3d::Zero();
    Eigen::Vector3d b = Eigen::Vector3d::Zero();
    for (int k = 0; k < count; ++k) {
      const SE3& T = T_seen_world[k];
      const Eigen::Vector3d p = T * point;
      if (!(p.z() > 1e-9)) return false;
      out->residual[k] = camera.Project(p) - track.points[k];
      Eigen::Matrix<double, 2, 3> j_project;
      j_project << camera.fx / p.z(), 0.0, -camera.fx * p.x() / (p.z() * p.z()), 0.0, camera.fy / p.z(),
          -camera.fy * p.y() / (p.z() * p.z());
      out->j_point[k] = j_project * T.rotation();
      // Exp(eps)^-1 X ~ X - rho - phi x X = X - rho + Hat(X) phi.
      out->j_eps[k].leftCols<3>() = -out->j_point[k];
      out->j_eps[k].rightCols<3>() = out->j_point[k] * Hat(point);
      H += out->j_point[k].transpose() * out->j_point[k];
      b -= out->j_point[k].transpose() * out->residual[k];
    }
    if (iteration < kPointIterations) point += H.ldlt().solve(b);
  }
  return true;
}

// The Schur complement of one linearised track's point, Huber-weighted
// (`weight` per unit squared residual), into the free frames' blocks.
void AddReducedTrack(const TrackPoseTerms& terms, const TrackLinearization& L, double weight, int num_fixed,
                     int offset, Eigen::MatrixXd* hessian, Eigen::VectorXd* gradient) {
  const int count = static_cast<int>(L.residual.size());
  std::vector<double> w(count);
  Eigen::Matrix3d H_xx = Eigen::Matrix3d::Zero();
  Eigen::Vector3d b_x = Eigen::Vector3d::Zero();
  for (int k = 0; k < count; ++k) {
    const double sigmas = L.residual[k].norm() / terms.sigma_px;
    w[k] = weight * (sigmas <= terms.huber ? 1.0 : terms.huber / sigmas);
    H_xx += w[k] * L.j_point[k].transpose() * L.j_point[k];
    b_x -= w[k] * L.j_point[k].transpose() * L.residual[k];
  }
  const Eigen::Matrix3d H_xx_inverse = H_xx.inverse();
  if (!H_xx_inverse.allFinite()) return;
  for (int k = 0; k < count; ++k) {
    const int f = L.first + k;
    if (f < num_fixed) continue;
    const int block = 6 * (f - offset);
    const Eigen::Matrix<double, 6, 3> H_ex = w[k] * L.j_eps[k].transpose() * L.j_point[k];
    hessian->block<6, 6>(block, block) += w[k] * L.j_eps[k].transpose() * L.j_eps[k];
    gradient->segment<6>(block) -=
        w[k] * L.j_eps[k].transpose() * L.residual[k] + H_ex * (H_xx_inverse * b_x);
    for (int l = 0; l < count; ++l) {
      const int g = L.first + l;
      if (g < num_fixed) continue;
      const Eigen::Matrix<double, 3, 6> H_xe = w[l] * L.j_point[l].transpose() * L.j_eps[l];
      hessian->block<6, 6>(block, 6 * (g - offset)) -= H_ex * H_xx_inverse * H_xe;
    }
  }
}

}  // namespace

double AddTrackNormalEquations(const TrackPoseTerms& terms, const std::vector<SE3>& T_world_cam,
                               int num_fixed, int offset, double photometric_scale, Eigen::MatrixXd* hessian,
                               Eigen::VectorXd* gradient) {
  const int num_frames = static_cast<int>(T_world_cam.size());
  std::vector<TrackLinearization> linear(terms.tracks.size());
  std::vector<char> linearised(terms.tracks.size(), 0);
  const double cap = terms.huber * terms.sigma_px;
  double cost = 0.0;
  std::vector<SE3> T_seen_world;
  for (size_t i = 0; i < terms.tracks.size(); ++i) {
    const FeatureTrack& track = terms.tracks[i];
    T_seen_world.clear();
    for (int k = 0; k < static_cast<int>(terms.T_cam_seen[i].size()); ++k) {
      const int f = track.first_frame + k;
      if (f < 0 || f >= num_frames) break;
      T_seen_world.push_back((T_world_cam[f] * terms.T_cam_seen[i][k]).Inverse());
    }
    linearised[i] = LinearizeTrack(track, terms.camera, T_seen_world, &linear[i]);
    if (!linearised[i]) continue;
    for (const Eigen::Vector2d& r : linear[i].residual) cost += std::min(r.squaredNorm(), cap * cap);
  }
  if (hessian == nullptr || gradient == nullptr) return cost;
  double gate = 1.0;
  if (terms.min_cost > 0.0) {
    gate = std::clamp((cost / terms.min_cost - 1.0 - terms.gate_start) / terms.gate_width, 0.0, 1.0);
  }
  if (!(gate > 0.0)) return cost;
  const double weight = gate * photometric_scale * terms.weight / (terms.sigma_px * terms.sigma_px);
  for (size_t i = 0; i < terms.tracks.size(); ++i) {
    if (linearised[i])
      AddReducedTrack(terms, linear[i], weight, std::max(num_fixed, 0), offset, hessian, gradient);
  }
  return cost;
}

double TrackCostMinimum(const TrackPoseTerms& terms, std::vector<SE3> T_world_cam, int num_fixed) {
  TrackPoseTerms plain = terms;
  plain.weight = 1.0;
  plain.min_cost = 0.0;
  num_fixed = std::max(1, num_fixed);
  const int num_frames = static_cast<int>(T_world_cam.size());
  double cost = AddTrackNormalEquations(plain, T_world_cam, num_fixed, num_fixed, 1.0, nullptr, nullptr);
  if (num_frames <= num_fixed) return cost;
  const int unknowns = 6 * (num_frames - num_fixed);
  double lambda = 1e-4;
  constexpr int kMaxIterations = 20;
  for (int iteration = 0; iteration < kMaxIterations; ++iteration) {
    Eigen::MatrixXd H = Eigen::MatrixXd::Zero(unknowns, unknowns);
    Eigen::VectorXd g = Eigen::VectorXd::Zero(unknowns);
    AddTrackNormalEquations(plain, T_world_cam, num_fixed, num_fixed, 1.0, &H, &g);
    // Damped: the tracks leave the scale (and, without parallax, more) free.
    for (int i = 0; i < unknowns; ++i) H(i, i) += lambda * H(i, i) + 1e-12;
    const Eigen::VectorXd step = H.ldlt().solve(g);
    if (!step.allFinite()) break;
    std::vector<SE3> trial = T_world_cam;
    for (int f = num_fixed; f < num_frames; ++f)
      trial[f] = SE3::Exp(step.segment<6>(6 * (f - num_fixed))) * trial[f];
    const double trial_cost =
        AddTrackNormalEquations(plain, trial, num_fixed, num_fixed, 1.0, nullptr, nullptr);
    if (trial_cost < cost) {
      const bool converged = cost - trial_cost < 1e-6 * cost;
      cost = trial_cost;
      T_world_cam = std::move(trial);
      lambda = std::max(1e-8, 0.3 * lambda);
      if (converged) break;
    } else {
      lambda *= 10.0;
    }
  }
  return cost;
}

namespace {

// The prior's and the tracks' terms (AddPosePriorNormalEquations,
// AddTrackNormalEquations).
void AddPosePriorAndTrackNormalEquations(const PosePriorTerms& prior, const std::vector<SE3>& T_world_cam,
                                         int num_fixed, int offset, double photometric_scale,
                                         Eigen::MatrixXd* hessian, Eigen::VectorXd* gradient) {
  AddPosePriorNormalEquations(prior, T_world_cam, num_fixed, offset, photometric_scale, hessian, gradient);
  if (prior.tracks.any()) {
    AddTrackNormalEquations(prior.tracks, T_world_cam, std::max(num_fixed, 0), offset, photometric_scale,
                            hessian, gradient);
  }
}

// The pose prior's terms in the pose system of UpdatePoses, in units of the
// pairs' mean absolute residual (AddPosePriorNormalEquations); none while no
// pair has a residual.
void AddPosePriorInPairUnits(const PosePriorTerms& prior, const std::vector<PairNormalEquations>& equations,
                             const std::vector<SE3>& T_world_cam, int num_fixed, Eigen::MatrixXd* hessian,
                             Eigen::VectorXd* gradient) {
  double absolute = 0.0, values = 0.0;
  for (const PairNormalEquations& eq : equations) {
    absolute += eq.absolute_residuals;
    values += eq.values;
  }
  if (values > 0.0) {
    AddPosePriorAndTrackNormalEquations(prior, T_world_cam, num_fixed, num_fixed, absolute / values, hessian,
                                        gradient);
  }
}

}  // namespace

std::vector<Vector6d> UpdatePoses(const PinholeCamera& camera_hr, const std::vector<cv::Mat>& inverse_depths,
                                  const std::vector<cv::Mat>& latents, const std::vector<PairMatching>& pairs,
                                  const StructureUpdateOptions& options, std::vector<SE3>* T_world_cam,
                                  int num_fixed, const PosePriorTerms* prior,
                                  const std::vector<BlurPoseTerm>* blur_terms) {
  options.Check();
  const int num_frames = static_cast<int>(T_world_cam->size());
  std::vector<Vector6d> total(num_frames, Vector6d::Zero());
  num_fixed = std::max(1, num_fixed);  // at least frame 0: the gauge
  if (num_frames <= num_fixed || (pairs.empty() && (blur_terms == nullptr || blur_terms->empty()))) return total;
  const int unknowns = 6 * (num_frames - num_fixed);
  // Gradients of every image that HR pairs warp, once per image.
  std::vector<const cv::Mat*> sources;
  for (const PairMatching& pair : pairs) {
    const cv::Mat* source = &SourceImage(pair, latents);
    if (pair.blur == nullptr && std::find(sources.begin(), sources.end(), source) == sources.end()) {
      sources.push_back(source);
    }
  }
  std::vector<cv::Mat> source_gx(sources.size()), source_gy(sources.size());
#pragma omp parallel for schedule(dynamic, 1)
  for (int i = 0; i < static_cast<int>(sources.size()); ++i)
    Gradients(*sources[i], &source_gx[i], &source_gy[i]);
  const std::vector<std::vector<int>> groups = GroupPairsByWarp(pairs);
  const int num_groups = static_cast<int>(groups.size());
  std::vector<PairNormalEquations> equations(num_groups);
  // Groups between two fixed frames enter only fixed rows (AssemblePoseSystem
  // leaves them out); a pose prior still reads their residuals.
  const bool skip_fixed_pairs = options.skip_held_pose_work && !(prior != nullptr && prior->any());
  for (int iteration = 0; iteration < options.pose_iterations; ++iteration) {
    // Per group (in parallel): r(eps) = r0 - A (eps_t - eps_s), A^T W A and A^T W r0.
#pragma omp parallel for schedule(dynamic, 1)
    for (int g = 0; g < num_groups; ++g) {
      const PairMatching& pair = pairs[groups[g].front()];
      if (skip_fixed_pairs && pair.t < num_fixed && pair.s < num_fixed) continue;
      const SE3& T_world_t = (*T_world_cam)[pair.t];
      const SE3& T_world_s = (*T_world_cam)[pair.s];
      if (pair.blur != nullptr) {
        equations[g] = BlurredPairNormalEquations(camera_hr, inverse_depths[pair.t], T_world_t, T_world_s,
                                                  SourceImage(pair, latents), pair, options.residual_epsilon);
        continue;
      }
      std::vector<HrPairImages> images;
      for (int p : groups[g]) {
        const cv::Mat& source = SourceImage(pairs[p], latents);
        const size_t i = std::find(sources.begin(), sources.end(), &source) - sources.begin();
        images.push_back({&source, &source_gx[i], &source_gy[i], pairs[p].observation});
      }
      equations[g] = HrPairNormalEquations(camera_hr, inverse_depths[pair.t], T_world_t, T_world_s, images,
                                           pair.mask, options.residual_epsilon, options.pose_pixel_stride);
    }
    Eigen::MatrixXd hessian;
    Eigen::VectorXd gradient;
    AssemblePoseSystem(pairs, groups, equations, num_fixed, unknowns, &hessian, &gradient);
    if (blur_terms != nullptr) AddBlurPoseTerms(*blur_terms, total, num_fixed, &hessian, &gradient);
    // Levenberg-Marquardt damping on the diagonal.
    Eigen::MatrixXd damped = hessian;
    for (int i = 0; i < unknowns; ++i) {
      damped(i, i) += options.pose_damping * hessian(i, i) + 1e-12;
    }
    if (prior != nullptr && prior->any_term()) {
      AddPosePriorInPairUnits(*prior, equations, *T_world_cam, num_fixed, &damped, &gradient);
    }
    const Eigen::VectorXd step = damped.ldlt().solve(gradient);
    if (!step.allFinite()) break;
    for (int f = num_fixed; f < num_frames; ++f) {
      const Vector6d eps = step.segment<6>(6 * (f - num_fixed));
      (*T_world_cam)[f] = SE3::Exp(eps) * (*T_world_cam)[f];
      total[f] += eps;
    }
  }
  return total;
}

// ---- The joint depth + pose step (eq:taylorExpansion, eq:updateVariables
// with every frame's inverse depth and the free poses as one unknown).
//
// Unknowns are laid out in one float vector for the CG: the inverse-depth
// increments of frame 0, 1, ... (HR images, row-major) and then 6 tangent
// components per frame.
//
// The CG is preconditioned by the Schur complement of the depth diagonal:
// with D_t = diag(N_t) (data, self term, TV stencil and damping of frame t's
// depth system) in place of N_dd,
//   M = [D     N_dp]      M^-1 [r_d] : z_p = S^-1 (r_p - N_pd D^-1 r_d),
//       [N_pd  N_pp],          [r_p]   z_d = D^-1 (r_d - N_dp z_p),
// S = N_pp - N_pd D^-1 N_dp the reduced camera system of the per-pixel
// inverse-depth blocks. The TV couples neighbouring pixels, so M is not N:
// the CG on N itself carries the coupling of the TV (and of the capture
// operators) that the per-pixel elimination leaves out.
class JointDepthPoseSystem::Impl {
 public:
  Impl(const PinholeCamera& camera_hr, const std::vector<SE3>& T_world_cam,
       const std::vector<cv::Mat>& latents, const std::vector<FrameDepthTerms>& frames, double parallax_scale,
       const StructureUpdateOptions& options, int num_fixed, const PosePriorTerms* prior)
      : T_world_cam_(T_world_cam),
        frames_(frames),
        options_(options),
        prior_(prior != nullptr && prior->any_term() ? prior : nullptr),
        num_frames_(static_cast<int>(frames.size())),
        num_fixed_(std::max(1, num_fixed)),
        pixels_(camera_hr.width * camera_hr.height),
        size_(camera_hr.width, camera_hr.height),
        threads_(ResolveThreads(options.num_threads)),
        systems_(frames.size()),
        reference_(frames.size(), 0) {
    if (T_world_cam.size() != frames.size()) {
      throw InputError("joint depth + pose step: one pose and one set of depth terms per frame");
    }
    for (int t = 0; t < num_frames_; ++t) {
      if (frames[t].pairs.empty() && frames[t].self == nullptr) continue;  // D_t stays
      reference_[t] = ReferenceFrame(t);
      systems_[t] = std::make_unique<DepthNormalEquations>(
          camera_hr, T_world_cam, latents, frames[t].pairs, frames[t].self, frames[t].edge_weight, parallax_scale,
          options, reference_[t], options.skip_held_pose_work ? num_fixed_ : 0);
      if (prior_ != nullptr) systems_[t]->MeasureResiduals();
    }
  }

  int num_values() const { return num_frames_ * pixels_ + 6 * num_frames_; }

  void Linearize(const std::vector<cv::Mat>& inverse_depths) {
#pragma omp parallel for schedule(dynamic, 1) num_threads(threads_)
    for (int t = 0; t < num_frames_; ++t) {
      if (!systems_[t]) continue;
      systems_[t]->Linearize(inverse_depths[t]);
      systems_[t]->ReleaseScratch();
    }
    const int n = 6 * num_frames_;
    pose_normal_ = Eigen::MatrixXd::Zero(n, n);
    pose_rhs_ = Eigen::VectorXd::Zero(n);
    for (int t = 0; t < num_frames_; ++t) {
      if (!systems_[t]) continue;
      for (size_t p = 0; p < frames_[t].pairs.size(); ++p) {
        const int s = frames_[t].pairs[p].s;
        const auto& pose = systems_[t]->pose_terms(p);
        // As UpdatePoses assembles them: eps_t with +A, eps_s with -A.
        pose_normal_.block<6, 6>(6 * t, 6 * t) += pose.block;
        pose_normal_.block<6, 6>(6 * s, 6 * s) += pose.block;
        pose_normal_.block<6, 6>(6 * t, 6 * s) -= pose.block;
        pose_normal_.block<6, 6>(6 * s, 6 * t) -= pose.block;
        pose_rhs_.segment<6>(6 * t) += pose.rhs;
        pose_rhs_.segment<6>(6 * s) -= pose.rhs;
      }
    }
    // Levenberg-Marquardt damping relative to the pose block's diagonal.
    for (int i = 0; i < n; ++i) pose_normal_(i, i) += options_.joint_pose_damping * pose_normal_(i, i) + 1e-12;
    if (prior_ != nullptr) AddPrior();
    SetGauge();
    FormReducedCameraSystem();
  }

  void RightHandSide(const std::vector<cv::Mat>& inverse_depths, cv::Mat* flat) {
    flat->create(1, num_values(), CV_32FC1);
    flat->setTo(0.0);
    for (int t = 0; t < num_frames_; ++t) {
      cv::Mat view = DepthView(*flat, t);
      if (systems_[t]) systems_[t]->RightHandSide(inverse_depths[t], &view);
    }
    Eigen::VectorXd poses = pose_rhs_;
    ProjectGauge(&poses);
    SetPoses(poses, flat);
  }

  // out = N in; `in` satisfies the gauge (held poses and the scale
  // component zero), and so does out's pose part.
  void ApplyNormal(const cv::Mat& in, cv::Mat* out) {
    out->create(1, num_values(), CV_32FC1);
    const Eigen::VectorXd in_poses = Poses(in);
    // Frame t's share of N_pd d and its rows of N_dp eps in one pass over
    // its couplings.
    std::vector<Eigen::VectorXd> parts(num_frames_, Eigen::VectorXd::Zero(6 * num_frames_));
#pragma omp parallel for schedule(dynamic, 1) num_threads(threads_)
    for (int t = 0; t < num_frames_; ++t) {
      const cv::Mat in_depth = DepthView(in, t);
      cv::Mat out_depth = DepthView(*out, t);
      if (!systems_[t]) {
        in_depth.copyTo(out_depth);
        continue;
      }
      systems_[t]->ApplyNormal(in_depth, &out_depth);
      CouplingProducts(t, &in_depth, in_poses, 1.0, nullptr, &out_depth, &parts[t]);
    }
    Eigen::VectorXd out_poses = pose_normal_ * in_poses + Sum(parts);
    ProjectGauge(&out_poses);
    SetPoses(out_poses, out);
  }

  // z = M^-1 r (see the class comment).
  void ApplyPreconditioner(const cv::Mat& residual, cv::Mat* z) {
    z->create(1, num_values(), CV_32FC1);
    // z_d = D^-1 r_d first: N_pd D^-1 r_d = N_pd z_d.
#pragma omp parallel for schedule(dynamic, 1) num_threads(threads_)
    for (int t = 0; t < num_frames_; ++t) {
      cv::Mat z_depth = DepthView(*z, t);
      if (systems_[t]) {
        cv::divide(DepthView(residual, t), systems_[t]->diagonal(), z_depth);
      } else {
        DepthView(residual, t).copyTo(z_depth);
      }
    }
    Eigen::VectorXd reduced = Poses(residual) - PosesFromDepths(*z);
    ProjectGauge(&reduced);
    Eigen::VectorXd z_poses = reduced_solver_.solve(reduced);
    ProjectGauge(&z_poses);
    SetPoses(z_poses, z);
#pragma omp parallel for schedule(dynamic, 1) num_threads(threads_)
    for (int t = 0; t < num_frames_; ++t) {
      if (!systems_[t]) continue;
      cv::Mat z_depth = DepthView(*z, t);
      AddDepthsFromPoses(t, z_poses, -1.0, &systems_[t]->diagonal(), &z_depth);
    }
  }

  void ProjectGauge(Eigen::VectorXd* poses) const {
    poses->head(6 * num_fixed_).setZero();
    if (gauge_.size() > 0) *poses -= gauge_ * gauge_.dot(*poses);
  }

  void ApplyStep(const cv::Mat& flat, std::vector<cv::Mat>* inverse_depths, std::vector<SE3>* T_world_cam) {
    for (int t = 0; t < num_frames_; ++t) {
      if (systems_[t]) systems_[t]->ApplyStep(DepthView(flat, t), &(*inverse_depths)[t]);
    }
    const Eigen::VectorXd poses = Poses(flat);
    for (int f = num_fixed_; f < num_frames_; ++f) {
      (*T_world_cam)[f] = SE3::Exp(poses.segment<6>(6 * f)) * (*T_world_cam)[f];
    }
  }

  // The flat vector's parts.
  cv::Mat DepthView(const cv::Mat& flat, int t) const {
    return cv::Mat(size_, CV_32FC1, const_cast<float*>(flat.ptr<float>()) + static_cast<size_t>(t) * pixels_);
  }
  Eigen::VectorXd Poses(const cv::Mat& flat) const {
    const float* p = flat.ptr<float>() + static_cast<size_t>(num_frames_) * pixels_;
    Eigen::VectorXd poses(6 * num_frames_);
    for (int i = 0; i < poses.size(); ++i) poses(i) = p[i];
    return poses;
  }
  void SetPoses(const Eigen::VectorXd& poses, cv::Mat* flat) const {
    float* p = flat->ptr<float>() + static_cast<size_t>(num_frames_) * pixels_;
    for (int i = 0; i < poses.size(); ++i) p[i] = static_cast<float>(poses(i));
  }
  cv::Mat Flatten(const JointStep& step) const {
    cv::Mat flat(1, num_values(), CV_32FC1);
    for (int t = 0; t < num_frames_; ++t) {
      cv::Mat view = DepthView(flat, t);
      step.inverse_depths[t].copyTo(view);
    }
    SetPoses(step.poses, &flat);
    return flat;
  }
  JointStep Unflatten(const cv::Mat& flat) const {
    JointStep step;
    for (int t = 0; t < num_frames_; ++t) step.inverse_depths.push_back(DepthView(flat, t).clone());
    step.poses = Poses(flat);
    return step;
  }
  const StructureUpdateOptions& options() const {
    return options_;
  }
  int threads() const {
    return threads_;
  }

 private:
  using PoseColumn = DepthNormalEquations::PoseColumn;
  // Frame t's columns of N_dp (none for a frame without terms).
  const std::vector<PoseColumn>& Couplings(int t) const {
    static const std::vector<PoseColumn> kNone;
    return systems_[t] ? systems_[t]->couplings() : kNone;
  }

  // A held frame among t and the frames its pairs match, else t.
  int ReferenceFrame(int t) const {
    if (t < num_fixed_) return t;
    for (const PairMatching& pair : frames_[t].pairs) {
      if (pair.s < num_fixed_) return pair.s;
    }
    return t;
  }

  // N_pd d for the depth part of `flat`.
  Eigen::VectorXd PosesFromDepths(const cv::Mat& flat) const {
    std::vector<Eigen::VectorXd> parts(num_frames_, Eigen::VectorXd::Zero(6 * num_frames_));
#pragma omp parallel for schedule(dynamic, 1) num_threads(threads_)
    for (int t = 0; t < num_frames_; ++t) {
      const cv::Mat depth = DepthView(flat, t);
      CouplingProducts(t, &depth, Eigen::VectorXd(), 0.0, nullptr, nullptr, &parts[t]);
    }
    return Sum(parts);
  }
  static Eigen::VectorXd Sum(const std::vector<Eigen::VectorXd>& parts) {
    Eigen::VectorXd sum = Eigen::VectorXd::Zero(parts.empty() ? 0 : parts[0].size());
    for (const Eigen::VectorXd& part : parts) sum += part;
    return sum;
  }
  // depth += scale * (N_dp poses) on frame t's rows (divided by `divisor`
  // per pixel if given).
  void AddDepthsFromPoses(int t, const Eigen::VectorXd& poses, double scale, const cv::Mat* divisor,
                          cv::Mat* depth) const {
    CouplingProducts(t, nullptr, poses, scale, divisor, depth, nullptr);
  }
  // One pass over frame t's coupling columns, row by row (a row of the
  // columns stays in cache for both products): with `depth` and `part`,
  // part += N_pd depth (frame t's share: float within a row, double across
  // rows); with `out`, out += scale * (N_dp poses) on t's rows, divided by
  // `divisor` per pixel if given.
  void CouplingProducts(int t, const cv::Mat* depth, const Eigen::VectorXd& poses, double scale,
                        const cv::Mat* divisor, cv::Mat* out, Eigen::VectorXd* part) const {
    const std::vector<PoseColumn>& couplings = Couplings(t);
    const int count = static_cast<int>(couplings.size());
    if (count == 0) return;
    const int reference = reference_[t];
    std::vector<float> factors(6 * count);
    std::vector<Vector6d> products(count, Vector6d::Zero());
    if (out != nullptr) {
      for (int c = 0; c < count; ++c) {
        const int frame = couplings[c].frame;
        for (int j = 0; j < 6; ++j) {
          factors[6 * c + j] = static_cast<float>(scale * (poses(6 * frame + j) - poses(6 * reference + j)));
        }
      }
    }
    const int width = size_.width;
    std::vector<const float*> columns(count);
    std::vector<float> sums(out != nullptr ? width : 0);
    for (int y = 0; y < size_.height; ++y) {
      for (int c = 0; c < count; ++c) columns[c] = couplings[c].images.ptr<float>(y);
      if (depth != nullptr) {
        const Eigen::Map<const Eigen::VectorXf> row_d(depth->ptr<float>(y), width);
        for (int c = 0; c < count; ++c) {
          const Eigen::Map<const Eigen::Matrix<float, 6, Eigen::Dynamic>> rows_a(columns[c], 6, width);
          products[c] += (rows_a * row_d).cast<double>();
        }
      }
      if (out == nullptr) continue;
      CouplingSums(columns, factors, width, sums.data());
      const float* divide = divisor != nullptr ? divisor->ptr<float>(y) : nullptr;
      float* out_row = out->ptr<float>(y);
      for (int x = 0; x < width; ++x) out_row[x] += divide != nullptr ? sums[x] / divide[x] : sums[x];
    }
    if (part == nullptr) return;
    for (int c = 0; c < count; ++c) {
      part->segment<6>(6 * couplings[c].frame) += products[c];
      part->segment<6>(6 * reference) -= products[c];
    }
  }

  // sums[x] = sum_{c, j} factors[6 c + j] columns[c][6 x + j], each pixel's
  // sum from 0 in the order (c, j). Four pixels at a time as 4-lane vectors
  // (a column's 24 values of four pixels regathered into six vectors by j):
  // the pixels' sums are independent, each value gets the same float
  // operations in the same order as one pixel's scalar sum.
  static void CouplingSums(const std::vector<const float*>& columns, const std::vector<float>& factors,
                           int width, float* __restrict sums) {
    using Float4 = float __attribute__((vector_size(16)));
    const int count = static_cast<int>(columns.size());
    int x = 0;
    for (; x + 4 <= width; x += 4) {
      Float4 sum = {0.0f, 0.0f, 0.0f, 0.0f};
      for (int c = 0; c < count; ++c) {
        const float* __restrict p = columns[c] + 6 * x;
        for (int j = 0; j < 6; ++j) {
          const Float4 values = {p[j], p[6 + j], p[12 + j], p[18 + j]};
          sum += factors[6 * c + j] * values;
        }
      }
      std::memcpy(sums + x, &sum, sizeof(sum));
    }
    for (; x < width; ++x) {
      float sum = 0.0f;
      for (int c = 0; c < count; ++c) {
        for (int j = 0; j < 6; ++j) sum += factors[6 * c + j] * columns[c][6 * x + j];
      }
      sums[x] = sum;
    }
  }

  // The pose prior's terms in N_pp and the pose rhs, in units of the pairs'
  // mean absolute residual (AddPosePriorNormalEquations).
  void AddPrior() {
    double absolute = 0.0, values = 0.0;
    for (const auto& system : systems_) {
      if (!system) continue;
      absolute += system->absolute_residuals();
      values += system->residual_values();
    }
    if (values > 0.0) {
      AddPosePriorAndTrackNormalEquations(*prior_, T_world_cam_, num_fixed_, 0, absolute / values,
                                          &pose_normal_, &pose_rhs_);
    }
  }

  // Whether the pose prior has a centre on a free frame: it fixes the scale.
  bool PriorFixesScale() const {
    if (prior_ == nullptr) return false;
    for (int f = num_fixed_; f < num_frames_ && f < static_cast<int>(prior_->centre_world.size()); ++f) {
      if (prior_->centre_world[f]) return true;
    }
    return false;
  }

  // The scale of a window with one held pose: the component of the first
  // free pose's increment that stretches its baseline b = c_f - c_h from the
  // held centre, b . (v + w x c_f) for eps = (v, w) (DLeftPerturbedPointDEps);
  // none when the pose prior fixes the scale.
  void SetGauge() {
    gauge_.resize(0);
    if (num_fixed_ != 1 || num_frames_ < 2 || PriorFixesScale()) return;
    const Eigen::Vector3d held = T_world_cam_[0].translation();
    const Eigen::Vector3d centre = T_world_cam_[1].translation();
    const Eigen::Vector3d baseline = centre - held;
    if (!(baseline.norm() > 1e-9)) return;  // no baseline: no scale to hold
    gauge_ = Eigen::VectorXd::Zero(6 * num_frames_);
    gauge_.segment<3>(6) = baseline;
    gauge_.segment<3>(9) = centre.cross(baseline);
    gauge_.normalize();
  }

  // S = N_pp - N_pd D^-1 N_dp on the gauge's subspace (P S P + (I - P), P
  // the gauge projection), factorised; N_pp alone if S is not positive.
  void FormReducedCameraSystem() {
    const int n = 6 * num_frames_;
    // Frame t's products of its stored columns a, b (in the order a, b), the
    // frames in parallel; summed below frame by frame in order (the sums of
    // one thread).
    std::vector<std::vector<Eigen::Matrix<double, 6, 6>>> products(num_frames_);
#pragma omp parallel for schedule(dynamic, 1) num_threads(threads_)
    for (int t = 0; t < num_frames_; ++t) {
      const std::vector<PoseColumn>& couplings = Couplings(t);
      if (couplings.empty()) continue;
      cv::Mat scaled(size_, CV_32FC(6));
      for (const PoseColumn& a : couplings) {
        const float* diagonal = systems_[t]->diagonal().ptr<float>();
        const float* in = a.images.ptr<float>();
        float* out = scaled.ptr<float>();
        for (int i = 0; i < pixels_; ++i) {
          for (int j = 0; j < 6; ++j) out[6 * i + j] = in[6 * i + j] / diagonal[i];
        }
        for (const PoseColumn& b : couplings) products[t].push_back(CouplingProduct(scaled, b.images));
      }
    }
    Eigen::MatrixXd reduced = pose_normal_;
    for (int t = 0; t < num_frames_; ++t) {
      const int r = reference_[t];
      const std::vector<PoseColumn>& couplings = Couplings(t);
      size_t next = 0;
      for (const PoseColumn& a : couplings) {
        for (const PoseColumn& b : couplings) {
          // The product of the stored columns a, b and, through the
          // reference's column -sum of them, its rows and columns.
          const Eigen::Matrix<double, 6, 6>& product = products[t][next++];
          reduced.block<6, 6>(6 * a.frame, 6 * b.frame) -= product;
          reduced.block<6, 6>(6 * r, 6 * b.frame) += product;
          reduced.block<6, 6>(6 * a.frame, 6 * r) += product;
          reduced.block<6, 6>(6 * r, 6 * r) -= product;
        }
      }
    }
    Eigen::MatrixXd projection = Eigen::MatrixXd::Identity(n, n);
    for (int i = 0; i < n; ++i) ProjectColumn(&projection, i);
    const Eigen::MatrixXd complement = Eigen::MatrixXd::Identity(n, n) - projection;
    reduced_solver_.compute(projection * reduced * projection + complement);
    if (reduced_solver_.info() != Eigen::Success || !reduced_solver_.isPositive()) {
      reduced_solver_.compute(projection * pose_normal_ * projection + complement);
    }
  }
  // sum_i a_i b_i^T over the pixels of two interleaved coupling images
  // (float within a row, double across rows).
  Eigen::Matrix<double, 6, 6> CouplingProduct(const cv::Mat& a, const cv::Mat& b) const {
    Eigen::Matrix<double, 6, 6> sum = Eigen::Matrix<double, 6, 6>::Zero();
    for (int y = 0; y < size_.height; ++y) {
      const Eigen::Map<const Eigen::Matrix<float, 6, Eigen::Dynamic>> rows_a(a.ptr<float>(y), 6, size_.width);
      const Eigen::Map<const Eigen::Matrix<float, 6, Eigen::Dynamic>> rows_b(b.ptr<float>(y), 6, size_.width);
      sum += (rows_a * rows_b.transpose()).cast<double>();
    }
    return sum;
  }
  void ProjectColumn(Eigen::MatrixXd* matrix, int i) const {
    Eigen::VectorXd column = matrix->col(i);
    ProjectGauge(&column);
    matrix->col(i) = column;
  }

  const std::vector<SE3>& T_world_cam_;
  const std::vector<FrameDepthTerms>& frames_;
  const StructureUpdateOptions& options_;
  const PosePriorTerms* prior_;  // nullptr: none
  const int num_frames_, num_fixed_, pixels_;
  const cv::Size size_;
  const int threads_;
  std::vector<std::unique_ptr<DepthNormalEquations>> systems_;  // nullptr: a frame without terms
  std::vector<int> reference_;        // per frame t: the pose column its couplings leave out
  Eigen::MatrixXd pose_normal_;       // N_pp (damped)
  Eigen::VectorXd pose_rhs_, gauge_;  // gauge_: unit, empty if none
  Eigen::LDLT<Eigen::MatrixXd> reduced_solver_;
};

JointDepthPoseSystem::JointDepthPoseSystem(const PinholeCamera& camera_hr,
                                           const std::vector<SE3>& T_world_cam,
                                           const std::vector<cv::Mat>& latents,
                                           const std::vector<FrameDepthTerms>& frames, double parallax_scale,
                                           const StructureUpdateOptions& options, int num_fixed,
                                           const PosePriorTerms* prior)
    : impl_(std::make_unique<Impl>(camera_hr, T_world_cam, latents, frames, parallax_scale, options, num_fixed,
                                   prior)) {}
JointDepthPoseSystem::~JointDepthPoseSystem() = default;

void JointDepthPoseSystem::Linearize(const std::vector<cv::Mat>& inverse_depths) {
  impl_->Linearize(inverse_depths);
}

JointStep JointDepthPoseSystem::RightHandSide(const std::vector<cv::Mat>& inverse_depths) {
  cv::Mat flat;
  impl_->RightHandSide(inverse_depths, &flat);
  return impl_->Unflatten(flat);
}

JointStep JointDepthPoseSystem::ApplyNormal(const JointStep& in) {
  cv::Mat out;
  impl_->ApplyNormal(impl_->Flatten(in), &out);
  return impl_->Unflatten(out);
}

void JointDepthPoseSystem::ProjectGauge(Eigen::VectorXd* poses) const {
  impl_->ProjectGauge(poses);
}

JointStep JointDepthPoseSystem::Solve(const JointStep& rhs) {
  cv::Mat step = cv::Mat::zeros(1, impl_->num_values(), CV_32FC1);
  Impl* impl = impl_.get();
  SolvePcg([impl](const cv::Mat& x, cv::Mat* out) { impl->ApplyNormal(x, out); },
           [impl](const cv::Mat& r, cv::Mat* z) { impl->ApplyPreconditioner(r, z); }, impl_->Flatten(rhs),
           impl_->options().joint_cg_iterations, impl_->options().depth_cg_tolerance, impl_->threads(),
           &step);
  return impl_->Unflatten(step);
}

void JointDepthPoseSystem::ApplyStep(const JointStep& step, std::vector<cv::Mat>* inverse_depths,
                                     std::vector<SE3>* T_world_cam) {
  impl_->ApplyStep(impl_->Flatten(step), inverse_depths, T_world_cam);
}

namespace {

// Box down-sampling by an integer factor (the scaling rule's, for images,
// inverse depths and edge weights).
cv::Mat BoxDownsampled(const cv::Mat& image, int factor) {
  cv::Mat out;
  cv::resize(image, out, cv::Size(image.cols / factor, image.rows / factor), 0.0, 0.0, cv::INTER_AREA);
  return out;
}

// The images of the coarse level: every image a pair points at (observation,
// source) and the latents, box-downsampled once each.
class CoarseImages {
 public:
  CoarseImages(const std::vector<cv::Mat>& latents, int factor) : factor_(factor) {
    for (const cv::Mat& latent : latents) latents_.push_back(BoxDownsampled(latent, factor));
    for (size_t i = 0; i < latents.size(); ++i) images_.emplace(&latents[i], &latents_[i]);
  }
  const std::vector<cv::Mat>& latents() const { return latents_; }
  // The coarse copy of `image` (made on first use; nullptr stays nullptr).
  const cv::Mat* Of(const cv::Mat* image) {
    if (image == nullptr) return nullptr;
    auto found = images_.find(image);
    if (found != images_.end()) return found->second;
    others_.push_back(BoxDownsampled(*image, factor_));
    images_.emplace(image, &others_.back());
    return &others_.back();
  }

 private:
  const int factor_;
  std::vector<cv::Mat> latents_;
  std::list<cv::Mat> others_;  // stable addresses
  std::map<const cv::Mat*, const cv::Mat*> images_;
};

// StructureUpdateOptions::joint_coarse_levels: the joint step on the window
// box-downsampled by `factor`, its inverse-depth increments up-sampled onto
// `inverse_depths` (each value kept above a quarter of itself, as the step
// does). False where the level does not apply (size, blurred pairs, self term).
bool CoarseJointStep(const PinholeCamera& camera_hr, const std::vector<cv::Mat>& latents,
                     const std::vector<FrameDepthTerms>& frames, double parallax_scale,
                     const StructureUpdateOptions& options, int factor, int num_fixed,
                     std::vector<SE3>* T_world_cam, std::vector<cv::Mat>* inverse_depths,
                     const PosePriorTerms* prior) {
  if (camera_hr.width % factor != 0 || camera_hr.height % factor != 0) return false;
  for (const FrameDepthTerms& frame : frames) {
    if (frame.self != nullptr) return false;
    for (const PairMatching& pair : frame.pairs) {
      if (pair.blur != nullptr) return false;
    }
  }
  CoarseImages images(latents, factor);
  std::vector<FrameDepthTerms> coarse(frames.size());
  std::vector<cv::Mat> rho(frames.size()), rho_before(frames.size());
  for (size_t t = 0; t < frames.size(); ++t) {
    for (PairMatching pair : frames[t].pairs) {
      pair.observation = images.Of(pair.observation);
      pair.source = images.Of(pair.source);
      if (!pair.mask.empty()) pair.mask = DownscaleMaskAll(pair.mask, factor);
      coarse[t].pairs.push_back(pair);
    }
    if (!frames[t].edge_weight.empty()) coarse[t].edge_weight = BoxDownsampled(frames[t].edge_weight, factor);
    rho[t] = BoxDownsampled((*inverse_depths)[t], factor);
    rho_before[t] = rho[t].clone();
  }
  StructureUpdateOptions coarse_options = options;
  coarse_options.joint_coarse_levels = 0;
  UpdateDepthAndPoses(camera_hr.Downscaled(factor), images.latents(), coarse, parallax_scale / factor,
                      coarse_options, num_fixed, T_world_cam, &rho, prior);
  for (size_t t = 0; t < frames.size(); ++t) {
    cv::Mat increment;
    cv::resize(rho[t] - rho_before[t], increment, (*inverse_depths)[t].size(), 0.0, 0.0, cv::INTER_LINEAR);
    cv::Mat& fine = (*inverse_depths)[t];
    const cv::Mat floor = fine * 0.25f;
    const cv::Mat moved = fine + increment;
    cv::max(moved, floor, fine);
  }
  return true;
}

}  // namespace

void UpdateDepthAndPoses(const PinholeCamera& camera_hr, const std::vector<cv::Mat>& latents,
                         const std::vector<FrameDepthTerms>& frames, double parallax_scale,
                         const StructureUpdateOptions& options, int num_fixed, std::vector<SE3>* T_world_cam,
                         std::vector<cv::Mat>* inverse_depths, const PosePriorTerms* prior) {
  options.Check();
  // The coarse levels move the poses along the bas-relief trade faster
  // (StructureUpdateOptions::joint_coarse_levels); a pose prior holds them
  // there itself, and the levels' depth increments then only shift the depth
  // in metres: skipped.
  const int coarse_levels = (prior != nullptr && prior->any()) ? 0 : options.joint_coarse_levels;
  for (int level = coarse_levels; level >= 1; --level) {
    CoarseJointStep(camera_hr, latents, frames, parallax_scale, options, 1 << level, num_fixed, T_world_cam,
                    inverse_depths, prior);
  }
  JointDepthPoseSystem system(camera_hr, *T_world_cam, latents, frames, parallax_scale, options, num_fixed,
                              prior);
  for (int irls = 0; irls < options.joint_irls_iterations; ++irls) {
    system.Linearize(*inverse_depths);
    const JointStep step = system.Solve(system.RightHandSide(*inverse_depths));
    if (!step.poses.allFinite()) break;
    system.ApplyStep(step, inverse_depths, T_world_cam);
  }
}

}  // namespace deblur_sr_mvs
