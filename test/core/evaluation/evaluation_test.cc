// Result folders (result_io), the paper's evaluation (evaluation) and the
// evaluate_sequence / superres_btvl1 tools.
#include "deblur_sr_mvs/core/evaluation/evaluation.h"

#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <Eigen/Geometry>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "deblur_sr_mvs/core/imaging/image_ops.h"
#include "deblur_sr_mvs/core/io/result_io.h"
#include "deblur_sr_mvs/core/io/sequence_io.h"

namespace deblur_sr_mvs {
namespace {

namespace fs = std::filesystem;

constexpr int kScale = 2;
constexpr int kLrWidth = 24;
constexpr int kLrHeight = 20;

// A fresh folder per test, removed afterwards.
class EvaluationTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const ::testing::TestInfo* info = ::testing::UnitTest::GetInstance()->current_test_info();
    dir_ = fs::path(::testing::TempDir()) /
           ("dsm_evaluation_" + std::string(info->name()) + "_" + std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override {
    std::error_code error;
    fs::remove_all(dir_, error);
  }
  std::string Path(const std::string& name) const { return (dir_ / name).string(); }

  fs::path dir_;
};

void ExpectInputError(const std::function<void()>& action, const std::vector<std::string>& parts) {
  try {
    action();
    ADD_FAILURE() << "expected InputError containing '" << parts.front() << "'";
  } catch (const InputError& error) {
    const std::string message = error.what();
    EXPECT_EQ(message.find('\n'), std::string::npos) << "not one line: " << message;
    for (const std::string& part : parts) {
      EXPECT_NE(message.find(part), std::string::npos)
          << "message '" << message << "' lacks '" << part << "'";
    }
  }
}

// Smooth random colour texture (values kept inside [20, 200] so that +-10
// offsets in the PSNR test do not saturate).
cv::Mat Texture(cv::Size size, int seed, int channels = 3) {
  cv::RNG rng(seed);
  cv::Mat noise(size, CV_32FC(channels));
  rng.fill(noise, cv::RNG::UNIFORM, 0.0, 1.0);
  cv::GaussianBlur(noise, noise, cv::Size(0, 0), 1.5);
  cv::normalize(noise, noise, 20.0, 200.0, cv::NORM_MINMAX);
  cv::Mat image;
  noise.convertTo(image, CV_8U);
  return image;
}

// A small sequence with ground truth: textures, slanted-plane depths and
// positions on a (non-collinear) arc.
Sequence MakeSequence(int num_frames, int channels = 3) {
  const PinholeCamera lr_camera(kLrWidth, kLrHeight, 20.0, 20.0, 11.5, 9.5);
  Sequence sequence;
  sequence.calibration = CameraCalibration::FromCamera(lr_camera, "test");
  SequenceGroundTruth gt;
  gt.calibration = CameraCalibration::FromCamera(lr_camera.Upscaled(kScale), "test_hr");
  const cv::Size hr_size(kLrWidth * kScale, kLrHeight * kScale);
  for (int i = 0; i < num_frames; ++i) {
    FrameRecord frame;
    frame.index = i;
    frame.stamp = 0.1 * (i + 1);
    frame.exposure = 0.05;
    sequence.frames.push_back(frame);
    cv::Mat latent = Texture(hr_size, 100 + i, channels);
    sequence.images.push_back(ToImage8(DownsampleBox(ToFloat01(latent), kScale)));
    gt.latent.push_back(latent);
    cv::Mat depth(hr_size, CV_32FC1);
    for (int y = 0; y < depth.rows; ++y) {
      for (int x = 0; x < depth.cols; ++x) depth.at<float>(y, x) = 1.0f + 0.02f * x + 0.01f * y + 0.1f * i;
    }
    depth.at<float>(0, 0) = 0.0f;  // unknown gt pixels stay out of the metrics
    gt.depth.push_back(depth);
    StampedPose pose;
    pose.stamp = frame.stamp;
    const double angle = 0.3 * i;
    pose.T_world_cam = SE3(SO3Exp(Eigen::Vector3d(0.0, 0.05 * i, 0.0)),
                           Eigen::Vector3d(std::sin(angle), 0.1 * i * i, 1.0 - std::cos(angle)));
    gt.poses.push_back(pose);
  }
  sequence.ground_truth = gt;
  return sequence;
}

// The result that reproduces the ground truth exactly.
SequenceResult PerfectResult(const Sequence& sequence) {
  SequenceResult result;
  result.calibration = sequence.ground_truth->calibration;
  result.frames = sequence.frames;
  for (std::size_t i = 0; i < sequence.frames.size(); ++i) {
    result.latent.push_back(sequence.ground_truth->latent[i].clone());
    result.depth.push_back(sequence.ground_truth->depth[i].clone());
  }
  result.poses = sequence.ground_truth->poses;
  result.report_json = "{\"method\": \"test\"}";
  return result;
}

bool SameFloatImage(const cv::Mat& a, const cv::Mat& b) {
  if (a.size() != b.size() || a.type() != b.type()) return false;
  for (int y = 0; y < a.rows; ++y) {
    for (int x = 0; x < a.cols; ++x) {
      const float u = a.at<float>(y, x);
      const float v = b.at<float>(y, x);
      if (!(u == v || (std::isnan(u) && std::isnan(v)))) return false;
    }
  }
  return true;
}

// --------------------------------------------------------------- result_io

TEST_F(EvaluationTest, ResultRoundTripWithDepthAndPoses) {
  const Sequence sequence = MakeSequence(3);
  SequenceResult result = PerfectResult(sequence);
  result.depth[1].at<float>(5, 7) = std::numeric_limits<float>::quiet_NaN();
  WriteResult(Path("out"), result);
  for (const char* file : {"camera.yaml", "frames.csv", "poses.txt", "report.json", "latent/000002.png",
                           "depth/000002.tiff", "depth_color/000002.png"}) {
    EXPECT_TRUE(fs::is_regular_file(dir_ / "out" / file)) << file;
  }
  const SequenceResult read = ReadResult(Path("out"));
  EXPECT_EQ(read.calibration.camera.width, result.calibration.camera.width);
  EXPECT_EQ(read.calibration.camera.height, result.calibration.camera.height);
  EXPECT_DOUBLE_EQ(read.calibration.camera.cx, result.calibration.camera.cx);
  ASSERT_EQ(read.frames.size(), 3u);
  ASSERT_EQ(read.latent.size(), 3u);
  ASSERT_EQ(read.depth.size(), 3u);
  ASSERT_EQ(read.poses.size(), 3u);
  for (int i = 0; i < 3; ++i) {
    EXPECT_EQ(read.frames[i].index, i);
    EXPECT_DOUBLE_EQ(read.frames[i].stamp, result.frames[i].stamp);
    EXPECT_DOUBLE_EQ(read.frames[i].exposure, result.frames[i].exposure);
    EXPECT_EQ(cv::norm(read.latent[i], result.latent[i], cv::NORM_INF), 0.0);
    EXPECT_TRUE(SameFloatImage(read.depth[i], result.depth[i])) << "frame " << i;
    EXPECT_LT((read.poses[i].T_world_cam.translation() - result.poses[i].T_world_cam.translation()).norm(),
              1e-12);
    EXPECT_LT((read.poses[i].T_world_cam.rotation() - result.poses[i].T_world_cam.rotation()).norm(), 1e-12);
  }
  EXPECT_TRUE(std::isnan(read.depth[1].at<float>(5, 7)));
  EXPECT_EQ(read.report_json, "{\"method\": \"test\"}\n");
}

TEST_F(EvaluationTest, ResultRoundTripImageOnly) {
  const Sequence sequence = MakeSequence(2, /*channels=*/1);
  SequenceResult result = PerfectResult(sequence);
  result.depth.clear();
  result.poses.clear();
  result.report_json.clear();
  WriteResult(Path("out"), result);
  EXPECT_FALSE(fs::exists(dir_ / "out" / "depth"));
  EXPECT_FALSE(fs::exists(dir_ / "out" / "depth_color"));
  EXPECT_FALSE(fs::exists(dir_ / "out" / "poses.txt"));
  const SequenceResult read = ReadResult(Path("out"));
  EXPECT_FALSE(read.HasDepth());
  EXPECT_FALSE(read.HasPoses());
  ASSERT_EQ(read.latent.size(), 2u);
  EXPECT_EQ(read.latent[0].type(), CV_8UC1);
  EXPECT_EQ(cv::norm(read.latent[1], result.latent[1], cv::NORM_INF), 0.0);
  EXPECT_EQ(read.report_json, "{}\n");
}

TEST_F(EvaluationTest, RewritingWithoutDepthDropsTheOldDepthAndPoses) {
  const Sequence sequence = MakeSequence(3);
  SequenceResult result = PerfectResult(sequence);
  WriteResult(Path("out"), result);
  result.depth.clear();
  result.poses.clear();
  WriteResult(Path("out"), result);
  const SequenceResult read = ReadResult(Path("out"));
  EXPECT_FALSE(read.HasDepth());
  EXPECT_FALSE(read.HasPoses());
}

TEST_F(EvaluationTest, DepthPreviewsShareOneRange) {
  const Sequence sequence = MakeSequence(2);
  SequenceResult result = PerfectResult(sequence);
  result.depth[0].setTo(1.0f);  // near
  result.depth[1].setTo(3.0f);  // far
  WriteResult(Path("out"), result);
  const cv::Mat near = cv::imread(Path("out/depth_color/000000.png"), cv::IMREAD_UNCHANGED);
  const cv::Mat far = cv::imread(Path("out/depth_color/000001.png"), cv::IMREAD_UNCHANGED);
  ASSERT_EQ(near.type(), CV_8UC3);
  ASSERT_EQ(far.type(), CV_8UC3);
  // Per-frame ranges would colour both constant maps alike.
  EXPECT_GT(cv::norm(near.at<cv::Vec3b>(10, 10), far.at<cv::Vec3b>(10, 10)), 50.0);
}

TEST_F(EvaluationTest, WriteResultRejectsInconsistentResults) {
  const Sequence sequence = MakeSequence(3);
  SequenceResult result = PerfectResult(sequence);
  result.latent.pop_back();
  ExpectInputError([&] { WriteResult(Path("a"), result); }, {Path("a"), "2 latent images for 3"});

  result = PerfectResult(sequence);
  cv::resize(result.latent[1], result.latent[1], cv::Size(10, 10));
  ExpectInputError([&] { WriteResult(Path("b"), result); }, {"000001.png", "10x10", "camera.yaml"});

  result = PerfectResult(sequence);
  result.latent[0].convertTo(result.latent[0], CV_32F, 1.0 / 255.0);
  ExpectInputError([&] { WriteResult(Path("c"), result); }, {"000000.png", "8-bit"});

  result = PerfectResult(sequence);
  result.depth.pop_back();
  ExpectInputError([&] { WriteResult(Path("d"), result); }, {"2 depth maps for 3"});

  result = PerfectResult(sequence);
  result.poses[2].stamp += 0.01;
  ExpectInputError([&] { WriteResult(Path("e"), result); }, {"poses.txt", "pose 2"});
}

TEST_F(EvaluationTest, MalformedResultFoldersNameTheFile) {
  ExpectInputError([&] { ReadResult(Path("missing")); }, {Path("missing"), "not found"});

  const Sequence sequence = MakeSequence(3);
  const SequenceResult result = PerfectResult(sequence);
  auto fresh = [&](const std::string& name) {
    WriteResult(Path(name), result);
    return dir_ / name;
  };

  fs::remove(fresh("no_camera") / "camera.yaml");
  ExpectInputError([&] { ReadResult(Path("no_camera")); }, {"no_camera/camera.yaml", "not found"});

  fs::remove(fresh("no_frames") / "frames.csv");
  ExpectInputError([&] { ReadResult(Path("no_frames")); }, {"no_frames/frames.csv", "not found"});

  fs::remove(fresh("no_latent") / "latent" / "000001.png");
  ExpectInputError([&] { ReadResult(Path("no_latent")); }, {"latent/000001.png", "not found"});

  const fs::path small = fresh("small_latent");
  cv::imwrite((small / "latent" / "000002.png").string(), cv::Mat(7, 9, CV_8UC3, cv::Scalar::all(1)));
  ExpectInputError([&] { ReadResult(Path("small_latent")); },
                   {"latent/000002.png", "9x7", "camera.yaml", "48x40"});

  fs::remove(fresh("no_depth") / "depth" / "000000.tiff");
  ExpectInputError([&] { ReadResult(Path("no_depth")); }, {"depth/000000.tiff", "not found"});

  const fs::path bad_depth = fresh("bad_depth");
  cv::imwrite((bad_depth / "depth" / "000001.tiff").string(), cv::Mat(40, 48, CV_8UC1, cv::Scalar(3)));
  ExpectInputError([&] { ReadResult(Path("bad_depth")); }, {"depth/000001.tiff", "32FC1"});

  const fs::path few_poses = fresh("few_poses");
  {
    std::ofstream out(few_poses / "poses.txt");
    out << "0.1 0 0 0 0 0 0 1\n0.2 1 0 0 0 0 0 1\n";
  }
  ExpectInputError([&] { ReadResult(Path("few_poses")); }, {"poses.txt", "2 poses for 3 frames"});

  const fs::path bad_stamps = fresh("bad_stamps");
  {
    std::ofstream out(bad_stamps / "poses.txt");
    out << "0.1 0 0 0 0 0 0 1\n0.2 1 0 0 0 0 0 1\n0.35 2 0 0 0 0 0 1\n";
  }
  ExpectInputError([&] { ReadResult(Path("bad_stamps")); }, {"poses.txt", "pose 2 has stamp 0.35"});
}

// -------------------------------------------------------------- evaluation

TEST_F(EvaluationTest, GroundTruthAsResultIsPerfect) {
  const Sequence sequence = MakeSequence(4);
  const EvaluationReport report = EvaluateResult(PerfectResult(sequence), sequence);
  EXPECT_EQ(report.num_frames, 4);
  EXPECT_EQ(report.scale, kScale);
  EXPECT_TRUE(report.colour);
  EXPECT_TRUE(std::isinf(report.mean_image_psnr_db));
  EXPECT_TRUE(std::isfinite(report.mean_bicubic_psnr_db));
  EXPECT_GT(report.mean_bicubic_psnr_db, 15.0);
  ASSERT_TRUE(report.mean_depth_relative_error.has_value());
  EXPECT_EQ(*report.mean_depth_relative_error, 0.0);
  EXPECT_TRUE(std::isinf(*report.mean_depth_psnr_db));
  EXPECT_EQ(report.num_depth_frames, 4);
  EXPECT_DOUBLE_EQ(report.mean_depth_coverage, 1.0);
  ASSERT_TRUE(report.ate_rmse.has_value());
  EXPECT_LT(*report.ate_rmse, 1e-9);
  for (const FrameEvaluation& frame : report.frames) {
    EXPECT_TRUE(std::isinf(frame.image_psnr_db));
    ASSERT_TRUE(frame.depth.has_value());
    EXPECT_NEAR(frame.depth->scale, 1.0, 1e-12);
    ASSERT_TRUE(frame.position_error.has_value());
    EXPECT_LT(*frame.position_error, 1e-9);
    ASSERT_TRUE(frame.rotation_error_deg.has_value());
    EXPECT_LT(*frame.rotation_error_deg, 1e-6);
  }
}

TEST_F(EvaluationTest, ScaledDepthAndSim3TrajectoryStillPerfect) {
  const Sequence sequence = MakeSequence(5);
  SequenceResult result = PerfectResult(sequence);
  for (cv::Mat& depth : result.depth) depth *= 0.25;  // exact in float
  // Result world = a similarity transform of the gt world (monocular scale).
  const double scale = 0.37;
  const Eigen::Matrix3d rotation = SO3Exp(Eigen::Vector3d(0.3, -1.2, 0.7));
  const Eigen::Vector3d translation(4.0, -2.0, 0.5);
  for (StampedPose& pose : result.poses) {
    pose.T_world_cam = SE3(rotation * pose.T_world_cam.rotation(),
                           scale * (rotation * pose.T_world_cam.translation()) + translation);
  }
  const EvaluationReport report = EvaluateResult(result, sequence);
  ASSERT_TRUE(report.mean_depth_relative_error.has_value());
  EXPECT_LT(*report.mean_depth_relative_error, 1e-6);
  EXPECT_GT(*report.mean_depth_psnr_db, 100.0);
  for (const FrameEvaluation& frame : report.frames) EXPECT_NEAR(frame.depth->scale, 4.0, 1e-6);
  ASSERT_TRUE(report.ate_rmse.has_value());
  EXPECT_LT(*report.ate_rmse, 1e-9);
  ASSERT_TRUE(report.trajectory_alignment.has_value());
  EXPECT_NEAR(report.trajectory_alignment->scale, 1.0 / scale, 1e-9);

  // Relative orientations do not depend on the world: still exact.
  ASSERT_TRUE(report.max_rotation_error_deg.has_value());
  EXPECT_LT(*report.max_rotation_error_deg, 1e-6);

  // Without scale alignment the same depth is far off.
  EvaluationOptions options;
  options.align_depth_scale = false;
  const EvaluationReport unaligned = EvaluateResult(result, sequence, options);
  EXPECT_NEAR(*unaligned.mean_depth_relative_error, 0.75, 1e-6);

  // Without trajectory alignment the positions are compared as they are:
  // exact for the ground truth itself, off for the similarity-moved ones.
  EvaluationOptions metric;
  metric.align_depth_scale = metric.align_trajectory = false;
  const EvaluationReport exact = EvaluateResult(PerfectResult(sequence), sequence, metric);
  ASSERT_TRUE(exact.ate_rmse.has_value());
  EXPECT_LT(*exact.ate_rmse, 1e-12);
  EXPECT_FALSE(exact.trajectory_alignment.has_value());
  const EvaluationReport moved = EvaluateResult(result, sequence, metric);
  ASSERT_TRUE(moved.ate_rmse.has_value());
  EXPECT_GT(*moved.ate_rmse, 0.5);
}

TEST_F(EvaluationTest, RotationErrorIsTheAngleRelativeToTheFirstFrame) {
  const Sequence sequence = MakeSequence(4);
  SequenceResult result = PerfectResult(sequence);
  // Frame 2 turned by 0.5 deg about the optical axis, in its own frame.
  const double angle = 0.5 * M_PI / 180.0;
  result.poses[2].T_world_cam = SE3(result.poses[2].T_world_cam.rotation() *
                                        Eigen::AngleAxisd(angle, Eigen::Vector3d::UnitZ()).toRotationMatrix(),
                                    result.poses[2].T_world_cam.translation());
  const EvaluationReport report = EvaluateResult(result, sequence);
  ASSERT_TRUE(report.frames[2].rotation_error_deg.has_value());
  EXPECT_NEAR(*report.frames[2].rotation_error_deg, 0.5, 1e-9);
  EXPECT_NEAR(*report.frames[1].rotation_error_deg, 0.0, 1e-9);
  EXPECT_NEAR(*report.max_rotation_error_deg, 0.5, 1e-9);
  EXPECT_NEAR(*report.mean_rotation_error_deg, 0.125, 1e-9);
}

TEST_F(EvaluationTest, HandCheckablePsnrInColourAndGray) {
  const Sequence sequence = MakeSequence(3);
  SequenceResult result = PerfectResult(sequence);
  // Every value off by 10: MSE 100, PSNR = 10 log10(255^2 / 100) = 28.1308 dB.
  for (cv::Mat& latent : result.latent) latent += cv::Scalar::all(10);
  const double expected = 10.0 * std::log10(255.0 * 255.0 / 100.0);
  const EvaluationReport colour = EvaluateResult(result, sequence);
  EXPECT_TRUE(colour.colour);
  EXPECT_NEAR(colour.mean_image_psnr_db, expected, 1e-9);
  for (const FrameEvaluation& frame : colour.frames) EXPECT_NEAR(frame.image_psnr_db, expected, 1e-9);

  // A gray result is compared with the gray ground truth, also off by 10.
  for (cv::Mat& latent : result.latent) cv::cvtColor(latent, latent, cv::COLOR_BGR2GRAY);
  const EvaluationReport gray = EvaluateResult(result, sequence);
  EXPECT_FALSE(gray.colour);
  EXPECT_NEAR(gray.mean_image_psnr_db, expected, 0.05);

  // Bicubic PSNR is the one of the up-sampled input.
  const cv::Mat bicubic = ToImage8(UpsampleBicubic(ToFloat01(sequence.images[1]), kScale));
  EXPECT_NEAR(colour.frames[1].bicubic_psnr_db, Psnr(bicubic, sequence.ground_truth->latent[1], 255.0),
              1e-12);
}

TEST_F(EvaluationTest, MissingDepthAndPosesAreNotApplicable) {
  const Sequence sequence = MakeSequence(3);
  SequenceResult result = PerfectResult(sequence);
  result.depth.clear();
  result.poses.clear();
  const EvaluationReport report = EvaluateResult(result, sequence);
  EXPECT_FALSE(report.mean_depth_psnr_db.has_value());
  EXPECT_FALSE(report.mean_depth_relative_error.has_value());
  EXPECT_FALSE(report.ate_rmse.has_value());
  EXPECT_FALSE(report.ate_note.empty());
  EXPECT_FALSE(report.depth_note.empty());
  EXPECT_FALSE(report.frames[0].depth.has_value());
  const std::string markdown = ToMarkdown(report, "bicubic");
  EXPECT_NE(markdown.find("| bicubic | n/a | n/a | n/a |"), std::string::npos) << markdown;
  const std::string json = ToJson(report, "bicubic");
  EXPECT_NE(json.find("\"ate_rmse\": null"), std::string::npos) << json;
  EXPECT_NE(json.find("\"depth_psnr_db\": null"), std::string::npos) << json;
}

TEST_F(EvaluationTest, AteNeedsThreeFramesAndAMovingEstimate) {
  const Sequence two = MakeSequence(2);
  const EvaluationReport short_report = EvaluateResult(PerfectResult(two), two);
  EXPECT_FALSE(short_report.ate_rmse.has_value());
  EXPECT_NE(short_report.ate_note.find("3 frames"), std::string::npos) << short_report.ate_note;
  EXPECT_TRUE(short_report.mean_depth_psnr_db.has_value());

  const Sequence sequence = MakeSequence(4);
  SequenceResult still = PerfectResult(sequence);
  for (StampedPose& pose : still.poses) pose.T_world_cam = SE3();
  const EvaluationReport report = EvaluateResult(still, sequence);
  EXPECT_FALSE(report.ate_rmse.has_value());
  EXPECT_NE(report.ate_note.find("no ATE"), std::string::npos) << report.ate_note;
}

TEST_F(EvaluationTest, FramesWithoutValidDepthAreLeftOut) {
  const Sequence sequence = MakeSequence(3);
  SequenceResult result = PerfectResult(sequence);
  result.depth[1].setTo(std::numeric_limits<float>::quiet_NaN());
  // Half of frame 2 invalid: coverage drops, the metrics stay exact.
  result.depth[2](cv::Rect(0, 0, result.depth[2].cols / 2, result.depth[2].rows)).setTo(0.0f);
  const EvaluationReport report = EvaluateResult(result, sequence);
  EXPECT_EQ(report.num_depth_frames, 2);
  EXPECT_FALSE(report.frames[1].depth.has_value());
  EXPECT_EQ(report.frames[1].depth_coverage, 0.0);
  EXPECT_NEAR(report.frames[2].depth_coverage, 0.5, 0.05);
  EXPECT_EQ(*report.mean_depth_relative_error, 0.0);
  EXPECT_FALSE(report.depth_note.empty());
}

// A wrong border strip outside the centre crop: invisible in the crop's
// error, seen on the full frame; marked NaN, it is left out of the full-frame
// error and lowers the full-frame coverage instead.
TEST_F(EvaluationTest, FullFrameDepthSeesTheBorderAndCountsNanAsUncovered) {
  const Sequence sequence = MakeSequence(3);
  SequenceResult result = PerfectResult(sequence);
  const int strip_width = result.depth[0].cols / 10;  // inside the 15 % the 70 % crop leaves out
  const cv::Rect strip(result.depth[0].cols - strip_width, 0, strip_width, result.depth[0].rows);
  // The ground truth has one unknown pixel per frame (outside the strip).
  const double strip_share = static_cast<double>(strip.area()) / (result.depth[0].total() - 1);
  for (cv::Mat& depth : result.depth) depth(strip) *= 2.0;
  const EvaluationReport wrong = EvaluateResult(result, sequence);
  EXPECT_EQ(*wrong.mean_depth_relative_error, 0.0);
  ASSERT_TRUE(wrong.mean_depth_relative_error_full_frame.has_value());
  EXPECT_NEAR(*wrong.mean_depth_relative_error_full_frame, strip_share, 1e-9);  // the strip is off by 100 %
  EXPECT_DOUBLE_EQ(wrong.mean_depth_coverage_full_frame, 1.0);

  for (cv::Mat& depth : result.depth) depth(strip).setTo(std::numeric_limits<float>::quiet_NaN());
  const EvaluationReport masked = EvaluateResult(result, sequence);
  EXPECT_EQ(*masked.mean_depth_relative_error_full_frame, 0.0);
  EXPECT_DOUBLE_EQ(masked.mean_depth_coverage, 1.0);
  EXPECT_NEAR(masked.mean_depth_coverage_full_frame, 1.0 - strip_share, 1e-9);
  ASSERT_TRUE(masked.frames[0].depth_full_frame.has_value());
  const std::string json = ToJson(masked, "masked");
  EXPECT_NE(json.find("\"depth_coverage_full_frame\": 0.9"), std::string::npos) << json;  // 0.916...
  EXPECT_NE(json.find("\"depth_relative_error_full_frame\": 0.0"), std::string::npos) << json;
}

TEST_F(EvaluationTest, MismatchedResultsAreInputErrors) {
  const Sequence sequence = MakeSequence(3);
  SequenceResult result = PerfectResult(sequence);
  result.frames.pop_back();
  result.latent.pop_back();
  result.depth.pop_back();
  result.poses.pop_back();
  ExpectInputError([&] { EvaluateResult(result, sequence); }, {"2 frames", "3"});

  result = PerfectResult(sequence);
  for (cv::Mat& latent : result.latent) cv::resize(latent, latent, cv::Size(24, 20));
  ExpectInputError([&] { EvaluateResult(result, sequence); }, {"24x20", "48x40"});

  result = PerfectResult(sequence);
  for (FrameRecord& frame : result.frames) frame.stamp += 1.0;
  ExpectInputError([&] { EvaluateResult(result, sequence); }, {"another sequence"});

  Sequence no_gt = sequence;
  no_gt.ground_truth.reset();
  ExpectInputError([&] { EvaluateResult(PerfectResult(sequence), no_gt); }, {"ground truth"});

  EvaluationOptions options;
  options.crop_fraction = 1.5;
  ExpectInputError([&] { EvaluateResult(PerfectResult(sequence), sequence, options); },
                   {"crop_fraction must be in [0, 1], got 1.5"});
}

TEST_F(EvaluationTest, MarkdownAndJsonCarryTheNumbers) {
  const Sequence sequence = MakeSequence(4);
  SequenceResult result = PerfectResult(sequence);
  for (cv::Mat& latent : result.latent) latent += cv::Scalar::all(10);  // 28.13 dB
  for (cv::Mat& depth : result.depth) depth.at<float>(20, 24) *= 1.5f;
  result.poses[2].T_world_cam =
      SE3(result.poses[2].T_world_cam.rotation(),
          result.poses[2].T_world_cam.translation() + Eigen::Vector3d(0.05, 0.0, 0.0));
  const EvaluationReport report = EvaluateResult(result, sequence);
  ASSERT_TRUE(report.ate_rmse.has_value());
  ASSERT_TRUE(report.mean_depth_psnr_db.has_value());
  auto fixed = [](double value, int decimals) {
    char buffer[64];
    std::snprintf(buffer, sizeof(buffer), "%.*f", decimals, value);
    return std::string(buffer);
  };
  const std::string markdown = ToMarkdown(report, "my|method");
  EXPECT_NE(markdown.find("| my\\|method | 28.13 | " + fixed(report.mean_bicubic_psnr_db, 2)),
            std::string::npos)
      << markdown;
  EXPECT_NE(markdown.find(fixed(*report.mean_depth_psnr_db, 2) + " | " +
                          fixed(*report.mean_depth_relative_error, 4) + " | " + fixed(*report.ate_rmse, 4)),
            std::string::npos)
      << markdown;
  EXPECT_NE(markdown.find("tab:quantBlur"), std::string::npos);
  EXPECT_NE(markdown.find("tab:quant)"), std::string::npos);

  const std::string json = ToJson(report, "my \"method\"");
  EXPECT_NE(json.find("\"method\": \"my \\\"method\\\"\""), std::string::npos) << json;
  EXPECT_NE(json.find("\"image_psnr_db\": 28.13"), std::string::npos) << json;
  EXPECT_NE(json.find("\"ate_rmse\": "), std::string::npos);
  EXPECT_EQ(json.find("inf"), std::string::npos) << json;
  EXPECT_EQ(json.find("nan"), std::string::npos) << json;
  EXPECT_EQ(std::count(json.begin(), json.end(), '{'), std::count(json.begin(), json.end(), '}'));
  EXPECT_EQ(std::count(json.begin(), json.end(), '['), std::count(json.begin(), json.end(), ']'));
  // The numbers read back exactly.
  const nlohmann::json parsed = nlohmann::json::parse(json);
  EXPECT_EQ(parsed["mean"]["ate_rmse"].get<double>(), *report.ate_rmse);
  EXPECT_EQ(parsed["mean"]["image_psnr_db"].get<double>(), report.mean_image_psnr_db);
  EXPECT_EQ(parsed["frames"][1]["depth_scale"].get<double>(), report.frames[1].depth->scale);

  // An exact match is "inf" in Markdown and null in JSON.
  const EvaluationReport perfect = EvaluateResult(PerfectResult(sequence), sequence);
  EXPECT_NE(ToMarkdown(perfect, "gt").find("| gt | inf |"), std::string::npos);
  EXPECT_NE(ToJson(perfect, "gt").find("\"image_psnr_db\": null"), std::string::npos);
}

TEST_F(EvaluationTest, JsonIsStrictWithNanAndAwkwardStrings) {
  const Sequence sequence = MakeSequence(4);
  EvaluationReport report = EvaluateResult(PerfectResult(sequence), sequence);
  report.mean_bicubic_psnr_db = std::numeric_limits<double>::quiet_NaN();
  report.frames[2].bicubic_psnr_db = -std::numeric_limits<double>::infinity();
  report.depth_note = "line one\nline \"two\"\t\x01";
  const std::string method = "my \"quoted\" \\ method\\";
  const std::string json = ToJson(report, method);
  nlohmann::json parsed;
  ASSERT_NO_THROW(parsed = nlohmann::json::parse(json)) << json;  // strict: no NaN, no comments
  EXPECT_EQ(parsed["method"], method);
  EXPECT_EQ(parsed["depth_note"], report.depth_note);
  EXPECT_TRUE(parsed["mean"]["bicubic_psnr_db"].is_null());
  EXPECT_TRUE(parsed["mean"]["image_psnr_db"].is_null());  // +inf: exact match
  EXPECT_TRUE(parsed["frames"][2]["bicubic_psnr_db"].is_null());
  EXPECT_EQ(parsed["frames"].size(), 4u);
  EXPECT_EQ(parsed["frames"][3]["index"], 3);
  // Keys in the documented order.
  std::vector<std::string> keys;
  const nlohmann::ordered_json ordered = nlohmann::ordered_json::parse(json);
  for (const auto& item : ordered.items()) keys.push_back(item.key());
  const std::vector<std::string> expected = {"method",
                                             "num_frames",
                                             "scale",
                                             "hr_width",
                                             "hr_height",
                                             "colour",
                                             "crop_fraction",
                                             "align_depth_scale",
                                             "align_trajectory",
                                             "mean",
                                             "num_depth_frames",
                                             "depth_note",
                                             "ate_note",
                                             "trajectory_alignment",
                                             "frames"};
  EXPECT_EQ(keys, expected);
  // Bytes that are not UTF-8 do not make the writer throw.
  EXPECT_NO_THROW(nlohmann::json::parse(ToJson(report, "bad \xff byte")));
}

// ------------------------------------------------------------------- tools

#ifdef DSM_TOOL_DIR

struct CommandResult {
  int exit_code = -1;
  std::string out;
  std::string err;
};

std::string ReadFile(const std::string& path) {
  std::ifstream in(path);
  std::ostringstream content;
  content << in.rdbuf();
  return content.str();
}

CommandResult RunTool(const std::string& tool, const std::string& arguments, const fs::path& scratch) {
  const std::string out_path = (scratch / (tool + ".stdout")).string();
  const std::string err_path = (scratch / (tool + ".stderr")).string();
  const std::string command =
      std::string(DSM_TOOL_DIR) + "/" + tool + " " + arguments + " >" + out_path + " 2>" + err_path;
  const int status = std::system(command.c_str());
  CommandResult result;
  result.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;  // -1: killed by a signal
  result.out = ReadFile(out_path);
  result.err = ReadFile(err_path);
  return result;
}

int CountLines(const std::string& text) {
  return static_cast<int>(std::count(text.begin(), text.end(), '\n'));
}

TEST_F(EvaluationTest, EvaluateToolRejectsAMissingFolderInOneLine) {
  const Sequence sequence = MakeSequence(3);
  WriteSequence(Path("seq"), sequence);
  const CommandResult missing =
      RunTool("evaluate_sequence", "--result " + Path("nope") + " --sequence " + Path("seq"), dir_);
  EXPECT_EQ(missing.exit_code, 2);
  EXPECT_EQ(CountLines(missing.err), 1) << missing.err;
  EXPECT_NE(missing.err.find(Path("nope")), std::string::npos) << missing.err;

  const CommandResult bad_flag =
      RunTool("evaluate_sequence", "--crop 2 --result " + Path("seq") + " --sequence " + Path("seq"), dir_);
  EXPECT_EQ(bad_flag.exit_code, 2);
  EXPECT_EQ(CountLines(bad_flag.err), 1) << bad_flag.err;
  EXPECT_NE(bad_flag.err.find("--crop"), std::string::npos) << bad_flag.err;

  // A result of another size than the ground truth names both folders.
  SequenceResult result = PerfectResult(sequence);
  result.calibration = sequence.calibration;
  result.latent = sequence.images;
  result.depth.clear();
  WriteResult(Path("lr_result"), result);
  const CommandResult wrong_size =
      RunTool("evaluate_sequence", "--result " + Path("lr_result") + " --sequence " + Path("seq"), dir_);
  EXPECT_EQ(wrong_size.exit_code, 2);
  EXPECT_EQ(CountLines(wrong_size.err), 1) << wrong_size.err;
  EXPECT_NE(wrong_size.err.find("24x20"), std::string::npos) << wrong_size.err;
}

TEST_F(EvaluationTest, EvaluateToolPrintsTablesAndWritesJson) {
  const Sequence sequence = MakeSequence(3);
  WriteSequence(Path("seq"), sequence);
  SequenceResult result = PerfectResult(sequence);
  for (cv::Mat& latent : result.latent) latent += cv::Scalar::all(10);
  WriteResult(Path("proposed"), result);
  const CommandResult run = RunTool("evaluate_sequence",
                                    "--result " + Path("proposed") + " --sequence " + Path("seq") +
                                        " --json " + Path("eval/metrics.json") + " --crop 0.5",
                                    dir_);
  ASSERT_EQ(run.exit_code, 0) << run.err;
  EXPECT_NE(run.out.find("| proposed | 28.13 |"), std::string::npos) << run.out;
  EXPECT_NE(run.out.find("| proposed | inf | 0.0000 | 0.0000 |"), std::string::npos) << run.out;
  const std::string json = ReadFile(Path("eval/metrics.json"));
  EXPECT_NE(json.find("\"crop_fraction\": 0.5"), std::string::npos) << json;
  EXPECT_NE(json.find("\"method\": \"proposed\""), std::string::npos) << json;
}

TEST_F(EvaluationTest, SuperresBtvl1WritesAnImageOnlyResult) {
  if (!fs::exists(fs::path(DSM_TOOL_DIR) / "superres_btvl1")) {
    GTEST_SKIP() << "superres_btvl1 not built (no OpenCV superres module)";
  }
  // Frames of one texture shifted by 2 HR px each, box-downsampled.
  const cv::Mat scene = Texture(cv::Size(80, 60), 7);
  Sequence sequence = MakeSequence(3);
  for (int i = 0; i < 3; ++i) {
    sequence.ground_truth->latent[i] = scene(cv::Rect(2 * i, i, 48, 40)).clone();
    sequence.images[i] = ToImage8(DownsampleBox(ToFloat01(sequence.ground_truth->latent[i]), kScale));
  }
  WriteSequence(Path("seq"), sequence);
  const CommandResult run =
      RunTool("superres_btvl1",
              "--input " + Path("seq") + " --output " + Path("btv") + " --iterations 10 --threads 1", dir_);
  ASSERT_EQ(run.exit_code, 0) << run.err;
  const SequenceResult result = ReadResult(Path("btv"));
  ASSERT_EQ(result.latent.size(), 3u);
  EXPECT_EQ(result.latent[0].size(), cv::Size(48, 40));
  EXPECT_EQ(result.latent[0].type(), CV_8UC3);
  EXPECT_FALSE(result.HasDepth());
  EXPECT_FALSE(result.HasPoses());
  const PinholeCamera expected = sequence.calibration.camera.Upscaled(kScale);
  EXPECT_DOUBLE_EQ(result.calibration.camera.cx, expected.cx);
  EXPECT_DOUBLE_EQ(result.calibration.camera.fy, expected.fy);
  EXPECT_NE(result.report_json.find("\"temporal_radius\": 2"), std::string::npos)
      << result.report_json;  // capped at frames - 1
  // Each output is its own frame, not a neighbour: closest to its ground truth.
  for (int k = 0; k < 3; ++k) {
    const double own = Psnr(result.latent[k], sequence.ground_truth->latent[k], 255.0);
    for (int j = 0; j < 3; ++j) {
      if (j == k) continue;
      EXPECT_GT(own, Psnr(result.latent[k], sequence.ground_truth->latent[j], 255.0) + 1.0);
    }
  }
  const CommandResult evaluated =
      RunTool("evaluate_sequence", "--result " + Path("btv") + " --sequence " + Path("seq"), dir_);
  EXPECT_EQ(evaluated.exit_code, 0) << evaluated.err;

  const CommandResult missing =
      RunTool("superres_btvl1", "--input " + Path("none") + " --output " + Path("x"), dir_);
  EXPECT_EQ(missing.exit_code, 2);
  EXPECT_EQ(CountLines(missing.err), 1) << missing.err;
  EXPECT_NE(missing.err.find(Path("none")), std::string::npos) << missing.err;
}

#endif  // DSM_TOOL_DIR

}  // namespace
}  // namespace deblur_sr_mvs
