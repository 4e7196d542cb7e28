#include "deblur_sr_mvs/core/estimation/initializer.h"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <functional>
#include <iostream>
#include <optional>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <Eigen/Geometry>
#include <opencv2/imgproc.hpp>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/evaluation/metrics.h"
#include "deblur_sr_mvs/core/geometry/pose_prior.h"
#include "deblur_sr_mvs/core/evaluation/synthesizer.h"
#include "deblur_sr_mvs/core/imaging/image_ops.h"
#include "deblur_sr_mvs/core/io/sequence_io.h"

namespace deblur_sr_mvs {
namespace {

namespace fs = std::filesystem;

// A 5-frame Dolls sequence (default lateral path, severe blur: ~7 LR px per
// exposure, scale 2) made by the synthesizer tool. ctest runs every TEST in
// its own process, so the sequence is cached in the temp folder under a name
// keyed by the tool binary (a rebuilt tool makes a new one), written to a
// private folder first and renamed into place (parallel ctest runs).
const Sequence& DollsSequence() {
  static const Sequence sequence = [] {
    const std::string tool = std::string(DSM_TOOL_DIR) + "/synthesize_sequence";
    std::error_code error;
    const auto stamp = fs::last_write_time(tool, error).time_since_epoch().count();
    const fs::path folder =
        fs::path(::testing::TempDir()) / ("dsm_initializer_dolls5_" + std::to_string(stamp) + "_" +
                                          std::to_string(fs::file_size(tool, error)));
    if (!fs::exists(folder / "frames.csv")) {
      const fs::path scratch = folder.string() + ".tmp" + std::to_string(::getpid());
      const std::string command = tool + " --scene " + std::string(DSM_SOURCE_DIR) +
                                  "/data/middlebury/Dolls --output " + scratch.string() +
                                  " --frames 5 --subframes 60 >/dev/null 2>&1";
      if (std::system(command.c_str()) != 0) {
        ADD_FAILURE() << "synthesize_sequence failed: " << command;
        return Sequence();
      }
      fs::rename(scratch, folder, error);  // fails harmlessly when another run won
      fs::remove_all(scratch, error);
    }
    return ReadSequence(folder.string(), /*read_ground_truth=*/true);
  }();
  return sequence;
}

std::vector<cv::Mat> FloatImages(const Sequence& sequence) {
  std::vector<cv::Mat> images;
  for (const cv::Mat& image : sequence.images) images.push_back(ToFloat01(image));
  return images;
}

const InitialStructure& DollsResult() {
  static const InitialStructure result = [] {
    const Sequence& sequence = DollsSequence();
    return InitializeStructure(FloatImages(sequence), sequence.calibration.camera, sequence.frames,
                               InitializerOptions());
  }();
  return result;
}

// Mean relative depth error (paper's metric: median scale alignment, 70 %
// centre crop) of LR depths up-sampled bicubically to the HR ground truth.
double MeanDepthError(const std::vector<cv::Mat>& depth_lr, const Sequence& sequence) {
  DepthMetricOptions options;
  options.crop_fraction = 0.7;
  double sum = 0.0;
  for (size_t t = 0; t < depth_lr.size(); ++t) {
    const cv::Mat& truth = sequence.ground_truth->depth[t];
    cv::Mat upsampled;
    cv::resize(depth_lr[t], upsampled, truth.size(), 0, 0, cv::INTER_CUBIC);
    sum += EvaluateDepth(upsampled, truth, options).relative_error;
  }
  return sum / depth_lr.size();
}

// Median of the valid (> 0) values of all the depth maps.
double MedianDepth(const std::vector<cv::Mat>& depth_lr) {
  std::vector<float> values;
  for (const cv::Mat& depth : depth_lr) {
    for (auto it = depth.begin<float>(); it != depth.end<float>(); ++it) {
      if (*it > 0.0f) values.push_back(*it);
    }
  }
  if (values.empty()) return 0.0;
  std::nth_element(values.begin(), values.begin() + values.size() / 2, values.end());
  return values[values.size() / 2];
}

void ExpectOneLine(const std::string& message) {
  EXPECT_FALSE(message.empty());
  EXPECT_EQ(message.find('\n'), std::string::npos) << message;
}

template <typename Error>
void ExpectThrowsWith(const std::function<void()>& call, const std::string& part) {
  try {
    call();
    ADD_FAILURE() << "expected an error mentioning '" << part << "'";
  } catch (const Error& error) {
    const std::string message = error.what();
    ExpectOneLine(message);
    EXPECT_NE(message.find(part), std::string::npos) << message;
  }
}

TEST(InitializerTest, RecoversTrajectoryWithUnitMedianDepth) {
  const Sequence& sequence = DollsSequence();
  ASSERT_EQ(sequence.images.size(), 5u);
  const InitialStructure& result = DollsResult();
  ASSERT_EQ(result.T_world_cam.size(), 5u);

  // Gauge: world = camera 0 at t_c, median of all valid LR depths 1.
  EXPECT_LT(result.T_world_cam[0].Log().norm(), 1e-9);
  EXPECT_NEAR(MedianDepth(result.depth_lr), 1.0, 1e-6);

  // Positions after Sim(3) alignment. Measured: 0.46 % of the path on this
  // sequence, 0.3-0.6 % on the four 10-frame scenes.
  std::vector<Eigen::Vector3d> estimate, truth;
  double path = 0.0;
  for (size_t t = 0; t < result.T_world_cam.size(); ++t) {
    estimate.push_back(result.T_world_cam[t].translation());
    truth.push_back(sequence.ground_truth->poses[t].T_world_cam.translation());
    if (t > 0) path += (truth[t] - truth[t - 1]).norm();
  }
  EXPECT_LT(AbsoluteTrajectoryRmse(estimate, truth), 0.03 * path);

  // Orientations relative to frame 0. Measured <= 0.03 deg; a reconstruction
  // that takes the sideways motion for a pan (the narrow-field ambiguity the
  // rotation prior resolves) is off by ~0.8 deg per frame.
  const SE3& T_world0 = sequence.ground_truth->poses[0].T_world_cam;
  for (size_t t = 1; t < result.T_world_cam.size(); ++t) {
    const Eigen::Matrix3d R_true =
        (T_world0.Inverse() * sequence.ground_truth->poses[t].T_world_cam).rotation();
    const double angle = Eigen::AngleAxisd(result.T_world_cam[t].rotation().transpose() * R_true).angle();
    EXPECT_LT(angle * 180.0 / M_PI, 0.3) << "frame " << t;
  }

  for (const char* stage :
       {"tracking", "pair: frames 0-1", "two-view", "bundle adjustment", "depth", "gauge", "total"}) {
    EXPECT_NE(result.summary.find(stage), std::string::npos) << result.summary;
  }
}

// The sparse part alone (what EstimateInWindows ties long sequences to):
// the trajectory of InitializeStructure, which runs the same sparse part,
// up to the scale; its own scale (the median depth of the triangulated
// points) puts the scene at about the dense depths' median.
TEST(InitializerTest, TrajectoryAloneIsTheStructuresUpToScale) {
  const Sequence& sequence = DollsSequence();
  const InitialStructure& structure = DollsResult();
  const InitialTrajectory trajectory = InitializeTrajectory(
      FloatImages(sequence), sequence.calibration.camera, sequence.frames, InitializerOptions());
  ASSERT_EQ(trajectory.T_world_cam.size(), structure.T_world_cam.size());
  EXPECT_LT(trajectory.T_world_cam[0].Log().norm(), 1e-9);
  const size_t last = structure.T_world_cam.size() - 1;
  const double scale =
      trajectory.T_world_cam[last].translation().norm() / structure.T_world_cam[last].translation().norm();
  std::cout << "point-depth gauge / dense-depth gauge: " << scale << "\n";
  EXPECT_GT(scale, 0.8);
  EXPECT_LT(scale, 1.25);
  for (size_t t = 1; t <= last; ++t) {
    const Eigen::Matrix3d R =
        structure.T_world_cam[t].rotation().transpose() * trajectory.T_world_cam[t].rotation();
    EXPECT_LT(Eigen::AngleAxisd(R).angle(), 1e-6) << "frame " << t;
    EXPECT_LT(
        (trajectory.T_world_cam[t].translation() - scale * structure.T_world_cam[t].translation()).norm(),
        1e-6 * trajectory.T_world_cam[last].translation().norm())
        << "frame " << t;
  }
  EXPECT_NE(trajectory.summary.find("median point depth 1"), std::string::npos) << trajectory.summary;
  EXPECT_EQ(trajectory.summary.find("depth pass"), std::string::npos)
      << "no dense stage: " << trajectory.summary;
  ExpectThrowsWith<InputError>(
      [&] {
        InitializeTrajectory(FloatImages(sequence), sequence.calibration.camera, sequence.frames,
                             InitializerOptions(), -1.0);
      },
      "readout_time");
}

TEST(InitializerTest, RecoversDepth) {
  const Sequence& sequence = DollsSequence();
  const InitialStructure& result = DollsResult();
  ASSERT_EQ(result.depth_lr.size(), 5u);
  const cv::Size lr_size(sequence.calibration.camera.width, sequence.calibration.camera.height);
  for (const cv::Mat& depth : result.depth_lr) {
    ASSERT_EQ(depth.type(), CV_32FC1);
    ASSERT_EQ(depth.size(), lr_size);
    int valid = 0;
    for (int y = 0; y < depth.rows; ++y) {
      for (int x = 0; x < depth.cols; ++x) valid += depth.at<float>(y, x) > 0.0f ? 1 : 0;
    }
    EXPECT_GT(valid, 0.99 * depth.total());
  }
  // Measured 0.018 here (0.010-0.032 on the four 10-frame scenes); the paper
  // reports 0.034-0.056 on Dolls after its full optimisation. Dolls is
  // shallow: the median depth everywhere already scores 0.064, so the bound
  // is ~2x the measurement and the estimate must also remove most of the
  // error of that constant map.
  const double error = MeanDepthError(result.depth_lr, sequence);
  EXPECT_LT(error, 0.035);
  std::vector<cv::Mat> constant;
  for (const cv::Mat& depth : result.depth_lr) {
    std::vector<float> values(depth.begin<float>(), depth.end<float>());
    std::nth_element(values.begin(), values.begin() + values.size() / 2, values.end());
    constant.push_back(cv::Mat(depth.size(), CV_32FC1, cv::Scalar(values[values.size() / 2])));
  }
  EXPECT_LT(error, 0.5 * MeanDepthError(constant, sequence));
}

TEST(InitializerTest, GrayFramesAndTwoFramesWork) {
  const Sequence& sequence = DollsSequence();
  std::vector<cv::Mat> gray;
  for (int t = 0; t < 2; ++t) {
    cv::Mat converted;
    cv::cvtColor(ToFloat01(sequence.images[t]), converted, cv::COLOR_BGR2GRAY);
    gray.push_back(converted);
  }
  const std::vector<FrameRecord> frames(sequence.frames.begin(), sequence.frames.begin() + 2);
  const InitialStructure result =
      InitializeStructure(gray, sequence.calibration.camera, frames, InitializerOptions());
  ASSERT_EQ(result.T_world_cam.size(), 2u);
  EXPECT_NEAR(MedianDepth(result.depth_lr), 1.0, 1e-6);
  // The ground truth moves along +x of camera 0.
  const Eigen::Vector3d direction = result.T_world_cam[1].translation().normalized();
  EXPECT_GT(direction.x(), 0.99);
  // Measured 0.013 (two frames, one neighbour each).
  EXPECT_LT(MeanDepthError(result.depth_lr, sequence), 0.035);
}

TEST(InitializerTest, UntexturedFramesGiveInitializationError) {
  const Sequence& sequence = DollsSequence();
  const PinholeCamera& camera = sequence.calibration.camera;
  for (const double value : {0.0, 0.5}) {
    const std::vector<cv::Mat> blank(3,
                                     cv::Mat(camera.height, camera.width, CV_32FC3, cv::Scalar::all(value)));
    const std::vector<FrameRecord> frames(sequence.frames.begin(), sequence.frames.begin() + 3);
    ExpectThrowsWith<InitializationError>(
        [&] { InitializeStructure(blank, camera, frames, InitializerOptions()); }, "features");
  }
}

TEST(InitializerTest, UnrelatedFramesGiveInitializationError) {
  const Sequence& sequence = DollsSequence();
  const PinholeCamera& camera = sequence.calibration.camera;
  std::vector<cv::Mat> noise;
  cv::RNG rng(7);
  for (int t = 0; t < 3; ++t) {
    cv::Mat image(camera.height, camera.width, CV_32FC3);
    rng.fill(image, cv::RNG::UNIFORM, 0.0, 1.0);
    cv::GaussianBlur(image, image, cv::Size(5, 5), 1.5);  // corners, but nothing to track
    noise.push_back(image);
  }
  const std::vector<FrameRecord> frames(sequence.frames.begin(), sequence.frames.begin() + 3);
  // Lucas-Kanade follows some blurred-noise corners consistently forward and
  // backward (OpenCV's tracker ~100 of 600, the earlier hand-written one ~50),
  // so a pair fails on too few tracks or points that triangulate, or a pair
  // passes and another frame then fails PnP ("frame 0 sees only 4
  // triangulated points" here): a one-line InitializationError either way,
  // and not a NoParallaxError (the noise tracks have parallax).
  try {
    InitializeStructure(noise, camera, frames, InitializerOptions());
    ADD_FAILURE() << "unrelated frames cannot be initialised";
  } catch (const NoParallaxError& error) {
    ADD_FAILURE() << "unrelated frames are not a pure rotation: " << error.what();
  } catch (const InitializationError& error) {
    ExpectOneLine(error.what());
    EXPECT_NE(std::string(error.what()).find("initialisation: "), std::string::npos) << error.what();
  }
}

// The frames carry no depth (the camera did not translate): initialisation
// must fail with a NoParallaxError of one line that says so.
void ExpectNoParallaxError(const std::vector<cv::Mat>& images, const PinholeCamera& camera,
                           const std::vector<FrameRecord>& frames, const std::string& what) {
  try {
    InitializeStructure(images, camera, frames, InitializerOptions());
    ADD_FAILURE() << what << " cannot be initialised";
  } catch (const NoParallaxError& error) {
    const std::string message = error.what();
    ExpectOneLine(message);
    // "no pair of the 3 frames has parallax: the best, frames 0-2, leaves
    // 0.041 px that no rotation explains (need 0.10 px); ..."
    EXPECT_NE(
        message.find("no pair of the " + std::to_string(images.size()) + " frames has parallax: the best, "),
        std::string::npos)
        << message;
    std::printf("%s: %s\n", what.c_str(), message.c_str());
  } catch (const InitializationError& error) {
    ADD_FAILURE() << what << ": expected NoParallaxError, got InitializationError: " << error.what();
  }
}

TEST(InitializerTest, StaticCameraGivesInitializationError) {
  const Sequence& sequence = DollsSequence();
  const std::vector<cv::Mat> images(3, ToFloat01(sequence.images[2]));
  const std::vector<FrameRecord> frames(sequence.frames.begin(), sequence.frames.begin() + 3);
  ExpectNoParallaxError(images, sequence.calibration.camera, frames, "a camera that does not move");
}

TEST(InitializerTest, PureRotationGivesInitializationError) {
  // Frames related by rotations only (homographies K R K^-1): no translation,
  // so no parallax and no depth. The initialiser must say so, not invent depth.
  const Sequence& sequence = DollsSequence();
  const PinholeCamera& camera = sequence.calibration.camera;
  const Eigen::Matrix3d K =
      (Eigen::Matrix3d() << camera.fx, 0, camera.cx, 0, camera.fy, camera.cy, 0, 0, 1).finished();
  const cv::Mat first = ToFloat01(sequence.images[2]);
  std::vector<cv::Mat> images;
  for (int t = 0; t < 3; ++t) {
    const Eigen::Matrix3d R =
        Eigen::AngleAxisd(0.01 * t, Eigen::Vector3d(0.2, 1.0, 0.1).normalized()).matrix();
    const Eigen::Matrix3d H = K * R * K.inverse();
    cv::Mat homography(3, 3, CV_64F);
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) homography.at<double>(r, c) = H(r, c);
    }
    cv::Mat warped;
    cv::warpPerspective(first, warped, homography, first.size(), cv::INTER_LINEAR, cv::BORDER_REFLECT);
    images.push_back(warped);
  }
  const std::vector<FrameRecord> frames(sequence.frames.begin(), sequence.frames.begin() + 3);
  ExpectNoParallaxError(images, camera, frames, "a purely rotating camera");
}

