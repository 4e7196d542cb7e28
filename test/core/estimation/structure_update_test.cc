// Jacobians of the linearised warp (eq:taylorExpansion) against central
// differences, and the blur derivative of the self-consistency term.
#include "deblur_sr_mvs/core/estimation/structure_update.h"

#include <cmath>
#include <cstdio>
#include <functional>
#include <string>
#include <utility>

#include <Eigen/Eigenvalues>
#include <opencv2/imgproc.hpp>

#include <gtest/gtest.h>

#include "deblur_sr_mvs/core/estimation/image_update.h"

namespace deblur_sr_mvs {
namespace {

// A smooth textured image: the analytic derivative samples central-difference
// gradients, the numeric one differentiates bilinear interpolation; they agree
// to second order in the texture frequency (a few % at 0.07 rad/px).
cv::Mat SmoothTexture(int width, int height) {
  cv::Mat image(height, width, CV_32FC3);
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      image.at<cv::Vec3f>(y, x) =
          cv::Vec3f(0.5f + 0.4f * std::sin(0.07f * x + 0.03f * y),
                    0.5f + 0.4f * std::cos(0.06f * y - 0.02f * x), 0.5f + 0.3f * std::sin(0.04f * (x + y)));
    }
  }
  cv::GaussianBlur(image, image, cv::Size(0, 0), 1.5);
  return image;
}

// "a b c d e f" with 3 significant digits.
std::string Format(const Vector6d& v) {
  char text[128];
  std::snprintf(text, sizeof(text), "%.3e %.3e %.3e %.3e %.3e %.3e", v(0), v(1), v(2), v(3), v(4), v(5));
  return text;
}

struct Scene {
  PinholeCamera camera{96, 72, 80.0, 82.0, 47.3, 35.6};
  cv::Mat inverse_depth;
  SE3 T_world_t = SE3::Exp((Vector6d() << 0.1, -0.02, 0.03, 0.01, 0.02, -0.01).finished());
  SE3 T_world_s = SE3::Exp((Vector6d() << 0.16, -0.01, 0.02, 0.015, 0.01, -0.005).finished());
  cv::Mat latent_s = SmoothTexture(96, 72);
  Scene() {
    inverse_depth = cv::Mat(72, 96, CV_32FC1);
    for (int y = 0; y < 72; ++y) {
      for (int x = 0; x < 96; ++x) inverse_depth.at<float>(y, x) = 0.5f + 0.002f * x + 0.001f * y;
    }
  }
};

// The pair (1 <- 0) of `scene` whose observation `truth` is frame 0's
// texture warped by the true poses; it names its own source image.
PairMatching TruthPair(const Scene& scene, const WarpLinearization& truth) {
  PairMatching pair;
  pair.t = 1;
  pair.s = 0;
  pair.observation = &truth.warped;
  pair.mask = truth.valid;
  pair.source = &scene.latent_s;
  return pair;
}

// Interior pixels valid in all three warps.
std::vector<cv::Point> CheckedPixels(const WarpLinearization& a, const WarpLinearization& b,
                                     const WarpLinearization& c) {
  std::vector<cv::Point> points;
  for (int y = 10; y < 62; y += 7) {
    for (int x = 10; x < 86; x += 9) {
      if (a.valid.at<uchar>(y, x) && b.valid.at<uchar>(y, x) && c.valid.at<uchar>(y, x)) {
        points.emplace_back(x, y);
      }
    }
  }
  return points;
}

