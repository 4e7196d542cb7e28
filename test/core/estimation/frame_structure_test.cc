// CrossBlurGeometry: the cross-blurred input pairs of the structure update
// (EstimatorOptions::cross_blurred_inputs) carry equal blur in both images;
// CaptureGeometryFrames: the poses a frame's capture geometry reads.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "deblur_sr_mvs/core/estimation/frame_structure.h"
#include "deblur_sr_mvs/core/imaging/capture_operator.h"

namespace deblur_sr_mvs {
namespace {

constexpr double kFrameInterval = 1.0 / 30.0;
constexpr double kExposure = 0.03;
constexpr double kFocal = 200.0;

// Three frames looking at a fronto-parallel plane at depth 1, translating
// along x by `positions` (world units), so that frame f sees the plane
// shifted by kFocal * positions[f] pixels; their velocities (hence blurs)
// differ.
std::vector<FrameStructure> PlaneFrames(const PinholeCamera& camera, const std::vector<double>& positions) {
  std::vector<FrameStructure> frames(positions.size());
  for (size_t f = 0; f < positions.size(); ++f) {
    frames[f].stamp = (f + 1) * kFrameInterval;
    frames[f].exposure = kExposure;
    frames[f].T_world_cam = SE3(Eigen::Matrix3d::Identity(), Eigen::Vector3d(positions[f], 0.0, 0.0));
    frames[f].depth_hr = cv::Mat(camera.height, camera.width, CV_32FC1, cv::Scalar(1.0f));
  }
  return frames;
}

// A smooth random texture, wider than the image by `margin` on each side.
cv::Mat Texture(int width, int height, int margin) {
  cv::Mat texture(height, width + 2 * margin, CV_32FC1);
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> uniform(0.0f, 1.0f);
  for (int y = 0; y < texture.rows; ++y) {
    for (int x = 0; x < texture.cols; ++x) texture.at<float>(y, x) = uniform(rng);
  }
  cv::GaussianBlur(texture, texture, cv::Size(0, 0), 1.5);
  return texture;
}

cv::Mat ApplyScaleOne(const CaptureGeometry& geometry, const cv::Mat& image) {
  CaptureOperatorOptions options;
  options.scale = 1;
  options.samples = 50;
  options.num_threads = 1;
  CaptureOperatorBuilder builder(options);
  CaptureOperator op;
  builder.Build(geometry, &op);
  cv::Mat out;
  op.Apply(image, &out);
  return out.reshape(1, image.rows);
}

// Mean |a(x) - b(x + shift)| over the columns [first, last) of every row.
double MeanShiftedDifference(const cv::Mat& a, const cv::Mat& b, int shift, int first, int last) {
  double sum = 0.0;
  int count = 0;
  for (int y = 0; y < a.rows; ++y) {
    for (int x = first; x < last; ++x) {
      sum += std::abs(a.at<float>(y, x) - b.at<float>(y, x + shift));
      ++count;
    }
  }
  return sum / count;
}

TEST(CrossBlurGeometry, OwnKernelIsTheFramesCapturePath) {
  const PinholeCamera camera(64, 48, kFocal, kFocal, 32.0, 24.0);
  const std::vector<FrameStructure> frames = PlaneFrames(camera, {0.0, 0.01, 0.04});
  for (int t = 0; t < 3; ++t) {
    const std::vector<SE3> own = VirtualCameraPoses(MakeCaptureGeometry(frames, camera, t, t), 9);
    const std::vector<SE3> cross = VirtualCameraPoses(CrossBlurGeometry(frames, camera, t, t), 9);
    ASSERT_EQ(own.size(), cross.size());
    for (size_t m = 0; m < own.size(); ++m) {
      EXPECT_NEAR((own[m].translation() - cross[m].translation()).norm(), 0.0, 1e-12);
      EXPECT_NEAR((own[m].rotation() - cross[m].rotation()).norm(), 0.0, 1e-12);
    }
  }
}

// The operator cache keys Psi_t[source] on the poses of CaptureGeometryFrames:
// moving any of those changes the geometry, moving any other frame does not
// (so a cached operator is never stale and never rebuilt for nothing).
TEST(CaptureGeometryFrames, ExactlyThePosesTheGeometryReads) {
  const PinholeCamera camera(64, 48, kFocal, kFocal, 32.0, 24.0);
  for (int num_frames : {2, 3, 5}) {
    std::vector<double> positions;
    for (int f = 0; f < num_frames; ++f) positions.push_back(0.01 * f + 0.002 * f * f);
    const std::vector<FrameStructure> frames = PlaneFrames(camera, positions);
    for (int t = 0; t < num_frames; ++t) {
      for (int source = 0; source < num_frames; ++source) {
        const std::vector<int> fixing = CaptureGeometryFrames(t, source, num_frames);
        EXPECT_EQ(fixing.front(), t);
        const CaptureGeometry geometry = MakeCaptureGeometry(frames, camera, t, source);
        for (int moved = 0; moved < num_frames; ++moved) {
          std::vector<FrameStructure> changed = frames;
          changed[moved].T_world_cam = SE3(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0.0, 1e-4, 0.0)) *
                                       changed[moved].T_world_cam;
          const bool reads = std::find(fixing.begin(), fixing.end(), moved) != fixing.end();
          EXPECT_EQ(!SameCaptureGeometry(geometry, MakeCaptureGeometry(changed, camera, t, source)), reads)
              << num_frames << " frames, t " << t << ", source " << source << ", moved " << moved;
        }
      }
    }
  }
}

// The exposure path of kernel_frame, seen from its own camera, is the path
// of the cross geometry seen from `frame`'s camera (moved rigidly), also
// for rotating cameras.
TEST(CrossBlurGeometry, MovesTheKernelFramesPathRigidly) {
  const PinholeCamera camera(64, 48, kFocal, kFocal, 32.0, 24.0);
  std::vector<FrameStructure> frames = PlaneFrames(camera, {0.0, 0.01, 0.04});
  Vector6d twist;
  twist << 0.01, -0.02, 0.005, 0.02, -0.01, 0.03;
  frames[1].T_world_cam = SE3::Exp(twist) * frames[1].T_world_cam;
  frames[2].T_world_cam = SE3::Exp(-2.0 * twist) * frames[2].T_world_cam;
  for (int a = 0; a < 3; ++a) {
    for (int b = 0; b < 3; ++b) {
      const std::vector<SE3> kernel = VirtualCameraPoses(MakeCaptureGeometry(frames, camera, b, b), 7);
      const std::vector<SE3> cross = VirtualCameraPoses(CrossBlurGeometry(frames, camera, a, b), 7);
      ASSERT_EQ(kernel.size(), cross.size());
      for (size_t m = 0; m < kernel.size(); ++m) {
        const SE3 in_kernel = frames[b].T_world_cam.Inverse() * kernel[m];
        const SE3 in_cross = frames[a].T_world_cam.Inverse() * cross[m];
        EXPECT_NEAR((in_kernel.translation() - in_cross.translation()).norm(), 0.0, 1e-9) << a << b << m;
        EXPECT_NEAR((in_kernel.rotation() - in_cross.rotation()).norm(), 0.0, 1e-9) << a << b << m;
      }
    }
  }
}

// Frames 1 and 2 move at 0.3 and 0.9 of a frame's shift per exposure (blur
// 1.8 and 5.4 px). Their inputs differ by more than the shift explains;
// each blurred by the other's blur they agree up to sampling.
TEST(CrossBlurGeometry, CrossBlurredPairCarriesEqualBlur) {
  const int width = 120, height = 40, margin = 20;
  const PinholeCamera camera(width, height, kFocal, kFocal, 60.0, 20.0);
  const std::vector<double> positions = {0.0, 0.01, 0.04};  // shifts 0, 2, 8 px
  const std::vector<FrameStructure> frames = PlaneFrames(camera, positions);
  const cv::Mat texture = Texture(width, height, margin);
  std::vector<cv::Mat> blurred(3);
  for (int f = 0; f < 3; ++f) {
    const int shift = static_cast<int>(std::lround(kFocal * positions[f]));
    const cv::Mat latent = texture(cv::Rect(margin + shift, 0, width, height)).clone();
    blurred[f] = ApplyScaleOne(MakeCaptureGeometry(frames, camera, f, f), latent);
  }
  const cv::Mat cross_12 = ApplyScaleOne(CrossBlurGeometry(frames, camera, 1, 2), blurred[1]);
  const cv::Mat cross_21 = ApplyScaleOne(CrossBlurGeometry(frames, camera, 2, 1), blurred[2]);
  // Frame 2 sees at x what frame 1 sees at x + 6.
  const double plain = MeanShiftedDifference(blurred[2], blurred[1], 6, 15, width - 21);
  const double cross = MeanShiftedDifference(cross_21, cross_12, 6, 15, width - 21);
  std::printf("mean |difference|: plain inputs %.5f, cross-blurred %.5f\n", plain, cross);
  EXPECT_GT(plain, 0.005);  // the blurs differ visibly
  EXPECT_LT(cross, 0.2 * plain);
}

}  // namespace
}  // namespace deblur_sr_mvs