// A 6-frame Dolls sequence on a synthesizer path (default blur: 14 HR px
// per exposure, scale 2), made with the synthesizer API.
Sequence SixFrameDollsSequence(CameraPathType path) {
  SynthesisOptions options;
  options.path = path;
  options.num_frames = 6;
  options.subframes = 60;
  const StereoScene scene = LoadMiddleburyScene(std::string(DSM_SOURCE_DIR) + "/data/middlebury/Dolls");
  return SynthesizeSequence(scene, options).sequence;
}

// A camera turning about its centre (path `rotate`).
const Sequence& RotationSequence() {
  static const Sequence sequence = SixFrameDollsSequence(CameraPathType::kRotate);
  return sequence;
}

// Angle (deg) between an estimated R_world_cam (world = camera 0) and the
// ground truth's orientation of frame t relative to frame 0.
double RotationErrorDeg(const Sequence& sequence, const Eigen::Matrix3d& R_world_cam, size_t t) {
  const std::vector<StampedPose>& poses = sequence.ground_truth->poses;
  const Eigen::Matrix3d R_true =
      poses[0].T_world_cam.rotation().transpose() * poses[t].T_world_cam.rotation();
  return Eigen::AngleAxisd(R_world_cam.transpose() * R_true).angle() * 180.0 / M_PI;
}