TEST(LinearizeWarp, InverseDepthDerivativeMatchesNumeric) {
  Scene scene;
  const WarpLinearization lin = LinearizeWarp(scene.camera, scene.inverse_depth, scene.T_world_t,
                                              scene.T_world_s, scene.latent_s, nullptr);
  const float h = 1e-3f;
  const WarpLinearization plus = LinearizeWarp(scene.camera, scene.inverse_depth + h, scene.T_world_t,
                                               scene.T_world_s, scene.latent_s, nullptr);
  const WarpLinearization minus = LinearizeWarp(scene.camera, scene.inverse_depth - h, scene.T_world_t,
                                                scene.T_world_s, scene.latent_s, nullptr);
  const std::vector<cv::Point> points = CheckedPixels(lin, plus, minus);
  ASSERT_GT(points.size(), 30u);
  double max_error = 0.0, max_value = 0.0;
  for (const cv::Point& p : points) {
    for (int c = 0; c < 3; ++c) {
      const double numeric = (plus.warped.at<cv::Vec3f>(p)[c] - minus.warped.at<cv::Vec3f>(p)[c]) / (2.0 * h);
      const double analytic = lin.d_inverse_depth.at<cv::Vec3f>(p)[c];
      max_error = std::max(max_error, std::abs(numeric - analytic));
      max_value = std::max(max_value, std::abs(numeric));
    }
  }
  std::printf("inverse depth: max error %.4f of max %.4f\n", max_error, max_value);
  EXPECT_GT(max_value, 0.01);  // the derivative is not trivially zero
  EXPECT_LT(max_error, 0.05 * max_value);
}

TEST(LinearizeWarp, PoseJacobiansMatchNumeric) {
  Scene scene;
  std::vector<cv::Mat> jacobians;
  const WarpLinearization lin = LinearizeWarp(scene.camera, scene.inverse_depth, scene.T_world_t,
                                              scene.T_world_s, scene.latent_s, &jacobians);
  ASSERT_EQ(jacobians.size(), 6u);
  const double h = 1e-4;
  for (int j = 0; j < 6; ++j) {
    Vector6d step = Vector6d::Zero();
    step(j) = h;
    // P_t = exp(eps) P_t0 (eq:updateVariables) ...
    const WarpLinearization plus =
        LinearizeWarp(scene.camera, scene.inverse_depth, SE3::Exp(step) * scene.T_world_t, scene.T_world_s,
                      scene.latent_s, nullptr);
    const WarpLinearization minus =
        LinearizeWarp(scene.camera, scene.inverse_depth, SE3::Exp(-step) * scene.T_world_t, scene.T_world_s,
                      scene.latent_s, nullptr);
    // ... and P_s = exp(eps) P_s0 moves the warp the opposite way.
    const WarpLinearization plus_s = LinearizeWarp(scene.camera, scene.inverse_depth, scene.T_world_t,
                                                   SE3::Exp(step) * scene.T_world_s, scene.latent_s, nullptr);
    const WarpLinearization minus_s =
        LinearizeWarp(scene.camera, scene.inverse_depth, scene.T_world_t, SE3::Exp(-step) * scene.T_world_s,
                      scene.latent_s, nullptr);
    const std::vector<cv::Point> points = CheckedPixels(lin, plus, minus);
    ASSERT_GT(points.size(), 30u);
    double max_error = 0.0, max_error_s = 0.0, max_value = 0.0;
    for (const cv::Point& p : points) {
      for (int c = 0; c < 3; ++c) {
        const double numeric =
            (plus.warped.at<cv::Vec3f>(p)[c] - minus.warped.at<cv::Vec3f>(p)[c]) / (2.0 * h);
        const double numeric_s =
            (plus_s.warped.at<cv::Vec3f>(p)[c] - minus_s.warped.at<cv::Vec3f>(p)[c]) / (2.0 * h);
        const double analytic = jacobians[j].at<cv::Vec3f>(p)[c];
        max_error = std::max(max_error, std::abs(numeric - analytic));
        max_error_s = std::max(max_error_s, std::abs(numeric_s + analytic));
        max_value = std::max(max_value, std::abs(numeric));
      }
    }
    std::printf("pose component %d: max error %.4f of max %.4f\n", j, max_error, max_value);
    EXPECT_GT(max_value, 0.01) << "component " << j;
    EXPECT_LT(max_error, 0.05 * max_value) << "component " << j;
    EXPECT_LT(max_error_s, 0.05 * max_value) << "component " << j;
  }
}

