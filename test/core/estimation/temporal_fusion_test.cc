// Temporal fusion of the restored images (temporal_fusion.h): registered
// neighbours with independent noise average it out, a neighbour that shows
// something else (occlusion, wrong geometry) leaves I_t alone, frames that
// land outside a neighbour keep I_t, radius 0 and held frames change nothing.
#include "deblur_sr_mvs/core/estimation/temporal_fusion.h"

#include <cmath>
#include <cstdio>
#include <functional>
#include <vector>

#include <gtest/gtest.h>

#include "deblur_sr_mvs/core/common/errors.h"

namespace deblur_sr_mvs {
namespace {

constexpr int kWidth = 80;
constexpr int kHeight = 60;
constexpr int kShiftPx = 2;  // image motion between consecutive frames
const PinholeCamera kCamera(kWidth, kHeight, 100.0, 100.0, 39.5, 29.5);

// A smooth, textured scene (intensity in [0.2, 0.8]) seen at column offset x0.
float Scene(int x, int y) {
  return 0.5f + 0.15f * std::sin(0.31f * x + 0.17f * y) + 0.15f * std::cos(0.23f * y - 0.11f * x);
}

// n cameras translating along x in front of a fronto-parallel plane at depth
// 1: frame k sees the scene shifted by k * kShiftPx pixels. Each frame gets
// its own Gaussian noise of `sigma`.
struct PlaneWindow {
  std::vector<cv::Mat> clean, noisy, depths;
  std::vector<SE3> T_world_cam;
};

PlaneWindow MakeWindow(int n, double sigma, int channels) {
  PlaneWindow window;
  cv::RNG rng(7);
  for (int k = 0; k < n; ++k) {
    cv::Mat clean(kHeight, kWidth, CV_32FC(channels));
    for (int y = 0; y < kHeight; ++y) {
      float* row = clean.ptr<float>(y);
      for (int x = 0; x < kWidth; ++x) {
        for (int c = 0; c < channels; ++c) row[x * channels + c] = Scene(x + k * kShiftPx, y) - 0.05f * c;
      }
    }
    cv::Mat noise(clean.size(), clean.type());
    rng.fill(noise, cv::RNG::NORMAL, cv::Scalar::all(0.0), cv::Scalar::all(sigma));
    window.clean.push_back(clean);
    window.noisy.push_back(clean + noise);
    window.depths.push_back(cv::Mat(kHeight, kWidth, CV_32FC1, cv::Scalar(1.0f)));
    // x_k = x_0 - k * shift: the camera moves by +shift / fx along x.
    window.T_world_cam.emplace_back(Eigen::Matrix3d::Identity(),
                                    Eigen::Vector3d(k * kShiftPx / kCamera.fx, 0.0, 0.0));
  }
  return window;
}

// RMS error (intensity) over the interior that every frame of the window sees.
double InteriorRms(const cv::Mat& image, const cv::Mat& truth) {
  const cv::Rect interior(4, 4, kWidth - 8 - 4 * kShiftPx, kHeight - 8);
  cv::Mat difference = image(interior) - truth(interior);
  return std::sqrt(cv::mean(difference.mul(difference))[0]);
}

TEST(TemporalFusion, AveragesTheIndependentNoiseOfRegisteredFrames) {
  for (int channels : {1, 3}) {
    const double sigma = 6.0 / 255.0;  // the restored images' noise at input sigma 2
    const PlaneWindow window = MakeWindow(5, sigma, channels);
    TemporalFusionOptions options;  // radius 2: frame 2 fuses all five
    const std::vector<cv::Mat> fused =
        FuseRestoredImages(kCamera, window.noisy, window.depths, window.T_world_cam, options, 0);
    const double before = InteriorRms(window.noisy[2], window.clean[2]);
    const double after = InteriorRms(fused[2], window.clean[2]);
    std::printf("%d channels: RMS error %.2f -> %.2f gray levels\n", channels, 255.0 * before, 255.0 * after);
    // Five frames: 1/sqrt(5) = 0.45 of the noise for equal weights; the
    // bicubic warp of a 2 px shift is exact on this smooth scene up to the
    // noise's own interpolation. Ask for less than 0.6.
    EXPECT_LT(after, 0.6 * before) << channels << " channels: " << before << " -> " << after;
  }
}

TEST(TemporalFusion, NoiseFreeRegisteredFramesStayAsTheyAre) {
  const PlaneWindow window = MakeWindow(5, 0.0, 3);
  const std::vector<cv::Mat> fused = FuseRestoredImages(kCamera, window.clean, window.depths,
                                                        window.T_world_cam, TemporalFusionOptions(), 0);
  EXPECT_LT(InteriorRms(fused[2], window.clean[2]), 0.5 / 255.0);
}

TEST(TemporalFusion, ANeighbourThatShowsSomethingElseIsLeftOut) {
  PlaneWindow window = MakeWindow(3, 0.0, 1);
  // Frame 0 and 2 show the inverted scene (an occluder, or wrong geometry):
  // the patch distance is ~0.3 intensity against h = 0.051.
  window.noisy[0] = 1.0 - window.clean[0];
  window.noisy[1] = window.clean[1];
  window.noisy[2] = 1.0 - window.clean[2];
  const std::vector<cv::Mat> fused = FuseRestoredImages(kCamera, window.noisy, window.depths,
                                                        window.T_world_cam, TemporalFusionOptions(), 0);
  EXPECT_LT(InteriorRms(fused[1], window.clean[1]), 1.0 / 255.0);
}

TEST(TemporalFusion, PixelsWithoutADepthOrOutsideTheNeighboursKeepTheirValue) {
  PlaneWindow window = MakeWindow(3, 3.0 / 255.0, 1);
  window.depths[1].colRange(0, 10).setTo(std::nanf(""));
  window.T_world_cam[0] = SE3(Eigen::Matrix3d::Identity(), Eigen::Vector3d(10.0, 0.0, 0.0));  // far away
  window.T_world_cam[2] = SE3(Eigen::Matrix3d::Identity(), Eigen::Vector3d(-10.0, 0.0, 0.0));
  const std::vector<cv::Mat> fused = FuseRestoredImages(kCamera, window.noisy, window.depths,
                                                        window.T_world_cam, TemporalFusionOptions(), 0);
  EXPECT_EQ(cv::norm(fused[1], window.noisy[1], cv::NORM_INF), 0.0);
}

TEST(TemporalFusion, RadiusZeroAndHeldFramesChangeNothing) {
  const PlaneWindow window = MakeWindow(4, 3.0 / 255.0, 3);
  TemporalFusionOptions off;
  off.radius = 0;
  const std::vector<cv::Mat> copies =
      FuseRestoredImages(kCamera, window.noisy, window.depths, window.T_world_cam, off, 0);
  const std::vector<cv::Mat> held = FuseRestoredImages(kCamera, window.noisy, window.depths,
                                                       window.T_world_cam, TemporalFusionOptions(), 2);
  for (int t = 0; t < 4; ++t) {
    EXPECT_EQ(cv::norm(copies[t], window.noisy[t], cv::NORM_INF), 0.0);
    if (t < 2) {
      EXPECT_EQ(cv::norm(held[t], window.noisy[t], cv::NORM_INF), 0.0);
    }
  }
  EXPECT_GT(cv::norm(held[2], window.noisy[2], cv::NORM_INF), 0.0);  // fused, the held frames lending
}

TEST(TemporalFusion, OptionsAreChecked) {
  EXPECT_NO_THROW(TemporalFusionOptions().Check());
  const std::vector<std::function<void(TemporalFusionOptions*)>> breakers = {
      [](TemporalFusionOptions* o) { o->patch_px = 4; },           // even
      [](TemporalFusionOptions* o) { o->radius = -1; },            // negative
      [](TemporalFusionOptions* o) { o->distance_scale = 0.0; }};  // no scale
  for (const auto& make_bad : breakers) {
    TemporalFusionOptions options;
    make_bad(&options);
    EXPECT_THROW(options.Check(), InputError);
  }
}

}  // namespace
}  // namespace deblur_sr_mvs