TEST(RotationOnlyMotionTest, RecoversPureRotationWithinAFifthOfADegree) {
  const Sequence& sequence = RotationSequence();
  ASSERT_EQ(sequence.images.size(), 6u);
  const RotationOnlyMotion motion = EstimateRotationOnlyMotion(
      FloatImages(sequence), sequence.calibration.camera, sequence.frames, InitializerOptions());
  ASSERT_EQ(motion.R_world_cam.size(), 6u);
  EXPECT_LT(Eigen::AngleAxisd(motion.R_world_cam[0]).angle(), 1e-12);  // world = camera 0
  std::printf("%s\n", motion.summary.c_str());
  const std::vector<StampedPose>& poses = sequence.ground_truth->poses;
  for (size_t t = 1; t < motion.R_world_cam.size(); ++t) {
    const double error = RotationErrorDeg(sequence, motion.R_world_cam[t], t);
    const double turned =
        Eigen::AngleAxisd(poses[0].T_world_cam.rotation().transpose() * poses[t].T_world_cam.rotation())
            .angle();
    std::printf("frame %zu: turned %.3f deg, error %.4f deg\n", t, turned * 180.0 / M_PI, error);
    EXPECT_LE(error, 0.2) << "frame " << t;  // issue 11's target
  }
  for (const char* stage : {"tracking", "rotation 0-1", "total"}) {
    EXPECT_NE(motion.summary.find(stage), std::string::npos) << motion.summary;
  }
}

TEST(RotationOnlyMotionTest, InitializeStructureGivesNoParallaxError) {
  const Sequence& sequence = RotationSequence();
  ExpectNoParallaxError(FloatImages(sequence), sequence.calibration.camera, sequence.frames,
                        "a camera turning about its centre");
}

TEST(RotationOnlyMotionTest, UntexturedFramesGiveInitializationError) {
  const Sequence& sequence = DollsSequence();
  const PinholeCamera& camera = sequence.calibration.camera;
  const std::vector<cv::Mat> blank(3, cv::Mat(camera.height, camera.width, CV_32FC3, cv::Scalar::all(0.5)));
  const std::vector<FrameRecord> frames(sequence.frames.begin(), sequence.frames.begin() + 3);
  ExpectThrowsWith<InitializationError>(
      [&] { EstimateRotationOnlyMotion(blank, camera, frames, InitializerOptions()); }, "features");
}

// An initialisation against the ground truth: ATE as a fraction of the
// path length, the worst rotation error of frames 1.. (each printed) and the
// LR depth rel. error (MeanDepthError).
struct InitialAccuracy {
  double ate_of_path = 0.0, worst_rotation_deg = 0.0, depth_error = 0.0;
};

InitialAccuracy MeasureInitialAccuracy(const Sequence& sequence, const InitialStructure& result) {
  const std::vector<StampedPose>& poses = sequence.ground_truth->poses;
  std::vector<Eigen::Vector3d> estimate, truth;
  double path = 0.0;
  InitialAccuracy accuracy;
  for (size_t t = 0; t < poses.size(); ++t) {
    estimate.push_back(result.T_world_cam[t].translation());
    truth.push_back(poses[t].T_world_cam.translation());
    if (t == 0) continue;
    path += (truth[t] - truth[t - 1]).norm();
    const double error = RotationErrorDeg(sequence, result.T_world_cam[t].rotation(), t);
    std::printf("frame %zu: rotation error %.3f deg\n", t, error);
    accuracy.worst_rotation_deg = std::max(accuracy.worst_rotation_deg, error);
  }
  accuracy.ate_of_path = AbsoluteTrajectoryRmse(estimate, truth) / path;
  accuracy.depth_error = MeanDepthError(result.depth_lr, sequence);
  std::printf("ATE %.2f %% of the path, worst rotation error %.3f deg, depth rel. error %.4f\n",
              100.0 * accuracy.ate_of_path, accuracy.worst_rotation_deg, accuracy.depth_error);
  return accuracy;
}

// A Dolls clip that starts slowly, like a hand-held one: the camera turns
// all along (0.1 rad/s about a mostly vertical axis, ~2 LR px per frame),
// frames 0-2 share one centre, and from frame 2's shutter close on the centre
// follows the calibrated lateral path (default 14 HR px of blur). Made with
// the synthesizer's API: the lateral sequence fixes the path's speed and the
// cameras; each frame is the mean of 60 sub-frame renders over its exposure,
// box-downsampled by 2 to 8 bits, as the synthesizer makes its frames.
const Sequence& StillThenTranslatingSequence() {
  static const Sequence sequence = [] {
    const StereoScene scene = LoadMiddleburyScene(std::string(DSM_SOURCE_DIR) + "/data/middlebury/Dolls");
    SynthesisOptions options;
    options.num_frames = 7;
    options.subframes = 51;
    const SynthesisResult lateral = SynthesizeSequence(scene, options);
    const CameraPath& path = lateral.path;
    const double still_until = FrameStamp(options, 2);
    const Eigen::Vector3d turn = 0.1 * Eigen::Vector3d(0.3, 1.0, 0.0).normalized();  // rad/s
    auto pose_at = [&](double t) {
      return SE3(SO3Exp((t - path.t_mid) * turn) * path.T_world_mid.rotation(),
                 path.PoseAt(std::max(t, still_until)).translation());
    };
    const PinholeCamera& hr = lateral.hr_camera;
    Sequence result;
    result.calibration = lateral.sequence.calibration;
    result.ground_truth.emplace();
    result.ground_truth->calibration = lateral.sequence.ground_truth->calibration;
    const SceneRenderer renderer(scene);
    RenderWorkspace workspace;
    RenderResult render;
    const int subframes = 60;
    const double exposure = FrameExposure(options);
    for (int i = 0; i < options.num_frames; ++i) {
      const double t_close = FrameStamp(options, i);
      const double t_open = t_close - exposure;
      const SceneRenderer culled =
          renderer.CulledFor(hr, {pose_at(t_open), pose_at(t_close - 0.5 * exposure), pose_at(t_close)});
      cv::Mat sum(hr.height, hr.width, CV_32FC3, cv::Scalar::all(0.0));
      for (int k = 0; k < subframes; ++k) {
        culled.Render(hr, pose_at(t_open + (k + 0.5) / subframes * exposure), RenderOptions(), &workspace,
                      &render);
        sum += render.image;
      }
      culled.Render(hr, pose_at(t_close), RenderOptions(), &workspace, &render);
      cv::Mat low_res, image8;
      cv::resize(sum / subframes, low_res, cv::Size(hr.width / 2, hr.height / 2), 0.0, 0.0, cv::INTER_AREA);
      low_res.convertTo(image8, CV_8UC3);
      result.frames.push_back({i, t_close, exposure});
      result.images.push_back(image8);
      result.ground_truth->depth.push_back(render.depth.clone());
      result.ground_truth->poses.push_back({t_close, pose_at(t_close)});
    }
    return result;
  }();
  return sequence;
}

