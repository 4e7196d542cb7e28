#include "deblur_sr_mvs/core/geometry/se3.h"

#include <algorithm>
#include <cmath>

#include <Eigen/SVD>

namespace deblur_sr_mvs {
namespace {

// Below this angle the closed forms lose precision; Taylor series are used.
constexpr double kSmallAngle = 1e-5;

Eigen::Matrix3d Orthonormalized(const Eigen::Matrix3d& rotation) {
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(rotation, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d result = svd.matrixU() * svd.matrixV().transpose();
  if (result.determinant() < 0.0) {
    Eigen::Matrix3d u = svd.matrixU();
    u.col(2) *= -1.0;
    result = u * svd.matrixV().transpose();
  }
  return result;
}

// Q(rho, phi) of Barfoot's SE(3) left Jacobian (State Estimation for Robotics,
// eq. 7.86): J_l(xi) = [[J_l(phi), Q], [0, J_l(phi)]].
Eigen::Matrix3d SE3JacobianQ(const Eigen::Vector3d& rho, const Eigen::Vector3d& phi) {
  const double theta = phi.norm();
  const Eigen::Matrix3d rho_x = Hat(rho);
  const Eigen::Matrix3d phi_x = Hat(phi);
  double c1, c2, c3;
  if (theta < 0.1) {
    // Series of the coefficients below around theta = 0: the closed forms
    // cancel catastrophically for small angles (c3 ~ theta^5 / theta^5).
    const double t2 = theta * theta;
    const double t4 = t2 * t2;
    c1 = 1.0 / 6.0 - t2 / 120.0 + t4 / 5040.0;
    c2 = 1.0 / 24.0 - t2 / 720.0 + t4 / 40320.0;
    c3 = 1.0 / 120.0 - t2 / 2520.0 + t4 / 120960.0;
  } else {
    const double t2 = theta * theta;
    const double t3 = t2 * theta;
    const double t4 = t2 * t2;
    const double t5 = t4 * theta;
    const double s = std::sin(theta);
    const double c = std::cos(theta);
    c1 = (theta - s) / t3;
    c2 = (t2 + 2.0 * c - 2.0) / (2.0 * t4);
    c3 = (2.0 * theta - 3.0 * s + theta * c) / (2.0 * t5);
  }
  const Eigen::Matrix3d a = phi_x * rho_x + rho_x * phi_x + phi_x * rho_x * phi_x;
  const Eigen::Matrix3d b = phi_x * phi_x * rho_x + rho_x * phi_x * phi_x - 3.0 * phi_x * rho_x * phi_x;
  const Eigen::Matrix3d d = phi_x * rho_x * phi_x * phi_x + phi_x * phi_x * rho_x * phi_x;
  return 0.5 * rho_x + c1 * a + c2 * b + c3 * d;
}

}  // namespace

Eigen::Matrix3d Hat(const Eigen::Vector3d& v) {
  Eigen::Matrix3d m;
  m << 0.0, -v.z(), v.y(), v.z(), 0.0, -v.x(), -v.y(), v.x(), 0.0;
  return m;
}

Eigen::Matrix3d SO3Exp(const Eigen::Vector3d& phi) {
  const double theta = phi.norm();
  const Eigen::Matrix3d phi_x = Hat(phi);
  if (theta < kSmallAngle) {
    return Eigen::Matrix3d::Identity() + phi_x + 0.5 * phi_x * phi_x;
  }
  const double a = std::sin(theta) / theta;
  const double b = (1.0 - std::cos(theta)) / (theta * theta);
  return Eigen::Matrix3d::Identity() + a * phi_x + b * phi_x * phi_x;
}

Eigen::Vector3d SO3Log(const Eigen::Matrix3d& rotation) {
  // The quaternion route is accurate near 0 and near pi alike.
  Eigen::Quaterniond q(rotation);
  q.normalize();
  if (q.w() < 0.0) q.coeffs() *= -1.0;  // angle in [0, pi]
  const Eigen::Vector3d v = q.vec();
  const double sin_half = v.norm();
  if (sin_half < kSmallAngle) {
    // theta ~= 2 sin(theta/2); second-order correction for accuracy.
    return (2.0 / q.w()) * (1.0 - sin_half * sin_half / (3.0 * q.w() * q.w())) * v;
  }
  const double theta = 2.0 * std::atan2(sin_half, q.w());
  return (theta / sin_half) * v;
}

Eigen::Matrix3d SO3LeftJacobian(const Eigen::Vector3d& phi) {
  const double theta = phi.norm();
  const Eigen::Matrix3d phi_x = Hat(phi);
  if (theta < kSmallAngle) {
    return Eigen::Matrix3d::Identity() + 0.5 * phi_x + phi_x * phi_x / 6.0;
  }
  const double t2 = theta * theta;
  return Eigen::Matrix3d::Identity() + ((1.0 - std::cos(theta)) / t2) * phi_x +
         ((theta - std::sin(theta)) / (t2 * theta)) * phi_x * phi_x;
}

Eigen::Matrix3d SO3LeftJacobianInverse(const Eigen::Vector3d& phi) {
  const double theta = phi.norm();
  const Eigen::Matrix3d phi_x = Hat(phi);
  if (theta < kSmallAngle) {
    return Eigen::Matrix3d::Identity() - 0.5 * phi_x + phi_x * phi_x / 12.0;
  }
  const double half = 0.5 * theta;
  const double coefficient = (1.0 - half * std::cos(half) / std::sin(half)) / (theta * theta);
  return Eigen::Matrix3d::Identity() - 0.5 * phi_x + coefficient * phi_x * phi_x;
}

SE3::SE3(const Eigen::Matrix3d& rotation, const Eigen::Vector3d& translation)
    : rotation_(Orthonormalized(rotation)), translation_(translation) {}

SE3::SE3(const Eigen::Quaterniond& rotation, const Eigen::Vector3d& translation)
    : rotation_(rotation.normalized().toRotationMatrix()), translation_(translation) {}

SE3 SE3::Exp(const Vector6d& xi) {
  const Eigen::Vector3d rho = xi.head<3>();
  const Eigen::Vector3d phi = xi.tail<3>();
  SE3 result;
  result.rotation_ = SO3Exp(phi);
  result.translation_ = SO3LeftJacobian(phi) * rho;
  return result;
}

Vector6d SE3::Log() const {
  const Eigen::Vector3d phi = SO3Log(rotation_);
  Vector6d xi;
  xi.head<3>() = SO3LeftJacobianInverse(phi) * translation_;
  xi.tail<3>() = phi;
  return xi;
}

SE3 SE3::Inverse() const {
  SE3 result;
  result.rotation_ = rotation_.transpose();
  result.translation_ = -(result.rotation_ * translation_);
  return result;
}

SE3 SE3::operator*(const SE3& other) const {
  SE3 result;
  result.rotation_ = rotation_ * other.rotation_;
  result.translation_ = rotation_ * other.translation_ + translation_;
  return result;
}

Matrix6d SE3::Adjoint() const {
  Matrix6d adjoint = Matrix6d::Zero();
  adjoint.topLeftCorner<3, 3>() = rotation_;
  adjoint.topRightCorner<3, 3>() = Hat(translation_) * rotation_;
  adjoint.bottomRightCorner<3, 3>() = rotation_;
  return adjoint;
}

Eigen::Matrix4d SE3::Matrix() const {
  Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
  m.topLeftCorner<3, 3>() = rotation_;
  m.topRightCorner<3, 1>() = translation_;
  return m;
}

Matrix6d SE3LeftJacobian(const Vector6d& xi) {
  const Eigen::Vector3d rho = xi.head<3>();
  const Eigen::Vector3d phi = xi.tail<3>();
  Matrix6d jacobian = Matrix6d::Zero();
  const Eigen::Matrix3d j_phi = SO3LeftJacobian(phi);
  jacobian.topLeftCorner<3, 3>() = j_phi;
  jacobian.bottomRightCorner<3, 3>() = j_phi;
  jacobian.topRightCorner<3, 3>() = SE3JacobianQ(rho, phi);
  return jacobian;
}

Matrix6d SE3LeftJacobianInverse(const Vector6d& xi) {
  const Eigen::Vector3d rho = xi.head<3>();
  const Eigen::Vector3d phi = xi.tail<3>();
  const Eigen::Matrix3d j_inv = SO3LeftJacobianInverse(phi);
  Matrix6d inverse = Matrix6d::Zero();
  inverse.topLeftCorner<3, 3>() = j_inv;
  inverse.bottomRightCorner<3, 3>() = j_inv;
  inverse.topRightCorner<3, 3>() = -j_inv * SE3JacobianQ(rho, phi) * j_inv;
  return inverse;
}

SE3 InterpolatePose(const SE3& T_world_s, const SE3& T_world_t, double alpha) {
  const Vector6d delta = (T_world_t * T_world_s.Inverse()).Log();
  return SE3::Exp(alpha * delta) * T_world_s;
}

SE3 PoseAtTime(const SE3& T_world_s, double s, const SE3& T_world_t, double t, double tau) {
  return InterpolatePose(T_world_s, T_world_t, (tau - s) / (t - s));
}

SE3 PoseOnQuadraticPath(const SE3& T_world_a, double a, const SE3& T_world_b, double b, const SE3& T_world_t,
                        double t, double tau) {
  return PoseOnPolynomialPath({{T_world_a, a}, {T_world_b, b}}, T_world_t, t, tau);
}

SE3 PoseOnPolynomialPath(const std::vector<TimedPose>& nodes, const SE3& T_world_t, double t, double tau) {
  const SE3 T_t_world = T_world_t.Inverse();
  Vector6d xi = Vector6d::Zero();
  for (size_t k = 0; k < nodes.size(); ++k) {
    // L_k(tau) = prod over the other nodes j (and t) of (tau - t_j) / (t_k - t_j).
    const double t_k = nodes[k].stamp;
    double weight = (tau - t) / (t_k - t);
    for (size_t j = 0; j < nodes.size(); ++j) {
      if (j != k) weight *= (tau - nodes[j].stamp) / (t_k - nodes[j].stamp);
    }
    xi += weight * (nodes[k].T_world_cam * T_t_world).Log();
  }
  return SE3::Exp(xi) * T_world_t;
}

Eigen::Matrix<double, 3, 6> DLeftPerturbedPointDEps(const Eigen::Vector3d& transformed_point) {
  Eigen::Matrix<double, 3, 6> jacobian;
  jacobian.leftCols<3>().setIdentity();
  jacobian.rightCols<3>() = -Hat(transformed_point);
  return jacobian;
}

bool TriangulateRays(const std::vector<Eigen::Vector3d>& rays, const std::vector<SE3>& T_cam_world,
                     Eigen::Vector3d* point_world) {
  const int count = static_cast<int>(std::min(rays.size(), T_cam_world.size()));
  if (count < 2) return false;
  Eigen::MatrixXd A(2 * count, 4);
  for (int k = 0; k < count; ++k) {
    Eigen::Matrix<double, 3, 4> P;
    P.leftCols<3>() = T_cam_world[k].rotation();
    P.col(3) = T_cam_world[k].translation();
    A.row(2 * k) = rays[k].x() * P.row(2) - P.row(0);
    A.row(2 * k + 1) = rays[k].y() * P.row(2) - P.row(1);
  }
  Eigen::JacobiSVD<Eigen::MatrixXd> svd(A, Eigen::ComputeFullV);
  const Eigen::Vector4d homogeneous = svd.matrixV().col(3);
  if (std::abs(homogeneous[3]) < 1e-12) return false;
  *point_world = homogeneous.head<3>() / homogeneous[3];
  return point_world->allFinite();
}

}  // namespace deblur_sr_mvs
