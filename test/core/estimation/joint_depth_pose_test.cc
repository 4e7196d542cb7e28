// The joint depth + pose step of the structure update (JointDepthPoseSystem,
// UpdateDepthAndPoses): its normal equations against central differences of
// the warp (eq:taylorExpansion, eq:updateVariables), and its effect on a
// two-frame scene with a perturbed pose against the alternation of depth and
// pose updates.
#include <cmath>
#include <cstdio>
#include <vector>

#include <gtest/gtest.h>

#include "deblur_sr_mvs/core/estimation/structure_update.h"

namespace deblur_sr_mvs {
namespace {

// A slanted textured plane n . X = 2 (world), seen by two cameras: each
// frame's image and inverse depth follow from ray-plane intersections, so the
// pair is consistent with the true structure.
struct PlaneScene {
  PinholeCamera camera{96, 72, 80.0, 82.0, 47.3, 35.6};
  Eigen::Vector3d normal{-0.3, 0.1, 1.0};
  std::vector<SE3> T_world_cam = {SE3::Exp((Vector6d() << 0.0, 0.0, 0.0, 0.0, 0.0, 0.0).finished()),
                                  SE3::Exp((Vector6d() << 0.12, 0.01, 0.0, 0.01, -0.02, 0.005).finished())};
  std::vector<cv::Mat> images, inverse_depths;

  PlaneScene() {
    for (const SE3& pose : T_world_cam) {
      cv::Mat image(camera.height, camera.width, CV_32FC3),
          inverse_depth(camera.height, camera.width, CV_32FC1);
      for (int y = 0; y < camera.height; ++y) {
        for (int x = 0; x < camera.width; ++x) {
          const Eigen::Vector3d ray = pose.rotation() * camera.Ray(x, y);  // z = 1 in the camera
          const double depth = (2.0 - normal.dot(pose.translation())) / normal.dot(ray);
          const Eigen::Vector3d point = pose.translation() + depth * ray;
          inverse_depth.at<float>(y, x) = static_cast<float>(1.0 / depth);
          // About 0.025 world units per pixel at depth 2: 0.06 - 0.1 rad/px.
          const double u = point.x() / 0.025, v = point.y() / 0.025;
          image.at<cv::Vec3f>(y, x) = cv::Vec3f(static_cast<float>(0.5 + 0.4 * std::sin(0.08 * u + 0.03 * v)),
                                                static_cast<float>(0.5 + 0.4 * std::cos(0.07 * v - 0.02 * u)),
                                                static_cast<float>(0.5 + 0.3 * std::sin(0.05 * (u + v))));
        }
      }
      images.push_back(image);
      inverse_depths.push_back(inverse_depth);
    }
  }

