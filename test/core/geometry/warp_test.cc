// ReprojectDepth against its contract, pixel by pixel: PixelTransferF::Warp
// of every valid source pixel to the nearest target pixel, the nearest
// surface kept, unreached pixels filled from the source or NaN.
#include "deblur_sr_mvs/core/geometry/warp.h"

#include <cmath>
#include <cstring>
#include <limits>

#include <gtest/gtest.h>

namespace deblur_sr_mvs {
namespace {

// The contract of ReprojectDepth written out with PixelTransferF::Warp.
cv::Mat ReprojectDepthReference(const PinholeCamera& camera, const cv::Mat& depth_source,
                                const SE3& T_target_source, bool fill_from_source) {
  const float empty = std::numeric_limits<float>::infinity();
  cv::Mat target(depth_source.size(), CV_32FC1, cv::Scalar(empty));
  const PixelTransferF transfer{PixelTransfer(camera, T_target_source)};
  for (int y = 0; y < camera.height; ++y) {
    float base[3];
    transfer.RowBase(static_cast<float>(y), base);
    for (int x = 0; x < camera.width; ++x) {
      const float depth = depth_source.at<float>(y, x);
      float u, v, z;
      if (!ValidDepth(depth) || !transfer.Warp(base, static_cast<float>(x), depth, &u, &v, &z)) continue;
      const int tx = static_cast<int>(std::floor(u + 0.5f));
      const int ty = static_cast<int>(std::floor(v + 0.5f));
      if (tx < 0 || ty < 0 || tx >= camera.width || ty >= camera.height) continue;
      float& slot = target.at<float>(ty, tx);
      slot = std::min(slot, z);
    }
  }
  for (int y = 0; y < camera.height; ++y) {
    for (int x = 0; x < camera.width; ++x) {
      float& value = target.at<float>(y, x);
      if (value == empty) value = fill_from_source ? depth_source.at<float>(y, x) : std::nanf("");
    }
  }
  return target;
}

// A slanted plane with a near box, unknown depth (0 and NaN) in places, and
// points behind the target camera after the motion.
cv::Mat TestDepth(int width, int height) {
  cv::Mat depth(height, width, CV_32FC1);
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      float d = 2.0f + 0.01f * x + 0.5f * std::sin(0.2f * y);
      if (x > 30 && x < 60 && y > 20 && y < 45) d = 0.8f;
      if ((x + 3 * y) % 17 == 0) d = 0.0f;
      if ((2 * x + y) % 23 == 0) d = std::nanf("");
      if (x < 6 && y < 6) d = 0.05f;  // behind the target camera after moving 0.3 forward
      depth.at<float>(y, x) = d;
    }
  }
  return depth;
}

TEST(ReprojectDepth, MatchesItsContractPixelByPixel) {
  const PinholeCamera camera(96, 72, 80.0, 82.0, 47.3, 35.6);
  const cv::Mat depth = TestDepth(camera.width, camera.height);
  const SE3 T_target_source = SE3::Exp((Vector6d() << 0.12, -0.05, -0.3, 0.02, -0.03, 0.01).finished());
  for (bool fill : {true, false}) {
    cv::Mat result;
    ReprojectDepth(camera, depth, T_target_source, fill, &result);
    const cv::Mat expected = ReprojectDepthReference(camera, depth, T_target_source, fill);
    ASSERT_EQ(result.size(), expected.size());
    ASSERT_EQ(result.type(), CV_32FC1);
    // Bit for bit, NaN included.
    EXPECT_EQ(std::memcmp(result.data, expected.data, result.total() * sizeof(float)), 0) << "fill " << fill;
    int reached = 0;
    for (int i = 0; i < static_cast<int>(result.total()); ++i)
      reached += result.ptr<float>()[i] != depth.ptr<float>()[i];
    EXPECT_GT(reached, static_cast<int>(result.total()) / 2);  // the motion moved most of the map
  }
}

TEST(ReprojectDepth, IdentityKeepsTheValidDepth) {
  const PinholeCamera camera(96, 72, 80.0, 82.0, 47.3, 35.6);
  const cv::Mat depth = TestDepth(camera.width, camera.height);
  cv::Mat result;
  ReprojectDepth(camera, depth, SE3(), /*fill_from_source=*/false, &result);
  for (int y = 0; y < camera.height; ++y) {
    for (int x = 0; x < camera.width; ++x) {
      const float d = depth.at<float>(y, x);
      if (ValidDepth(d)) {
        EXPECT_FLOAT_EQ(result.at<float>(y, x), d) << x << ", " << y;
      } else {
        EXPECT_TRUE(std::isnan(result.at<float>(y, x))) << x << ", " << y;
      }
    }
  }
}

}  // namespace
}  // namespace deblur_sr_mvs
