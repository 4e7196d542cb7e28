// Consistency between neighbouring depth maps (depth_consistency.h): noisy
// depth maps of one plane get closer to the truth, an occluding neighbour
// does not pull the background, a frame without a consistent neighbour
// (single frame, radius 0, no overlap) keeps its depth bit for bit, unknown
// depth stays unknown, the frames' order does not matter.
#include "deblur_sr_mvs/core/estimation/depth_consistency.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <vector>

#include <Eigen/Geometry>
#include <gtest/gtest.h>

#include "../support/same_bits.h"
#include "deblur_sr_mvs/core/common/errors.h"

namespace deblur_sr_mvs {
namespace {

constexpr int kWidth = 80;
constexpr int kHeight = 60;
const PinholeCamera kCamera(kWidth, kHeight, 100.0, 100.0, 39.5, 29.5);
constexpr double kPlaneZ = 2.0;  // the plane Z_world = 2

// n cameras moving along x (and a little forward), turning a little about
// y, in front of the plane Z_world = kPlaneZ.
std::vector<SE3> Cameras(int n) {
  std::vector<SE3> T_world_cam;
  for (int k = 0; k < n; ++k) {
    const Eigen::Matrix3d R = Eigen::AngleAxisd(0.01 * (k - n / 2), Eigen::Vector3d::UnitY()).toRotationMatrix();
    T_world_cam.emplace_back(R, Eigen::Vector3d(0.04 * k, 0.005 * k, 0.02 * k));
  }
  return T_world_cam;
}

// The true depth map of the plane in camera T_world_cam.
cv::Mat PlaneDepth(const SE3& T_world_cam) {
  cv::Mat depth(kHeight, kWidth, CV_32FC1);
  const Eigen::Matrix3d R = T_world_cam.rotation();
  const Eigen::Vector3d c = T_world_cam.translation();
  for (int y = 0; y < kHeight; ++y) {
    for (int x = 0; x < kWidth; ++x) {
      const Eigen::Vector3d ray_world = R * kCamera.Ray(x, y);  // z = 1 in the camera
      depth.at<float>(y, x) = static_cast<float>((kPlaneZ - c.z()) / ray_world.z());
    }
  }
  return depth;
}

// The true depth maps, each with its own multiplicative noise of `sigma`.
std::vector<cv::Mat> NoisyDepths(const std::vector<SE3>& T_world_cam, double sigma, std::vector<cv::Mat>* truth) {
  cv::RNG rng(11);
  std::vector<cv::Mat> noisy;
  for (const SE3& pose : T_world_cam) {
    truth->push_back(PlaneDepth(pose));
    cv::Mat factor(kHeight, kWidth, CV_32FC1);
    rng.fill(factor, cv::RNG::NORMAL, cv::Scalar(1.0), cv::Scalar(sigma));
    noisy.push_back(truth->back().mul(factor));
  }
  return noisy;
}

// Mean relative depth error over the central part of the image.
double RelativeError(const cv::Mat& depth, const cv::Mat& truth) {
  const cv::Rect centre(15, 10, kWidth - 30, kHeight - 20);
  cv::Mat relative = cv::abs(depth(centre) - truth(centre)) / truth(centre);
  return cv::mean(relative)[0];
}

DepthConsistencyOptions On(int radius, double tolerance) {
  DepthConsistencyOptions options;
  options.radius = radius;
  options.tolerance = tolerance;
  return options;
}

TEST(DepthConsistency, NoisyDepthMapsOfAPlaneGetCloserToTheTruth) {
  const std::vector<SE3> T_world_cam = Cameras(5);
  for (double sigma : {0.005, 0.02}) {
    std::vector<cv::Mat> truth;
    const std::vector<cv::Mat> noisy = NoisyDepths(T_world_cam, sigma, &truth);
    for (auto combination : {DepthConsistencyOptions::Combination::kMean, DepthConsistencyOptions::Combination::kMedian}) {
      DepthConsistencyOptions options = On(2, 4.0 * sigma);
      options.combination = combination;
      const std::vector<cv::Mat> fused = FuseNeighbourDepths(kCamera, noisy, T_world_cam, options);
      const double before = RelativeError(noisy[2], truth[2]);
      const double after = RelativeError(fused[2], truth[2]);
      std::printf("sigma %.3f %s: rel. error %.5f -> %.5f\n", sigma,
                  combination == DepthConsistencyOptions::Combination::kMean ? "mean" : "median", before, after);
      // Five independent maps: the mean's error is 1/sqrt(5) = 0.45 of one
      // map's (the bilinear lookup averages the neighbours' noise further);
      // the median's is larger (0.54 for a normal sample of 5). Ask for 0.7.
      EXPECT_LT(after, 0.7 * before) << sigma;
      // Every frame gains, the end frames (two neighbours) as well.
      for (int t = 0; t < 5; ++t) EXPECT_LT(RelativeError(fused[t], truth[t]), RelativeError(noisy[t], truth[t]));
    }
  }
}

TEST(DepthConsistency, ExactDepthMapsStayExact) {
  const std::vector<SE3> T_world_cam = Cameras(3);
  std::vector<cv::Mat> truth;
  const std::vector<cv::Mat> exact = NoisyDepths(T_world_cam, 0.0, &truth);
  const std::vector<cv::Mat> fused = FuseNeighbourDepths(kCamera, exact, T_world_cam, On(1, 0.05));
  for (int t = 0; t < 3; ++t) EXPECT_LT(RelativeError(fused[t], truth[t]), 1e-4) << t;
}

TEST(DepthConsistency, AnOccludingNeighbourDoesNotPullTheBackground) {
  const std::vector<SE3> T_world_cam = Cameras(3);
  std::vector<cv::Mat> truth;
  std::vector<cv::Mat> depths = NoisyDepths(T_world_cam, 0.01, &truth);
  // Frames 0 and 2 see a near object (depth 0.6, 30 % of the plane's) over
  // their left half, which frame 1 does not have (it sees the plane there).
  depths[0].colRange(0, kWidth / 2).setTo(0.6f);
  depths[2].colRange(0, kWidth / 2).setTo(0.6f);
  const std::vector<cv::Mat> fused = FuseNeighbourDepths(kCamera, depths, T_world_cam, On(1, 0.2));
  // Frame 1's pixels that both neighbours see occluded (their left half,
  // less the few pixels of image motion) keep their depth bit for bit; its
  // right half, where the neighbours agree, gets closer to the truth.
  const cv::Range occluded(0, kWidth / 2 - 8);
  const cv::Range agreeing(kWidth / 2 + 8, kWidth - 4);
  EXPECT_TRUE(SameBits(fused[1].colRange(occluded).clone(), depths[1].colRange(occluded).clone()));
  const auto error = [&truth](const cv::Mat& depth, const cv::Range& columns) {
    cv::Mat relative = cv::abs(depth.colRange(columns) - truth[1].colRange(columns)) / truth[1].colRange(columns);
    return cv::mean(relative)[0];
  };
  EXPECT_LT(error(fused[1], agreeing), 0.8 * error(depths[1], agreeing));
  // With the occluder everywhere in both neighbours, frame 1 has no
  // consistent neighbour and keeps its depth bit for bit.
  depths[0].setTo(0.6f);
  depths[2].setTo(0.6f);
  EXPECT_TRUE(SameBits(FuseNeighbourDepths(kCamera, depths, T_world_cam, On(1, 0.2))[1], depths[1]));
}

TEST(DepthConsistency, WithoutConsistentNeighboursTheDepthIsUnchangedBitForBit) {
  const std::vector<SE3> T_world_cam = Cameras(3);
  std::vector<cv::Mat> truth;
  std::vector<cv::Mat> depths = NoisyDepths(T_world_cam, 0.01, &truth);
  depths[1].at<float>(5, 5) = std::nanf("");
  depths[1].at<float>(6, 6) = 0.0f;
  // A single frame.
  const std::vector<cv::Mat> single =
      FuseNeighbourDepths(kCamera, {depths[1]}, {T_world_cam[1]}, On(2, 0.05));
  EXPECT_TRUE(SameBits(single[0], depths[1]));
  // Radius 0.
  const std::vector<cv::Mat> off = FuseNeighbourDepths(kCamera, depths, T_world_cam, On(0, 0.05));
  for (int t = 0; t < 3; ++t) EXPECT_TRUE(SameBits(off[t], depths[t])) << t;
  // Neighbours that see none of the plane frame 1 sees.
  std::vector<SE3> apart = T_world_cam;
  apart[0] = SE3(Eigen::Matrix3d::Identity(), Eigen::Vector3d(50.0, 0.0, 0.0));
  apart[2] = SE3(Eigen::Matrix3d::Identity(), Eigen::Vector3d(-50.0, 0.0, 0.0));
  EXPECT_TRUE(SameBits(FuseNeighbourDepths(kCamera, depths, apart, On(1, 0.05))[1], depths[1]));
  // Neighbours without a known depth.
  std::vector<cv::Mat> unknown = depths;
  unknown[0] = cv::Mat(kHeight, kWidth, CV_32FC1, cv::Scalar(std::nanf("")));
  unknown[2] = cv::Mat::zeros(kHeight, kWidth, CV_32FC1);
  EXPECT_TRUE(SameBits(FuseNeighbourDepths(kCamera, unknown, T_world_cam, On(1, 0.05))[1], depths[1]));
}

TEST(DepthConsistency, UnknownDepthStaysUnknownAndTheInputsAreNotChanged) {
  const std::vector<SE3> T_world_cam = Cameras(3);
  std::vector<cv::Mat> truth;
  std::vector<cv::Mat> depths = NoisyDepths(T_world_cam, 0.01, &truth);
  depths[1].rowRange(20, 30).setTo(std::nanf(""));
  std::vector<cv::Mat> copies;
  for (const cv::Mat& depth : depths) copies.push_back(depth.clone());
  const std::vector<cv::Mat> fused = FuseNeighbourDepths(kCamera, depths, T_world_cam, On(1, 0.05));
  for (int y = 20; y < 30; ++y) {
    for (int x = 0; x < kWidth; ++x) EXPECT_TRUE(std::isnan(fused[1].at<float>(y, x)));
  }
  for (int t = 0; t < 3; ++t) EXPECT_TRUE(SameBits(depths[t], copies[t])) << t;
}

TEST(DepthConsistency, TheFramesOrderDoesNotMatter) {
  const std::vector<SE3> T_world_cam = Cameras(4);
  std::vector<cv::Mat> truth;
  const std::vector<cv::Mat> depths = NoisyDepths(T_world_cam, 0.01, &truth);
  DepthConsistencyOptions options = On(1, 0.05);
  options.combination = DepthConsistencyOptions::Combination::kMedian;
  const std::vector<cv::Mat> forward = FuseNeighbourDepths(kCamera, depths, T_world_cam, options);
  const std::vector<cv::Mat> reversed_depths(depths.rbegin(), depths.rend());
  const std::vector<SE3> reversed_poses(T_world_cam.rbegin(), T_world_cam.rend());
  const std::vector<cv::Mat> backward = FuseNeighbourDepths(kCamera, reversed_depths, reversed_poses, options);
  for (int t = 0; t < 4; ++t) {
    EXPECT_LT(cv::norm(forward[t], backward[3 - t], cv::NORM_INF), 1e-6) << t;
  }
}

TEST(DepthConsistency, OptionsCheck) {
  EXPECT_NO_THROW(DepthConsistencyOptions().Check());
  EXPECT_EQ(DepthConsistencyOptions().radius, 0);  // off by default (depth_consistency.h says why)
  EXPECT_NO_THROW(On(10, 1.0).Check());
  EXPECT_THROW(On(-1, 0.05).Check(), InputError);
  EXPECT_THROW(On(11, 0.05).Check(), InputError);
  EXPECT_THROW(On(1, 0.0).Check(), InputError);
  EXPECT_THROW(On(1, 1.5).Check(), InputError);
  EXPECT_THROW(On(1, std::nan("")).Check(), InputError);
  DepthConsistencyOptions bad = On(1, 0.05);
  bad.combination = static_cast<DepthConsistencyOptions::Combination>(7);
  EXPECT_THROW(bad.Check(), InputError);
  // The stage checks its options and its inputs.
  const std::vector<SE3> T_world_cam = Cameras(2);
  std::vector<cv::Mat> truth;
  const std::vector<cv::Mat> depths = NoisyDepths(T_world_cam, 0.0, &truth);
  EXPECT_THROW(FuseNeighbourDepths(kCamera, depths, T_world_cam, On(-1, 0.05)), InputError);
  EXPECT_THROW(FuseNeighbourDepths(kCamera, depths, {T_world_cam[0]}, On(1, 0.05)), InputError);
  EXPECT_THROW(FuseNeighbourDepths(kCamera, {depths[0], cv::Mat::zeros(3, 3, CV_32FC1)}, T_world_cam, On(1, 0.05)),
               InputError);
}

}  // namespace
}  // namespace deblur_sr_mvs
