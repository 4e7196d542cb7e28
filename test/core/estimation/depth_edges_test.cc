// Depth edges (depth_edges.h): the guided weighted median moves a fattened
// depth edge back onto the image edge, keeps a thin structure thin, keeps
// flat and smooth depth, and leaves invalid pixels alone.
#include "deblur_sr_mvs/core/estimation/depth_edges.h"

#include <cmath>
#include <limits>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/estimation/estimator.h"

namespace deblur_sr_mvs {
namespace {

constexpr int kWidth = 64;
constexpr int kHeight = 48;
constexpr float kNear = 2.0f;  // inverse depth of the foreground
constexpr float kFar = 1.0f;   // inverse depth of the background

DepthEdgeOptions On(int radius) {
  DepthEdgeOptions options;
  options.radius_px = radius;
  options.sigma = 0.1;
  return options;
}

// A guide whose columns [begin, end) show a bright, textured foreground on a
// dark, textured background (a deterministic +-0.02 pattern: the guide of a
// real scene is not flat).
cv::Mat BarGuide(int begin, int end) {
  cv::Mat guide(kHeight, kWidth, CV_32FC3);
  for (int y = 0; y < kHeight; ++y) {
    for (int x = 0; x < kWidth; ++x) {
      const float texture = 0.02f * static_cast<float>(((x * 7 + y * 13) % 5) - 2) / 2.0f;
      const float base = x >= begin && x < end ? 0.7f : 0.25f;
      guide.at<cv::Vec3f>(y, x) = cv::Vec3f(base + texture, base + 0.5f * texture, base - texture);
    }
  }
  return guide;
}

// Inverse depth kNear on columns [begin, end), kFar elsewhere.
cv::Mat BarDepth(int begin, int end) {
  cv::Mat inverse_depth(kHeight, kWidth, CV_32FC1, cv::Scalar(kFar));
  inverse_depth.colRange(begin, end).setTo(kNear);
  return inverse_depth;
}

// Columns whose every pixel holds the foreground's inverse depth.
int ForegroundColumns(const cv::Mat& inverse_depth) {
  int columns = 0;
  for (int x = 0; x < kWidth; ++x) {
    bool all = true;
    for (int y = 0; y < kHeight; ++y) all = all && inverse_depth.at<float>(y, x) == kNear;
    columns += all;
  }
  return columns;
}

TEST(RefineDepthEdges, AFattenedStepEdgeReturnsToTheImageEdge) {
  // Image edge at x = 32; the foreground depth spread 4 px onto the
  // background (the initialiser's 5x5 LR patch at scale 2). The window of
  // the band's first pixel must hold more background beyond the band than
  // band: radius 9 (10 background columns, 4 of them band); at radius 7 the
  // two tie (8 columns, 4 band).
  const cv::Mat guide = BarGuide(0, 32);
  cv::Mat inverse_depth = BarDepth(0, 36);
  RefineDepthEdges(guide, On(9), &inverse_depth);
  const cv::Mat truth = BarDepth(0, 32);
  EXPECT_EQ(cv::countNonZero(inverse_depth != truth), 0);
}

TEST(RefineDepthEdges, AThinStructureIsNotFattenedAndStaysWhole) {
  // A 3-px bar (a table leg) whose depth came out 9 px wide: back to 3 px,
  // and the bar keeps its depth (a plain median of the window would erase it).
  // Radius 9: the window of a band pixel holds 16 background-like columns,
  // 6 of them band (at 7: 12 and 6, a tie).
  const cv::Mat guide = BarGuide(30, 33);
  cv::Mat inverse_depth = BarDepth(27, 36);
  RefineDepthEdges(guide, On(9), &inverse_depth);
  EXPECT_EQ(ForegroundColumns(inverse_depth), 3);
  EXPECT_EQ(cv::countNonZero(inverse_depth != BarDepth(30, 33)), 0);
  // The unweighted median of the same window loses the true bar.
  DepthEdgeOptions flat = On(9);
  flat.sigma = 1.0;  // weights within [exp(-0.5 * 0.45^2 * 3), 1]: nearly flat
  cv::Mat plain = BarDepth(30, 33);
  RefineDepthEdges(guide, flat, &plain);
  EXPECT_LT(ForegroundColumns(plain), 3);
}

TEST(RefineDepthEdges, ASlantedPlaneWithoutImageEdgesKeepsItsDepth) {
  // Smooth depth under a textured guide without edges: the weighted median
  // of a linear ramp is the centre value (up to the filter's value set).
  const cv::Mat guide = BarGuide(0, 0);
  cv::Mat inverse_depth(kHeight, kWidth, CV_32FC1);
  for (int y = 0; y < kHeight; ++y) {
    for (int x = 0; x < kWidth; ++x) inverse_depth.at<float>(y, x) = 1.0f + 0.01f * x + 0.005f * y;
  }
  const cv::Mat before = inverse_depth.clone();
  RefineDepthEdges(guide, On(5), &inverse_depth);
  // Away from the border (where the window is cut and the median shifts).
  const cv::Rect inner(5, 5, kWidth - 10, kHeight - 10);
  double max_difference = 0.0;
  cv::minMaxLoc(cv::abs(inverse_depth(inner) - before(inner)), nullptr, &max_difference);
  EXPECT_LT(max_difference, 0.011);  // one pixel step of the ramp
}

TEST(RefineDepthEdges, InvalidPixelsNeitherVoteNorChange) {
  const cv::Mat guide = BarGuide(0, 32);
  cv::Mat inverse_depth = BarDepth(0, 32);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  inverse_depth.at<float>(10, 40) = nan;
  inverse_depth.at<float>(20, 10) = 0.0f;
  RefineDepthEdges(guide, On(7), &inverse_depth);
  EXPECT_TRUE(std::isnan(inverse_depth.at<float>(10, 40)));
  EXPECT_EQ(inverse_depth.at<float>(20, 10), 0.0f);
  // Every other pixel keeps its (already right) depth.
  EXPECT_EQ(inverse_depth.at<float>(10, 41), kFar);
  EXPECT_EQ(inverse_depth.at<float>(20, 11), kNear);
}

// A colour guide with many colours (the filter clusters them with
// cv::kmeans, which draws from OpenCV's global generator): the same input
// gives the same depth, call after call, and the caller's generator state
// is left as it was. With the generator unseeded, every later call on this
// input differed from the first.
TEST(RefineDepthEdges, SameInputGivesTheSameDepthAndTheGeneratorIsLeftAlone) {
  cv::Mat guide(kHeight, kWidth, CV_32FC3);
  cv::Mat inverse_depth(kHeight, kWidth, CV_32FC1);
  cv::RNG fill(7);
  fill.fill(guide, cv::RNG::UNIFORM, 0.0, 1.0);
  fill.fill(inverse_depth, cv::RNG::UNIFORM, 0.5, 2.0);
  cv::theRNG().state = 42;
  cv::Mat first = inverse_depth.clone();
  RefineDepthEdges(guide, On(8), &first);
  EXPECT_EQ(cv::theRNG().state, 42u);
  for (int call = 0; call < 3; ++call) {
    cv::theRNG().next();
    cv::Mat again = inverse_depth.clone();
    RefineDepthEdges(guide, On(8), &again);
    EXPECT_EQ(cv::norm(first, again, cv::NORM_INF), 0.0) << "call " << call;
  }
}

// Two threads refining at once (e.g. the streams of two nodelets in one
// process): OpenCV's filter is not reentrant, and without the refinement's
// lock this crashed. Each thread gets the depth a lone call gives.
TEST(RefineDepthEdges, ConcurrentCallsGiveTheDepthOfALoneCall) {
  cv::Mat guide(120, 160, CV_32FC3);
  cv::Mat inverse_depth(120, 160, CV_32FC1);
  cv::RNG fill(11);
  fill.fill(guide, cv::RNG::UNIFORM, 0.0, 1.0);
  fill.fill(inverse_depth, cv::RNG::UNIFORM, 0.5, 2.0);
  cv::Mat alone = inverse_depth.clone();
  RefineDepthEdges(guide, On(8), &alone);
  std::vector<cv::Mat> results(2);
  auto refine = [&](int which) {
    for (int call = 0; call < 5; ++call) {
      results[which] = inverse_depth.clone();
      RefineDepthEdges(guide, On(8), &results[which]);
    }
  };
  std::thread first(refine, 0), second(refine, 1);
  first.join();
  second.join();
  for (const cv::Mat& result : results) EXPECT_EQ(cv::norm(alone, result, cv::NORM_INF), 0.0);
}

TEST(RefineDepthEdges, OffChangesNothingAndOptionsAreChecked) {
  const cv::Mat guide = BarGuide(0, 32);
  cv::Mat inverse_depth = BarDepth(0, 36);
  RefineDepthEdges(guide, On(0), &inverse_depth);
  EXPECT_EQ(cv::countNonZero(inverse_depth != BarDepth(0, 36)), 0);
  EXPECT_NO_THROW(On(7).Check());
  EXPECT_THROW(On(-1).Check(), InputError);
  DepthEdgeOptions bad = On(7);
  bad.sigma = 0.0;
  EXPECT_THROW(bad.Check(), InputError);
  EstimatorOptions estimator;
  EXPECT_NO_THROW(estimator.Check());
  estimator.depth_edges.radius_px = -1;
  EXPECT_THROW(estimator.Check(), InputError);
  cv::Mat wrong_size(10, 10, CV_32FC1, cv::Scalar(1.0f));
  EXPECT_THROW(RefineDepthEdges(guide, On(7), &wrong_size), InputError);
}

}  // namespace
}  // namespace deblur_sr_mvs
