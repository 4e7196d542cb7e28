// Integration test of sequence_to_bag and bag_to_sequence (docs/tools.md):
// a synthesized sequence (synthesize_sequence) and hand-made ones go to a bag
// and back, exactly (images bitwise, stamps and exposures to 1 ns, camera and
// gt as written, a rolling shutter's readout time exactly); malformed bags and
// bad input exit with code 2 and one line on stderr. Runs the installed-style executables; no ROS master
// needed.
#include <sys/wait.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <limits>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include <geometry_msgs/PoseStamped.h>
#include <gtest/gtest.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/TimeReference.h>
#include <std_msgs/Float64.h>
#include <boost/make_shared.hpp>

#include <nlohmann/json.hpp>

#include "deblur_sr_mvs/core/io/sequence_io.h"
#include "status_report.h"

namespace deblur_sr_mvs {
namespace {

namespace fs = std::filesystem;

struct ToolResult {
  int exit_code = -1;  // -1: killed by a signal
  std::string out;
  std::string err;
};

std::string ReadText(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

std::string Quote(const std::string& text) {
  return "'" + text + "'";
}

// Runs `tool arguments...` with stdout and stderr captured in files.
ToolResult RunTool(const std::string& tool, const std::vector<std::string>& arguments,
                   const fs::path& scratch) {
  std::string command = Quote(tool);
  for (const std::string& argument : arguments) command += " " + Quote(argument);
  const fs::path out = scratch / "tool.out";
  const fs::path err = scratch / "tool.err";
  command += " >" + Quote(out.string()) + " 2>" + Quote(err.string());
  const int status = std::system(command.c_str());
  ToolResult result;
  if (status != -1 && WIFEXITED(status)) result.exit_code = WEXITSTATUS(status);
  result.out = ReadText(out);
  result.err = ReadText(err);
  return result;
}

// The error contract: exit code 2 and exactly one non-empty line on stderr
// that contains `needle`.
void ExpectOneLineError(const ToolResult& result, const std::string& needle) {
  EXPECT_EQ(result.exit_code, 2) << "stderr: " << result.err;
  ASSERT_FALSE(result.err.empty());
  EXPECT_EQ(result.err.back(), '\n') << result.err;
  EXPECT_EQ(std::count(result.err.begin(), result.err.end(), '\n'), 1) << result.err;
  EXPECT_NE(result.err.find(needle), std::string::npos) << "expected '" << needle << "' in: " << result.err;
}

bool BitwiseEqual(const cv::Mat& a, const cv::Mat& b) {
  if (a.type() != b.type() || a.size() != b.size()) return false;
  const std::size_t row_bytes = a.cols * a.elemSize();
  for (int row = 0; row < a.rows; ++row) {
    if (std::memcmp(a.ptr(row), b.ptr(row), row_bytes) != 0) return false;
  }
  return true;
}

void ExpectSameCalibration(const CameraCalibration& a, const CameraCalibration& b) {
  EXPECT_EQ(a.camera.width, b.camera.width);
  EXPECT_EQ(a.camera.height, b.camera.height);
  EXPECT_EQ(a.camera.fx, b.camera.fx);
  EXPECT_EQ(a.camera.fy, b.camera.fy);
  EXPECT_EQ(a.camera.cx, b.camera.cx);
  EXPECT_EQ(a.camera.cy, b.camera.cy);
  EXPECT_EQ(a.camera_name, b.camera_name);
  EXPECT_EQ(a.distortion_model, b.distortion_model);
  EXPECT_EQ(a.distortion, b.distortion);
  EXPECT_EQ(a.rectification, b.rectification);
  EXPECT_EQ(a.projection, b.projection);
}

// Images bitwise, stamps and exposures to 1 ns, the camera exactly, gt too.
void ExpectSameSequence(const Sequence& expected, const Sequence& actual, double exposure_tolerance = 1e-9) {
  ExpectSameCalibration(expected.calibration, actual.calibration);
  ASSERT_EQ(expected.frames.size(), actual.frames.size());
  for (std::size_t i = 0; i < expected.frames.size(); ++i) {
    EXPECT_EQ(actual.frames[i].index, expected.frames[i].index);
    EXPECT_NEAR(actual.frames[i].stamp, expected.frames[i].stamp, 1e-9) << "frame " << i;
    EXPECT_NEAR(actual.frames[i].exposure, expected.frames[i].exposure, exposure_tolerance) << "frame " << i;
    EXPECT_TRUE(BitwiseEqual(expected.images[i], actual.images[i])) << "image " << i;
  }
  ASSERT_EQ(expected.ground_truth.has_value(), actual.ground_truth.has_value());
  if (!expected.ground_truth) return;
  const SequenceGroundTruth& a = *expected.ground_truth;
  const SequenceGroundTruth& b = *actual.ground_truth;
  ExpectSameCalibration(a.calibration, b.calibration);
  ASSERT_EQ(a.latent.size(), b.latent.size());
  ASSERT_EQ(a.depth.size(), b.depth.size());
  ASSERT_EQ(a.poses.size(), b.poses.size());
  for (std::size_t i = 0; i < a.latent.size(); ++i) {
    EXPECT_TRUE(BitwiseEqual(a.latent[i], b.latent[i])) << "gt latent " << i;
    EXPECT_TRUE(BitwiseEqual(a.depth[i], b.depth[i])) << "gt depth " << i;  // NaN included
    EXPECT_NEAR(a.poses[i].stamp, b.poses[i].stamp, 1e-9);
    EXPECT_EQ(a.poses[i].T_world_cam.translation(), b.poses[i].T_world_cam.translation());
    EXPECT_LE((a.poses[i].T_world_cam.rotation() - b.poses[i].T_world_cam.rotation()).cwiseAbs().maxCoeff(),
              1e-12);
  }
}

// A sensor_msgs/Image filled by hand (not through cv_bridge), as another
// driver would write it.
sensor_msgs::Image MakeImage(const ros::Time& stamp, int width, int height, const std::string& encoding,
                             int bytes_per_pixel, std::uint8_t seed) {
  sensor_msgs::Image image;
  image.header.stamp = stamp;
  image.header.frame_id = "cam";
  image.width = width;
  image.height = height;
  image.encoding = encoding;
  image.step = width * bytes_per_pixel;
  image.data.resize(static_cast<std::size_t>(image.step) * height);
  for (std::size_t i = 0; i < image.data.size(); ++i) image.data[i] = static_cast<std::uint8_t>(seed + 7 * i);
  return image;
}

sensor_msgs::CameraInfo MakeInfo(const ros::Time& stamp, int width, int height) {
  sensor_msgs::CameraInfo info;
  info.header.stamp = stamp;
  info.header.frame_id = "cam";
  info.width = width;
  info.height = height;
  info.distortion_model = "plumb_bob";
  info.D = {0, 0, 0, 0, 0};
  info.K = {50, 0, width / 2.0, 0, 50, height / 2.0, 0, 0, 1};
  info.R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  info.P = {50, 0, width / 2.0, 0, 0, 50, height / 2.0, 0, 0, 0, 1, 0};
  return info;
}

class BagToolsTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    char pattern[] = "/tmp/dsm_bag_tools_test_XXXXXX";
    const char* made = mkdtemp(pattern);
    ASSERT_NE(made, nullptr);
    root_ = made;
    // A small colour sequence with gt/ and rotating poses (arc path). The
    // exposure fills the frame interval (ratio 1): the tightest case for
    // stamps rounded to the ROS nanosecond.
    const ToolResult synth =
        RunTool(DSM_SYNTHESIZE_SEQUENCE,
                {"--scene", std::string(DSM_SOURCE_DIR) + "/data/middlebury/Dolls", "--output",
                 (root_ / "synth").string(), "--frames", "4", "--subframes", "51", "--hr-width", "96",
                 "--hr-height", "64", "--path", "arc", "--exposure-ratio", "1"},
                root_);
    ASSERT_EQ(synth.exit_code, 0) << synth.err;
  }
  static void TearDownTestSuite() {
    std::error_code ignored;
    fs::remove_all(root_, ignored);
  }

