// MidExposureToShutterClose: the initialiser's move of each frame's camera
// from mid-exposure (where the tracks of blurred frames put it) to its
// shutter close t_c, the stamp of the output poses.

#include <cmath>
#include <vector>

#include <gtest/gtest.h>
#include <Eigen/Geometry>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/estimation/initializer.h"
#include "deblur_sr_mvs/core/geometry/se3.h"

namespace deblur_sr_mvs {
namespace {

// Ten frames at 30 frames/s whose exposures change from frame to frame
// (auto-exposure), 0.5-0.9 of the interval.
std::vector<FrameRecord> Frames() {
  const double interval = 1.0 / 30.0;
  const double fractions[] = {0.8, 0.5, 0.9, 0.7, 0.8, 0.6, 0.9, 0.5, 0.8, 0.7};
  std::vector<FrameRecord> frames;
  for (int t = 0; t < 10; ++t) {
    FrameRecord frame;
    frame.index = t;
    frame.stamp = 0.1 + t * interval;
    frame.exposure = fractions[t] * interval;
    frames.push_back(frame);
  }
  return frames;
}

double MidExposure(const FrameRecord& frame) {
  return frame.stamp - 0.5 * frame.exposure;
}

template <typename Path>
std::vector<SE3> PosesAt(const std::vector<FrameRecord>& frames, const Path& path, bool mid_exposure) {
  std::vector<SE3> poses;
  for (const FrameRecord& frame : frames)
    poses.push_back(path(mid_exposure ? MidExposure(frame) : frame.stamp));
  return poses;
}

// A camera that accelerates along a line with a fixed orientation (a hand-held
// camera speeding up, like the synthesizer's hand-held path between its
// turns): 0.75 m/s at tau = 0.1 s, 6 m/s^2.
SE3 AcceleratingCamera(double tau) {
  const Eigen::Matrix3d R_world_cam =
      Eigen::AngleAxisd(0.2, Eigen::Vector3d(0.3, 1.0, 0.1).normalized()).toRotationMatrix();
  const double s = tau - 0.1;
  const Eigen::Vector3d direction = Eigen::Vector3d(1.0, 0.2, -0.1).normalized();
  return SE3(R_world_cam, Eigen::Vector3d(0.1, -0.05, 0.0) + (0.75 * s + 3.0 * s * s) * direction);
}

double PositionError(const SE3& a, const SE3& b) {
  return (a.translation() - b.translation()).norm();
}

double AngleError(const SE3& a, const SE3& b) {
  return Eigen::AngleAxisd(a.rotation().transpose() * b.rotation()).angle();
}

TEST(ShutterClose, AcceleratingCameraIsPlacedWhereItIsAtTheStamp) {
  const std::vector<FrameRecord> frames = Frames();
  const std::vector<SE3> T_world_cam =
      MidExposureToShutterClose(frames, PosesAt(frames, AcceleratingCamera, /*mid_exposure=*/true));
  const std::vector<SE3> truth = PosesAt(frames, AcceleratingCamera, /*mid_exposure=*/false);
  ASSERT_EQ(T_world_cam.size(), frames.size());
  // Every frame with a later neighbour follows the quadratic exactly.
  for (size_t t = 0; t + 1 < frames.size(); ++t) {
    EXPECT_LT(PositionError(T_world_cam[t], truth[t]), 1e-12) << "frame " << t;
    EXPECT_LT(AngleError(T_world_cam[t], truth[t]), 1e-12) << "frame " << t;
  }
  // The last frame extrapolates the geodesic through its predecessor's
  // mid-exposure: behind by (e / 2)(1 + e' / 2) a T^2 / 2 for its exposure
  // e and its predecessor's e' in intervals (0.7, 0.8), a = 6 m/s^2 and
  // T = 1/30 s: 1.63 mm; (e / 4 + e^2 / 8) a T^2 where the two are equal.
  const double interval = 1.0 / 30.0, e = 0.7, e_before = 0.8;
  const double lag = 0.5 * e * (1.0 + 0.5 * e_before) / 2.0 * 6.0 * interval * interval;
  EXPECT_NEAR(PositionError(T_world_cam.back(), truth.back()), lag, 0.02 * lag);
}

// A screw motion (constant linear and angular velocity: the lateral, arc and
// forward paths) is moved exactly at every frame, the last one included.
TEST(ShutterClose, ConstantVelocityIsExactForEveryFrame) {
  Vector6d twist;
  twist << 0.4, -0.1, 0.2, 0.3, -0.5, 0.2;  // per second: translation, then rotation
  const SE3 T_world_start(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0.0, 0.0, -1.0));
  const auto screw = [&](double tau) { return SE3::Exp(tau * twist) * T_world_start; };
  const std::vector<FrameRecord> frames = Frames();
  const std::vector<SE3> T_world_cam = MidExposureToShutterClose(frames, PosesAt(frames, screw, true));
  const std::vector<SE3> truth = PosesAt(frames, screw, false);
  for (size_t t = 0; t < frames.size(); ++t) {
    EXPECT_LT(PositionError(T_world_cam[t], truth[t]), 1e-9) << "frame " << t;
    EXPECT_LT(AngleError(T_world_cam[t], truth[t]), 1e-9) << "frame " << t;
  }
}

TEST(ShutterClose, TwoFramesUseTheGeodesic) {
  std::vector<FrameRecord> frames = Frames();
  frames.resize(2);
  Vector6d twist;
  twist << 0.4, 0.0, 0.1, 0.0, 0.3, 0.0;
  const auto screw = [&](double tau) { return SE3::Exp(tau * twist); };
  const std::vector<SE3> T_world_cam = MidExposureToShutterClose(frames, PosesAt(frames, screw, true));
  for (int t = 0; t < 2; ++t) EXPECT_LT(PositionError(T_world_cam[t], screw(frames[t].stamp)), 1e-9);
}

TEST(ShutterClose, WrongPoseCountIsAnInputError) {
  const std::vector<FrameRecord> frames = Frames();
  EXPECT_THROW(MidExposureToShutterClose(frames, std::vector<SE3>(3)), InputError);
  EXPECT_THROW(MidExposureToShutterClose({frames[0]}, std::vector<SE3>(1)), InputError);
}

}  // namespace
}  // namespace deblur_sr_mvs