// The pose update on an HR pair (the fused per-pixel normal equations):
// frame 1's image is frame 0's texture warped by the true poses; from a
// perturbed P_1 the Gauss-Newton/IRLS steps return to the truth, with every
// pixel and with the strided pixel subset. The pair names its own source
// image, so the latents passed in are not read.
TEST(UpdatePoses, RecoversAPerturbedPoseFromAnHrPair) {
  Scene scene;
  const WarpLinearization truth = LinearizeWarp(scene.camera, scene.inverse_depth, scene.T_world_t,
                                                scene.T_world_s, scene.latent_s, nullptr);
  const PairMatching pair = TruthPair(scene, truth);
  const std::vector<cv::Mat> unused_latents(2, cv::Mat::zeros(72, 96, CV_32FC3));
  const std::vector<cv::Mat> inverse_depths = {scene.inverse_depth, scene.inverse_depth};
  const Vector6d perturbation = (Vector6d() << 0.004, -0.003, 0.002, 0.002, -0.003, 0.002).finished();
  for (int stride : {1, 2}) {
    StructureUpdateOptions options;
    options.pose_pixel_stride = stride;
    options.pose_iterations = 8;
    std::vector<SE3> poses = {scene.T_world_s, SE3::Exp(perturbation) * scene.T_world_t};
    const double before = (poses[1] * scene.T_world_t.Inverse()).Log().norm();
    const std::vector<Vector6d> steps =
        UpdatePoses(scene.camera, inverse_depths, unused_latents, {pair}, options, &poses);
    const double after = (poses[1] * scene.T_world_t.Inverse()).Log().norm();
    std::printf("stride %d: pose error %.2e -> %.2e\n", stride, before, after);
    EXPECT_LT(after, 0.05 * before) << "stride " << stride;
    EXPECT_EQ(steps[0], Vector6d::Zero());  // frame 0 is the gauge
    EXPECT_TRUE((poses[0].translation() - scene.T_world_s.translation()).isZero());
  }
}

// The HR pair's normal equations (pixel by pixel, the Jacobian from the
// projection into s, float sums within a row) against the general form
// through a capture operator (pose Jacobian images of LinearizeWarp, double
// sums) with an identity operator: the same Gauss-Newton step.
TEST(UpdatePoses, HrPairStepMatchesTheOperatorFormWithAnIdentityOperator) {
  Scene scene;
  const WarpLinearization truth = LinearizeWarp(scene.camera, scene.inverse_depth, scene.T_world_t,
                                                scene.T_world_s, scene.latent_s, nullptr);
  CaptureGeometry geometry;  // no motion within the exposure, source = t: Psi = I
  geometry.camera_hr = scene.camera;
  geometry.depth_hr = 1.0 / scene.inverse_depth;
  geometry.T_world_cam = scene.T_world_t;
  geometry.T_world_neighbour = scene.T_world_t;
  geometry.neighbour_stamp = 0.0;
  geometry.stamp = 1.0;
  geometry.exposure = 0.5;
  CaptureOperatorOptions op_options;
  op_options.scale = 1;
  op_options.samples = 4;
  op_options.num_threads = 1;
  CaptureOperator identity;
  CaptureOperatorBuilder(op_options).Build(geometry, &identity);
  cv::Mat identity_check;
  identity.Apply(scene.latent_s, &identity_check);
  ASSERT_EQ(cv::norm(identity_check, scene.latent_s, cv::NORM_INF), 0.0);

  const PairMatching hr_pair = TruthPair(scene, truth);
  PairMatching operator_pair = hr_pair;
  operator_pair.blur = &identity;
  const std::vector<cv::Mat> unused_latents(2, cv::Mat::zeros(72, 96, CV_32FC3));
  const std::vector<cv::Mat> inverse_depths = {scene.inverse_depth, scene.inverse_depth};
  StructureUpdateOptions options;
  options.pose_pixel_stride = 1;
  options.pose_iterations = 1;
  const Vector6d perturbation = (Vector6d() << 0.004, -0.003, 0.002, 0.002, -0.003, 0.002).finished();
  std::vector<Vector6d> steps;
  for (const PairMatching& pair : {hr_pair, operator_pair}) {
    std::vector<SE3> poses = {scene.T_world_s, SE3::Exp(perturbation) * scene.T_world_t};
    steps.push_back(UpdatePoses(scene.camera, inverse_depths, unused_latents, {pair}, options, &poses)[1]);
  }
  std::printf("HR step %s\noperator step %s\n", Format(steps[0]).c_str(), Format(steps[1]).c_str());
  ASSERT_GT(steps[1].norm(), 0.1 * perturbation.norm());
  EXPECT_LT((steps[0] - steps[1]).norm(), 1e-3 * steps[1].norm());
}