TEST(InitializerTest, StartsFromThePairWithParallax) {
  const Sequence& sequence = StillThenTranslatingSequence();
  const PinholeCamera& camera = sequence.calibration.camera;
  const std::vector<cv::Mat> images = FloatImages(sequence);
  // Frames 0-2 alone only turn: no pair of them has parallax.
  ExpectNoParallaxError({images.begin(), images.begin() + 3}, camera,
                        {sequence.frames.begin(), sequence.frames.begin() + 3}, "frames that only turn");

  const InitialStructure result = InitializeStructure(images, camera, sequence.frames, InitializerOptions());
  std::printf("%s\n", result.summary.c_str());
  ASSERT_EQ(result.T_world_cam.size(), 7u);
  EXPECT_EQ(result.summary.find("pair: frames 0-1"), std::string::npos) << result.summary;
  EXPECT_LT(result.T_world_cam[0].Log().norm(), 1e-9);
  EXPECT_NEAR(MedianDepth(result.depth_lr), 1.0, 1e-6);

  const InitialAccuracy accuracy = MeasureInitialAccuracy(sequence, result);
  // Measured: pair 2-3 (0.49 px of rotation-free parallax), ATE 1.25 % of
  // the path (the lateral Dolls test's bound, 3 %, holds), depth rel. error
  // 0.035 (lateral 5-frame Dolls: 0.018). The orientation errors grow by
  // ~0.19 deg per frame (0.07 at frame 1, 0.92 at frame 6): the true turn,
  // ~2 LR px per frame, is mostly taken for sideways motion, the narrow-field
  // ambiguity that RotationPrior (rotation_prior_px = 1 px per frame) settles
  // towards the least rotation; the positions absorb it. Guarded at ~1.5x.
  EXPECT_LT(accuracy.ate_of_path, 0.03);
  EXPECT_LT(accuracy.depth_error, 0.05);
  EXPECT_LT(accuracy.worst_rotation_deg, 1.5);
}

// A camera on an arc that keeps looking at a point twice the median scene
// depth ahead (path `arc`).
const Sequence& ArcSequence() {
  static const Sequence sequence = SixFrameDollsSequence(CameraPathType::kArc);
  return sequence;
}

double MeanRotationErrorDeg(const Sequence& sequence, const InitialStructure& result) {
  double sum = 0.0;
  for (size_t t = 1; t < result.T_world_cam.size(); ++t) {
    sum += RotationErrorDeg(sequence, result.T_world_cam[t].rotation(), t);
  }
  return sum / (result.T_world_cam.size() - 1);
}

// The initialisation of `sequence` with `base` options and one with `change`
// applied to them, with their mean rotation errors (deg) and depth rel.
// errors.
struct InitialisationPair {
  InitialStructure plain, changed;
  double plain_rotation = 0.0, changed_rotation = 0.0, plain_depth = 0.0, changed_depth = 0.0;
};

InitialisationPair InitialiseTwice(const Sequence& sequence,
                                   const std::function<void(InitializerOptions*)>& change,
                                   const InitializerOptions& base = InitializerOptions()) {
  const std::vector<cv::Mat> images = FloatImages(sequence);
  const PinholeCamera& camera = sequence.calibration.camera;
  InitialisationPair pair;
  pair.plain = InitializeStructure(images, camera, sequence.frames, base, sequence.readout_time);
  InitializerOptions options = base;
  change(&options);
  pair.changed = InitializeStructure(images, camera, sequence.frames, options, sequence.readout_time);
  pair.plain_rotation = MeanRotationErrorDeg(sequence, pair.plain);
  pair.changed_rotation = MeanRotationErrorDeg(sequence, pair.changed);
  pair.plain_depth = MeanDepthError(pair.plain.depth_lr, sequence);
  pair.changed_depth = MeanDepthError(pair.changed.depth_lr, sequence);
  return pair;
}

// Prints the plain run's summary and both runs' errors.
void PrintPair(const InitialisationPair& pair, const std::string& changed_label) {
  std::printf("%s\nmean rotation error %.3f deg (%s: %.3f deg), depth rel. error %.4f (%.4f)\n",
              pair.plain.summary.c_str(), pair.plain_rotation, changed_label.c_str(), pair.changed_rotation,
              pair.plain_depth, pair.changed_depth);
}

// A clip of `num_frames` frames with noise sigma 1 of `scene_name` on `path`
// (seed, readout ratio and sub-frames per exposure as given), made with the
// synthesizer API as `synthesize_sequence` makes it.
Sequence NoisyClip(const std::string& scene_name, CameraPathType path, std::uint64_t seed,
                   double readout_ratio, int num_frames, int subframes) {
  SynthesisOptions synthesis;
  synthesis.path = path;
  synthesis.num_frames = num_frames;
  synthesis.subframes = subframes;
  synthesis.noise_sigma = 1.0;
  synthesis.seed = seed;
  synthesis.readout_ratio = readout_ratio;
  const StereoScene scene =
      LoadMiddleburyScene(std::string(DSM_SOURCE_DIR) + "/data/middlebury/" + scene_name);
  return SynthesizeSequence(scene, synthesis).sequence;
}

// The benchmark's clips: 10 frames, 200 sub-frames per exposure.
Sequence TenFrameSequence(const std::string& scene_name, CameraPathType path, std::uint64_t seed,
                          double readout_ratio) {
  return NoisyClip(scene_name, path, seed, readout_ratio, 10, SynthesisOptions().subframes);
}

// InitializerOptions::track_consistency_z: an 8-frame lateral Aloe clip with
// sensor noise (sigma 1 gray level), where Lucas-Kanade tracks slide along
// the leaves' edges. Measured when the test was written: 94 tracks left out
// of the adjustment; mean rotation error 0.056 deg against 1.121 without
// the test, LR depth rel. error 0.0266 against 0.0447 (the tool's clip of
// the same arguments, `estimate_sequence --iterations 0`: 0.46 against 0.97
// deg, ATE 0.42 against 0.56 mm).
TEST(InitializerTest, TracksThatFollowNoPointLeaveTheAdjustment) {
  const Sequence sequence = NoisyClip("Aloe", CameraPathType::kLateral, 3, 0.0, 8, 60);
  const InitialisationPair pair =
      InitialiseTwice(sequence, [](InitializerOptions* o) { o->track_consistency_z = 0.0; });
  PrintPair(pair, "without the test");
  EXPECT_NE(pair.plain.summary.find("tracks follow no point"), std::string::npos) << pair.plain.summary;
  EXPECT_EQ(pair.changed.summary.find("track consistency"), std::string::npos) << pair.changed.summary;
  // At least a quarter of the rotation error and a tenth of the depth error go.
  EXPECT_LT(pair.plain_rotation, 0.75 * pair.changed_rotation);
  EXPECT_LT(pair.plain_depth, 0.9 * pair.changed_depth);
}

TEST(InitializerTest, ArcPathTurnIsNotTakenForSidewaysMotion) {
  const Sequence& sequence = ArcSequence();
  const InitialisationPair pair =
      InitialiseTwice(sequence, [](InitializerOptions* towards_no_rotation) {
        towards_no_rotation->fixation_prior = false;
      });
  const InitialStructure& fixation = pair.plain;
  const double error = pair.plain_rotation;
  const double still_error = pair.changed_rotation;
  const double depth_error = pair.plain_depth;
  const double still_depth_error = pair.changed_depth;
  std::printf(
      "%s\nmean rotation error %.3f deg (prior towards no rotation: %.3f deg), depth rel. error "
      "%.4f (%.4f)\n",
      fixation.summary.c_str(), error, still_error, depth_error, still_depth_error);
  EXPECT_NE(fixation.summary.find("median depths lowers the reprojection cost"), std::string::npos);
  EXPECT_NE(fixation.summary.find("): kept"), std::string::npos) << fixation.summary;
  // Measured: 0.352 deg, depth 0.0138 (towards no rotation: 2.295 deg,
  // 0.0702); the turn is fitted at 1.83 median depths (the path: 2).
  EXPECT_LT(error, 0.5);
  EXPECT_GT(still_error, 1.0);
  EXPECT_LT(depth_error, still_depth_error);
}

// The ground-truth poses of `sequence` as a pose prior (T_prior_cam at the
// frame stamps), frames `bad` moved by `offset` (m) along x.
std::vector<std::optional<SE3>> GroundTruthPrior(const Sequence& sequence, const std::vector<int>& bad = {},
                                                 double offset = 0.0) {
  std::vector<std::optional<SE3>> prior;
  for (const StampedPose& pose : sequence.ground_truth->poses) prior.push_back(pose.T_world_cam);
  for (int t : bad) {
    prior[t] = SE3(prior[t]->rotation(), prior[t]->translation() + Eigen::Vector3d(offset, 0.0, 0.0));
  }
  return prior;
}

