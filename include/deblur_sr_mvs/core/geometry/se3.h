// A small SE(3)/SO(3) Lie-group library (Sophus is not packaged in Debian).
//
// Frames are explicit in names: T_a_b maps coordinates in frame b into frame a,
// so T_world_cam is the camera pose (camera -> world), the paper's P_t.
// Tangent vectors are ordered xi = (rho, phi): translation part first, then
// rotation, and Exp(xi) = [[Exp_SO3(phi), J_l(phi) rho], [0, 1]].
#pragma once

#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace deblur_sr_mvs {

using Vector6d = Eigen::Matrix<double, 6, 1>;
using Matrix6d = Eigen::Matrix<double, 6, 6>;

// Skew-symmetric matrix: Hat(a) * b = a x b.
Eigen::Matrix3d Hat(const Eigen::Vector3d& v);

Eigen::Matrix3d SO3Exp(const Eigen::Vector3d& phi);
// Rotation vector with angle in [0, pi].
Eigen::Vector3d SO3Log(const Eigen::Matrix3d& rotation);
// Left Jacobian of SO(3): Exp(phi + d) ~= Exp(J_l(phi) d) Exp(phi).
Eigen::Matrix3d SO3LeftJacobian(const Eigen::Vector3d& phi);
Eigen::Matrix3d SO3LeftJacobianInverse(const Eigen::Vector3d& phi);

class SE3 {
 public:
  SE3() : rotation_(Eigen::Matrix3d::Identity()), translation_(Eigen::Vector3d::Zero()) {}
  // `rotation` must be orthonormal with determinant +1 (re-orthonormalised).
  SE3(const Eigen::Matrix3d& rotation, const Eigen::Vector3d& translation);
  SE3(const Eigen::Quaterniond& rotation, const Eigen::Vector3d& translation);

  static SE3 Exp(const Vector6d& xi);
  Vector6d Log() const;

  SE3 Inverse() const;
  SE3 operator*(const SE3& other) const;
  Eigen::Vector3d operator*(const Eigen::Vector3d& point) const { return rotation_ * point + translation_; }
  // Adjoint: T Exp(xi) T^-1 = Exp(Adj(T) xi).
  Matrix6d Adjoint() const;

  const Eigen::Matrix3d& rotation() const { return rotation_; }
  const Eigen::Vector3d& translation() const { return translation_; }
  Eigen::Quaterniond quaternion() const { return Eigen::Quaterniond(rotation_); }
  Eigen::Matrix4d Matrix() const;

 private:
  Eigen::Matrix3d rotation_;
  Eigen::Vector3d translation_;
};

// Left Jacobian of SE(3): Exp(xi + d) ~= Exp(J_l(xi) d) Exp(xi).
Matrix6d SE3LeftJacobian(const Vector6d& xi);
Matrix6d SE3LeftJacobianInverse(const Vector6d& xi);

// Pose on the geodesic from T_world_s (alpha = 0) to T_world_t (alpha = 1),
// eq:interpolatingP: P_tau = exp(alpha log(P_t P_s^-1)) P_s, with
// alpha = (tau - s) / (t - s). alpha outside [0, 1] extrapolates.
SE3 InterpolatePose(const SE3& T_world_s, const SE3& T_world_t, double alpha);
// The same at time `tau` for poses at times s and t (s != t).
SE3 PoseAtTime(const SE3& T_world_s, double s, const SE3& T_world_t, double t, double tau);
// The curved path through three poses at distinct times a, b and t: the
// quadratic in se(3), relative to P_t, through their twists,
//   P_tau = exp(xi(tau)) P_t,  xi(tau) = L_a(tau) log(P_a P_t^-1) + L_b(tau) log(P_b P_t^-1),
// with L_a, L_b the Lagrange weights of a and b on the nodes {a, b, t}. It
// passes through the three poses at their times, and on a constant-velocity
// path (P_tau = exp((tau - t) w) P_t, rotation below pi between the poses)
// it is that path: eq:interpolatingP's geodesic, PoseAtTime above.
SE3 PoseOnQuadraticPath(const SE3& T_world_a, double a, const SE3& T_world_b, double b, const SE3& T_world_t,
                        double t, double tau);
// One node of a polynomial path: a pose and its time.
struct TimedPose {
  SE3 T_world_cam;
  double stamp = 0.0;
};
// The polynomial path in se(3), relative to P_t, through P_t at t and every
// node at its time (times distinct):
//   P_tau = exp(xi(tau)) P_t,  xi(tau) = sum_k L_k(tau) log(P_k P_t^-1),
// L_k the Lagrange weight of node k on the nodes and t. One node: the
// geodesic of eq:interpolatingP; two: PoseOnQuadraticPath; three: the cubic,
// which follows a camera whose acceleration changes. On a constant-velocity
// path it is that path for any number of nodes.
SE3 PoseOnPolynomialPath(const std::vector<TimedPose>& nodes, const SE3& T_world_t, double t, double tau);

// Derivative of (Exp(eps) T) * p with respect to eps at eps = 0, for the
// transformed point q = T p: [I, -Hat(q)] (3x6). Used by the structure update
// (eq:updateVariables), where P = exp(eps) P0.
Eigen::Matrix<double, 3, 6> DLeftPerturbedPointDEps(const Eigen::Vector3d& transformed_point);

// Linear (DLT) triangulation of the world point that ray k (camera frame,
// z = 1) sees from camera T_cam_world[k]. False with fewer than 2 rays, a
// point at infinity or a result that is not finite.
bool TriangulateRays(const std::vector<Eigen::Vector3d>& rays, const std::vector<SE3>& T_cam_world,
                     Eigen::Vector3d* point_world);

}  // namespace deblur_sr_mvs