// A restored pair and an input pair of the same frames and mask share each
// pixel's warp in UpdatePoses; with a copy of the mask they are summed pair by
// pair: the same step.
TEST(UpdatePoses, PairsSharingTheirMaskGiveTheStepOfSeparatePairs) {
  Scene scene;
  const WarpLinearization truth = LinearizeWarp(scene.camera, scene.inverse_depth, scene.T_world_t,
                                                scene.T_world_s, scene.latent_s, nullptr);
  cv::Mat input_source, input_observation;  // another image pair of the same frames
  cv::GaussianBlur(scene.latent_s, input_source, cv::Size(0, 0), 1.0);
  input_observation = LinearizeWarp(scene.camera, scene.inverse_depth, scene.T_world_t, scene.T_world_s,
                                    input_source, nullptr)
                          .warped;
  const PairMatching restored = TruthPair(scene, truth);
  PairMatching input = restored;
  input.observation = &input_observation;
  input.source = &input_source;
  const std::vector<cv::Mat> unused_latents(2, cv::Mat::zeros(72, 96, CV_32FC3));
  const std::vector<cv::Mat> inverse_depths = {scene.inverse_depth, scene.inverse_depth};
  StructureUpdateOptions options;
  options.pose_iterations = 2;
  const Vector6d perturbation = (Vector6d() << 0.004, -0.003, 0.002, 0.002, -0.003, 0.002).finished();
  std::vector<Vector6d> steps;
  for (bool shared_mask : {true, false}) {
    PairMatching second = input;
    if (!shared_mask) second.mask = input.mask.clone();
    std::vector<SE3> poses = {scene.T_world_s, SE3::Exp(perturbation) * scene.T_world_t};
    steps.push_back(
        UpdatePoses(scene.camera, inverse_depths, unused_latents, {restored, second}, options, &poses)[1]);
  }
  std::printf("shared mask %s\nseparate    %s\n", Format(steps[0]).c_str(), Format(steps[1]).c_str());
  ASSERT_GT(steps[1].norm(), 0.5 * perturbation.norm());
  EXPECT_LT((steps[0] - steps[1]).norm(), 1e-4 * steps[1].norm());
}

TEST(StructureUpdateOptions, RejectsBadValues) {
  StructureUpdateOptions options;
  options.Check();
  options.lambda_d = -1.0;
  EXPECT_ANY_THROW(options.Check());
  options = StructureUpdateOptions();
  options.depth_cg_iterations = 0;
  EXPECT_ANY_THROW(options.Check());
  options = StructureUpdateOptions();
  options.pose_pixel_stride = 0;
  EXPECT_ANY_THROW(options.Check());
  options = StructureUpdateOptions();
  options.depth_damping = std::nan("");
  EXPECT_ANY_THROW(options.Check());
  options = StructureUpdateOptions();
  options.blur_pose_samples = 0;
  EXPECT_ANY_THROW(options.Check());
  options = StructureUpdateOptions();
  options.blur_pose_stride = 9;
  EXPECT_ANY_THROW(options.Check());
  options = StructureUpdateOptions();
  options.blur_pose_weight = -1.0;
  EXPECT_ANY_THROW(options.Check());
}

