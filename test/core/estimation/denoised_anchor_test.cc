// The denoised anchor of the last image pass (DenoisedAnchorOptions): its
// settings follow the noise estimate above the estimator's floor, the
// non-local-means anchor brings a noisy image closer to the truth, and the
// image update's proximity term (QuadraticAnchor) is exact: weight 0 is the
// update of before bit for bit, a large weight gives the anchor.
#include "deblur_sr_mvs/core/estimation/denoised_anchor.h"

#include <cmath>
#include <random>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/estimation/image_update.h"
#include "deblur_sr_mvs/core/estimation/input_denoising.h"
#include "deblur_sr_mvs/core/imaging/capture_operator.h"

namespace deblur_sr_mvs {
namespace {

constexpr double kGray = 1.0 / 255.0;

// Below the floor (the estimates of noise-free frames read 0.46-0.85 gray
// levels) there is no anchor; above it h and the weight follow the rule.
TEST(DenoisedAnchor, SettingsFollowTheNoiseAboveTheFloor) {
  DenoisedAnchorOptions options;
  options.enabled = true;
  for (double estimate : {0.0, 0.46, 0.85, 0.9}) {
    EXPECT_FALSE(AnchorSettings(options, estimate * kGray, 30.0, kGray).active) << estimate;
  }
  const DenoisedAnchorSettings settings = AnchorSettings(options, 2.0 * kGray, 30.0, kGray);
  ASSERT_TRUE(settings.active);
  const double input = std::sqrt(4.0 - 0.81) * kGray;
  EXPECT_NEAR(settings.input_noise, input, 1e-12);
  EXPECT_NEAR(settings.amplified_noise, 3.0 * input, 1e-12);
  EXPECT_NEAR(settings.h, 3.0 * input, 1e-12);
  EXPECT_NEAR(settings.weight, 30.0 * std::hypot(kGray, input) / (9.0 * input * input), 1e-9);
  // More noise: a larger h and a weaker pull.
  const DenoisedAnchorSettings more = AnchorSettings(options, 4.0 * kGray, 30.0, kGray);
  EXPECT_GT(more.h, settings.h);
  EXPECT_LT(more.weight, settings.weight);
  DenoisedAnchorOptions off;
  off.enabled = false;
  EXPECT_FALSE(AnchorSettings(off, 4.0 * kGray, 30.0, kGray).active);
}

TEST(DenoisedAnchor, BadOptionsThrow) {
  DenoisedAnchorOptions options;
  options.amplification = 0.0;
  EXPECT_THROW(options.Check(), InputError);
  options = DenoisedAnchorOptions();
  options.template_px = 6;
  EXPECT_THROW(options.Check(), InputError);
  options = DenoisedAnchorOptions();
  options.fusion_radius = 0;
  EXPECT_THROW(options.Check(), InputError);
  EXPECT_NO_THROW(DenoisedAnchorOptions().Check());
}

// A piecewise smooth colour image (ramps and a disc) in [0.2, 0.8].
cv::Mat Cartoon(int rows, int cols) {
  cv::Mat image(rows, cols, CV_32FC3);
  for (int y = 0; y < rows; ++y) {
    for (int x = 0; x < cols; ++x) {
      const float ramp = 0.2f + 0.3f * static_cast<float>(x) / static_cast<float>(cols);
      image.at<cv::Vec3f>(y, x) = cv::Vec3f(ramp, 0.5f, 0.8f - ramp);
    }
  }
  cv::circle(image, cv::Point(cols / 2, rows / 2), rows / 4, cv::Scalar(0.7, 0.3, 0.4), cv::FILLED);
  return image;
}

double RmsGray(const cv::Mat& a, const cv::Mat& b) {
  const double n = static_cast<double>(a.total() * a.channels());
  return 255.0 * cv::norm(a, b, cv::NORM_L2) / std::sqrt(n);
}

// Noise of 6 gray levels: the anchor at h = 6 gray levels is closer to the
// truth than the noisy image (less than 0.6x its RMS error).
TEST(DenoisedAnchor, NoisyImageGetsCloserToTheTruth) {
  const cv::Mat truth = Cartoon(60, 80);
  cv::Mat noise(truth.size(), truth.type());
  cv::theRNG().state = 7;
  cv::randn(noise, cv::Scalar::all(0.0), cv::Scalar::all(6.0 * kGray));
  const cv::Mat noisy = truth + noise;
  const cv::Mat anchor = DenoisedAnchor(noisy, 6.0 * kGray, DenoisedAnchorOptions());
  ASSERT_EQ(anchor.type(), noisy.type());
  const double before = RmsGray(noisy, truth), after = RmsGray(anchor, truth);
  std::printf("RMS error %.2f -> %.2f gray levels\n", before, after);
  EXPECT_LT(after, 0.6 * before);
}

// What the filter leaves alone keeps its float value: a constant image
// between two 8-bit levels comes back bit for bit.
TEST(DenoisedAnchor, KeepsTheFloatValuesTheFilterDoesNotChange) {
  const cv::Mat flat(20, 30, CV_32FC1, cv::Scalar(0.4 + 0.3 * kGray));
  const cv::Mat anchor = DenoisedAnchor(flat, 3.0 * kGray, DenoisedAnchorOptions());
  EXPECT_EQ(cv::norm(anchor, flat, cv::NORM_INF), 0.0);
  EXPECT_THROW(DenoisedAnchor(cv::Mat(4, 4, CV_8UC1), kGray, DenoisedAnchorOptions()), InputError);
}

// A small deblurring problem (image_update_test.cc's): motion blur and 2x
// down-sampling of a random image.
struct Problem {
  CaptureOperator op;
  cv::Mat truth, observation;
};

Problem MakeProblem() {
  const int hr_rows = 24, hr_cols = 32;
  CaptureGeometry geometry;
  geometry.camera_hr = PinholeCamera(hr_cols, hr_rows, 30.0, 30.0, hr_cols / 2.0, hr_rows / 2.0);
  geometry.depth_hr = cv::Mat(hr_rows, hr_cols, CV_32FC1, cv::Scalar(2.0));
  geometry.T_world_cam = SE3(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0.0, 0.0, 0.0));
  geometry.T_world_neighbour = SE3(Eigen::Matrix3d::Identity(), Eigen::Vector3d(-0.05, 0.0, 0.0));
  geometry.stamp = 1.0;
  geometry.neighbour_stamp = 0.9;
  geometry.exposure = 0.08;
  CaptureOperatorOptions op_options;
  op_options.samples = 10;
  Problem problem;
  problem.op = BuildCaptureOperator(geometry, op_options);
  problem.truth.create(hr_rows, hr_cols, CV_32FC1);
  cv::theRNG().state = 5;
  cv::randu(problem.truth, 0.0, 1.0);
  problem.op.Apply(problem.truth, &problem.observation);
  return problem;
}

TEST(QuadraticAnchor, ZeroWeightIsTheUpdateOfBefore) {
  const Problem problem = MakeProblem();
  const std::vector<LinearL1Term> terms{{&problem.op, &problem.observation, cv::Mat(), 1.0}};
  ImageUpdateOptions options;
  options.lambda_i = 0.01;
  options.num_threads = 1;
  const cv::Mat start(problem.truth.size(), CV_32FC1, cv::Scalar(0.5));
  cv::Mat plain = start.clone(), anchored = start.clone();
  UpdateImage(terms, options, &plain);
  const cv::Mat anchor_image = problem.truth.clone();
  const QuadraticAnchor zero{&anchor_image, 0.0};
  UpdateImage(terms, options, &anchored, &zero);
  EXPECT_EQ(cv::norm(plain, anchored, cv::NORM_INF), 0.0);
  const QuadraticAnchor wrong{&problem.observation, 1.0};  // LR size
  EXPECT_THROW(UpdateImage(terms, options, &anchored, &wrong), InputError);
}

// The proximity term pulls the solution to the anchor: a weight far above the
// data terms' curvature gives the anchor; a moderate one lands between the
// anchor-free solution and the anchor, and lowers the energy with the term.
TEST(QuadraticAnchor, PullsTheSolutionTowardsTheAnchor) {
  const Problem problem = MakeProblem();
  const std::vector<LinearL1Term> terms{{&problem.op, &problem.observation, cv::Mat(), 1.0}};
  ImageUpdateOptions options;
  options.lambda_i = 0.01;
  options.num_threads = 1;
  options.irls_iterations = 6;
  options.cg_iterations = 50;
  options.cg_tolerance = 0.0;
  const cv::Mat start(problem.truth.size(), CV_32FC1, cv::Scalar(0.5));
  const cv::Mat anchor_image(problem.truth.size(), CV_32FC1, cv::Scalar(0.3));
  cv::Mat plain = start.clone(), strong = start.clone();
  UpdateImage(terms, options, &plain);
  const QuadraticAnchor heavy{&anchor_image, 1e6};
  UpdateImage(terms, options, &strong, &heavy);
  EXPECT_LT(cv::norm(strong, anchor_image, cv::NORM_INF), 1e-3);
  cv::Mat moderate = start.clone();
  const QuadraticAnchor some{&anchor_image, 50.0};
  UpdateImage(terms, options, &moderate, &some);
  const double to_anchor = cv::norm(moderate, anchor_image), plain_to_anchor = cv::norm(plain, anchor_image);
  EXPECT_LT(to_anchor, plain_to_anchor);
  EXPECT_GT(to_anchor, cv::norm(strong, anchor_image));
}

// The input filter's strength: none below the floor or when off, then
// h_scale x sqrt(sigma^2 - floor^2).
TEST(InputDenoising, StrengthFollowsTheNoiseAboveTheFloor) {
  InputDenoisingOptions options;
  options.enabled = true;
  for (double estimate : {0.0, 0.46, 0.85, 0.9}) {
    EXPECT_EQ(InputDenoisingStrength(options, estimate * kGray), 0.0) << estimate;
  }
  EXPECT_NEAR(InputDenoisingStrength(options, 2.0 * kGray), std::sqrt(4.0 - 0.81) * kGray, 1e-12);
  options.h_scale = 0.5;
  EXPECT_NEAR(InputDenoisingStrength(options, 4.0 * kGray), 0.5 * std::sqrt(16.0 - 0.81) * kGray, 1e-12);
  options.enabled = false;
  EXPECT_EQ(InputDenoisingStrength(options, 4.0 * kGray), 0.0);
  options = InputDenoisingOptions();
  options.search_px = 20;
  EXPECT_THROW(options.Check(), InputError);
  EXPECT_NO_THROW(InputDenoisingOptions().Check());
}

// Three 8-bit frames of one scene with independent noise of 6 gray levels:
// each filtered frame is closer to the truth (the middle one, which has a
// neighbour on either side, less than 0.6x the noisy frame's RMS error).
TEST(InputDenoising, NoisyFramesGetCloserToTheTruth) {
  const cv::Mat truth = Cartoon(60, 80);
  std::vector<cv::Mat> frames;
  cv::theRNG().state = 11;
  for (int t = 0; t < 3; ++t) {
    cv::Mat noise(truth.size(), truth.type()), quantised;
    cv::randn(noise, cv::Scalar::all(0.0), cv::Scalar::all(6.0 * kGray));
    cv::Mat noisy = truth + noise;
    noisy.convertTo(quantised, CV_8U, 255.0);  // as read from 8-bit files
    quantised.convertTo(noisy, CV_32F, 1.0 / 255.0);
    frames.push_back(noisy);
  }
  const std::vector<cv::Mat> filtered = DenoiseInputFrames(frames, 6.0 * kGray, InputDenoisingOptions());
  ASSERT_EQ(filtered.size(), frames.size());
  for (int t = 0; t < 3; ++t) {
    const double before = RmsGray(frames[t], truth), after = RmsGray(filtered[t], truth);
    std::printf("frame %d: RMS error %.2f -> %.2f gray levels\n", t, before, after);
    EXPECT_LT(after, (t == 1 ? 0.6 : 0.8) * before);
  }
  EXPECT_THROW(DenoiseInputFrames({frames[0], cv::Mat(4, 4, CV_32FC3)}, kGray, InputDenoisingOptions()),
               InputError);
}

}  // namespace
}  // namespace deblur_sr_mvs
