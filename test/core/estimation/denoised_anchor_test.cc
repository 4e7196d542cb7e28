// The denoised anchor of the last image pass (DenoisedAnchorOptions) and the
// input denoising (InputDenoisingOptions): their settings follow the noise
// estimate above the estimator's floor, and the non-local-means filters
// bring noisy images closer to the truth. The image update's proximity term
// (QuadraticAnchor) is tested in image_update_test.cc.
#include "deblur_sr_mvs/core/estimation/denoised_anchor.h"

#include <cmath>
#include <random>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/estimation/input_denoising.h"

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