  // Both ordered pairs (0 <- 1, 1 <- 0) on the HR images, as the depth
  // update of each frame sees them; `mask` (optional) limits the pixels.
  std::vector<FrameDepthTerms> Terms(const cv::Mat& mask) const {
    std::vector<FrameDepthTerms> terms(2);
    for (int t = 0; t < 2; ++t) {
      PairMatching pair;
      pair.t = t;
      pair.s = 1 - t;
      pair.observation = &images[t];
      pair.mask = mask;
      terms[t].pairs.push_back(pair);
    }
    return terms;
  }
};

// The quadratic and linear forms of the joint normal equations along a
// direction x = (d_0, d_1, eps_1) against the directional derivative J x of
// the warped images by central differences: with no TV and no damping,
// x^T N x = sum_p sum_i w_i (J_p x)_i^2 and rhs^T x = sum_p sum_i w_i r0_i
// (J_p x)_i, w the IRLS weights at the linearisation point.
TEST(JointDepthPoseSystem, NormalEquationsMatchNumericDifferences) {
  const PlaneScene scene;
  // The pixels whose warps stay inside the other image under the probes.
  cv::Mat mask = cv::Mat::zeros(72, 96, CV_8UC1);
  mask(cv::Rect(14, 10, 68, 52)).setTo(255);
  const std::vector<FrameDepthTerms> terms = scene.Terms(mask);
  StructureUpdateOptions options;
  options.lambda_d = 0.0;
  options.depth_damping = 0.0;
  options.pose_damping = 0.0;
  // A linearisation point off the truth (residuals not all small), so that
  // the IRLS weights vary.
  std::vector<cv::Mat> rho = {scene.inverse_depths[0] * 1.02, scene.inverse_depths[1] * 0.99};
  std::vector<SE3> poses = scene.T_world_cam;
  poses[1] = SE3::Exp((Vector6d() << 0.0, 0.003, -0.002, 0.001, 0.0, -0.001).finished()) * poses[1];
  JointDepthPoseSystem system(scene.camera, poses, scene.images, terms, /*parallax_scale=*/8.0, options, 1);
  system.Linearize(rho);
  const JointStep rhs = system.RightHandSide(rho);

  JointStep x;
  for (int t = 0; t < 2; ++t) {
    cv::Mat d(72, 96, CV_32FC1);
    for (int y = 0; y < 72; ++y) {
      for (int xx = 0; xx < 96; ++xx) d.at<float>(y, xx) = 0.01f * std::sin(0.1f * xx + 0.2f * y + t);
    }
    x.inverse_depths.push_back(d);
  }
  x.poses = Eigen::VectorXd::Zero(12);
  x.poses.segment<6>(6) << 0.004, -0.003, 0.002, 0.002, -0.003, 0.002;
  system.ProjectGauge(&x.poses);
  EXPECT_TRUE(x.poses.head<6>().isZero());  // frame 0 held
  EXPECT_GT(x.poses.segment<6>(6).norm(), 0.0);
  const JointStep nx = system.ApplyNormal(x);
  double quadratic = x.poses.dot(nx.poses), linear = x.poses.dot(rhs.poses);
  for (int t = 0; t < 2; ++t) {
    quadratic += x.inverse_depths[t].dot(nx.inverse_depths[t]);
    linear += x.inverse_depths[t].dot(rhs.inverse_depths[t]);
  }

  const double h = 1e-3;
  auto warped_at = [&](int t, double step) {
    std::vector<SE3> moved = poses;
    moved[1] = SE3::Exp(step * x.poses.segment<6>(6)) * poses[1];
    const cv::Mat rho_t = rho[t] + step * x.inverse_depths[t];
    return LinearizeWarp(scene.camera, rho_t, moved[t], moved[1 - t], scene.images[1 - t], nullptr);
  };
  double numeric_quadratic = 0.0, numeric_linear = 0.0;
  for (int t = 0; t < 2; ++t) {
    const WarpLinearization at = warped_at(t, 0.0), plus = warped_at(t, h), minus = warped_at(t, -h);
    for (int y = 0; y < 72; ++y) {
      for (int xx = 0; xx < 96; ++xx) {
        if (!mask.at<uchar>(y, xx)) continue;
        ASSERT_TRUE(at.valid.at<uchar>(y, xx) && plus.valid.at<uchar>(y, xx) && minus.valid.at<uchar>(y, xx));
        for (int c = 0; c < 3; ++c) {
          const double r0 = scene.images[t].at<cv::Vec3f>(y, xx)[c] - at.warped.at<cv::Vec3f>(y, xx)[c];
          const double w = 1.0 / std::max(std::abs(r0), options.residual_epsilon);
          const double jx =
              (plus.warped.at<cv::Vec3f>(y, xx)[c] - minus.warped.at<cv::Vec3f>(y, xx)[c]) / (2 * h);
          numeric_quadratic += w * jx * jx;
          numeric_linear += w * r0 * jx;
        }
      }
    }
  }
  std::printf("x^T N x: %.6g (numeric %.6g); rhs^T x: %.6g (numeric %.6g)\n", quadratic, numeric_quadratic,
              linear, numeric_linear);
  EXPECT_GT(numeric_quadratic, 0.0);
  EXPECT_NEAR(quadratic, numeric_quadratic, 0.03 * numeric_quadratic);
  EXPECT_NEAR(linear, numeric_linear, 0.03 * std::abs(numeric_linear));
}

double PoseError(const SE3& estimate, const SE3& truth) {
  return (estimate * truth.Inverse()).Log().norm();
}

// Mean |rho - rho_true| / rho_true over the pixels of frame t seen by both.
double DepthError(const cv::Mat& estimate, const cv::Mat& truth) {
  double sum = 0.0;
  int count = 0;
  for (int y = 12; y < 60; ++y) {
    for (int x = 16; x < 80; ++x) {
      sum += std::abs(estimate.at<float>(y, x) - truth.at<float>(y, x)) / truth.at<float>(y, x);
      ++count;
    }
  }
  return sum / count;
}

struct StepResult {
  double pose_error = 0.0, depth_error = 0.0;
  double initial_pose_error = 0.0, initial_depth_error = 0.0;
};

// `rounds` structure updates from a fronto-parallel start and a perturbed
// P_1: per round either the depth updates of both frames then the pose
// update (the alternation), or the joint step then the pose update.
StepResult RunStructureUpdates(const PlaneScene& scene, bool joint, int rounds) {
  StructureUpdateOptions options;
  const std::vector<FrameDepthTerms> terms = scene.Terms(cv::Mat());
  std::vector<PairMatching> pairs = {terms[0].pairs[0], terms[1].pairs[0]};
  const double mean_rho = 0.5 * (cv::mean(scene.inverse_depths[0])[0] + cv::mean(scene.inverse_depths[1])[0]);
  std::vector<cv::Mat> rho(2);
  for (cv::Mat& r : rho) r = cv::Mat(72, 96, CV_32FC1, cv::Scalar(mean_rho));
  // Off the baseline direction: the scale of the window stays as it is.
  std::vector<SE3> poses = scene.T_world_cam;
  poses[1] = SE3::Exp((Vector6d() << 0.0, 0.006, 0.004, 0.004, -0.003, 0.002).finished()) * poses[1];
  const double parallax_scale = scene.camera.fx * 0.12;
  StepResult result;
  result.initial_pose_error = PoseError(poses[1], scene.T_world_cam[1]);
  result.initial_depth_error =
      0.5 * (DepthError(rho[0], scene.inverse_depths[0]) + DepthError(rho[1], scene.inverse_depths[1]));
  for (int round = 0; round < rounds; ++round) {
    if (joint) {
      UpdateDepthAndPoses(scene.camera, scene.images, terms, parallax_scale, options, 1, &poses, &rho);
    } else {
      const std::vector<SE3> depth_poses = poses;
      for (int t = 0; t < 2; ++t) {
        UpdateDepth(scene.camera, depth_poses, scene.images, terms[t].pairs, nullptr, cv::Mat(),
                    parallax_scale, options, &rho[t]);
      }
    }
    UpdatePoses(scene.camera, rho, scene.images, pairs, options, &poses, 1);
  }
  result.pose_error = PoseError(poses[1], scene.T_world_cam[1]);
  result.depth_error =
      0.5 * (DepthError(rho[0], scene.inverse_depths[0]) + DepthError(rho[1], scene.inverse_depths[1]));
  return result;
}

// Measured (3 rounds): from pose error 9.0e-3 and depth error 0.060 the
// alternation ends at 1.2e-2 and 0.058 (the depth absorbed the pose error:
// the pose update then finds the biased depth consistent), the joint step at
// 4.2e-3 and 0.025. After one round the joint step's pose error is still
// above the start (1.6e-2 against 1.3e-2 for the alternation): the depth
// starts fronto-parallel, and the poses follow it first.
TEST(UpdateDepthAndPoses, BeatsTheAlternationFromAPerturbedPose) {
  const PlaneScene scene;
  for (int rounds : {1, 3}) {
    const StepResult alternation = RunStructureUpdates(scene, /*joint=*/false, rounds);
    const StepResult joint = RunStructureUpdates(scene, /*joint=*/true, rounds);
    std::printf(
        "%d round(s), from pose error %.2e, inverse-depth rel. error %.4f: pose error %.2e (alternation "
        "%.2e), inverse-depth rel. error %.4f (alternation %.4f)\n",
        rounds, joint.initial_pose_error, joint.initial_depth_error, joint.pose_error, alternation.pose_error,
        joint.depth_error, alternation.depth_error);
    if (rounds < 3) continue;
    EXPECT_LT(joint.pose_error, joint.initial_pose_error);
    EXPECT_LT(joint.depth_error, 0.5 * joint.initial_depth_error);
    EXPECT_LT(joint.pose_error, 0.5 * alternation.pose_error);
    EXPECT_LT(joint.depth_error, 0.6 * alternation.depth_error);
  }
}

TEST(StructureUpdateOptions, RejectsBadJointCgIterations) {
  StructureUpdateOptions options;
  options.joint_cg_iterations = 0;
  EXPECT_ANY_THROW(options.Check());
}

}  // namespace
}  // namespace deblur_sr_mvs