// ---- Blur as motion evidence: three frames 0.1 s apart on an accelerating
// path with rotation, a slanted plane at depth ~2, exposure 0.06 s (about
// 3 HR px of blur); frame 1's path is the quadratic through all three. With
// `fourth_frame`, a fourth whose acceleration differs: frame 2's path is the
// cubic through all four.
struct BlurScene {
  explicit BlurScene(bool fourth_frame) : BlurScene() {
    if (!fourth_frame) return;
    stamps.push_back(0.3);
    poses.push_back(SE3::Exp((Vector6d() << 0.26, 0.05, 0.06, 0.035, -0.03, 0.01).finished()));
  }
  PinholeCamera camera{96, 72, 80.0, 82.0, 47.3, 35.6};
  cv::Mat depth = cv::Mat(72, 96, CV_32FC1);
  cv::Mat inverse_depth = cv::Mat(72, 96, CV_32FC1);
  cv::Mat latent = SmoothTexture(96, 72);
  std::vector<double> stamps = {0.0, 0.1, 0.2};
  std::vector<SE3> poses = {SE3(),
                            SE3::Exp((Vector6d() << 0.08, 0.02, 0.03, 0.01, -0.015, 0.005).finished()),
                            SE3::Exp((Vector6d() << 0.18, 0.03, 0.05, 0.025, -0.02, 0.012).finished())};
  BlurScene() {
    for (int y = 0; y < 72; ++y) {
      for (int x = 0; x < 96; ++x) {
        inverse_depth.at<float>(y, x) = 0.5f + 0.002f * x + 0.001f * y;
        depth.at<float>(y, x) = 1.0f / inverse_depth.at<float>(y, x);
      }
    }
  }
  // Psi_t's self-consistency geometry at `T_world_cam`.
  CaptureGeometry Geometry(const std::vector<SE3>& T_world_cam, int t) const {
    CaptureGeometry geometry;
    geometry.camera_hr = camera;
    geometry.depth_hr = depth;
    SetBlurPath(T_world_cam, stamps, t, &geometry);
    geometry.exposure = 0.06;
    return geometry;
  }
  // Psi_t I_t (LR) at `T_world_cam`.
  cv::Mat Predict(const std::vector<SE3>& T_world_cam, int t, const CaptureOperatorOptions& options) const {
    cv::Mat out;
    BuildCaptureOperator(Geometry(T_world_cam, t), options).Apply(latent, &out);
    return out;
  }
};

