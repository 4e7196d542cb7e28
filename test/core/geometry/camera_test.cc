// The K scaling rule of docs/file_formats.md#scaling-rule against real box-downsampling.
#include "deblur_sr_mvs/core/geometry/camera.h"

#include <opencv2/imgproc.hpp>

#include <gtest/gtest.h>

namespace deblur_sr_mvs {
namespace {

TEST(PinholeCamera, UpscaleRuleIsTheSpecFormula) {
  const PinholeCamera lr(320, 240, 300.0, 310.0, 159.5, 119.5);
  const PinholeCamera hr = lr.Upscaled(2);
  EXPECT_EQ(hr.width, 640);
  EXPECT_EQ(hr.height, 480);
  EXPECT_DOUBLE_EQ(hr.fx, 600.0);
  EXPECT_DOUBLE_EQ(hr.fy, 620.0);
  EXPECT_DOUBLE_EQ(hr.cx, 2 * 159.5 + 0.5);
  EXPECT_DOUBLE_EQ(hr.cy, 2 * 119.5 + 0.5);
  const PinholeCamera back = hr.Downscaled(2);
  EXPECT_DOUBLE_EQ(back.cx, lr.cx);
  EXPECT_DOUBLE_EQ(back.fy, lr.fy);
  EXPECT_EQ(back.width, lr.width);
}

TEST(PinholeCamera, ProjectAndRayAreInverse) {
  const PinholeCamera camera(64, 48, 50.0, 55.0, 31.2, 23.9);
  const Eigen::Vector3d point(0.3, -0.2, 2.5);
  const Eigen::Vector2d pixel = camera.Project(point);
  const Eigen::Vector3d back = point.z() * camera.Ray(pixel.x(), pixel.y());
  EXPECT_LT((back - point).norm(), 1e-12);
}

// Render a 3D point's blob at HR through the HR camera, box-downsample with
// OpenCV, and find its centroid in LR: it must sit where the LR camera
// (Downscaled by the rule) projects the same point.
TEST(PinholeCamera, ScalingRuleMatchesBoxDownsampling) {
  for (int scale : {2, 3, 4}) {
    const PinholeCamera lr(40, 30, 35.0, 36.0, 19.3, 14.1);
    const PinholeCamera hr = lr.Upscaled(scale);
    const Eigen::Vector3d point(0.11, -0.07, 1.0);
    const Eigen::Vector2d at_hr = hr.Project(point);
    // A smooth Gaussian blob: its centroid survives the box filter exactly.
    cv::Mat image(hr.height, hr.width, CV_64FC1);
    const double sigma = 2.0 * scale;
    for (int y = 0; y < image.rows; ++y) {
      for (int x = 0; x < image.cols; ++x) {
        const double dx = x - at_hr.x();
        const double dy = y - at_hr.y();
        image.at<double>(y, x) = std::exp(-(dx * dx + dy * dy) / (2 * sigma * sigma));
      }
    }
    cv::Mat small;
    cv::resize(image, small, cv::Size(lr.width, lr.height), 0, 0, cv::INTER_AREA);
    const cv::Moments moments = cv::moments(small);
    const Eigen::Vector2d centroid(moments.m10 / moments.m00, moments.m01 / moments.m00);
    const Eigen::Vector2d expected = lr.Project(point);
    EXPECT_LT((centroid - expected).norm(), 1e-6) << "scale " << scale;
    // The naive rule cx' = cx / s would be off by (s-1)/(2s) px.
    EXPECT_GT(std::abs(centroid.x() - (hr.cx / scale + hr.fx / scale * point.x() / point.z())), 0.2);
  }
}

TEST(PinholeCamera, ProblemNamesBadIntrinsics) {
  EXPECT_TRUE(PinholeCamera(10, 10, 5, 5, 5, 5).Problem().empty());
  EXPECT_FALSE(PinholeCamera(0, 10, 5, 5, 5, 5).Problem().empty());
  EXPECT_FALSE(PinholeCamera(10, 10, -5, 5, 5, 5).Problem().empty());
  EXPECT_FALSE(PinholeCamera(10, 10, 5, 5, NAN, 5).Problem().empty());
}

}  // namespace
}  // namespace deblur_sr_mvs