  void SetUp() override {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    dir_ = root_ / info->name();
    fs::create_directories(dir_);
  }

  static ToolResult ToBag(const fs::path& sequence, const fs::path& bag,
                          std::vector<std::string> extra = {}) {
    std::vector<std::string> arguments = {"--input", sequence.string(), "--output", bag.string()};
    arguments.insert(arguments.end(), extra.begin(), extra.end());
    return RunTool(DSM_SEQUENCE_TO_BAG, arguments, root_);
  }
  static ToolResult ToSequence(const fs::path& bag, const fs::path& sequence,
                               std::vector<std::string> extra = {}) {
    std::vector<std::string> arguments = {"--input", bag.string(), "--output", sequence.string()};
    arguments.insert(arguments.end(), extra.begin(), extra.end());
    return RunTool(DSM_BAG_TO_SEQUENCE, arguments, root_);
  }

  // Writes a bag by hand (for the malformed cases).
  void WriteBag(const fs::path& path, const std::function<void(rosbag::Bag*)>& fill) {
    rosbag::Bag bag;
    bag.open(path.string(), rosbag::bagmode::Write);
    fill(&bag);
    bag.close();
  }

  static fs::path root_;
  fs::path dir_;
};

fs::path BagToolsTest::root_;

TEST_F(BagToolsTest, SynthesizedColourSequenceRoundTripsWithGroundTruth) {
  const fs::path synth = root_ / "synth";
  const ToolResult to_bag = ToBag(synth, dir_ / "seq.bag");
  ASSERT_EQ(to_bag.exit_code, 0) << to_bag.err;
  EXPECT_TRUE(to_bag.err.empty()) << to_bag.err;
  const ToolResult to_seq = ToSequence(dir_ / "seq.bag", dir_ / "back");
  ASSERT_EQ(to_seq.exit_code, 0) << to_seq.err;
  EXPECT_TRUE(to_seq.err.empty()) << to_seq.err;

  const Sequence original = ReadSequence(synth.string(), true);
  ASSERT_TRUE(original.ground_truth.has_value());
  ASSERT_EQ(original.images.front().channels(), 3);
  const Sequence restored = ReadSequence((dir_ / "back").string(), true);
  ExpectSameSequence(original, restored);

  // A second round trip changes nothing: stamps and exposures are already on
  // the nanosecond grid, so those files are identical. Poses pass through a
  // rotation matrix (quaternion -> SE3 -> quaternion), which is exact to a
  // few ulps only, not bit for bit (it depends on the compiler's contraction).
  ASSERT_EQ(ToBag(dir_ / "back", dir_ / "again.bag").exit_code, 0);
  ASSERT_EQ(ToSequence(dir_ / "again.bag", dir_ / "again").exit_code, 0);
  for (const char* file : {"frames.csv", "camera.yaml", "gt/camera.yaml"}) {
    EXPECT_EQ(ReadText(dir_ / "back" / file), ReadText(dir_ / "again" / file)) << file;
  }
  const std::vector<StampedPose> poses_back = ReadTumTrajectory((dir_ / "back/gt/poses.txt").string());
  const std::vector<StampedPose> poses_again = ReadTumTrajectory((dir_ / "again/gt/poses.txt").string());
  ASSERT_EQ(poses_back.size(), poses_again.size());
  for (size_t i = 0; i < poses_back.size(); ++i) {
    EXPECT_EQ(poses_back[i].stamp, poses_again[i].stamp) << i;
    EXPECT_EQ(poses_back[i].T_world_cam.translation(), poses_again[i].T_world_cam.translation()) << i;
    EXPECT_LT((poses_back[i].T_world_cam.rotation() - poses_again[i].T_world_cam.rotation()).norm(), 1e-14)
        << i;
  }
}

TEST_F(BagToolsTest, BagHoldsTheDocumentedTopicsAndEncodings) {
  const fs::path synth = root_ / "synth";
  ASSERT_EQ(ToBag(synth, dir_ / "seq.bag", {"--frame-id", "cam_optical"}).exit_code, 0);
  const Sequence original = ReadSequence(synth.string(), true);

  rosbag::Bag bag;
  bag.open((dir_ / "seq.bag").string(), rosbag::bagmode::Read);
  std::vector<sensor_msgs::ImageConstPtr> images, gt_images, gt_depths;
  std::vector<sensor_msgs::CameraInfoConstPtr> infos, gt_infos;
  std::vector<sensor_msgs::TimeReferenceConstPtr> exposures;
  std::vector<geometry_msgs::PoseStampedConstPtr> poses;
  std::string camera_name;
  for (const rosbag::MessageInstance& m : rosbag::View(bag)) {
    const std::string& topic = m.getTopic();
    if (topic == "/camera/image_raw") images.push_back(m.instantiate<sensor_msgs::Image>());
    if (topic == "/camera/camera_info") {
      infos.push_back(m.instantiate<sensor_msgs::CameraInfo>());
      camera_name = m.getConnectionHeader()->at("camera_name");
    }
    if (topic == "/camera/exposure") exposures.push_back(m.instantiate<sensor_msgs::TimeReference>());
    if (topic == "/gt/image") gt_images.push_back(m.instantiate<sensor_msgs::Image>());
    if (topic == "/gt/depth") gt_depths.push_back(m.instantiate<sensor_msgs::Image>());
    if (topic == "/gt/camera_info") gt_infos.push_back(m.instantiate<sensor_msgs::CameraInfo>());
    if (topic == "/gt/pose") poses.push_back(m.instantiate<geometry_msgs::PoseStamped>());
  }
  const std::size_t count = original.frames.size();
  for (std::size_t n : {images.size(), infos.size(), exposures.size(), gt_images.size(), gt_depths.size(),
                        gt_infos.size(), poses.size()}) {
    ASSERT_EQ(n, count);
  }
  EXPECT_EQ(camera_name, original.calibration.camera_name);
  for (std::size_t i = 0; i < count; ++i) {
    const ros::Time stamp = ros::Time().fromSec(original.frames[i].stamp);
    const sensor_msgs::Image& image = *images[i];
    EXPECT_EQ(image.header.stamp, stamp);
    EXPECT_EQ(image.header.frame_id, "cam_optical");
    EXPECT_EQ(image.encoding, "rgb8");
    // Same header on image, camera_info and exposure.
    EXPECT_EQ(infos[i]->header.stamp, stamp);
    EXPECT_EQ(infos[i]->header.frame_id, "cam_optical");
    EXPECT_EQ(exposures[i]->header.stamp, stamp);
    EXPECT_NEAR((exposures[i]->header.stamp - exposures[i]->time_ref).toSec(), original.frames[i].exposure,
                1e-9);
    // RGB byte order in the message, BGR in OpenCV.
    const cv::Vec3b bgr = original.images[i].at<cv::Vec3b>(0, 1);
    EXPECT_EQ(image.data[3], bgr[2]);
    EXPECT_EQ(image.data[4], bgr[1]);
    EXPECT_EQ(image.data[5], bgr[0]);
    // CameraInfo from camera.yaml.
    const CameraCalibration& calibration = original.calibration;
    EXPECT_EQ(infos[i]->width, static_cast<std::uint32_t>(calibration.camera.width));
    EXPECT_EQ(infos[i]->height, static_cast<std::uint32_t>(calibration.camera.height));
    EXPECT_EQ(infos[i]->K[0], calibration.camera.fx);
    EXPECT_EQ(infos[i]->K[2], calibration.camera.cx);
    EXPECT_EQ(infos[i]->K[4], calibration.camera.fy);
    EXPECT_EQ(infos[i]->K[5], calibration.camera.cy);
    EXPECT_EQ(infos[i]->K[8], 1.0);
    EXPECT_EQ(infos[i]->P[0], calibration.projection(0, 0));
    EXPECT_EQ(infos[i]->distortion_model, calibration.distortion_model);
    EXPECT_EQ(infos[i]->D, calibration.distortion);
    // Ground truth.
    EXPECT_EQ(gt_depths[i]->encoding, "32FC1");
    EXPECT_EQ(gt_images[i]->encoding, "rgb8");
    EXPECT_EQ(gt_images[i]->width,
              static_cast<std::uint32_t>(original.ground_truth->calibration.camera.width));
    EXPECT_EQ(gt_infos[i]->header.stamp, stamp);
    EXPECT_EQ(poses[i]->header.frame_id, "world");
    EXPECT_EQ(poses[i]->pose.position.x, original.ground_truth->poses[i].T_world_cam.translation().x());
  }
  bag.close();
}

// A gray sequence written through the core API: varying exposures, distortion,
// a custom P and camera name, epoch stamps; and one frame pair whose stamps
// round towards each other, so that an exposure filling the interval exceeds
// the rounded interval by 1 ns and is clamped to it.
TEST_F(BagToolsTest, GraySequenceWithEpochStampsRoundTrips) {
  Sequence sequence;
  sequence.calibration.camera = PinholeCamera(20, 15, 31.5, 32.25, 9.75, 7.125);
  sequence.calibration.camera_name = "left camera: gray";
  sequence.calibration.distortion = {-0.1, 0.02, 0.001, -0.002, 0.0};
  sequence.calibration.rectification << 1, 0, 0, 0, 0.99, 0.01, 0, -0.01, 0.99;
  sequence.calibration.projection << 30, 0, 9.5, 0.5, 0, 30, 7, 0, 0, 0, 1, 0;
  const double base = 1700000000.0;
  const std::vector<double> stamps = {base + 0.25, base + 0.3, base + 0.375, base + 0.5};
  const std::vector<double> exposures = {0.01, 0.05, 0.0625, 0.02};
  std::mt19937 random(5);
  for (std::size_t i = 0; i < stamps.size(); ++i) {
    sequence.frames.push_back({static_cast<int>(i), stamps[i], exposures[i]});
    cv::Mat image(15, 20, CV_8UC1);
    for (int p = 0; p < image.rows * image.cols; ++p) image.data[p] = static_cast<std::uint8_t>(random());
    sequence.images.push_back(image);
  }
  WriteSequence((dir_ / "gray").string(), sequence);
  const Sequence original = ReadSequence((dir_ / "gray").string(), true);
  ASSERT_FALSE(original.ground_truth.has_value());

  ASSERT_EQ(ToBag(dir_ / "gray", dir_ / "gray.bag", {"--compression", "lz4"}).exit_code, 0);
  const ToolResult back = ToSequence(dir_ / "gray.bag", dir_ / "back");
  ASSERT_EQ(back.exit_code, 0) << back.err;
  const Sequence restored = ReadSequence((dir_ / "back").string(), true);
  ExpectSameSequence(original, restored);

  // Stamps 1.0000000006 and 1.0100000004 round to 1.000000001 and 1.01: the
  // exposure 0.0099999998 (the whole interval) becomes 10 ms in the bag, 1 ns
  // more than the rounded interval, and is clamped to it.
  Sequence tight = sequence;
  tight.frames = {{0, 1.0000000006, 0.0099999998},
                  {1, 1.0100000004, 0.0099999998},
                  {2, 1.0200000004, 0.005},
                  {3, 1.0300000004, 0.005}};
  WriteSequence((dir_ / "tight").string(), tight);
  ASSERT_EQ(ToBag(dir_ / "tight", dir_ / "tight.bag").exit_code, 0);
  const ToolResult tight_back = ToSequence(dir_ / "tight.bag", dir_ / "tight_back");
  ASSERT_EQ(tight_back.exit_code, 0) << tight_back.err;
  const Sequence tight_restored = ReadSequence((dir_ / "tight_back").string(), true);
  ExpectSameSequence(ReadSequence((dir_ / "tight").string(), true), tight_restored, 2e-9);
  EXPECT_EQ(tight_restored.frames[1].exposure,
            tight_restored.frames[1].stamp - tight_restored.frames[0].stamp);
}

// The values of the std_msgs/Float64 messages on `topic`, with their bag
// times and (the last one's) connection header.
std::vector<double> ReadoutMessages(const fs::path& bag_path, const std::string& topic,
                                    std::vector<ros::Time>* bag_times = nullptr,
                                    ros::M_string* connection = nullptr) {
  rosbag::Bag bag;
  bag.open(bag_path.string(), rosbag::bagmode::Read);
  std::vector<double> values;
  for (const rosbag::MessageInstance& m : rosbag::View(bag, rosbag::TopicQuery(topic))) {
    values.push_back(m.instantiate<std_msgs::Float64>()->data);
    if (bag_times != nullptr) bag_times->push_back(m.getTime());
    if (connection != nullptr) *connection = *m.getConnectionHeader();
  }
  bag.close();
  return values;
}

// A rolling-shutter sequence (sensor.yaml) keeps its readout time exactly:
// one latched std_msgs/Float64 at the first frame's bag time, back to
// sensor.yaml; --readout-time overrides it, --readout-topic renames it.
TEST_F(BagToolsTest, RollingShutterReadoutTimeRoundTripsExactly) {
  const fs::path synth = dir_ / "rolling";
  const ToolResult made = RunTool(DSM_SYNTHESIZE_SEQUENCE,
                                  {"--scene", std::string(DSM_SOURCE_DIR) + "/data/middlebury/Dolls",
                                   "--output", synth.string(), "--frames", "3", "--subframes", "51",
                                   "--hr-width", "96", "--hr-height", "64", "--readout-ratio", "0.8"},
                                  dir_);
  ASSERT_EQ(made.exit_code, 0) << made.err;
  const Sequence original = ReadSequence(synth.string(), true);
  ASSERT_GT(original.readout_time, 0.0);

  const ToolResult to_bag = ToBag(synth, dir_ / "rolling.bag");
  ASSERT_EQ(to_bag.exit_code, 0) << to_bag.err;
  std::vector<ros::Time> bag_times;
  ros::M_string connection;
  const std::vector<double> values =
      ReadoutMessages(dir_ / "rolling.bag", "/camera/readout_time", &bag_times, &connection);
  ASSERT_EQ(values.size(), 1u);
  EXPECT_EQ(values[0], original.readout_time);  // bit for bit
  EXPECT_EQ(bag_times[0], ros::Time().fromSec(original.frames[0].stamp));
  EXPECT_EQ(connection["latching"], "1");
  EXPECT_EQ(connection["type"], "std_msgs/Float64");
  EXPECT_NE(connection["readout_convention"].find("row 0"), std::string::npos);

  const ToolResult back = ToSequence(dir_ / "rolling.bag", dir_ / "back");
  ASSERT_EQ(back.exit_code, 0) << back.err;
  EXPECT_NE(back.out.find("readout time"), std::string::npos) << back.out;
  const Sequence restored = ReadSequence((dir_ / "back").string(), true);
  ExpectSameSequence(original, restored);
  EXPECT_EQ(restored.readout_time, original.readout_time);
  EXPECT_EQ(ReadText(synth / "sensor.yaml"), ReadText(dir_ / "back" / "sensor.yaml"));

  // --readout-time sets or overrides the topic; 0 = global shutter.
  ASSERT_EQ(ToSequence(dir_ / "rolling.bag", dir_ / "back", {"--readout-time", "0.0125"}).exit_code, 0);
  EXPECT_EQ(ReadSequence((dir_ / "back").string(), false).readout_time, 0.0125);
  ASSERT_EQ(ToSequence(dir_ / "rolling.bag", dir_ / "back", {"--readout-time", "0"}).exit_code, 0);
  EXPECT_FALSE(fs::exists(dir_ / "back" / "sensor.yaml"));  // the stale one is gone
  EXPECT_EQ(ReadSequence((dir_ / "back").string(), false).readout_time, 0.0);

  // Another topic name, in both tools.
  ASSERT_EQ(ToBag(synth, dir_ / "renamed.bag", {"--readout-topic", "/cam/rs"}).exit_code, 0);
  EXPECT_TRUE(ReadoutMessages(dir_ / "renamed.bag", "/camera/readout_time").empty());
  ASSERT_EQ(ToSequence(dir_ / "renamed.bag", dir_ / "renamed", {"--readout-topic", "/cam/rs"}).exit_code, 0);
  EXPECT_EQ(ReadSequence((dir_ / "renamed").string(), false).readout_time, original.readout_time);
}

// A global-shutter sequence: no readout topic, no sensor.yaml, and the same
// bag byte for byte each time.
TEST_F(BagToolsTest, GlobalShutterSequenceHasNoReadoutTopic) {
  const fs::path synth = root_ / "synth";
  ASSERT_EQ(ReadSequence(synth.string(), false).readout_time, 0.0);
  ASSERT_EQ(ToBag(synth, dir_ / "a.bag").exit_code, 0);
  ASSERT_EQ(ToBag(synth, dir_ / "b.bag").exit_code, 0);
  EXPECT_TRUE(ReadText(dir_ / "a.bag") == ReadText(dir_ / "b.bag"));
  rosbag::Bag bag;
  bag.open((dir_ / "a.bag").string(), rosbag::bagmode::Read);
  for (const rosbag::ConnectionInfo* connection : rosbag::View(bag).getConnections()) {
    EXPECT_NE(connection->datatype, "std_msgs/Float64") << connection->topic;
  }
  bag.close();
  const ToolResult back = ToSequence(dir_ / "a.bag", dir_ / "back");
  ASSERT_EQ(back.exit_code, 0) << back.err;
  EXPECT_FALSE(fs::exists(dir_ / "back" / "sensor.yaml"));
  EXPECT_EQ(back.out.find("readout"), std::string::npos) << back.out;
}

// Readout times a sequence cannot have are refused with one line naming the
// problem, and nothing is written.
TEST_F(BagToolsTest, BadReadoutTimesAreRefused) {
  // Frames 0.1 s apart; the readout messages as given.
  const auto bag_with = [this](const std::string& name, const std::vector<double>& readouts) {
    WriteBag(dir_ / name, [&readouts](rosbag::Bag* bag) {
      for (int i = 0; i < 3; ++i) {
        const ros::Time stamp(10, 100000000 * i);
        bag->write("/camera/image_raw", stamp, MakeImage(stamp, 8, 6, "mono8", 1, i));
        bag->write("/camera/camera_info", stamp, MakeInfo(stamp, 8, 6));
        if (i < static_cast<int>(readouts.size())) {
          std_msgs::Float64 readout;
          readout.data = readouts[i];
          bag->write("/camera/readout_time", stamp, readout);
        }
      }
    });
    return dir_ / name;
  };
  const std::vector<std::string> exposure = {"--exposure", "0.05"};
  const auto refused = [&](const fs::path& bag, const std::string& needle,
                           std::vector<std::string> extra = {}) {
    SCOPED_TRACE(bag.filename().string() + " " + needle);
    extra.insert(extra.end(), exposure.begin(), exposure.end());
    ExpectOneLineError(ToSequence(bag, dir_ / "out", extra), needle);
    EXPECT_FALSE(fs::exists(dir_ / "out"));
  };
  refused(bag_with("negative.bag", {-0.01}), ">= 0");
  refused(bag_with("nan.bag", {std::numeric_limits<double>::quiet_NaN()}), "finite");
  refused(bag_with("long.bag", {0.2}), "exceeds the frame interval 0.1");
  refused(bag_with("two.bag", {0.01, 0.02}), "differs");
  refused(bag_with("fine.bag", {0.01}), "--readout-time", {"--readout-time", "0.5"});
  refused(bag_with("fine.bag", {0.01}), "--readout-time", {"--readout-time", "-1"});
  refused(bag_with("fine.bag", {0.01}), "--readout-time", {"--readout-time", "nan"});

  // Repeated equal values are one readout time; the whole interval is allowed.
  const ToolResult same = ToSequence(bag_with("same.bag", {0.1, 0.1, 0.1}), dir_ / "same", exposure);
  ASSERT_EQ(same.exit_code, 0) << same.err;
  EXPECT_EQ(ReadSequence((dir_ / "same").string(), false).readout_time, 0.1);

  // The wrong type on the readout topic.
  WriteBag(dir_ / "type.bag", [](rosbag::Bag* bag) {
    const ros::Time stamp(1, 0);
    bag->write("/camera/image_raw", stamp, MakeImage(stamp, 4, 3, "mono8", 1, 0));
    bag->write("/camera/camera_info", stamp, MakeInfo(stamp, 4, 3));
    sensor_msgs::TimeReference wrong;
    wrong.header.stamp = stamp;
    bag->write("/camera/readout_time", stamp, wrong);
  });
  refused(dir_ / "type.bag", "std_msgs/Float64");
}

TEST_F(BagToolsTest, BagWithoutExposureNeedsTheExposureFlag) {
  WriteBag(dir_ / "plain.bag", [](rosbag::Bag* bag) {
    for (int i = 0; i < 3; ++i) {
      const ros::Time stamp(10, 100000000 * i);
      bag->write("/camera/image_raw", stamp, MakeImage(stamp, 8, 6, "mono8", 1, i));
      bag->write("/camera/camera_info", stamp, MakeInfo(stamp, 8, 6));
    }
  });
  ExpectOneLineError(ToSequence(dir_ / "plain.bag", dir_ / "no_exposure"), "--exposure");
  EXPECT_FALSE(fs::exists(dir_ / "no_exposure"));

  const ToolResult with_flag = ToSequence(dir_ / "plain.bag", dir_ / "seq", {"--exposure", "0.04"});
  ASSERT_EQ(with_flag.exit_code, 0) << with_flag.err;
  const Sequence sequence = ReadSequence((dir_ / "seq").string(), true);
  ASSERT_EQ(sequence.frames.size(), 3u);
  for (const FrameRecord& frame : sequence.frames) EXPECT_EQ(frame.exposure, 0.04);
  EXPECT_EQ(sequence.calibration.camera_name, "camera");  // no connection header field

  // An exposure longer than the frame interval is refused, naming the flag.
  ExpectOneLineError(ToSequence(dir_ / "plain.bag", dir_ / "long", {"--exposure", "0.2"}), "--exposure");
  ExpectOneLineError(ToSequence(dir_ / "plain.bag", dir_ / "bad", {"--exposure", "-1"}), "--exposure");
}

TEST_F(BagToolsTest, AcceptsBgr8AndRejectsMono16) {
  WriteBag(dir_ / "bgr.bag", [](rosbag::Bag* bag) {
    for (int i = 0; i < 2; ++i) {
      const ros::Time stamp(5, 500000000 * i);
      bag->write("/cam/image", stamp, MakeImage(stamp, 7, 5, "bgr8", 3, i));
      bag->write("/cam/info", stamp, MakeInfo(stamp, 7, 5));
    }
  });
  const ToolResult bgr =
      ToSequence(dir_ / "bgr.bag", dir_ / "bgr",
                 {"--image-topic", "/cam/image", "--info-topic", "/cam/info", "--exposure", "0.1"});
  ASSERT_EQ(bgr.exit_code, 0) << bgr.err;
  const Sequence sequence = ReadSequence((dir_ / "bgr").string(), false);
  const sensor_msgs::Image expected = MakeImage(ros::Time(5, 500000000), 7, 5, "bgr8", 3, 1);
  ASSERT_EQ(sequence.images[1].type(), CV_8UC3);
  EXPECT_EQ(std::memcmp(sequence.images[1].data, expected.data.data(), expected.data.size()), 0);

  WriteBag(dir_ / "mono16.bag", [](rosbag::Bag* bag) {
    const ros::Time stamp(5, 0);
    bag->write("/camera/image_raw", stamp, MakeImage(stamp, 7, 5, "mono16", 2, 0));
    bag->write("/camera/camera_info", stamp, MakeInfo(stamp, 7, 5));
  });
  ExpectOneLineError(ToSequence(dir_ / "mono16.bag", dir_ / "mono16", {"--exposure", "0.01"}), "mono16");

  WriteBag(dir_ / "short.bag", [](rosbag::Bag* bag) {
    const ros::Time stamp(5, 0);
    sensor_msgs::Image image = MakeImage(stamp, 7, 5, "rgb8", 3, 0);
    image.data.resize(image.data.size() - 1);
    bag->write("/camera/image_raw", stamp, image);
    bag->write("/camera/camera_info", stamp, MakeInfo(stamp, 7, 5));
  });
  ExpectOneLineError(ToSequence(dir_ / "short.bag", dir_ / "short", {"--exposure", "0.01"}),
                     "/camera/image_raw");
}

TEST_F(BagToolsTest, MalformedBagsExitWithOneLine) {
  // No camera_info at all.
  WriteBag(dir_ / "no_info.bag", [](rosbag::Bag* bag) {
    const ros::Time stamp(1, 0);
    bag->write("/camera/image_raw", stamp, MakeImage(stamp, 4, 3, "mono8", 1, 0));
  });
  ExpectOneLineError(ToSequence(dir_ / "no_info.bag", dir_ / "out", {"--exposure", "0.01"}),
                     "/camera/camera_info");

  // A camera_info whose stamp differs from the image's.
  WriteBag(dir_ / "mismatch.bag", [](rosbag::Bag* bag) {
    const ros::Time stamp(1, 0);
    bag->write("/camera/image_raw", stamp, MakeImage(stamp, 4, 3, "mono8", 1, 0));
    bag->write("/camera/camera_info", stamp, MakeInfo(ros::Time(1, 5), 4, 3));
  });
  ExpectOneLineError(ToSequence(dir_ / "mismatch.bag", dir_ / "out", {"--exposure", "0.01"}), "same stamp");

  // A camera_info of another size.
  WriteBag(dir_ / "size.bag", [](rosbag::Bag* bag) {
    const ros::Time stamp(1, 0);
    bag->write("/camera/image_raw", stamp, MakeImage(stamp, 4, 3, "mono8", 1, 0));
    bag->write("/camera/camera_info", stamp, MakeInfo(stamp, 8, 6));
  });
  ExpectOneLineError(ToSequence(dir_ / "size.bag", dir_ / "out", {"--exposure", "0.01"}), "4x3");

  // Header stamps going back (bag time increasing).
  WriteBag(dir_ / "back.bag", [](rosbag::Bag* bag) {
    for (int i = 0; i < 2; ++i) {
      const ros::Time stamp(2 - i, 0);
      bag->write("/camera/image_raw", ros::Time(1 + i, 0), MakeImage(stamp, 4, 3, "mono8", 1, i));
      bag->write("/camera/camera_info", ros::Time(1 + i, 0), MakeInfo(stamp, 4, 3));
    }
  });
  ExpectOneLineError(ToSequence(dir_ / "back.bag", dir_ / "out", {"--exposure", "0.01"}), "increase");

  // The image topic carrying another type.
  WriteBag(dir_ / "type.bag", [](rosbag::Bag* bag) {
    const ros::Time stamp(1, 0);
    bag->write("/camera/image_raw", stamp, MakeInfo(stamp, 4, 3));
  });
  ExpectOneLineError(ToSequence(dir_ / "type.bag", dir_ / "out"), "sensor_msgs/Image");

  // Truncated copies of a good bag, and a file that is no bag at all.
  ASSERT_EQ(ToBag(root_ / "synth", dir_ / "good.bag").exit_code, 0);
  const std::string good = ReadText(dir_ / "good.bag");
  for (const std::size_t length : {std::size_t{0}, std::size_t{12}, std::size_t{100}, good.size() / 3,
                                   good.size() / 2, good.size() - 100, good.size() - 1}) {
    const fs::path truncated = dir_ / ("truncated_" + std::to_string(length) + ".bag");
    std::ofstream(truncated, std::ios::binary) << good.substr(0, length);
    SCOPED_TRACE("truncated to " + std::to_string(length) + " of " + std::to_string(good.size()) + " bytes");
    ExpectOneLineError(ToSequence(truncated, dir_ / "out"), truncated.string());
  }
  std::ofstream(dir_ / "text.bag") << "not a bag\n";
  ExpectOneLineError(ToSequence(dir_ / "text.bag", dir_ / "out"), "text.bag");
  ExpectOneLineError(ToSequence(dir_ / "missing.bag", dir_ / "out"), "missing.bag");
  EXPECT_FALSE(fs::exists(dir_ / "out"));
}

TEST_F(BagToolsTest, BadCommandLinesAndFoldersExitWithOneLine) {
  ExpectOneLineError(ToBag(dir_ / "no_such_sequence", dir_ / "x.bag"), "no_such_sequence");
  EXPECT_FALSE(fs::exists(dir_ / "x.bag"));
  ExpectOneLineError(RunTool(DSM_SEQUENCE_TO_BAG, {"--input"}, dir_), "--input");
  ExpectOneLineError(RunTool(DSM_BAG_TO_SEQUENCE, {"--output", "x"}, dir_), "--input");
  ExpectOneLineError(RunTool(DSM_BAG_TO_SEQUENCE, {"--frobnicate", "x"}, dir_), "--frobnicate");
  EXPECT_EQ(RunTool(DSM_SEQUENCE_TO_BAG, {"--help"}, dir_).exit_code, 0);
  EXPECT_EQ(RunTool(DSM_BAG_TO_SEQUENCE, {"--help"}, dir_).exit_code, 0);

  // A negative stamp cannot become ROS time.
  Sequence sequence;
  sequence.calibration.camera = PinholeCamera(4, 3, 5, 5, 1.5, 1);
  sequence.frames = {{0, -0.5, 0.01}, {1, -0.4, 0.01}};
  sequence.images = {cv::Mat(3, 4, CV_8UC1, cv::Scalar(1)), cv::Mat(3, 4, CV_8UC1, cv::Scalar(2))};
  WriteSequence((dir_ / "negative").string(), sequence);
  ExpectOneLineError(ToBag(dir_ / "negative", dir_ / "negative.bag"), "negative");
  EXPECT_FALSE(fs::exists(dir_ / "negative.bag"));

  // bag_to_sequence writes into a new, empty or sequence folder only, and
  // replaces a sequence folder's frames (no stale frames or gt/ survive).
  ASSERT_EQ(ToBag(root_ / "synth", dir_ / "synth.bag").exit_code, 0);
  fs::create_directories(dir_ / "busy");
  std::ofstream(dir_ / "busy" / "notes.txt") << "mine\n";
  ExpectOneLineError(ToSequence(dir_ / "synth.bag", dir_ / "busy"), "busy");
  EXPECT_TRUE(fs::exists(dir_ / "busy" / "notes.txt"));

  ASSERT_EQ(ToSequence(dir_ / "synth.bag", dir_ / "replaced").exit_code, 0);
  std::ofstream(dir_ / "replaced" / "notes.txt") << "mine\n";
  ASSERT_EQ(ToBag(root_ / "synth", dir_ / "two.bag", {"--no-ground-truth"}).exit_code, 0);
  const ToolResult replaced = ToSequence(dir_ / "two.bag", dir_ / "replaced");
  ASSERT_EQ(replaced.exit_code, 0) << replaced.err;
  EXPECT_FALSE(fs::exists(dir_ / "replaced" / "gt"));
  EXPECT_TRUE(fs::exists(dir_ / "replaced" / "notes.txt"));
  EXPECT_FALSE(ReadSequence((dir_ / "replaced").string(), true).ground_truth.has_value());
}

// bag_to_result's report.json: a window whose iteration was undone has a NaN
// energy; the report is strict JSON with null in its place. The exposures
// come along.
TEST(BagToResultReport, NanEnergyBecomesNullInStrictJson) {
  auto status = boost::make_shared<EstimatorStatus>();
  status->window_index = 1;
  status->success = true;
  status->frame_stamps.resize(3);
  status->message = "iteration 1 lost the energy (not finite): undone, \"quoted\" \\ text";
  status->energies = {12.5, std::numeric_limits<double>::quiet_NaN(), 11.0};
  status->stage_names = {"image update", "structure update"};
  status->stage_seconds = {0.25, std::numeric_limits<double>::infinity()};
  status->processing_seconds = 1.5;
  status->scale_note = "arbitrary";
  status->exposure_source = "topic for 2 of 3 frames, parameter for the rest";
  status->frame_exposures = {0.02, 0.021, 0.01};
  status->frame_gains = {1.0, 1.05, 0.98};
  status->exposures_rejected = 4;
  const std::vector<EstimatorStatusConstPtr> statuses = {status};
  const std::string text = JsonText(StatusReportJson(statuses));
  nlohmann::json report;
  ASSERT_NO_THROW(report = nlohmann::json::parse(text)) << text;
  ASSERT_EQ(report["windows"].size(), 1u);
  const nlohmann::json& window = report["windows"][0];
  EXPECT_EQ(window["frames"], 3);
  EXPECT_EQ(window["message"], status->message);
  ASSERT_EQ(window["energies"].size(), 3u);
  EXPECT_EQ(window["energies"][0].get<double>(), 12.5);
  EXPECT_TRUE(window["energies"][1].is_null());
  EXPECT_TRUE(window["stages"]["structure update"].is_null());
  EXPECT_EQ(report["scale_note"], "arbitrary");
  // The exposure of each frame and where it came from (docs/file_formats.md#report).
  EXPECT_EQ(window["exposure_source"], status->exposure_source);
  ASSERT_EQ(window["frame_exposures"].size(), 3u);
  EXPECT_EQ(window["frame_exposures"][1].get<double>(), 0.021);
  ASSERT_EQ(window["frame_gains"].size(), 3u);
  EXPECT_EQ(window["frame_gains"][1].get<double>(), 1.05);
  EXPECT_EQ(report["exposures_rejected"], 4);
  EXPECT_EQ(nlohmann::json::parse(JsonText(StatusReportJson({})))["windows"].size(), 0u);
}

}  // namespace
}  // namespace deblur_sr_mvs

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