// Depth in metres with no per-frame scale: the structure carried into the
// ground truth's frame by the robust Sim(3) of its poses onto the true ones
// (as estimate_sequence --pose-prior does), then the mean depth rel. error
// (70 % centre crop) against the ground truth. *aligned: the same with each
// frame's depth scaled by its median ratio (MeanDepthError).
double MetricDepthError(const InitialStructure& result, const Sequence& sequence, double* aligned) {
  std::vector<SE3> truth;
  for (const StampedPose& pose : sequence.ground_truth->poses) truth.push_back(pose.T_world_cam);
  const PriorAlignment alignment = AlignToPrior(result.T_world_cam, truth, PosePriorOptions());
  EXPECT_TRUE(alignment.valid) << alignment.note;
  DepthMetricOptions options;
  options.crop_fraction = 0.7;
  options.align_scale = false;
  double sum = 0.0;
  for (size_t t = 0; t < result.depth_lr.size(); ++t) {
    const cv::Mat& depth_truth = sequence.ground_truth->depth[t];
    cv::Mat upsampled;
    cv::resize(result.depth_lr[t] * alignment.estimate_to_prior.scale, upsampled, depth_truth.size(), 0, 0,
               cv::INTER_CUBIC);
    sum += EvaluateDepth(upsampled, depth_truth, options).relative_error;
  }
  *aligned = MeanDepthError(result.depth_lr, sequence);
  return sum / result.depth_lr.size();
}

TEST(InitializerTest, ArcPathWithAPosePriorHasDepthInMetres) {
  const Sequence& sequence = ArcSequence();
  const std::vector<cv::Mat> images = FloatImages(sequence);
  const PinholeCamera& camera = sequence.calibration.camera;
  InitializerOptions alignment_only;
  alignment_only.pose_prior_position_sigma = 0.0;
  const std::vector<std::optional<SE3>> exact = GroundTruthPrior(sequence);
  // Frames 1 and 4 of the prior 20 cm off (the path is 24 cm long).
  const std::vector<std::optional<SE3>> bad = GroundTruthPrior(sequence, {1, 4}, 0.2);
  const InitialStructure without =
      InitializeStructure(images, camera, sequence.frames, alignment_only, 0.0, exact);
  const InitialStructure with = InitializeStructure(images, camera, sequence.frames, InitializerOptions(), 0.0, exact);
  const InitialStructure with_bad =
      InitializeStructure(images, camera, sequence.frames, InitializerOptions(), 0.0, bad);
  double aligned_without = 0.0, aligned_with = 0.0, aligned_bad = 0.0;
  const double metric_without = MetricDepthError(without, sequence, &aligned_without);
  const double metric_with = MetricDepthError(with, sequence, &aligned_with);
  const double metric_bad = MetricDepthError(with_bad, sequence, &aligned_bad);
  std::printf("%s\n", with.summary.c_str());
  std::printf(
      "depth rel. error in metres / scale-aligned: prior only aligning %.4f / %.4f (%.2f), in the bundle "
      "adjustment %.4f / %.4f (%.2f), with 2 bad prior poses %.4f / %.4f (%.2f); mean rotation error "
      "%.3f, %.3f, %.3f deg\n",
      metric_without, aligned_without, metric_without / aligned_without, metric_with, aligned_with,
      metric_with / aligned_with, metric_bad, aligned_bad, metric_bad / aligned_bad,
      MeanRotationErrorDeg(sequence, without), MeanRotationErrorDeg(sequence, with),
      MeanRotationErrorDeg(sequence, with_bad));
  EXPECT_NE(with.summary.find("pose prior: Sim(3) scale"), std::string::npos) << with.summary;
  EXPECT_NE(with_bad.summary.find("from 4 of 6 frames"), std::string::npos) << with_bad.summary;
  // The criterion: metres within 10 % of the scale-aligned figure.
  EXPECT_LE(metric_with, 1.1 * aligned_with);
  EXPECT_LE(metric_bad, 1.1 * aligned_bad);
  EXPECT_GT(metric_without, 2.0 * aligned_without);  // what the prior in the adjustment changes
  EXPECT_LT(MeanRotationErrorDeg(sequence, with), 0.5 * MeanRotationErrorDeg(sequence, without));
}

TEST(InitializerTest, WrongNumberOfPriorPosesIsAnInputError) {
  const Sequence& sequence = ArcSequence();
  const std::vector<std::optional<SE3>> prior(2, SE3());
  ExpectThrowsWith<InputError>(
      [&] {
        InitializeStructure(FloatImages(sequence), sequence.calibration.camera, sequence.frames,
                            InitializerOptions(), 0.0, prior);
      },
      "2 pose prior entries for 6 frames");
}

TEST(InitializerTest, LateralPathKeepsThePriorTowardsNoRotation) {
  const InitialStructure& result = DollsResult();
  EXPECT_NE(result.summary.find("): no turn"), std::string::npos) << result.summary;
}

// With a turn test that keeps no turn the output is the default's (the test
// only decides; the bundle adjustment's threads reorder sums at the 1e-16
// level, hence 1e-12). `next`: the summary line after the test's.
void ExpectTheLateralPathsStructure(const std::function<void(InitializerOptions*)>& change,
                                    const std::string& test_name, const std::string& next) {
  const Sequence& sequence = DollsSequence();
  InitializerOptions options;
  change(&options);
  const InitialStructure tested =
      InitializeStructure(FloatImages(sequence), sequence.calibration.camera, sequence.frames, options);
  const InitialStructure& plain = DollsResult();
  std::printf("%s\n", tested.summary.c_str());
  EXPECT_NE(tested.summary.find(test_name), std::string::npos) << tested.summary;
  EXPECT_NE(tested.summary.find("): no turn\n" + next), std::string::npos) << tested.summary;
  ASSERT_EQ(tested.T_world_cam.size(), plain.T_world_cam.size());
  for (size_t t = 0; t < plain.T_world_cam.size(); ++t) {
    EXPECT_LT((tested.T_world_cam[t].Matrix() - plain.T_world_cam[t].Matrix()).norm(), 1e-12) << t;
    EXPECT_LT(cv::norm(tested.depth_lr[t], plain.depth_lr[t], cv::NORM_INF), 1e-5) << t;
  }
}

// InitializerOptions::dense_fixation_test (a second depth stage only decides).
TEST(InitializerTest, DenseTurnTestKeepsTheLateralPathsStructure) {
  ExpectTheLateralPathsStructure([](InitializerOptions* o) { o->dense_fixation_test = true; },
                                 "dense turn test", "gauge");
}

// InitializerOptions::flow_fixation_test (the flow only decides).
TEST(InitializerTest, FlowTurnTestKeepsTheLateralPathsStructure) {
  ExpectTheLateralPathsStructure([](InitializerOptions* o) { o->flow_fixation_test = true; }, "flow turn test",
                                 "poses moved");
}

// InitializerOptions::flow_test_min_gap / flow_test_max_gap: every pair of
// the 5-frame window (a longest gap beyond the window is the window's), and
// no pair at all (a shortest gap the window does not have: no sample, no
// turn); either way the test only decides.
TEST(InitializerTest, FlowTurnTestOfAllGapsKeepsTheLateralPathsStructure) {
  ExpectTheLateralPathsStructure(
      [](InitializerOptions* o) {
        o->flow_fixation_test = true;
        o->flow_test_max_gap = 99;
      },
      "10 pairs of gaps 1-4", "poses moved");
}

TEST(InitializerTest, FlowTurnTestWithoutPairsKeepsNoTurn) {
  ExpectTheLateralPathsStructure(
      [](InitializerOptions* o) {
        o->flow_fixation_test = true;
        o->flow_test_min_gap = 5;
        o->flow_test_max_gap = 5;
      },
      "over 0 tiles, bound inf; 0 pairs", "poses moved");
}