// J of BlurPoseJacobian against central differences of Psi_t I_t, the
// operator rebuilt for every pose of frame t's blur path moved along each
// axis: frame 1 of three (the quadratic) and frame 2 of four (the cubic).
// The operator samples D_t at every virtual camera (no reprojection: the
// Jacobian's D_tau ~ D_t) with the Jacobian's 16 virtual cameras; the
// relative error of each column (over the interior LR pixels) stays within
// 5 %; with the reprojected depths and M = 50 (`with_reprojection`) within
// 10 %. The cubic's frame 2 moves farther over its exposure than the
// quadratic's frame 1, and D_tau ~ D_t costs it up to 17 % with the
// reprojected depths: the path's derivative is what its test checks.
void ExpectBlurPoseJacobianMatches(const BlurScene& scene, int t, const std::vector<int>& path,
                                   bool with_reprojection) {
  const int frames = static_cast<int>(path.size());
  const cv::Mat jacobian = BlurPoseJacobian(scene.Geometry(scene.poses, t), 16, 2, scene.inverse_depth,
                                            scene.latent, 16, 1);
  ASSERT_EQ(jacobian.channels(), 3 * 6 * frames);
  for (const bool reproject : {false, true}) {
    if (reproject && !with_reprojection) continue;
    CaptureOperatorOptions options;
    options.samples = reproject ? 50 : 16;
    options.reproject_depth = reproject;
    double worst = 0.0;
    for (int k = 0; k < frames; ++k) {
      for (int j = 0; j < 6; ++j) {
        const double h = 1e-4;
        std::vector<SE3> plus = scene.poses, minus = scene.poses;
        Vector6d eps = Vector6d::Zero();
        eps(j) = h;
        plus[path[k]] = SE3::Exp(eps) * plus[path[k]];
        minus[path[k]] = SE3::Exp(-eps) * minus[path[k]];
        const cv::Mat numeric = (scene.Predict(plus, t, options) - scene.Predict(minus, t, options)) / (2.0 * h);
        double error = 0.0, norm = 0.0;
        for (int y = 4; y < 32; ++y) {
          for (int x = 4; x < 44; ++x) {
            for (int c = 0; c < 3; ++c) {
              const double n = numeric.at<cv::Vec3f>(y, x)[c];
              const double a = jacobian.ptr<float>(y)[(x * 3 + c) * 6 * frames + 6 * k + j];
              error += (a - n) * (a - n);
              norm += n * n;
            }
          }
        }
        const double relative = std::sqrt(error / norm);
        std::printf("frame %d, reproject %d, pose %d axis %d: |J| %.3f, relative error %.4f\n", t, reproject,
                    k, j, std::sqrt(norm), relative);
        EXPECT_GT(norm, 1e-2);  // the column is not trivially zero
        worst = std::max(worst, relative);
      }
    }
    EXPECT_LT(worst, reproject ? 0.10 : 0.05);
  }
}

TEST(BlurPoseJacobian, MatchesNumericDifferencesOfTheOperator) {
  ExpectBlurPoseJacobianMatches(BlurScene(), 1, {1, 0, 2}, true);  // P_t, P_neighbour, P_second_neighbour
}

TEST(BlurPoseJacobian, MatchesNumericDifferencesOnTheCubicPath) {
  // P_t, P_neighbour, P_second_neighbour, P_third_neighbour.
  ExpectBlurPoseJacobianMatches(BlurScene(/*fourth_frame=*/true), 2, {2, 1, 3, 0}, false);
}

// The pose error of frame 1 before and after 4 rounds of the pose update
// on the blur terms that `make_terms` gives at the current poses (in the
// frames' own order), from P_1 moved by 0.3 of its motion from frame 0 in a
// direction other than the motion. P_0 and P_2 are held: the pose update
// holds leading frames, so frame 1 sits at index 2 (frames 0, 2, 1).
using BlurTermMaker = std::function<std::vector<BlurPoseTerm>(const std::vector<SE3>& T_world_cam)>;
std::pair<double, double> RecoverPerturbedPose(const BlurScene& scene, const BlurTermMaker& make_terms) {
  const Vector6d motion = (scene.poses[1] * scene.poses[0].Inverse()).Log();
  std::vector<SE3> poses = {scene.poses[0], scene.poses[2], scene.poses[1]};
  poses[2] = SE3::Exp(0.3 * (Vector6d() << motion(1), -motion(0), motion(2), -motion(5), motion(3),
                                   motion(4)).finished()) * poses[2];
  const std::vector<cv::Mat> unused(3, cv::Mat::zeros(72, 96, CV_32FC3));
  StructureUpdateOptions options;
  const double before = (poses[2] * scene.poses[1].Inverse()).Log().norm();
  for (int round = 0; round < 4; ++round) {
    const std::vector<BlurPoseTerm> terms = make_terms({poses[0], poses[2], poses[1]});
    UpdatePoses(scene.camera, {scene.inverse_depth, scene.inverse_depth, scene.inverse_depth}, unused, {},
                options, &poses, /*num_fixed=*/2, /*prior=*/nullptr, &terms);
  }
  return {before, (poses[2] * scene.poses[1].Inverse()).Log().norm()};
}

