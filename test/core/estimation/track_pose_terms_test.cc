// Feature tracks as pose evidence (TrackPoseTerms, EstimatorOptions::
// track_pose_weight): the reduced normal equations of the tracks' reprojection
// errors (every track's point eliminated) against numeric differences of the
// cost with the points re-triangulated, the tracks' least cost from disturbed
// poses, and the gate.
#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include <gtest/gtest.h>
#include <Eigen/Eigenvalues>

#include "deblur_sr_mvs/core/estimation/structure_update.h"

namespace deblur_sr_mvs {
namespace {

constexpr int kFrames = 4;
constexpr int kPoints = 40;

// Four cameras moving right and turning a little, 40 points 2-4 units in
// front, tracked in every frame (noise_px: per coordinate, Gaussian); each
// observation's camera is a small turn and shift off its frame's pose, as
// a blur path's mid-exposure, growing down the image as a rolling
// shutter's rows.
struct Scene {
  std::vector<SE3> T_world_cam;
  TrackPoseTerms terms;
};

Scene MakeScene(double noise_px) {
  Scene scene;
  std::mt19937 random(7);
  std::uniform_real_distribution<double> uniform(-1.0, 1.0);
  std::normal_distribution<double> noise(0.0, noise_px);
  scene.terms.camera = PinholeCamera(160, 120, 150.0, 150.0, 79.5, 59.5);
  for (int f = 0; f < kFrames; ++f) {
    scene.T_world_cam.emplace_back(SO3Exp(Eigen::Vector3d(0.01 * f, -0.02 * f, 0.005 * f)),
                                   Eigen::Vector3d(0.1 * f, 0.01 * f, 0.02 * f));
  }
  for (int i = 0; i < kPoints; ++i) {
    const Eigen::Vector3d point(uniform(random), 0.7 * uniform(random), 3.0 + uniform(random));
    FeatureTrack track;
    std::vector<SE3> T_cam_seen;
    for (int f = 0; f < kFrames; ++f) {
      const double row = 0.5 + 0.3 * point.y();  // about where the point lies, 0 .. 1 down the image
      T_cam_seen.emplace_back(SO3Exp(Eigen::Vector3d(-0.002, 0.003, 0.001) * row),
                              Eigen::Vector3d(-0.02, 0.001, -0.002) * row);
      const SE3 T_seen_world = (scene.T_world_cam[f] * T_cam_seen.back()).Inverse();
      const Eigen::Vector2d pixel = scene.terms.camera.Project(T_seen_world * point);
      track.points.push_back(pixel + Eigen::Vector2d(noise(random), noise(random)));
    }
    scene.terms.tracks.push_back(track);
    scene.terms.T_cam_seen.push_back(T_cam_seen);
  }
  scene.terms.weight = 2.0;
  scene.terms.sigma_px = 0.5;
  scene.terms.huber = 1e9;  // quadratic everywhere: the cost below is the energy's
  return scene;
}

std::vector<SE3> Perturbed(const std::vector<SE3>& poses, int f, int component, double h) {
  std::vector<SE3> out = poses;
  Vector6d eps = Vector6d::Zero();
  eps(component) = h;
  out[f] = SE3::Exp(eps) * out[f];
  return out;
}

// The right-hand side is minus the gradient, in the free frames' tangents, of
// the energy 0.5 b w / sigma^2 sum |r|^2 with every point at its least-squares
// position for the poses (central differences, the points re-triangulated at
// each; the point's own gradient vanishes there, so the envelope theorem
// makes the reduced gradient exact).
TEST(TrackPoseTerms, ReducedGradientMatchesNumericDifferences) {
  const Scene scene = MakeScene(0.3);
  const double scale = 0.05;
  const int num_fixed = 1, unknowns = 6 * (kFrames - num_fixed);
  Eigen::MatrixXd hessian = Eigen::MatrixXd::Zero(unknowns, unknowns);
  Eigen::VectorXd gradient = Eigen::VectorXd::Zero(unknowns);
  const double cost = AddTrackNormalEquations(scene.terms, scene.T_world_cam, num_fixed, num_fixed, scale,
                                              &hessian, &gradient);
  EXPECT_GT(cost, 0.0);
  const double energy_per_cost = 0.5 * scale * scene.terms.weight / std::pow(scene.terms.sigma_px, 2);
  const double h = 1e-6;
  for (int i = 0; i < unknowns; ++i) {
    const int f = num_fixed + i / 6;
    const double plus = AddTrackNormalEquations(scene.terms, Perturbed(scene.T_world_cam, f, i % 6, h),
                                                num_fixed, num_fixed, scale, nullptr, nullptr);
    const double minus = AddTrackNormalEquations(scene.terms, Perturbed(scene.T_world_cam, f, i % 6, -h),
                                                 num_fixed, num_fixed, scale, nullptr, nullptr);
    const double numeric = energy_per_cost * (plus - minus) / (2.0 * h);
    EXPECT_NEAR(-gradient(i), numeric, 1e-4 * std::max(1.0, std::abs(numeric))) << "unknown " << i;
  }
  // The reduced Gauss-Newton matrix is symmetric and positive semi-definite.
  EXPECT_LT((hessian - hessian.transpose()).norm(), 1e-9 * hessian.norm());
  EXPECT_GT(Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd>(hessian).eigenvalues().minCoeff(),
            -1e-9 * hessian.norm());
}

// Noise-free tracks: from poses turned and shifted off the truth (not along
// the scale, which tracks leave free), the tracks' least cost is zero to
// rounding, and one Gauss-Newton step of the reduced system takes most of
// the cost away.
TEST(TrackPoseTerms, LeastCostFromDisturbedPoses) {
  const Scene scene = MakeScene(0.0);
  std::vector<SE3> disturbed = scene.T_world_cam;
  for (int f = 1; f < kFrames; ++f) {
    Vector6d eps;
    eps << 0.006 * f, -0.003, 0.0045, 0.003, -0.006 * f, 0.0015;
    disturbed[f] = SE3::Exp(eps) * disturbed[f];
  }
  const double before = AddTrackNormalEquations(scene.terms, disturbed, 1, 1, 1.0, nullptr, nullptr);
  EXPECT_GT(before, 1.0);  // px^2 over 160 observations
  EXPECT_LT(TrackCostMinimum(scene.terms, disturbed, 1), 1e-8 * before);
  const int unknowns = 6 * (kFrames - 1);
  Eigen::MatrixXd hessian = Eigen::MatrixXd::Zero(unknowns, unknowns);
  Eigen::VectorXd gradient = Eigen::VectorXd::Zero(unknowns);
  AddTrackNormalEquations(scene.terms, disturbed, 1, 1, 1.0, &hessian, &gradient);
  for (int i = 0; i < unknowns; ++i) hessian(i, i) *= 1.0 + 1e-6;  // the scale's null direction
  const Eigen::VectorXd step = hessian.ldlt().solve(gradient);
  std::vector<SE3> stepped = disturbed;
  for (int f = 1; f < kFrames; ++f) stepped[f] = SE3::Exp(step.segment<6>(6 * (f - 1))) * stepped[f];
  EXPECT_LT(AddTrackNormalEquations(scene.terms, stepped, 1, 1, 1.0, nullptr, nullptr), 0.01 * before);
}

// The gate multiplies the terms by clamp((c / c_min - 1 - start) / width, 0,
// 1): nothing at c / c_min <= 1 + start, all of it from 1 + start + width,
// half of it halfway.
TEST(TrackPoseTerms, GateScalesTheTerms) {
  Scene scene = MakeScene(0.3);
  const int unknowns = 6 * (kFrames - 1);
  const auto system = [&](double min_cost, Eigen::MatrixXd* hessian, Eigen::VectorXd* gradient) {
    scene.terms.min_cost = min_cost;
    *hessian = Eigen::MatrixXd::Zero(unknowns, unknowns);
    *gradient = Eigen::VectorXd::Zero(unknowns);
    return AddTrackNormalEquations(scene.terms, scene.T_world_cam, 1, 1, 1.0, hessian, gradient);
  };
  Eigen::MatrixXd full_h, h;
  Eigen::VectorXd full_g, g;
  const double cost = system(0.0, &full_h, &full_g);  // no gate
  ASSERT_GT(full_g.norm(), 0.0);
  scene.terms.gate_start = 0.2;
  scene.terms.gate_width = 0.5;
  system(cost / 1.15, &h, &g);
  EXPECT_EQ(h.norm(), 0.0);
  EXPECT_EQ(g.norm(), 0.0);
  system(cost / 1.8, &h, &g);
  EXPECT_LT((h - full_h).norm(), 1e-12 * full_h.norm());
  EXPECT_LT((g - full_g).norm(), 1e-12 * full_g.norm());
  system(cost / 1.45, &h, &g);
  EXPECT_LT((h - 0.5 * full_h).norm(), 1e-9 * full_h.norm());
  EXPECT_LT((g - 0.5 * full_g).norm(), 1e-9 * full_g.norm());
}

}  // namespace
}  // namespace deblur_sr_mvs