// An arc around a scene of little depth range (Aloe, the fixation point
// twice the median depth away, noise 1): the tracks leave the turn open, a
// turn test decides it. Returns the test's summary and errors, beside the
// default's. Both with track_consistency_z 0: with the inconsistent tracks
// left out, the tracks find this turn themselves (202.9 sigma^2, bound 18.9;
// mean rotation error 0.334 deg), and the turn tests have nothing to decide.
InitialisationPair ArcTurnTest(const std::function<void(InitializerOptions*)>& change,
                               const std::string& test_name) {
  SynthesisOptions synthesis;
  synthesis.path = CameraPathType::kArc;
  synthesis.num_frames = 6;
  synthesis.subframes = 60;
  synthesis.noise_sigma = 1.0;
  const StereoScene scene = LoadMiddleburyScene(std::string(DSM_SOURCE_DIR) + "/data/middlebury/Aloe");
  const Sequence sequence = SynthesizeSequence(scene, synthesis).sequence;
  InitializerOptions base;
  base.track_consistency_z = 0.0;
  InitialisationPair pair = InitialiseTwice(sequence, change, base);
  std::printf("%s\nmean rotation error %.3f deg (tracks only: %.3f deg), depth rel. error %.4f (%.4f)\n",
              pair.changed.summary.c_str(), pair.changed_rotation, pair.plain_rotation, pair.changed_depth,
              pair.plain_depth);
  EXPECT_NE(pair.plain.summary.find("): no turn"), std::string::npos) << pair.plain.summary;
  EXPECT_NE(pair.changed.summary.find(test_name), std::string::npos) << pair.changed.summary;
  EXPECT_NE(pair.changed.summary.find("): turn kept"), std::string::npos) << pair.changed.summary;
  return pair;
}

TEST(InitializerTest, DenseTurnTestFindsTheArcTurnThatTheTracksLeaveOpen) {
  const InitialisationPair pair =
      ArcTurnTest([](InitializerOptions* o) { o->dense_fixation_test = true; }, "dense turn test");
  // Measured: the tracks' gain 11.7 sigma^2 (bound 46.9 then, 18.9 now), the dense test's
  // 3.38 standard errors (bound 3.09; data cost -1.60 %; 3.44 before the first
  // and last frames' blur paths curved): mean rotation error 0.583 deg (tracks
  // only 2.351), depth rel. error 0.0298 (0.0658).
  EXPECT_LT(pair.changed_rotation, 0.5 * pair.plain_rotation);
  EXPECT_LT(pair.changed_depth, pair.plain_depth);
}

// The same arc decided by the dense flow's epipolar distances, with 16 px
// tiles (the dense test's blocks as samples): the mechanism finds the turn.
// With the default 32 px tiles (the flow's correlation length) it keeps no
// turn here: 1.89 standard errors over 25 tiles, bound 3.47 (BENCHMARKS.md,
// "forward-backward flow and tiles").
TEST(InitializerTest, FlowTurnTestFindsTheArcTurnThatTheTracksLeaveOpen) {
  const InitialisationPair pair = ArcTurnTest(
      [](InitializerOptions* o) {
        o->flow_fixation_test = true;
        o->flow_test_tile_px = 16;
      },
      "flow turn test");
  // Measured (turn2, before the forward-backward check): the flow test's
  // 4.39 standard errors (bound 3.09; epipolar distances -4.99 %): mean
  // rotation error 0.581 deg (tracks only 2.350), depth rel. error 0.0297
  // (0.0656), the dense test's turn.
  EXPECT_LT(pair.changed_rotation, 0.5 * pair.plain_rotation);
  EXPECT_LT(pair.changed_depth, pair.plain_depth);
}

// The tracks keep a turn that the camera does not make (flow_turn_check
// off), and the flow turn check drops it, which lowers the rotation error
// at least fourfold and the depth error too. Both with track_consistency_z
// 0, the tracks as they were when these tests were written: leaving out the
// tracks that follow no point brings the rolling-shutter clip's false turn
// below the tracks-alone bound (45.8 sigma^2, bound 46.9; 0.448 deg), not
// the lateral one's. The tracks-only runs (flow_turn_check off) decide at
// fixation_test_alone_z (46.9); the runs with the check screen at
// fixation_test_z (18.9).
void ExpectFlowCheckDropsTheTracksTurn(const Sequence& sequence) {
  InitializerOptions base;
  base.track_consistency_z = 0.0;
  const InitialisationPair pair = InitialiseTwice(
      sequence, [](InitializerOptions* o) { o->flow_turn_check = false; }, base);
  PrintPair(pair, "tracks only");
  EXPECT_NE(pair.changed.summary.find("): kept"), std::string::npos) << pair.changed.summary;
  EXPECT_NE(pair.plain.summary.find("): turn dropped"), std::string::npos) << pair.plain.summary;
  EXPECT_LT(pair.plain_rotation, 0.25 * pair.changed_rotation);
  EXPECT_LT(pair.plain_depth, pair.changed_depth);
}

// InitializerOptions::flow_turn_check: on a 10-frame lateral path of a leafy
// scene (Aloe, noise 1) the tracks' persistent errors favour a turn that is
// not there by far more than their bound; the flow does not confirm it, and
// the check drops it. Measured: the tracks' gain 101.7 sigma^2 (bound 46.9)
// for a turn towards a point at -1.09 median depths; the flow's 0.03
// standard errors over 20 tiles (bound 1.03): mean rotation error 0.140 deg
// (tracks only 1.935), depth rel. error 0.0266 (0.0629).
TEST(InitializerTest, FlowTurnCheckDropsTheTracksTurnOnALateralPath) {
  ExpectFlowCheckDropsTheTracksTurn(TenFrameSequence("Aloe", CameraPathType::kLateral, 0, 0.0));
}

// The same check on a rolling-shutter window: a hand-held clip read out
// over 0.8 of the frame interval (Reindeer, seed 3; `synthesize_sequence
// --path handheld --readout-ratio 0.8`), on which the tracks keep a turn
// that the camera does not make. Before the check ran with a rolling
// shutter, nothing dropped it, and the joint and baseline iterations kept
// its rotation error of about 4 deg. Measured: the tracks' gain 54.1
// sigma^2 (bound 46.9) for a turn towards a point at 1.92 median depths;
// the flow's 0.12 standard errors over 20 tiles (bound 1.03): mean rotation
// error 0.441 deg (tracks only 3.598), depth rel. error 0.0423 (0.0493).
// (estimate_sequence on the tool's sequence of the same arguments: 81.6
// sigma^2, -0.71 standard errors, 0.40 against 4.05 deg.)
TEST(InitializerTest, FlowTurnCheckDropsTheTracksTurnOnARollingShutterHandHeldPath) {
  const Sequence sequence = TenFrameSequence("Reindeer", CameraPathType::kHandheld, 3, 0.8);
  ASSERT_GT(sequence.readout_time, 0.0);
  ExpectFlowCheckDropsTheTracksTurn(sequence);
}

// The arc turn that the tracks find (Dolls, the arc sequence above) is
// confirmed by the flow and kept (measured: 4.00 standard errors over 30
// tiles).
TEST(InitializerTest, FlowTurnCheckKeepsTheArcTurnTheTracksFind) {
  const InitialStructure result = InitializeStructure(FloatImages(ArcSequence()), ArcSequence().calibration.camera,
                                                      ArcSequence().frames, InitializerOptions());
  std::printf("%s\n", result.summary.c_str());
  EXPECT_NE(result.summary.find("flow turn check"), std::string::npos) << result.summary;
  EXPECT_NE(result.summary.find("): turn kept"), std::string::npos) << result.summary;
}

// InitializerOptions::fixation_test_z: the benchmark's arc around Aloe (a
// scene of little depth range; 10 frames, noise 1, seed 4). Its turn lowers
// the tracks' cost by 26.1 sigma^2: above the screen's bound (z = 4, 18.9),
// so the flow turn check decides it, and the flow confirms it (1.65
// standard errors, bound 1.03). Without the flow check the tracks decide
// alone at fixation_test_alone_z (z = 6, 46.9) and keep no turn. Measured:
// mean rotation error 1.73 deg against 3.86, LR depth rel. error 0.0325
// against 0.0608 (the tool's run of the same clip, `estimate_sequence
// --iterations 0`: 1.45 against 3.47 deg, 0.031 against 0.063).
TEST(InitializerTest, TrackScreenLetsTheFlowConfirmAShallowArcsTurn) {
  const Sequence sequence = TenFrameSequence("Aloe", CameraPathType::kArc, 4, 0.0);
  const InitialisationPair pair =
      InitialiseTwice(sequence, [](InitializerOptions* o) { o->flow_turn_check = false; });
  PrintPair(pair, "without the flow check");
  EXPECT_NE(pair.plain.summary.find("bound 18.9): kept"), std::string::npos) << pair.plain.summary;
  EXPECT_NE(pair.plain.summary.find("): turn kept"), std::string::npos) << pair.plain.summary;
  EXPECT_NE(pair.changed.summary.find("bound 46.9): no turn"), std::string::npos) << pair.changed.summary;
  EXPECT_LT(pair.plain_rotation, 0.5 * pair.changed_rotation);
  EXPECT_LT(pair.plain_depth, 0.75 * pair.changed_depth);
}