StructureUpdateOptions BlurTestOptions() {
  StructureUpdateOptions options;
  options.blur_pose_samples = 16;
  return options;
}

// Blur alone fixes a perturbed pose: frame 1's observation is Psi_1 I_1 at
// the true poses, and the pose update sees no pairs, only frame 1's blur
// term with the true sharp image I_1 (frames 1, 0, 2 are indices 2, 0, 1).
TEST(UpdatePoses, BlurAloneRecoversAPerturbedPose) {
  const BlurScene scene;
  const CaptureOperatorOptions operator_options;
  const cv::Mat observation = scene.Predict(scene.poses, 1, operator_options);
  const auto [before, after] = RecoverPerturbedPose(scene, [&](const std::vector<SE3>& path) {
    const cv::Mat predicted = scene.Predict(path, 1, operator_options);
    return std::vector<BlurPoseTerm>{LinearizeBlurInPoses(scene.Geometry(path, 1), {2, 0, 1}, 50, 2,
                                                          scene.inverse_depth, scene.latent, observation,
                                                          predicted, 30.0, BlurTestOptions())};
  });
  std::printf("blur alone: pose error %.2e -> %.2e\n", before, after);
  EXPECT_LT(after, 0.2 * before);
}

// Why the self term does not help the estimator (BENCHMARKS.md "Blur as
// motion evidence in the pose update"): when I_1 is the image restored from
// B_1 through the current, perturbed blur (the image update of the self term
// alone, from the bicubic input) before each round, the term holds P_1 where
// it is; the same rounds with the true sharp image (the test above) remove
// the error.
TEST(UpdatePoses, BlurOfAnImageRestoredThroughTheSameBlurHoldsThePose) {
  const BlurScene scene;
  const CaptureOperatorOptions operator_options;
  const cv::Mat observation = scene.Predict(scene.poses, 1, operator_options);
  cv::Mat latent;
  cv::resize(observation, latent, scene.latent.size(), 0, 0, cv::INTER_CUBIC);
  const auto [before, after] = RecoverPerturbedPose(scene, [&](const std::vector<SE3>& path) {
    const CaptureOperator psi = BuildCaptureOperator(scene.Geometry(path, 1), operator_options);
    UpdateImage({{&psi, &observation, cv::Mat(), 30.0}}, ImageUpdateOptions(), &latent);
    cv::Mat predicted;
    psi.Apply(latent, &predicted);
    return std::vector<BlurPoseTerm>{LinearizeBlurInPoses(scene.Geometry(path, 1), {2, 0, 1}, 50, 2,
                                                          scene.inverse_depth, latent, observation, predicted,
                                                          30.0, BlurTestOptions())};
  });
  std::printf("restored through the perturbed blur: pose error %.2e -> %.2e\n", before, after);
  EXPECT_GT(after, 0.5 * before);
}

// The blurred pair form: frame 1's sharp image is frame 0's texture warped
// into 1 at the true poses, its observation that image through Psi_1; the
// pair (1 <- 0) alone (its blur path and its warp linearised) brings P_1
// back.
TEST(UpdatePoses, BlurredPairAloneRecoversAPerturbedPose) {
  const BlurScene scene;
  const CaptureOperatorOptions operator_options;
  const cv::Mat& latent_0 = scene.latent;
  const cv::Mat sharp_1 =
      LinearizeWarp(scene.camera, scene.inverse_depth, scene.poses[1], scene.poses[0], latent_0, nullptr).warped;
  cv::Mat observation;
  BuildCaptureOperator(scene.Geometry(scene.poses, 1), operator_options).Apply(sharp_1, &observation);
  const auto [before, after] = RecoverPerturbedPose(scene, [&](const std::vector<SE3>& path) {
    const CaptureGeometry geometry = scene.Geometry(path, 1);
    const CaptureOperator psi = BuildCaptureOperator(geometry, operator_options);
    return std::vector<BlurPoseTerm>{LinearizeBlurredPairInPoses(geometry, {2, 0, 1}, 0, 50, 2,
                                                                 scene.inverse_depth, path[0], latent_0, psi,
                                                                 observation, 1.0, BlurTestOptions())};
  });
  std::printf("blurred pair alone: pose error %.2e -> %.2e\n", before, after);
  EXPECT_LT(after, 0.2 * before);
}

