#include "deblur_sr_mvs/core/io/sequence_io.h"

#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <random>
#include <string>

#include <gtest/gtest.h>
#include <unistd.h>
#include <yaml-cpp/yaml.h>
#include <opencv2/imgcodecs.hpp>

namespace deblur_sr_mvs {
namespace {

namespace fs = std::filesystem;

// A fresh folder per test, removed afterwards.
class SequenceIoTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const ::testing::TestInfo* info = ::testing::UnitTest::GetInstance()->current_test_info();
    dir_ = fs::path(::testing::TempDir()) /
           ("dsm_sequence_io_" + std::string(info->name()) + "_" + std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override {
    std::error_code error;
    fs::remove_all(dir_, error);
  }

  std::string Path(const std::string& name) const { return (dir_ / name).string(); }

  std::string WriteText(const std::string& name, const std::string& content) const {
    const std::string path = Path(name);
    fs::create_directories(fs::path(path).parent_path());
    std::ofstream(path, std::ios::binary) << content;
    return path;
  }

  fs::path dir_;
};

// Runs `read` and checks that it throws InputError whose message contains
// every one of `parts` (the file name, and the line/problem where given).
void ExpectInputError(const std::function<void()>& read, const std::vector<std::string>& parts) {
  try {
    read();
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

void Truncate(const std::string& path, std::uintmax_t size) {
  fs::resize_file(path, size);
}

CameraCalibration AwkwardCalibration() {
  CameraCalibration calibration;
  calibration.camera =
      PinholeCamera(641, 479, 0.1 + 0.2 + 500.0, 1.0 / 3.0 + 499.0, 320.123456789012345, 239.98765432109876);
  calibration.camera_name = "cam: left #1";  // needs quoting
  calibration.distortion_model = "rational_polynomial";
  calibration.distortion = {-0.1234567890123456, 1e-17, 3.0e-300, -2.5, 0.1 + 0.7, 1.0 / 7.0, 0.0, -0.0};
  calibration.rectification << 0.9999, 0.01, -1.0 / 3.0, 2e-8, 1.0, 0.5, 0.25, 0.125, 1.0 / 9.0;
  calibration.projection << 1.0 / 3.0, 0, 320.5, -12.345678901234567, 0, 2.0 / 3.0, 240.25, 1e-9, 0, 0, 1, 0;
  return calibration;
}

// ----------------------------------------------------------- camera.yaml

TEST_F(SequenceIoTest, CameraYamlRoundTripIsExact) {
  const CameraCalibration written = AwkwardCalibration();
  const std::string path = Path("sub/camera.yaml");  // parent created by the writer
  WriteCameraYaml(path, written);
  const CameraCalibration read = ReadCameraYaml(path);
  EXPECT_EQ(read.camera.width, written.camera.width);
  EXPECT_EQ(read.camera.height, written.camera.height);
  EXPECT_EQ(read.camera.fx, written.camera.fx);
  EXPECT_EQ(read.camera.fy, written.camera.fy);
  EXPECT_EQ(read.camera.cx, written.camera.cx);
  EXPECT_EQ(read.camera.cy, written.camera.cy);
  EXPECT_EQ(read.camera_name, written.camera_name);
  EXPECT_EQ(read.distortion_model, written.distortion_model);
  EXPECT_EQ(read.distortion, written.distortion);
  EXPECT_TRUE(read.HasDistortion());
  EXPECT_EQ(read.rectification, written.rectification);
  EXPECT_EQ(read.projection, written.projection);
}

TEST_F(SequenceIoTest, CameraYamlWritesKZeroForZeroProjection) {
  CameraCalibration calibration;
  calibration.camera = PinholeCamera(64, 48, 50.5, 51.5, 31.5, 23.5);
  ASSERT_TRUE(calibration.projection.isZero(0.0));
  const std::string path = Path("camera.yaml");
  WriteCameraYaml(path, calibration);
  const CameraCalibration read = ReadCameraYaml(path);
  Eigen::Matrix<double, 3, 4> expected = Eigen::Matrix<double, 3, 4>::Zero();
  expected.leftCols<3>() = calibration.camera.K();
  EXPECT_EQ(read.projection, expected);
  EXPECT_FALSE(read.HasDistortion());
  EXPECT_EQ(read.camera_name, "camera");

  const CameraCalibration from_camera = CameraCalibration::FromCamera(calibration.camera, "x");
  EXPECT_EQ(from_camera.projection, expected);
  EXPECT_EQ(from_camera.camera_name, "x");
  EXPECT_EQ(from_camera.distortion.size(), 5u);
}

TEST_F(SequenceIoTest, CameraYamlReadsRosStyleFileWithDefaults) {
  // As camera_calibration writes it, with CRLF, comments and a data list over
  // several lines; optional keys are missing.
  const std::string path = WriteText("ros.yaml",
                                     "# calibrated by hand\r\n"
                                     "image_width: 640\r\n"
                                     "image_height: 480\r\n"
                                     "camera_matrix:\r\n"
                                     "  rows: 3\r\n"
                                     "  cols: 3\r\n"
                                     "  data: [ 525.0, 0.0, 319.5,\r\n"
                                     "          0.0, 526.5, 239.5,  # row 2\r\n"
                                     "          0.0, 0.0, 1.0 ]\r\n"
                                     "\r\n"
                                     "distortion_model: 'plumb_bob'\r\n");
  const CameraCalibration read = ReadCameraYaml(path);
  EXPECT_EQ(read.camera.width, 640);
  EXPECT_EQ(read.camera.height, 480);
  EXPECT_EQ(read.camera.fx, 525.0);
  EXPECT_EQ(read.camera.fy, 526.5);
  EXPECT_EQ(read.camera.cx, 319.5);
  EXPECT_EQ(read.camera.cy, 239.5);
  EXPECT_EQ(read.camera_name, "camera");
  EXPECT_EQ(read.distortion_model, "plumb_bob");
  EXPECT_EQ(read.distortion, std::vector<double>(5, 0.0));
  EXPECT_EQ(read.rectification, Eigen::Matrix3d::Identity());
  EXPECT_EQ(read.projection(0, 0), 525.0);
  EXPECT_EQ(read.projection(1, 2), 239.5);
  EXPECT_EQ(read.projection(2, 3), 0.0);

  // Flow-style maps are accepted too.
  const std::string flow =
      WriteText("flow.yaml",
                "image_width: 4\nimage_height: 3\n"
                "camera_matrix: {rows: 3, cols: 3, data: [2, 0, 1.5, 0, 2, 1, 0, 0, 1]}\n"
                "distortion_coefficients: {rows: 1, cols: 0, data: []}\n");
  const CameraCalibration flow_read = ReadCameraYaml(flow);
  EXPECT_EQ(flow_read.camera.cx, 1.5);
  EXPECT_TRUE(flow_read.distortion.empty());
}

TEST_F(SequenceIoTest, CameraYamlErrorsNameFileAndLine) {
  const std::string good_k =
      "camera_matrix:\n  rows: 3\n  cols: 3\n  data: [500, 0, 320, 0, 500, 240, 0, 0, 1]\n";
  const std::string size = "image_width: 640\nimage_height: 480\n";
  auto read = [](const std::string& path) { return [path] { ReadCameraYaml(path); }; };

  ExpectInputError(read(Path("missing.yaml")), {Path("missing.yaml"), "not found"});
  ExpectInputError(read(WriteText("empty.yaml", "")), {"empty.yaml", "empty"});
  ExpectInputError(read(WriteText("blank.yaml", "\n  \n# only a comment\n")), {"blank.yaml", "empty"});
  ExpectInputError(read(WriteText("garbage.yaml", "\x89PNG\x01\x02 garbage here\n")),
                   {"garbage.yaml:1:", "key: value"});
  ExpectInputError(read(WriteText("indent.yaml", size + "   stray: 1\n")), {"indent.yaml:3:", "indentation"});
  ExpectInputError(read(WriteText("nowidth.yaml", "image_height: 480\n" + good_k)),
                   {"nowidth.yaml", "missing key 'image_width'"});
  ExpectInputError(read(WriteText("nok.yaml", size)), {"nok.yaml", "missing key 'camera_matrix'"});
  ExpectInputError(read(WriteText("nodata.yaml", size + "camera_matrix:\n  rows: 3\n  cols: 3\n")),
                   {"nodata.yaml:3:", "missing key 'data'"});
  ExpectInputError(
      read(WriteText(
          "count.yaml",
          size + "camera_matrix:\n  rows: 3\n  cols: 3\n  data: [500, 0, 320, 0, 500, 240, 0, 0]\n")),
      {"count.yaml:6:", "8 values", "9"});
  ExpectInputError(
      read(WriteText("rows.yaml",
                     size + "camera_matrix:\n  rows: 2\n  cols: 3\n  data: [1, 0, 0, 0, 1, 0]\n")),
      {"rows.yaml:4:", "rows is 2, expected 3"});
  ExpectInputError(
      read(WriteText(
          "nan.yaml",
          size + "camera_matrix:\n  rows: 3\n  cols: 3\n  data: [500, 0, abc, 0, 500, 240, 0, 0, 1]\n")),
      {"nan.yaml:6:", "'abc' is not a number"});
  ExpectInputError(read(WriteText("width.yaml", "image_width: 0\nimage_height: 480\n" + good_k)),
                   {"width.yaml:1:", "image_width", "positive"});
  ExpectInputError(read(WriteText("widthtext.yaml", "image_width: wide\nimage_height: 480\n" + good_k)),
                   {"widthtext.yaml:1:", "'wide'"});
  ExpectInputError(
      read(WriteText(
          "focal.yaml",
          size + "camera_matrix:\n  rows: 3\n  cols: 3\n  data: [-500, 0, 320, 0, 500, 240, 0, 0, 1]\n")),
      {"focal.yaml:3:", "focal length"});
  ExpectInputError(
      read(WriteText(
          "skew.yaml",
          size + "camera_matrix:\n  rows: 3\n  cols: 3\n  data: [500, 1, 320, 0, 500, 240, 0, 0, 1]\n")),
      {"skew.yaml:3:", "[fx 0 cx; 0 fy cy; 0 0 1]"});
  ExpectInputError(read(WriteText("unterminated.yaml",
                                  size + "camera_matrix:\n  rows: 3\n  cols: 3\n  data: [500, 0, 320,\n")),
                   {"unterminated.yaml:7:", "closing bracket"});  // yaml-cpp: where the ']' is missing
  ExpectInputError(read(WriteText("dup.yaml", size + "image_width: 320\n" + good_k)),
                   {"dup.yaml:3:", "duplicate key 'image_width'"});
  ExpectInputError(
      read(WriteText(
          "dist.yaml",
          size + good_k + "distortion_coefficients:\n  rows: 1\n  cols: 5\n  data: [0, 0, 0, 0]\n")),
      {"dist.yaml:10:", "4 values"});
  ExpectInputError(
      read(WriteText(
          "proj.yaml",
          size + good_k + "projection_matrix:\n  rows: 3\n  cols: 3\n  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]\n")),
      {"proj.yaml:9:", "cols is 3, expected 4"});
}

TEST_F(SequenceIoTest, CameraYamlKeepsTheCameraCalibrationLayout) {
  // The keys and rows/cols/data matrices that ROS's camera_calibration_parsers read.
  const std::string path = Path("camera.yaml");
  WriteCameraYaml(path, AwkwardCalibration());
  const YAML::Node root = YAML::LoadFile(path);
  ASSERT_TRUE(root.IsMap());
  EXPECT_EQ(root["image_width"].as<int>(), 641);
  EXPECT_EQ(root["image_height"].as<int>(), 479);
  EXPECT_EQ(root["camera_name"].as<std::string>(), "cam: left #1");
  EXPECT_EQ(root["distortion_model"].as<std::string>(), "rational_polynomial");
  const std::pair<const char*, std::pair<int, int>> matrices[] = {{"camera_matrix", {3, 3}},
                                                                  {"distortion_coefficients", {1, 8}},
                                                                  {"rectification_matrix", {3, 3}},
                                                                  {"projection_matrix", {3, 4}}};
  for (const auto& [key, size] : matrices) {
    const YAML::Node matrix = root[key];
    ASSERT_TRUE(matrix.IsMap()) << key;
    EXPECT_EQ(matrix["rows"].as<int>(), size.first) << key;
    EXPECT_EQ(matrix["cols"].as<int>(), size.second) << key;
    ASSERT_TRUE(matrix["data"].IsSequence()) << key;
    EXPECT_EQ(matrix["data"].size(), static_cast<std::size_t>(size.first * size.second)) << key;
  }
  EXPECT_EQ(root["camera_matrix"]["data"][0].as<double>(), 0.1 + 0.2 + 500.0);
}

TEST_F(SequenceIoTest, CameraYamlRoundTripsAwkwardNames) {
  CameraCalibration written = AwkwardCalibration();
  for (const std::string name : {"quote \" and backslash \\", "line\nbreak: #x", "- [a, b]", "", " padded ",
                                 "true", "42", "caf\xc3\xa9"}) {
    written.camera_name = name;
    written.distortion_model = name;
    WriteCameraYaml(Path("camera.yaml"), written);
    const CameraCalibration read = ReadCameraYaml(Path("camera.yaml"));
    EXPECT_EQ(read.camera_name, name);
    EXPECT_EQ(read.distortion_model, name);
  }
}

TEST_F(SequenceIoTest, CameraYamlAcceptsOtherValidYaml) {
  const std::string k = "camera_matrix:\n  rows: 3\n  cols: 3\n  data:\n";
  std::string block_list = k;
  for (const char* value : {"500", "0", "320", "0", "500", "240", "0", "0", "1"}) {
    block_list += std::string("    - ") + value + "\n";
  }
  // An OpenCV-style header, and a block list where camera_calibration writes [a, b, ...].
  const CameraCalibration read = ReadCameraYaml(
      WriteText("block.yaml", "%YAML:1.0\nimage_width: 640\nimage_height: 480\n" + block_list));
  EXPECT_EQ(read.camera.fx, 500.0);
  EXPECT_EQ(read.camera.cy, 240.0);
}

TEST_F(SequenceIoTest, CameraYamlSyntaxErrorsAreOneLine) {
  const std::string size = "image_width: 640\nimage_height: 480\n";
  auto read = [](const std::string& path) { return [path] { ReadCameraYaml(path); }; };
  ExpectInputError(read(WriteText("tab.yaml", size + "camera_matrix:\n\trows: 3\n")), {"tab.yaml:4:"});
  ExpectInputError(read(WriteText("flow.yaml", size + "camera_matrix: {rows: 3\n")),
                   {"flow.yaml:", "missing closing bracket"});
  ExpectInputError(read(WriteText("close.yaml", size + "camera_name: [a]]\n")),
                   {"close.yaml:3:", "unbalanced"});
  ExpectInputError(read(WriteText("escape.yaml", size + "camera_name: \"\\q\x01\"\n")),
                   {"escape.yaml:3:", "invalid YAML"});
  ExpectInputError(read(WriteText("key.yaml", size + "[a, b]: 1\n")), {"key.yaml:3:", "key '[list]'"});
  ExpectInputError(read(WriteText("list.yaml", "- 1\n- 2\n")), {"list.yaml:1:", "key: value"});
  ExpectInputError(read(WriteText("dupk.yaml", size + "camera_matrix: {rows: 3, rows: 3}\n")),
                   {"dupk.yaml:3:", "duplicate key 'rows'"});
  ExpectInputError(read(WriteText("name.yaml", size + "camera_name: {a: 1}\n")), {"name.yaml:3:", "string"});
  ExpectInputError(
      read(WriteText("item.yaml",
                     size + "camera_matrix: {rows: 3, cols: 3, data: [1, 0, 1, 0, 1, 1, 0, 0, [1]]}\n")),
      {"item.yaml:3:", "'[list]' is not a number"});
}

// ------------------------------------------------------------ frames.csv

TEST_F(SequenceIoTest, FramesCsvRoundTrip) {
  std::vector<FrameRecord> written;
  for (int i = 0; i < 5; ++i) {
    FrameRecord frame;
    frame.index = i;
    frame.stamp = 1700000000.0 + 0.1 * i + 1.0 / 3.0;
    frame.exposure = 0.05 + 0.001 * i;
    written.push_back(frame);
  }
  const std::string path = Path("a/frames.csv");
  WriteFramesCsv(path, written);
  const std::vector<FrameRecord> read = ReadFramesCsv(path);
  ASSERT_EQ(read.size(), written.size());
  for (std::size_t i = 0; i < read.size(); ++i) {
    EXPECT_EQ(read[i].index, written[i].index);
    EXPECT_EQ(read[i].stamp, written[i].stamp);
    EXPECT_EQ(read[i].exposure, written[i].exposure);
  }
}

TEST_F(SequenceIoTest, FramesCsvToleratesCrlfTrailingSpaceAndDecimalRounding) {
  // 0.3 - 0.2 < 0.1 in binary; an exposure equal to the decimal interval is fine.
  const std::string path =
      WriteText("frames.csv", "index,stamp,exposure  \r\n0,0.1,0.1\r\n1,0.2,0.1 \r\n2,0.3,0.1\r\n\r\n");
  const std::vector<FrameRecord> frames = ReadFramesCsv(path);
  ASSERT_EQ(frames.size(), 3u);
  EXPECT_EQ(frames[2].stamp, 0.3);
  EXPECT_EQ(
      ReadFramesCsv(WriteText("bom.csv", "\xEF\xBB\xBFindex,stamp,exposure\n0,1,0.5\n1,2,0.5\n")).size(), 2u);
  // A single frame only needs a positive exposure.
  EXPECT_EQ(ReadFramesCsv(WriteText("one.csv", "index,stamp,exposure\n0,5,10\n")).size(), 1u);
}

TEST_F(SequenceIoTest, FramesCsvErrorsNameFileAndLine) {
  auto read = [](const std::string& path) { return [path] { ReadFramesCsv(path); }; };
  const std::string header = "index,stamp,exposure\n";
  ExpectInputError(read(Path("none.csv")), {"none.csv", "not found"});
  ExpectInputError(read(WriteText("empty.csv", "")), {"empty.csv", "empty"});
  ExpectInputError(read(WriteText("header.csv", "idx,t,e\n0,0,0.01\n")), {"header.csv:1:", "header"});
  ExpectInputError(read(WriteText("noframes.csv", header)), {"noframes.csv", "no frames"});
  ExpectInputError(read(WriteText("order.csv", header + "0,0.1,0.05\n1,0.3,0.05\n2,0.2,0.05\n")),
                   {"order.csv:4:", "stamp 0.2 is not after the previous stamp 0.3"});
  ExpectInputError(read(WriteText("dup.csv", header + "0,0.1,0.05\n1,0.1,0.05\n")),
                   {"dup.csv:3:", "is not after"});
  ExpectInputError(read(WriteText("zero.csv", header + "0,0.1,0.05\n1,0.2,0\n")),
                   {"zero.csv:3:", "exposure 0", "> 0"});
  ExpectInputError(read(WriteText("neg.csv", header + "0,0.1,-0.05\n1,0.2,0.05\n")),
                   {"neg.csv:2:", "exposure"});
  ExpectInputError(read(WriteText("long.csv", header + "0,0.1,0.05\n1,0.2,0.05\n2,0.25,0.06\n")),
                   {"long.csv:4:", "exceeds the frame interval", "previous"});
  ExpectInputError(read(WriteText("first.csv", header + "0,0.1,0.2\n1,0.2,0.05\n")),
                   {"first.csv:2:", "exceeds the frame interval", "next"});
  ExpectInputError(read(WriteText("index.csv", header + "0,0.1,0.05\n2,0.2,0.05\n")),
                   {"index.csv:3:", "contiguous"});
  ExpectInputError(read(WriteText("fields.csv", header + "0,0.1\n")), {"fields.csv:2:", "3 fields"});
  ExpectInputError(read(WriteText("text.csv", header + "0,abc,0.05\n")),
                   {"text.csv:2:", "'abc' is not a number"});
  ExpectInputError(read(WriteText("inf.csv", header + "0,0.1,0.05\n1,inf,0.05\n")),
                   {"inf.csv:3:", "not finite"});
  ExpectInputError(read(WriteText("gap.csv", header + "0,0.1,0.05\n\n1,0.2,0.05\n")),
                   {"gap.csv:3:", "empty line"});
}

// ------------------------------------------------------------ TUM poses

TEST_F(SequenceIoTest, TumRoundTrip) {
  std::mt19937 random(7);
  std::normal_distribution<double> normal;
  std::vector<StampedPose> written;
  for (int i = 0; i < 10; ++i) {
    StampedPose pose;
    pose.stamp = 1700000000.0 + 0.033 * i + 1e-7;
    const Eigen::Quaterniond q =
        Eigen::Quaterniond(normal(random), normal(random), normal(random), normal(random)).normalized();
    pose.T_world_cam = SE3(q, Eigen::Vector3d(normal(random), normal(random), 100.0 * normal(random)));
    written.push_back(pose);
  }
  const std::string path = Path("poses.txt");
  WriteTumTrajectory(path, written);
  const std::vector<StampedPose> read = ReadTumTrajectory(path);
  ASSERT_EQ(read.size(), written.size());
  for (std::size_t i = 0; i < read.size(); ++i) {
    EXPECT_NEAR(read[i].stamp, written[i].stamp, 1e-9);
    EXPECT_LT((read[i].T_world_cam.translation() - written[i].T_world_cam.translation()).norm(), 1e-9);
    EXPECT_LT((read[i].T_world_cam.rotation() - written[i].T_world_cam.rotation()).norm(), 1e-9);
  }
}

TEST_F(SequenceIoTest, TumSkipsCommentsAndNormalisesQuaternion) {
  const std::string path = WriteText("poses.txt",
                                     "# timestamp tx ty tz qx qy qz qw\n\n"
                                     "1.5 1 2 3 0 0 0 2\r\n"
                                     "  # indented comment\n"
                                     "2.5\t4 5 6 0 0 1 1   \n");
  const std::vector<StampedPose> poses = ReadTumTrajectory(path);
  ASSERT_EQ(poses.size(), 2u);
  EXPECT_EQ(poses[0].stamp, 1.5);
  EXPECT_LT((poses[0].T_world_cam.rotation() - Eigen::Matrix3d::Identity()).norm(), 1e-12);
  EXPECT_EQ(poses[1].T_world_cam.translation(), Eigen::Vector3d(4, 5, 6));
  // 90 degrees about z: x -> y.
  EXPECT_LT((poses[1].T_world_cam.rotation() * Eigen::Vector3d::UnitX() - Eigen::Vector3d::UnitY()).norm(),
            1e-12);
}

TEST_F(SequenceIoTest, TumErrorsNameFileAndLine) {
  auto read = [](const std::string& path) { return [path] { ReadTumTrajectory(path); }; };
  ExpectInputError(read(Path("none.txt")), {"none.txt", "not found"});
  ExpectInputError(read(WriteText("empty.txt", "")), {"empty.txt", "no poses"});
  ExpectInputError(read(WriteText("short.txt", "# c\n1 0 0 0 0 0 0 1\n2 0 0 0 0 0 1\n")),
                   {"short.txt:3:", "expected 8 values"});
  ExpectInputError(read(WriteText("text.txt", "1 0 0 x 0 0 0 1\n")), {"text.txt:1:", "'x' is not a number"});
  ExpectInputError(read(WriteText("nan.txt", "1 0 0 nan 0 0 0 1\n")), {"nan.txt:1:", "not finite"});
  ExpectInputError(read(WriteText("zero.txt", "1 0 0 0 0 0 0 0\n")), {"zero.txt:1:", "zero norm"});
}

// ------------------------------------------------------------ images

TEST_F(SequenceIoTest, DepthTiffRoundTripIsBitwiseIncludingNan) {
  cv::Mat depth(7, 9, CV_32FC1);
  cv::randu(depth, 0.1f, 20.0f);
  depth.at<float>(0, 0) = std::numeric_limits<float>::quiet_NaN();
  depth.at<float>(3, 4) = 0.0f;
  depth.at<float>(6, 8) = std::numeric_limits<float>::infinity();
  depth.at<float>(2, 1) = 1.0f / 3.0f;
  const std::string path = Path("d/depth.tiff");
  WriteDepthTiff(path, depth);
  const cv::Mat read = ReadDepthTiff(path);
  ASSERT_EQ(read.type(), CV_32FC1);
  ASSERT_EQ(read.size(), depth.size());
  for (int y = 0; y < depth.rows; ++y) {
    EXPECT_EQ(std::memcmp(read.ptr(y), depth.ptr(y), depth.cols * sizeof(float)), 0) << "row " << y;
  }
  EXPECT_TRUE(std::isnan(read.at<float>(0, 0)));
}

TEST_F(SequenceIoTest, DepthTiffErrors) {
  auto read = [](const std::string& path) { return [path] { ReadDepthTiff(path); }; };
  ExpectInputError(read(Path("none.tiff")), {"none.tiff", "not found"});
  ExpectInputError(read(WriteText("empty.tiff", "")), {"empty.tiff", "empty"});
  cv::Mat depth(64, 64, CV_32FC1, cv::Scalar(2.0f));
  const std::string truncated = Path("truncated.tiff");
  WriteDepthTiff(truncated, depth);
  Truncate(truncated, fs::file_size(truncated) / 3);
  ExpectInputError(read(truncated), {"truncated.tiff"});
  const std::string bytes = Path("bytes.tiff");
  ASSERT_TRUE(cv::imwrite(bytes, cv::Mat(4, 4, CV_8UC1, cv::Scalar(3))));
  ExpectInputError(read(bytes), {"bytes.tiff", "float32", "8UC1"});
  ExpectInputError([&] { WriteDepthTiff(Path("x.tiff"), cv::Mat(2, 2, CV_64FC1)); }, {"x.tiff", "32FC1"});
  ExpectInputError([&] { WriteDepthTiff(Path("x.png"), depth); }, {"x.png", ".tiff"});
}

TEST_F(SequenceIoTest, ImageRoundTrip) {
  cv::Mat gray(5, 7, CV_8UC1);
  cv::Mat colour(5, 7, CV_8UC3);
  cv::randu(gray, 0, 256);
  cv::randu(colour, 0, 256);
  WriteImage(Path("i/gray.png"), gray);
  WriteImage(Path("i/colour.png"), colour);
  const cv::Mat gray_read = ReadImage8(Path("i/gray.png"));
  const cv::Mat colour_read = ReadImage8(Path("i/colour.png"));
  ASSERT_EQ(gray_read.type(), CV_8UC1);
  ASSERT_EQ(colour_read.type(), CV_8UC3);
  EXPECT_EQ(cv::norm(gray_read, gray, cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::norm(colour_read, colour, cv::NORM_INF), 0.0);
}

TEST_F(SequenceIoTest, ImageErrors) {
  auto read = [](const std::string& path) { return [path] { ReadImage8(path); }; };
  ExpectInputError(read(Path("none.png")), {"none.png", "not found"});
  ExpectInputError(read(WriteText("empty.png", "")), {"empty.png", "empty"});
  ExpectInputError(read(WriteText("text.png", "this is not a png")), {"text.png", "cannot be decoded"});
  cv::Mat image(64, 64, CV_8UC3);
  cv::randu(image, 0, 256);  // noise: compresses badly, so the cut lands in pixel data
  const std::string truncated = Path("truncated.png");
  WriteImage(truncated, image);
  Truncate(truncated, fs::file_size(truncated) / 2);
  ExpectInputError(read(truncated), {"truncated.png", "cannot be decoded"});
  const std::string deep = Path("deep.png");
  WriteImage(deep, cv::Mat(4, 4, CV_16UC1, cv::Scalar(1000)));
  ExpectInputError(read(deep), {"deep.png", "8-bit"});
  const std::string alpha = Path("alpha.png");
  WriteImage(alpha, cv::Mat(4, 4, CV_8UC4, cv::Scalar(1, 2, 3, 4)));
  ExpectInputError(read(alpha), {"alpha.png", "4 channels"});
  ExpectInputError([&] { WriteImage(Path("f.png"), cv::Mat(2, 2, CV_32FC1)); }, {"f.png", "8- or 16-bit"});
}

TEST(FrameStemTest, ZeroPadsToSixDigits) {
  EXPECT_EQ(FrameStem(0), "000000");
  EXPECT_EQ(FrameStem(42), "000042");
  EXPECT_EQ(FrameStem(123456), "123456");
}

// ------------------------------------------------------------ sequences

Sequence MakeSequence(int frames, bool with_gt) {
  Sequence sequence;
  const PinholeCamera camera(8, 6, 10.0, 10.5, 3.5, 2.5);
  sequence.calibration = CameraCalibration::FromCamera(camera, "test_cam");
  SequenceGroundTruth gt;
  gt.calibration = CameraCalibration::FromCamera(camera.Upscaled(2), "test_cam_hr");
  for (int i = 0; i < frames; ++i) {
    FrameRecord frame;
    frame.index = i;
    frame.stamp = 10.0 + 0.1 * i;
    frame.exposure = 0.04;
    sequence.frames.push_back(frame);
    cv::Mat image(camera.height, camera.width, CV_8UC3);
    cv::randu(image, 0, 256);
    sequence.images.push_back(image);
    cv::Mat latent(2 * camera.height, 2 * camera.width, CV_8UC3);
    cv::randu(latent, 0, 256);
    gt.latent.push_back(latent);
    cv::Mat depth(2 * camera.height, 2 * camera.width, CV_32FC1);
    cv::randu(depth, 1.0f, 5.0f);
    depth.at<float>(0, i) = std::numeric_limits<float>::quiet_NaN();
    gt.depth.push_back(depth);
    StampedPose pose;
    pose.stamp = frame.stamp;
    pose.T_world_cam =
        SE3(Eigen::Quaterniond(Eigen::AngleAxisd(0.1 * i, Eigen::Vector3d(1, 2, 3).normalized())),
            Eigen::Vector3d(0.1 * i, -0.05 * i, 0.01));
    gt.poses.push_back(pose);
  }
  if (with_gt) sequence.ground_truth = gt;
  return sequence;
}

bool SameBits(const cv::Mat& a, const cv::Mat& b) {
  if (a.size() != b.size() || a.type() != b.type()) return false;
  for (int y = 0; y < a.rows; ++y) {
    if (std::memcmp(a.ptr(y), b.ptr(y), a.cols * a.elemSize()) != 0) return false;
  }
  return true;
}

TEST_F(SequenceIoTest, SequenceRoundTripWithGroundTruth) {
  const Sequence written = MakeSequence(4, true);
  const std::string folder = Path("seq");
  WriteSequence(folder, written);
  EXPECT_TRUE(fs::exists(dir_ / "seq/images/000003.png"));
  EXPECT_TRUE(fs::exists(dir_ / "seq/gt/depth/000000.tiff"));

  const Sequence read = ReadSequence(folder, true);
  EXPECT_EQ(read.calibration.camera.width, 8);
  EXPECT_EQ(read.calibration.camera_name, "test_cam");
  ASSERT_EQ(read.frames.size(), 4u);
  ASSERT_EQ(read.images.size(), 4u);
  for (std::size_t i = 0; i < 4; ++i) {
    EXPECT_EQ(read.frames[i].stamp, written.frames[i].stamp);
    EXPECT_EQ(read.frames[i].exposure, written.frames[i].exposure);
    EXPECT_TRUE(SameBits(read.images[i], written.images[i])) << i;
  }
  ASSERT_TRUE(read.ground_truth.has_value());
  const SequenceGroundTruth& gt = *read.ground_truth;
  EXPECT_EQ(gt.calibration.camera.width, 16);
  EXPECT_EQ(gt.calibration.camera.cx, written.ground_truth->calibration.camera.cx);
  ASSERT_EQ(gt.poses.size(), 4u);
  for (std::size_t i = 0; i < 4; ++i) {
    EXPECT_TRUE(SameBits(gt.latent[i], written.ground_truth->latent[i])) << i;
    EXPECT_TRUE(SameBits(gt.depth[i], written.ground_truth->depth[i])) << i;
    EXPECT_NEAR(gt.poses[i].stamp, written.frames[i].stamp, 1e-12);
    EXPECT_LT((gt.poses[i].T_world_cam.Matrix() - written.ground_truth->poses[i].T_world_cam.Matrix()).norm(),
              1e-9);
  }
  // Without read_ground_truth the gt/ folder is ignored.
  EXPECT_FALSE(ReadSequence(folder, false).ground_truth.has_value());
  // Without gt/ there is no ground truth even when asked for.
  WriteSequence(Path("plain"), MakeSequence(2, false));
  EXPECT_FALSE(ReadSequence(Path("plain"), true).ground_truth.has_value());
}

TEST_F(SequenceIoTest, SequenceErrorsNameTheFile) {
  auto read = [](const std::string& folder, bool gt) { return [folder, gt] { ReadSequence(folder, gt); }; };
  ExpectInputError(read(Path("nothing"), true), {"nothing", "not found"});

  const std::string folder = Path("seq");
  WriteSequence(folder, MakeSequence(3, true));
  fs::remove(dir_ / "seq/images/000001.png");
  ExpectInputError(read(folder, false), {"seq/images/000001.png", "not found"});

  WriteSequence(folder, MakeSequence(3, true));
  WriteImage(Path("seq/images/000002.png"), cv::Mat(6, 9, CV_8UC3, cv::Scalar(1, 2, 3)));
  ExpectInputError(read(folder, false), {"seq/images/000002.png", "9x6", "8x6", "camera.yaml"});

  WriteSequence(folder, MakeSequence(3, true));
  WriteImage(Path("seq/images/000001.png"), cv::Mat(6, 8, CV_8UC1, cv::Scalar(1)));
  ExpectInputError(read(folder, false), {"seq/images/000001.png", "channel"});

  WriteSequence(folder, MakeSequence(3, true));
  fs::remove(dir_ / "seq/frames.csv");
  ExpectInputError(read(folder, false), {"seq/frames.csv", "not found"});

  WriteSequence(folder, MakeSequence(3, true));
  fs::remove(dir_ / "seq/gt/depth/000002.tiff");
  ExpectInputError(read(folder, true), {"seq/gt/depth/000002.tiff", "not found"});
  EXPECT_NO_THROW(ReadSequence(folder, false));

  WriteSequence(folder, MakeSequence(3, true));
  WriteImage(Path("seq/gt/latent/000000.png"), cv::Mat(6, 8, CV_8UC3, cv::Scalar(1, 2, 3)));
  ExpectInputError(read(folder, true), {"seq/gt/latent/000000.png", "8x6", "16x12"});

  // One pose too few.
  WriteSequence(folder, MakeSequence(3, true));
  std::vector<StampedPose> poses = ReadTumTrajectory(Path("seq/gt/poses.txt"));
  poses.pop_back();
  WriteTumTrajectory(Path("seq/gt/poses.txt"), poses);
  ExpectInputError(read(folder, true), {"seq/gt/poses.txt", "2 poses for 3 frames"});

  // Stamps that do not match the frames.
  poses = ReadTumTrajectory(Path("seq/gt/poses.txt"));
  poses.push_back(poses.back());
  poses.back().stamp += 0.1 + 1e-5;
  WriteTumTrajectory(Path("seq/gt/poses.txt"), poses);
  ExpectInputError(read(folder, true), {"seq/gt/poses.txt", "pose 2"});

  // Inconsistent sequences are not written.
  Sequence bad = MakeSequence(3, true);
  bad.images.pop_back();
  ExpectInputError([&] { WriteSequence(Path("bad"), bad); }, {"bad", "2 images for 3 frames"});
  bad = MakeSequence(3, true);
  bad.ground_truth->depth.pop_back();
  ExpectInputError([&] { WriteSequence(Path("bad"), bad); }, {"bad", "ground truth"});
}

TEST_F(SequenceIoTest, WritersReportUnwritablePaths) {
  // A regular file where a folder is needed.
  const std::string blocker = WriteText("blocker", "x");
  ExpectInputError([&] { WriteFramesCsv(blocker + "/frames.csv", {}); }, {"blocker/frames.csv"});
  ExpectInputError([&] { WriteCameraYaml(blocker + "/camera.yaml", AwkwardCalibration()); },
                   {"blocker/camera.yaml"});
  ExpectInputError([&] { WriteImage(blocker + "/a.png", cv::Mat(2, 2, CV_8UC1)); }, {"blocker/a.png"});
}

// ----------------------------------------------------------- sensor.yaml

TEST_F(SequenceIoTest, SensorYamlRoundTripsThroughTheSequence) {
  Sequence written = MakeSequence(3, true);
  written.readout_time = 0.08 / 3.0;  // not a short decimal: exact round trip
  const std::string folder = Path("rolling");
  WriteSequence(folder, written);
  ASSERT_TRUE(fs::exists(dir_ / "rolling/sensor.yaml"));
  EXPECT_EQ(ReadSequence(folder, false).readout_time, written.readout_time);
  EXPECT_EQ(ReadSensorYaml(Path("rolling/sensor.yaml"), written.frames), written.readout_time);
  // The readout may take the whole frame interval (0.1 s here).
  WriteText("rolling/sensor.yaml", "readout_time: 0.1\n");
  EXPECT_EQ(ReadSequence(folder, false).readout_time, 0.1);
  // A readout of exactly one frame interval passes despite stamp rounding.
  for (int i = 0; i < 3; ++i) {
    written.frames[i].stamp = (i + 1) / 30.0;
    written.frames[i].exposure = 0.8 / 30.0;
  }
  written.readout_time = 1.0 / 30.0;
  written.ground_truth.reset();
  WriteSequence(folder, written);
  EXPECT_EQ(ReadSequence(folder, false).readout_time, 1.0 / 30.0);
  // Global shutter: no sensor.yaml, and rewriting removes a stale one.
  written.readout_time = 0.0;
  WriteSequence(folder, written);
  EXPECT_FALSE(fs::exists(dir_ / "rolling/sensor.yaml"));
  EXPECT_EQ(ReadSequence(folder, false).readout_time, 0.0);
  // An explicit 0 reads as the global shutter.
  WriteText("rolling/sensor.yaml", "# global shutter\nreadout_time: 0\n");
  EXPECT_EQ(ReadSequence(folder, false).readout_time, 0.0);
}

TEST_F(SequenceIoTest, SensorYamlErrorsNameFileAndLine) {
  WriteSequence(Path("seq"), MakeSequence(3, false));  // frame interval 0.1 s
  const std::string sensor = Path("seq/sensor.yaml");
  const std::vector<std::pair<std::string, std::vector<std::string>>> cases = {
      {"# comment\nreadout_time: -0.01\n", {"sensor.yaml:2:", ">= 0"}},
      {"readout_time: fast\n", {"sensor.yaml:1:", "number", "'fast'"}},
      {"readout_time: [0.01]\n", {"sensor.yaml:1:", "number"}},
      {"readout_time: nan\n", {"sensor.yaml:1:", "finite"}},
      {"\n\nreadout_time: 0.2\n", {"sensor.yaml:3:", "exceeds the frame interval 0.1"}},
      {"readout_time: 0.01\nexposure: 0.02\n", {"sensor.yaml:2:", "unknown key 'exposure'"}},
      {"readout_time: 0.01\nreadout_time: 0.02\n", {"sensor.yaml:2:", "duplicate key"}},
      {"readout_time: [0.01\n", {"sensor.yaml:", "unterminated"}},
      {"{}\n", {"sensor.yaml", "missing key 'readout_time'"}},
      {"", {"sensor.yaml", "empty"}},
      {"0.01\n", {"sensor.yaml:1:", "expected 'readout_time: <seconds>'"}},
  };
  for (const auto& [content, parts] : cases) {
    SCOPED_TRACE(content);
    WriteText("seq/sensor.yaml", content);
    ExpectInputError([&] { ReadSequence(Path("seq"), false); }, parts);
  }
  ExpectInputError([&] { WriteSensorYaml(sensor, -1.0); }, {"sensor.yaml", ">= 0"});
}

// The check behind ReadSensorYaml, shared with bag_to_sequence.
TEST_F(SequenceIoTest, ReadoutTimeProblemNamesTheProblem) {
  const std::vector<FrameRecord> frames = MakeSequence(3, false).frames;  // interval 0.1 s
  EXPECT_EQ(ReadoutTimeProblem(0.0, frames), "");
  EXPECT_EQ(ReadoutTimeProblem(0.1, frames), "");  // the whole interval
  EXPECT_NE(ReadoutTimeProblem(-0.01, frames).find(">= 0"), std::string::npos);
  EXPECT_NE(ReadoutTimeProblem(std::nan(""), {}).find("finite"), std::string::npos);
  EXPECT_NE(ReadoutTimeProblem(0.2, frames).find("exceeds the frame interval 0.1"), std::string::npos);
  EXPECT_EQ(ReadoutTimeProblem(0.2, {}), "");  // no interval to exceed
}

}  // namespace
}  // namespace deblur_sr_mvs
