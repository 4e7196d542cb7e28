// Property tests of the SE(3)/SO(3) library: round trips, group laws and
// Jacobians against central differences.
#include "deblur_sr_mvs/core/geometry/se3.h"

#include <random>
#include <vector>

#include <gtest/gtest.h>

namespace deblur_sr_mvs {
namespace {

Vector6d RandomTangent(std::mt19937* rng, double rotation_scale, double translation_scale) {
  std::normal_distribution<double> normal(0.0, 1.0);
  Vector6d xi;
  for (int i = 0; i < 3; ++i) xi(i) = translation_scale * normal(*rng);
  for (int i = 3; i < 6; ++i) xi(i) = rotation_scale * normal(*rng);
  return xi;
}

double MaxAbs(const Eigen::MatrixXd& m) {
  return m.cwiseAbs().maxCoeff();
}

TEST(SE3, ExpLogRoundTripAtManyScales) {
  std::mt19937 rng(1);
  for (double rotation_scale : {0.0, 1e-9, 1e-6, 1e-3, 0.05, 0.3, 1.0}) {
    for (int trial = 0; trial < 50; ++trial) {
      Vector6d xi = RandomTangent(&rng, rotation_scale, 0.7);
      if (xi.tail<3>().norm() > 3.0) continue;  // keep the angle below pi
      const Vector6d back = SE3::Exp(xi).Log();
      EXPECT_LT((back - xi).norm(), 1e-10 * (1.0 + xi.norm()))
          << "scale " << rotation_scale << " xi " << xi.transpose();
    }
  }
}

TEST(SE3, LogExpRoundTripOfGroupElements) {
  std::mt19937 rng(2);
  for (int trial = 0; trial < 100; ++trial) {
    const SE3 pose = SE3::Exp(RandomTangent(&rng, 0.8, 2.0));
    const SE3 back = SE3::Exp(pose.Log());
    EXPECT_LT(MaxAbs(back.Matrix() - pose.Matrix()), 1e-12);
  }
}

TEST(SE3, RotationNearPiRoundTrips) {
  const Eigen::Vector3d axis = Eigen::Vector3d(1, 2, -0.5).normalized();
  for (double angle : {M_PI - 1e-3, M_PI - 1e-7}) {
    const Eigen::Matrix3d r = SO3Exp(angle * axis);
    EXPECT_LT(MaxAbs(SO3Exp(SO3Log(r)) - r), 1e-9);
  }
}

TEST(SE3, InverseAndComposition) {
  std::mt19937 rng(3);
  const SE3 a = SE3::Exp(RandomTangent(&rng, 0.5, 1.0));
  const SE3 b = SE3::Exp(RandomTangent(&rng, 0.5, 1.0));
  EXPECT_LT(MaxAbs((a * a.Inverse()).Matrix() - Eigen::Matrix4d::Identity()), 1e-14);
  EXPECT_LT(MaxAbs((a * b).Matrix() - a.Matrix() * b.Matrix()), 1e-14);
  const Eigen::Vector3d p(0.3, -1.0, 2.0);
  EXPECT_LT(((a * b) * p - a * (b * p)).norm(), 1e-14);
}

TEST(SE3, AdjointConjugatesExp) {
  std::mt19937 rng(4);
  const SE3 t = SE3::Exp(RandomTangent(&rng, 0.6, 1.5));
  const Vector6d xi = RandomTangent(&rng, 0.2, 0.3);
  const SE3 lhs = t * SE3::Exp(xi) * t.Inverse();
  const SE3 rhs = SE3::Exp(t.Adjoint() * xi);
  EXPECT_LT(MaxAbs(lhs.Matrix() - rhs.Matrix()), 1e-12);
}

// Exp(xi + d) ~= Exp(J_l(xi) d) Exp(xi): compare J_l against the numeric
// derivative of Log(Exp(xi + h e_i) Exp(xi)^-1) / h.
TEST(SE3, LeftJacobianMatchesNumeric) {
  std::mt19937 rng(5);
  for (double rotation_scale : {1e-8, 0.01, 0.05, 0.09, 0.2, 1.0}) {
    const Vector6d xi = RandomTangent(&rng, rotation_scale, 0.8);
    Matrix6d numeric;
    const double h = 1e-6;
    for (int i = 0; i < 6; ++i) {
      Vector6d step = Vector6d::Zero();
      step(i) = h;
      const Vector6d plus = (SE3::Exp(xi + step) * SE3::Exp(xi).Inverse()).Log();
      const Vector6d minus = (SE3::Exp(xi - step) * SE3::Exp(xi).Inverse()).Log();
      numeric.col(i) = (plus - minus) / (2.0 * h);
    }
    EXPECT_LT(MaxAbs(SE3LeftJacobian(xi) - numeric), 1e-8) << "rotation scale " << rotation_scale;
    EXPECT_LT(MaxAbs(SE3LeftJacobianInverse(xi) * SE3LeftJacobian(xi) - Matrix6d::Identity()), 1e-10);
  }
}

TEST(SO3, LeftJacobianMatchesNumeric) {
  std::mt19937 rng(6);
  std::normal_distribution<double> normal(0.0, 0.7);
  for (int trial = 0; trial < 20; ++trial) {
    const Eigen::Vector3d phi(normal(rng), normal(rng), normal(rng));
    Eigen::Matrix3d numeric;
    const double h = 1e-6;
    for (int i = 0; i < 3; ++i) {
      const Eigen::Vector3d step = h * Eigen::Vector3d::Unit(i);
      numeric.col(i) = (SO3Log(SO3Exp(phi + step) * SO3Exp(phi).transpose()) -
                        SO3Log(SO3Exp(phi - step) * SO3Exp(phi).transpose())) /
                       (2.0 * h);
    }
    EXPECT_LT(MaxAbs(SO3LeftJacobian(phi) - numeric), 1e-8);
    EXPECT_LT(MaxAbs(SO3LeftJacobianInverse(phi) * SO3LeftJacobian(phi) - Eigen::Matrix3d::Identity()),
              1e-12);
  }
}

TEST(SE3, PointJacobianMatchesNumeric) {
  std::mt19937 rng(7);
  const SE3 pose = SE3::Exp(RandomTangent(&rng, 0.5, 1.0));
  const Eigen::Vector3d p(0.4, -0.2, 3.0);
  Eigen::Matrix<double, 3, 6> numeric;
  const double h = 1e-6;
  for (int i = 0; i < 6; ++i) {
    Vector6d step = Vector6d::Zero();
    step(i) = h;
    numeric.col(i) = ((SE3::Exp(step) * pose) * p - (SE3::Exp(-step) * pose) * p) / (2.0 * h);
  }
  EXPECT_LT(MaxAbs(DLeftPerturbedPointDEps(pose * p) - numeric), 1e-8);
}

TEST(SE3, InterpolationEndPointsAndMidpoint) {
  std::mt19937 rng(8);
  const SE3 T_world_s = SE3::Exp(RandomTangent(&rng, 0.4, 1.0));
  const SE3 T_world_t = SE3::Exp(RandomTangent(&rng, 0.4, 1.0));
  EXPECT_LT(MaxAbs(InterpolatePose(T_world_s, T_world_t, 0.0).Matrix() - T_world_s.Matrix()), 1e-12);
  EXPECT_LT(MaxAbs(InterpolatePose(T_world_s, T_world_t, 1.0).Matrix() - T_world_t.Matrix()), 1e-12);
  // Two half steps compose to the whole step (constant velocity on the geodesic).
  const SE3 half = InterpolatePose(T_world_s, T_world_t, 0.5);
  const SE3 step = half * T_world_s.Inverse();
  EXPECT_LT(MaxAbs((step * step * T_world_s).Matrix() - T_world_t.Matrix()), 1e-12);
  // Extrapolation backwards continues the same motion.
  const SE3 before = InterpolatePose(T_world_s, T_world_t, -1.0);
  EXPECT_LT(MaxAbs((step * step * before).Matrix() - T_world_s.Matrix()), 1e-12);
}

// The curved blur path: through its three poses at their times, in any
// order of the times (before, between or after t).
TEST(SE3, QuadraticPathPassesThroughItsPoses) {
  std::mt19937 rng(9);
  for (int trial = 0; trial < 20; ++trial) {
    const SE3 T_world_a = SE3::Exp(RandomTangent(&rng, 0.3, 0.5));
    const SE3 T_world_b = SE3::Exp(RandomTangent(&rng, 0.3, 0.5));
    const SE3 T_world_t = SE3::Exp(RandomTangent(&rng, 0.3, 0.5));
    const double t = 1.0;
    for (const auto& [a, b] : {std::pair{0.9, 1.1}, std::pair{1.1, 1.2}, std::pair{0.8, 0.9}}) {
      EXPECT_LT(MaxAbs(PoseOnQuadraticPath(T_world_a, a, T_world_b, b, T_world_t, t, a).Matrix() -
                       T_world_a.Matrix()),
                1e-12);
      EXPECT_LT(MaxAbs(PoseOnQuadraticPath(T_world_a, a, T_world_b, b, T_world_t, t, b).Matrix() -
                       T_world_b.Matrix()),
                1e-12);
      EXPECT_LT(MaxAbs(PoseOnQuadraticPath(T_world_a, a, T_world_b, b, T_world_t, t, t).Matrix() -
                       T_world_t.Matrix()),
                1e-12);
    }
  }
}

// On a constant-velocity path P_tau = Exp((tau - t) w) P_t the curve is that
// path, eq:interpolatingP's geodesic, inside and outside its nodes.
TEST(SE3, QuadraticPathIsTheGeodesicAtConstantVelocity) {
  std::mt19937 rng(10);
  for (int trial = 0; trial < 20; ++trial) {
    const Vector6d twist = RandomTangent(&rng, 2.0, 3.0);  // per second; 0.1 s apart: small angles
    const SE3 T_world_t = SE3::Exp(RandomTangent(&rng, 0.5, 1.0));
    const double t = 2.0, a = 1.9, b = 2.1;
    auto path = [&](double tau) { return SE3::Exp((tau - t) * twist) * T_world_t; };
    for (double tau : {1.75, 1.9, 1.97, 2.0, 2.05, 2.18}) {
      const SE3 curved = PoseOnQuadraticPath(path(a), a, path(b), b, T_world_t, t, tau);
      EXPECT_LT(MaxAbs(curved.Matrix() - path(tau).Matrix()), 1e-12) << tau;
      EXPECT_LT(MaxAbs(curved.Matrix() - PoseAtTime(path(a), a, T_world_t, t, tau).Matrix()), 1e-12) << tau;
    }
  }
}

// An accelerating path: the curve through three samples follows it to second
// order, the geodesic through two of them only to first order.
TEST(SE3, QuadraticPathFollowsAnAcceleratingPath) {
  const Vector6d velocity = (Vector6d() << 1.0, 0.2, 0.0, 0.1, 0.3, 0.0).finished();
  const Vector6d acceleration = (Vector6d() << 0.0, 4.0, 1.0, 0.0, 0.0, 2.0).finished();
  auto path = [&](double tau) { return SE3::Exp(tau * velocity + 0.5 * tau * tau * acceleration); };
  const double h = 0.05;
  const double tau = -1.5 * h;  // an opening before the first node, as for frame 0
  const SE3 curved = PoseOnQuadraticPath(path(h), h, path(2 * h), 2 * h, path(0.0), 0.0, tau);
  const SE3 straight = PoseAtTime(path(h), h, path(0.0), 0.0, tau);
  const double curved_error = MaxAbs(curved.Matrix() - path(tau).Matrix());
  const double straight_error = MaxAbs(straight.Matrix() - path(tau).Matrix());
  EXPECT_LT(curved_error, 0.05 * straight_error) << curved_error << " " << straight_error;
}

// The cubic through four poses: through each at its time, and exact on a
// path whose twist relative to P_t is cubic in time (a changing
// acceleration), where the quadratic through three of them is not.
TEST(SE3, CubicPathFollowsAChangingAcceleration) {
  const Vector6d velocity = (Vector6d() << 1.0, 0.2, 0.0, 0.1, 0.3, 0.0).finished();
  const Vector6d acceleration = (Vector6d() << 0.0, 4.0, 1.0, 0.0, 0.0, 2.0).finished();
  const Vector6d jerk = (Vector6d() << 30.0, 0.0, -20.0, 10.0, 0.0, 5.0).finished();
  auto path = [&](double tau) {
    return SE3::Exp(tau * velocity + 0.5 * tau * tau * acceleration + tau * tau * tau / 6.0 * jerk);
  };
  const double h = 0.05;
  const std::vector<TimedPose> nodes = {{path(-h), -h}, {path(h), h}, {path(-2 * h), -2 * h}};
  for (const TimedPose& node : nodes) {
    EXPECT_LT(
        MaxAbs(PoseOnPolynomialPath(nodes, path(0.0), 0.0, node.stamp).Matrix() - node.T_world_cam.Matrix()),
        1e-12);
  }
  for (double fraction : {0.0, 0.3, 0.8}) {  // over an exposure of 0.8 intervals, ending at t
    const double tau = -fraction * h;
    const double cubic_error =
        MaxAbs(PoseOnPolynomialPath(nodes, path(0.0), 0.0, tau).Matrix() - path(tau).Matrix());
    EXPECT_LT(cubic_error, 1e-12) << tau;
    if (fraction == 0.0) continue;
    const double quadratic_error = MaxAbs(
        PoseOnQuadraticPath(path(-h), -h, path(h), h, path(0.0), 0.0, tau).Matrix() - path(tau).Matrix());
    EXPECT_GT(quadratic_error, 1e-5) << tau;
  }
}

// TriangulateRays: the rays of a point from three cameras give the point
// back; one ray gives nothing.
TEST(TriangulateRays, RecoversThePointItsRaysSee) {
  const Eigen::Vector3d point(0.3, -0.2, 4.0);
  std::vector<SE3> T_cam_world;
  std::vector<Eigen::Vector3d> rays;
  for (int k = 0; k < 3; ++k) {
    T_cam_world.push_back(
        SE3(SO3Exp(Eigen::Vector3d(0.02 * k, -0.03 * k, 0.01)), Eigen::Vector3d(-0.2 * k, 0.05 * k, 0.1)));
    const Eigen::Vector3d p = T_cam_world.back() * point;
    rays.push_back(p / p.z());
  }
  Eigen::Vector3d triangulated;
  ASSERT_TRUE(TriangulateRays(rays, T_cam_world, &triangulated));
  EXPECT_LT((triangulated - point).norm(), 1e-9);
  EXPECT_FALSE(TriangulateRays({rays[0]}, {T_cam_world[0]}, &triangulated));
}

}  // namespace
}  // namespace deblur_sr_mvs