// What blur cannot add (BENCHMARKS.md "Blur as motion evidence in the pose
// update", the arc path): on a nearly fronto-parallel plane seen by a camera
// moving sideways, the least constrained direction of P_1 in frame 1's blur
// term (J^T J of BlurPoseJacobian's P_1 columns) is the one of the HR pair
// (1 <- 0) (J^T J of LinearizeWarp's pose Jacobians): a translation traded
// for a rotation (bas-relief). The blur sees the same motion field as the
// pair, over a shorter time.
TEST(BlurPoseJacobian, SharesTheWeakestDirectionOfAnHrPair) {
  BlurScene scene;
  for (int y = 0; y < 72; ++y) {
    for (int x = 0; x < 96; ++x) {
      scene.inverse_depth.at<float>(y, x) = 0.5f + 0.0002f * x;
      scene.depth.at<float>(y, x) = 1.0f / scene.inverse_depth.at<float>(y, x);
    }
  }
  const std::vector<SE3> poses = {SE3(), SE3::Exp((Vector6d() << 0.05, 0, 0, 0, 0, 0).finished()),
                                  SE3::Exp((Vector6d() << 0.1, 0, 0, 0, 0, 0).finished())};
  const cv::Mat blur = BlurPoseJacobian(scene.Geometry(poses, 1), 50, 2, scene.inverse_depth, scene.latent, 16, 1);
  std::vector<cv::Mat> pair;
  LinearizeWarp(scene.camera, scene.inverse_depth, poses[1], poses[0], scene.latent, &pair);
  Matrix6d blur_normal = Matrix6d::Zero(), pair_normal = Matrix6d::Zero();
  for (int y = 0; y < blur.rows; ++y) {
    for (int x = 0; x < blur.cols * 3; ++x) {
      const Vector6d a = Eigen::Map<const Eigen::Matrix<float, 6, 1>>(blur.ptr<float>(y) + x * 18).cast<double>();
      blur_normal += a * a.transpose();
    }
  }
  for (int y = 0; y < 72; ++y) {
    for (int x = 0; x < 96; ++x) {
      for (int c = 0; c < 3; ++c) {
        Vector6d a;
        for (int j = 0; j < 6; ++j) a(j) = pair[j].at<cv::Vec3f>(y, x)[c];
        pair_normal += a * a.transpose();
      }
    }
  }
  const Eigen::SelfAdjointEigenSolver<Matrix6d> blur_eigen(blur_normal), pair_eigen(pair_normal);
  const double cosine = std::abs(blur_eigen.eigenvectors().col(0).dot(pair_eigen.eigenvectors().col(0)));
  std::printf("weakest direction: blur %s (eigenvalue ratio %.2e), pair %s (%.2e), |cos| %.4f\n",
              Format(blur_eigen.eigenvectors().col(0)).c_str(),
              blur_eigen.eigenvalues()(0) / blur_eigen.eigenvalues()(5),
              Format(pair_eigen.eigenvectors().col(0)).c_str(),
              pair_eigen.eigenvalues()(0) / pair_eigen.eigenvalues()(5), cosine);
  EXPECT_GT(cosine, 0.95);
}

}  // namespace
}  // namespace deblur_sr_mvs