TEST(InitializerTest, BadOptionsAndInputsGiveInputError) {
  auto expect_bad = [](const std::function<void(InitializerOptions*)>& change, const std::string& field) {
    InitializerOptions options;
    change(&options);
    ExpectThrowsWith<InputError>([&] { options.Check(); }, field);
  };
  // One message style (core/common/options_check.h): "<field> must be ..., got <value>".
  expect_bad([](InitializerOptions* o) { o->num_threads = -1; },
             "initializer: num_threads must be >= 0, got -1");
  expect_bad([](InitializerOptions* o) { o->num_planes = 2; },
             "initializer: num_planes must be in [4, 512], got 2");
  expect_bad([](InitializerOptions* o) { o->ransac_confidence = 1.5; },
             "initializer: ransac_confidence must be in (0, 1), got 1.5");
  expect_bad([](InitializerOptions* o) { o->feature_quality = 0.0; },
             "initializer: feature_quality must be in (0, 1), got 0");
  expect_bad([](InitializerOptions* o) { o->ransac_threshold_px = 0.0; },
             "initializer: ransac_threshold_px must be > 0, got 0");
  expect_bad([](InitializerOptions* o) { o->depth_tv_weight = -1.0; },
             "initializer: depth_tv_weight must be >= 0, got -1");
  expect_bad([](InitializerOptions* o) { o->neighbours_per_side = 0; },
             "initializer: neighbours_per_side must be in [1, 5], got 0");
  expect_bad([](InitializerOptions* o) { o->theta_end = 2.0 * o->theta_start; },
             "initializer: theta_end must be in [0, 0.5], got 1");
  expect_bad([](InitializerOptions* o) { o->capture_samples = 0; },
             "initializer: capture_samples must be in [1, 1000], got 0");
  expect_bad([](InitializerOptions* o) { o->rotation_prior_px = 0.0; },
             "initializer: rotation_prior_px must be > 0, got 0");
  expect_bad([](InitializerOptions* o) { o->ba_loss_px = std::nan(""); },
             "initializer: ba_loss_px must be > 0, got nan");
  expect_bad([](InitializerOptions* o) { o->dense_test_block_px = 0; },
             "initializer: dense_test_block_px must be >= 1, got 0");
  expect_bad([](InitializerOptions* o) { o->flow_test_tile_px = 0; },
             "initializer: flow_test_tile_px must be >= 1, got 0");
  expect_bad([](InitializerOptions* o) { o->flow_test_min_gap = 0; },
             "initializer: flow_test_min_gap must be >= 1, got 0");
  expect_bad(
      [](InitializerOptions* o) {
        o->flow_test_min_gap = 3;
        o->flow_test_max_gap = 2;
      },
      "initializer: flow_test_max_gap must be >= 3, got 2");
  expect_bad([](InitializerOptions* o) { o->dense_test_z = 0.0; },
             "initializer: dense_test_z must be > 0, got 0");
  expect_bad([](InitializerOptions* o) { o->flow_turn_check_z = -1.0; },
             "initializer: flow_turn_check_z must be > 0, got -1");
  expect_bad([](InitializerOptions* o) { o->fixation_test_alone_z = 0.0; },
             "initializer: fixation_test_alone_z must be > 0, got 0");
  expect_bad([](InitializerOptions* o) { o->pose_prior_position_sigma = -0.01; },
             "initializer: pose_prior_position_sigma must be >= 0, got -0.01");
  expect_bad([](InitializerOptions* o) { o->pose_prior_rotation_sigma_deg = std::nan(""); },
             "initializer: pose_prior_rotation_sigma_deg must be >= 0, got nan");
  expect_bad([](InitializerOptions* o) { o->pose_prior.outlier_distance = 0.0; },
             "initializer: pose_prior: outlier_distance must be > 0, got 0");
  expect_bad([](InitializerOptions* o) { o->edge_weight.sigma = 0.0; },
             "initializer: edge_weight: edge weight: sigma must be > 0, got 0");
  EXPECT_NO_THROW(InitializerOptions().Check());

  // InitializeStructure checks its options and inputs before any work.
  const PinholeCamera camera(64, 48, 60.0, 60.0, 31.5, 23.5);
  const std::vector<cv::Mat> images(2, cv::Mat(48, 64, CV_32FC1, cv::Scalar(0.5)));
  std::vector<FrameRecord> frames(2);
  frames[0] = {0, 0.1, 0.05};
  frames[1] = {1, 0.2, 0.05};
  InitializerOptions bad;
  bad.min_inliers = 2;
  ExpectThrowsWith<InputError>([&] { InitializeStructure(images, camera, frames, bad); },
                               "initializer: min_inliers must be >= 8, got 2");
  ExpectThrowsWith<InputError>(
      [&] { InitializeStructure({images[0]}, camera, {frames[0]}, InitializerOptions()); },
      "at least 2 frames");
  ExpectThrowsWith<InputError>(
      [&] {
        const std::vector<cv::Mat> wrong(2, cv::Mat(40, 64, CV_32FC1, cv::Scalar(0.5)));
        InitializeStructure(wrong, camera, frames, InitializerOptions());
      },
      "image 0");
  ExpectThrowsWith<InputError>(
      [&] {
        std::vector<FrameRecord> backwards = frames;
        backwards[1].stamp = 0.05;
        InitializeStructure(images, camera, backwards, InitializerOptions());
      },
      "stamps");
}

// A hand-held clip with long blur (6 frames, noise sigma 1, `--seed 11`,
// a median of `blur_px` HR px per exposure at scale 2), made with the
// synthesizer API as `synthesize_sequence --path handheld` makes it.
Sequence LongBlurSequence(const std::string& scene_name, double blur_px) {
  SynthesisOptions options;
  options.path = CameraPathType::kHandheld;
  options.num_frames = 6;
  options.noise_sigma = 1.0;
  options.seed = 11;
  options.blur_px = blur_px;
  const StereoScene scene =
      LoadMiddleburyScene(std::string(DSM_SOURCE_DIR) + "/data/middlebury/" + scene_name);
  return SynthesizeSequence(scene, options).sequence;
}

// InitializerOptions::half_resolution_retry. Moebius at 30 HR px (15 LR px)
// of blur on 123x161 frames: at the input size the tracks give out (the
// corners smear below Lucas-Kanade's eigenvalue floor); at half size the
// initialisation goes through, and its depth maps come back at the input size.
TEST(InitializerTest, LongBlurInitialisesAtHalfResolution) {
  const Sequence sequence = LongBlurSequence("Moebius", 30.0);
  const std::vector<cv::Mat> images = FloatImages(sequence);
  const PinholeCamera& camera = sequence.calibration.camera;
  InitializerOptions without_retry;
  without_retry.half_resolution_retry = false;
  EXPECT_THROW(InitializeStructure(images, camera, sequence.frames, without_retry), InitializationError);

  const InitialStructure result = InitializeStructure(images, camera, sequence.frames, InitializerOptions());
  std::printf("%s\n", result.summary.c_str());
  EXPECT_EQ(result.summary.rfind("half resolution: 61x80 px", 0), 0u) << result.summary;
  ASSERT_EQ(result.depth_lr.size(), images.size());
  for (const cv::Mat& depth : result.depth_lr) {
    EXPECT_EQ(depth.size(), cv::Size(camera.width, camera.height));
  }
  EXPECT_NEAR(MedianDepth(result.depth_lr), 1.0, 0.05);
  const InitialAccuracy accuracy = MeasureInitialAccuracy(sequence, result);
  // Measured: ATE 4.8 % of the path, worst rotation error 0.75 deg, depth
  // rel. error 0.046 (the joint iterations refine all three). Guarded at
  // about 1.5x.
  EXPECT_LT(accuracy.ate_of_path, 0.075);
  EXPECT_LT(accuracy.worst_rotation_deg, 1.2);
  EXPECT_LT(accuracy.depth_error, 0.07);

  // The trajectory alone and the readout search retry the same way. The
  // clip has a global shutter; the search's flat cost puts the readout at
  // 0.137 of the frame interval (rms 0.163 against 0.166 px at 0): within its
  // known error on motion this smooth (BENCHMARKS.md "Readout time measured
  // from the tracks").
  const InitialTrajectory trajectory =
      InitializeTrajectory(images, camera, sequence.frames, InitializerOptions());
  EXPECT_EQ(trajectory.summary.rfind("half resolution: 61x80 px", 0), 0u) << trajectory.summary;
  ASSERT_EQ(trajectory.T_world_cam.size(), images.size());
  const ReadoutEstimate readout =
      EstimateReadoutTime(images, camera, sequence.frames, InitializerOptions(), ReadoutSearchOptions());
  EXPECT_EQ(readout.summary.rfind("half resolution: 61x80 px", 0), 0u) << readout.summary;
  EXPECT_EQ(readout.cost.size(), 11u);
  EXPECT_LT(readout.fraction, 0.2) << readout.summary;
  EXPECT_THROW(EstimateReadoutTime(images, camera, sequence.frames, without_retry, ReadoutSearchOptions()),
               InitializationError);
}

// A camera that pans fast (path `rotate`, 60 HR px of blur on 200x152
// frames): the input-size frames show no parallax but do not track well
// enough for the rotations; at half size they do. InitializeStructure says
// NoParallaxError (so the caller takes the rotation-only path), and
// EstimateRotationOnlyMotion measures the orientations at half size.
TEST(RotationOnlyMotionTest, LongBlurRotationIsMeasuredAtHalfResolution) {
  SynthesisOptions options;
  options.path = CameraPathType::kRotate;
  options.num_frames = 6;
  options.noise_sigma = 1.0;
  options.seed = 11;
  options.blur_px = 60.0;
  options.subframes = 60;
  options.hr_width = 400;
  options.hr_height = 304;
  const StereoScene scene = LoadMiddleburyScene(std::string(DSM_SOURCE_DIR) + "/data/middlebury/Dolls");
  const Sequence sequence = SynthesizeSequence(scene, options).sequence;
  const std::vector<cv::Mat> images = FloatImages(sequence);
  const PinholeCamera& camera = sequence.calibration.camera;
  EXPECT_THROW(InitializeStructure(images, camera, sequence.frames, InitializerOptions()), NoParallaxError);
  InitializerOptions without_retry;
  without_retry.half_resolution_retry = false;
  EXPECT_THROW(EstimateRotationOnlyMotion(images, camera, sequence.frames, without_retry),
               InitializationError);

  const RotationOnlyMotion motion =
      EstimateRotationOnlyMotion(images, camera, sequence.frames, InitializerOptions());
  EXPECT_EQ(motion.summary.rfind("half resolution: 100x76 px", 0), 0u) << motion.summary;
  ASSERT_EQ(motion.R_world_cam.size(), images.size());
  double worst = 0.0;
  for (size_t t = 1; t < motion.R_world_cam.size(); ++t) {
    worst = std::max(worst, RotationErrorDeg(sequence, motion.R_world_cam[t], t));
  }
  std::printf("worst rotation error %.3f deg\n", worst);
  // Measured: 0.024 deg. The bound is the README's for a rotation-only
  // window (Reliability, row 16): 0.2 deg.
  EXPECT_LT(worst, 0.2);
}

// When the half-size try fails too, the error is still one line and names
// both failures (Reindeer at 30 HR px of blur).
TEST(InitializerTest, FailureAtBothSizesNamesBoth) {
  const Sequence sequence = LongBlurSequence("Reindeer", 30.0);
  ExpectThrowsWith<InitializationError>(
      [&] {
        InitializeStructure(FloatImages(sequence), sequence.calibration.camera, sequence.frames,
                            InitializerOptions());
      },
      "; at half resolution: initialisation: ");
}

// Frames of a 30 fps clip with an exposure of 0.8 frame intervals, the pose
// at each frame's mid-exposure and at its stamp (shutter close) from `path`.
struct MidAndClose {
  std::vector<FrameRecord> frames;
  std::vector<SE3> T_world_mid, T_world_close;
};
MidAndClose PosesOnPath(int num_frames, const std::function<SE3(double)>& path) {
  constexpr double kInterval = 1.0 / 30.0, kExposure = 0.8 * kInterval;
  MidAndClose poses;
  for (int i = 0; i < num_frames; ++i) {
    const FrameRecord frame{i, (i + 1) * kInterval, kExposure};
    poses.frames.push_back(frame);
    poses.T_world_mid.push_back(path(frame.stamp - 0.5 * frame.exposure));
    poses.T_world_close.push_back(path(frame.stamp));
  }
  return poses;
}

// A hand-held camera accelerates: the tracks give its poses at mid-exposure,
// and the shutter-close poses must follow the acceleration. On a path of
// constant acceleration (a translation quadratic in time) every interior
// frame is exact. The first frame, on the geodesic through the mid-exposure
// poses of frames 0 and 1, misses by a (e/2) (dt - e/2) / 2; the last,
// extrapolated along the geodesic through its predecessor, by
// a (e/2) (dt + e/2) / 2. The geodesic through t-1 and t that was used
// before missed every frame but the first by that much (1.4 mm here).
TEST(MidExposureToShutterClose, FollowsAConstantAccelerationExceptAtTheEnds) {
  const Eigen::Vector3d velocity(0.3, 0.1, 0.0), acceleration(4.0, 0.0, -2.0);  // m/s, m/s^2
  const MidAndClose poses = PosesOnPath(6, [&](double tau) {
    return SE3(Eigen::Matrix3d::Identity(), velocity * tau + 0.5 * acceleration * tau * tau);
  });
  const std::vector<SE3> T_world_cam = MidExposureToShutterClose(poses.frames, poses.T_world_mid);
  ASSERT_EQ(T_world_cam.size(), poses.frames.size());
  const int last = static_cast<int>(T_world_cam.size()) - 1;
  for (int t = 1; t < last; ++t) {
    EXPECT_LT((T_world_cam[t].translation() - poses.T_world_close[t].translation()).norm(), 1e-12)
        << "frame " << t;
    EXPECT_LT(
        Eigen::AngleAxisd(T_world_cam[t].rotation().transpose() * poses.T_world_close[t].rotation()).angle(),
        1e-9);
  }
  const double half_exposure = 0.5 * poses.frames[last].exposure;
  const double interval = poses.frames[last].stamp - poses.frames[last - 1].stamp;
  const double first_miss = (T_world_cam[0].translation() - poses.T_world_close[0].translation()).norm();
  const double last_miss = (T_world_cam[last].translation() - poses.T_world_close[last].translation()).norm();
  std::printf("first frame: %.4f mm off, last frame: %.4f mm off\n", 1e3 * first_miss, 1e3 * last_miss);
  EXPECT_NEAR(first_miss, 0.5 * acceleration.norm() * half_exposure * (interval - half_exposure), 1e-12);
  EXPECT_NEAR(last_miss, 0.5 * acceleration.norm() * half_exposure * (interval + half_exposure), 1e-12);
}

// At constant velocity (a constant twist: turning while moving) both the
// quadratic and the geodesic are the path itself: every frame is exact.
TEST(MidExposureToShutterClose, IsExactAtConstantVelocity) {
  Vector6d twist;
  twist << 0.4, -0.1, 0.2, 0.3, -0.5, 0.2;  // per second
  const SE3 T_world_start(Eigen::Matrix3d(Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitY())),
                          Eigen::Vector3d(0.1, 0.0, -0.2));
  const MidAndClose poses = PosesOnPath(5, [&](double tau) { return SE3::Exp(tau * twist) * T_world_start; });
  const std::vector<SE3> T_world_cam = MidExposureToShutterClose(poses.frames, poses.T_world_mid);
  for (size_t t = 0; t < T_world_cam.size(); ++t) {
    EXPECT_LT((T_world_cam[t].translation() - poses.T_world_close[t].translation()).norm(), 1e-9)
        << "frame " << t;
    EXPECT_LT(
        Eigen::AngleAxisd(T_world_cam[t].rotation().transpose() * poses.T_world_close[t].rotation()).angle(),
        1e-9);
  }
}

TEST(MidExposureToShutterClose, RejectsTooFewFramesOrPoses) {
  const MidAndClose poses =
      PosesOnPath(3, [](double tau) { return SE3(Eigen::Matrix3d::Identity(), Eigen::Vector3d(tau, 0, 0)); });
  EXPECT_THROW(MidExposureToShutterClose({poses.frames[0]}, {poses.T_world_mid[0]}), InputError);
  EXPECT_THROW(MidExposureToShutterClose(poses.frames, {poses.T_world_mid[0], poses.T_world_mid[1]}),
               InputError);
}

}  // namespace
}  // namespace deblur_sr_mvs
