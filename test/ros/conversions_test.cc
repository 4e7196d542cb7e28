// The node's message conversions and parameters (no ROS master needed).
#include <cmath>
#include <limits>

#include <gtest/gtest.h>
#include <ros/time.h>
#include <sensor_msgs/image_encodings.h>
#include <sensor_msgs/point_cloud2_iterator.h>

#include "deblur_sr_mvs/ros/conversions.h"
#include "deblur_sr_mvs/ros/node_parameters.h"

namespace deblur_sr_mvs {
namespace ros_glue {
namespace {

sensor_msgs::Image MakeImage(const std::string& encoding, int width, int height, int bytes_per_pixel) {
  sensor_msgs::Image image;
  image.encoding = encoding;
  image.width = width;
  image.height = height;
  image.step = width * bytes_per_pixel;
  image.data.resize(image.step * height);
  for (size_t i = 0; i < image.data.size(); ++i) image.data[i] = static_cast<uint8_t>((i * 37) % 256);
  return image;
}

sensor_msgs::CameraInfo MakeInfo(int width, int height) {
  sensor_msgs::CameraInfo info;
  info.width = width;
  info.height = height;
  info.distortion_model = "plumb_bob";
  info.D.assign(5, 0.0);
  info.K = {200.0, 0.0, 31.5, 0.0, 210.0, 23.5, 0.0, 0.0, 1.0};
  info.R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  info.P = {200.0, 0.0, 31.5, 0.0, 0.0, 210.0, 23.5, 0.0, 0.0, 0.0, 1.0, 0.0};
  return info;
}

TEST(ImageConversion, EveryAcceptedEncodingRoundTripsExactly) {
  struct Case {
    std::string encoding;
    int bytes;
    ImageFamily family;
  };
  for (const Case& c : {Case{"mono8", 1, ImageFamily::kMono8}, Case{"mono16", 2, ImageFamily::kMono16},
                        Case{"rgb8", 3, ImageFamily::kRgb8}, Case{"bgr8", 3, ImageFamily::kBgr8}}) {
    const sensor_msgs::Image image = MakeImage(c.encoding, 16, 8, c.bytes);
    ImageFamily family;
    const cv::Mat float01 = ImageToFloat01(image, &family);
    EXPECT_EQ(family, c.family) << c.encoding;
    EXPECT_EQ(float01.channels(), c.bytes == 3 ? 3 : 1);
    double low, high;
    cv::minMaxLoc(float01.reshape(1), &low, &high);
    EXPECT_GE(low, 0.0);
    EXPECT_LE(high, 1.0);
    const sensor_msgs::Image back = Float01ToImage(float01, family, image.header);
    EXPECT_EQ(back.encoding, c.encoding);
    EXPECT_EQ(back.data, image.data) << c.encoding;
  }
}

TEST(ImageConversion, RgbBecomesBgrInside) {
  sensor_msgs::Image image = MakeImage("rgb8", 1, 1, 3);
  image.data = {255, 0, 0};  // red
  const cv::Mat float01 = ImageToFloat01(image, nullptr);
  EXPECT_FLOAT_EQ(float01.at<cv::Vec3f>(0, 0)[2], 1.0f);  // BGR: red is last
  EXPECT_FLOAT_EQ(float01.at<cv::Vec3f>(0, 0)[0], 0.0f);
}

TEST(ImageConversion, RejectsBadImagesWithOneLine) {
  EXPECT_THROW(ImageToFloat01(MakeImage("yuv422", 4, 4, 2), nullptr), InputError);
  EXPECT_THROW(ImageToFloat01(MakeImage("32FC1", 4, 4, 4), nullptr), InputError);
  sensor_msgs::Image empty = MakeImage("mono8", 0, 0, 1);
  EXPECT_THROW(ImageToFloat01(empty, nullptr), InputError);
  sensor_msgs::Image truncated = MakeImage("rgb8", 8, 8, 3);
  truncated.data.resize(10);
  EXPECT_THROW(ImageToFloat01(truncated, nullptr), InputError);
  // Found by fuzz_image_message: OpenCV threw its own multi-line error.
  sensor_msgs::Image odd_step = MakeImage("mono16", 4, 4, 2);
  odd_step.step = 9;
  odd_step.data.resize(9 * 4);
  EXPECT_THROW(ImageToFloat01(odd_step, nullptr), InputError);
  sensor_msgs::Image short_step = MakeImage("rgb8", 8, 8, 3);
  short_step.step = 8;
  EXPECT_THROW(ImageToFloat01(short_step, nullptr), InputError);
}

TEST(ImageConversion, NanAndOutOfRangeValuesNeverReachTheMessage) {
  cv::Mat float01(2, 2, CV_32FC1);
  float01.at<float>(0, 0) = std::numeric_limits<float>::quiet_NaN();
  float01.at<float>(0, 1) = -0.5f;
  float01.at<float>(1, 0) = 1.5f;
  float01.at<float>(1, 1) = 0.5f;
  const sensor_msgs::Image message = Float01ToImage(float01, ImageFamily::kMono8, std_msgs::Header());
  EXPECT_EQ(message.data, (std::vector<uint8_t>{0, 0, 255, 128}));
}

TEST(CameraInfoConversion, IntrinsicsFromK) {
  const PinholeCamera camera = CameraFromInfo(MakeInfo(64, 48), 64, 48, DistortionPolicy::kReject);
  EXPECT_DOUBLE_EQ(camera.fx, 200.0);
  EXPECT_DOUBLE_EQ(camera.fy, 210.0);
  EXPECT_DOUBLE_EQ(camera.cx, 31.5);
  EXPECT_DOUBLE_EQ(camera.cy, 23.5);
}

TEST(CameraInfoConversion, RejectsWhatCannotBeTrusted) {
  EXPECT_THROW(CameraFromInfo(MakeInfo(64, 48), 32, 24, DistortionPolicy::kReject), InputError);
  sensor_msgs::CameraInfo zero = MakeInfo(64, 48);
  zero.K.fill(0.0);
  EXPECT_THROW(CameraFromInfo(zero, 64, 48, DistortionPolicy::kReject), InputError);
  sensor_msgs::CameraInfo nan = MakeInfo(64, 48);
  nan.K[2] = std::nan("");
  EXPECT_THROW(CameraFromInfo(nan, 64, 48, DistortionPolicy::kReject), InputError);
  sensor_msgs::CameraInfo binned = MakeInfo(64, 48);
  binned.binning_x = 2;
  EXPECT_THROW(CameraFromInfo(binned, 64, 48, DistortionPolicy::kReject), InputError);
}

TEST(CameraInfoConversion, DistortionIsRejectedUnlessTheImageIsRectified) {
  sensor_msgs::CameraInfo distorted = MakeInfo(64, 48);
  distorted.D[0] = -0.2;
  distorted.P[0] = 190.0;  // the rectified camera differs from K
  EXPECT_THROW(CameraFromInfo(distorted, 64, 48, DistortionPolicy::kReject), InputError);
  const PinholeCamera camera = CameraFromInfo(distorted, 64, 48, DistortionPolicy::kAssumeRectified);
  EXPECT_DOUBLE_EQ(camera.fx, 190.0);
}

TEST(CameraInfoConversion, ScaledInfoFollowsTheHalfPixelRule) {
  const PinholeCamera camera(64, 48, 200.0, 210.0, 31.5, 23.5);
  std_msgs::Header header;
  header.frame_id = "cam";
  const sensor_msgs::CameraInfo info = ScaledCameraInfo(camera, 2, header);
  EXPECT_EQ(info.width, 128u);
  EXPECT_EQ(info.height, 96u);
  EXPECT_DOUBLE_EQ(info.K[0], 400.0);
  EXPECT_DOUBLE_EQ(info.K[2], 2 * 31.5 + 0.5);  // c' = s c + (s - 1) / 2
  EXPECT_DOUBLE_EQ(info.K[4], 420.0);
  EXPECT_DOUBLE_EQ(info.K[5], 2 * 23.5 + 0.5);
  EXPECT_DOUBLE_EQ(info.P[0], info.K[0]);
  EXPECT_DOUBLE_EQ(info.P[2], info.K[2]);
  EXPECT_DOUBLE_EQ(info.P[6], info.K[5]);
  EXPECT_EQ(info.header.frame_id, "cam");
  // Read back, the info gives the core's up-scaled camera.
  const PinholeCamera back = CameraFromInfo(info, 128, 96, DistortionPolicy::kReject);
  const PinholeCamera expected = camera.Upscaled(2);
  EXPECT_DOUBLE_EQ(back.cx, expected.cx);
  EXPECT_DOUBLE_EQ(back.fy, expected.fy);
}

TEST(DepthConversion, InvalidDepthBecomesNan) {
  cv::Mat depth = (cv::Mat_<float>(1, 4) << 2.0f, 0.0f, -1.0f, std::numeric_limits<float>::infinity());
  const sensor_msgs::Image message = DepthToImage(depth, std_msgs::Header());
  EXPECT_EQ(message.encoding, sensor_msgs::image_encodings::TYPE_32FC1);
  const float* values = reinterpret_cast<const float*>(message.data.data());
  EXPECT_FLOAT_EQ(values[0], 2.0f);
  EXPECT_TRUE(std::isnan(values[1]));
  EXPECT_TRUE(std::isnan(values[2]));
  EXPECT_TRUE(std::isnan(values[3]));
}

TEST(PointCloud, BackProjectsSubsampledValidPixels) {
  const PinholeCamera camera(4, 4, 2.0, 2.0, 1.5, 1.5);
  cv::Mat depth(4, 4, CV_32FC1, cv::Scalar(3.0f));
  depth.at<float>(2, 2) = std::numeric_limits<float>::quiet_NaN();
  const cv::Mat image(4, 4, CV_32FC1, cv::Scalar(0.5f));
  const sensor_msgs::PointCloud2 cloud = DepthToPoints(depth, image, camera, 2, std_msgs::Header());
  EXPECT_EQ(cloud.width, 3u);  // (0,0), (2,0), (0,2); (2,2) is invalid
  sensor_msgs::PointCloud2ConstIterator<float> x(cloud, "x"), z(cloud, "z");
  sensor_msgs::PointCloud2ConstIterator<uint8_t> r(cloud, "r");
  EXPECT_FLOAT_EQ(*x, 3.0f * (0 - 1.5f) / 2.0f);
  EXPECT_FLOAT_EQ(*z, 3.0f);
  EXPECT_EQ(*r, 128);
}

TEST(PoseConversion, RoundTripsToDoublePrecision) {
  Vector6d xi;
  // Small, large (w < 0 in Eigen's quaternion of the matrix: no sign flip
  // must happen) and near-pi rotations.
  for (const double angle : {0.0, 0.3, 2.0, 3.1, 3.14159}) {
    xi << 0.5, -1.25, 3.0, angle * 0.6, -angle * 0.48, angle * 0.64;
    const SE3 T = SE3::Exp(xi);
    const geometry_msgs::Pose pose = PoseToMsg(T);
    const Eigen::Quaterniond q = T.quaternion().normalized();
    EXPECT_EQ(pose.orientation.w, q.w()) << angle;  // copied as it is
    EXPECT_EQ(pose.orientation.x, q.x()) << angle;
    EXPECT_EQ(pose.position.z, T.translation().z());
    const SE3 back = PoseFromMsg(pose);
    EXPECT_EQ(back.translation(), T.translation()) << angle;
    EXPECT_LT((back.rotation() - T.rotation()).cwiseAbs().maxCoeff(), 1e-15) << angle;
    // The tf transform carries the pose's numbers.
    const geometry_msgs::Transform transform = TransformToMsg(T);
    EXPECT_EQ(transform.translation.x, pose.position.x);
    EXPECT_EQ(transform.translation.y, pose.position.y);
    EXPECT_EQ(transform.translation.z, pose.position.z);
    EXPECT_EQ(transform.rotation, pose.orientation);
    const SE3 from_transform = TransformFromMsg(transform);
    EXPECT_EQ(from_transform.translation(), back.translation()) << angle;
    EXPECT_EQ(from_transform.rotation(), back.rotation()) << angle;
    // Message -> SE3 -> message: the same quaternion (up to sign).
    const geometry_msgs::Pose again = PoseToMsg(back);
    const Eigen::Vector4d first(pose.orientation.w, pose.orientation.x, pose.orientation.y,
                                pose.orientation.z);
    Eigen::Vector4d second(again.orientation.w, again.orientation.x, again.orientation.y,
                           again.orientation.z);
    if (first.dot(second) < 0.0) second = -second;
    EXPECT_LT((first - second).cwiseAbs().maxCoeff(), 1e-15) << angle;
  }
}

TEST(PoseConversion, RejectsNonFiniteOrZeroQuaternions) {
  geometry_msgs::Pose pose;
  pose.orientation.w = 2.0;  // not normalised: normalised on the way in
  EXPECT_DOUBLE_EQ(PoseFromMsg(pose).rotation().trace(), 3.0);
  pose.orientation.w = 0.0;
  EXPECT_THROW(PoseFromMsg(pose), InputError);
  pose.orientation.w = 1.0;
  pose.position.y = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(PoseFromMsg(pose), InputError);
}

TEST(NodeParameters, StampPositionGivesTheShutterClose) {
  NodeParameters params;
  params.exposure_time = 0.02;
  params.stamp_position = ParseStampPosition("start");
  EXPECT_DOUBLE_EQ(params.CloseOffset(), 0.02);
  params.stamp_position = ParseStampPosition("middle");
  EXPECT_DOUBLE_EQ(params.CloseOffset(), 0.01);
  params.stamp_position = ParseStampPosition("end");
  EXPECT_DOUBLE_EQ(params.CloseOffset(), 0.0);
  EXPECT_THROW(ParseStampPosition("centre"), InputError);
}

// An exposure message (time_ref = shutter open t_o, docs/ros_interface.md#exposure)
// gives back the exposure e whose shutter close follows stamp_position:
// t_c - t_o = e for the stamp that stamp_position puts within [t_o, t_c].
TEST(NodeParameters, ShutterOpenGivesTheExposureConsistentWithTheClose) {
  NodeParameters params;
  params.exposure_time = 0.5;  // not used: each frame's own exposure
  const double exposure = 0.02;
  for (const char* position : {"middle", "end"}) {
    params.stamp_position = ParseStampPosition(position);
    const double stamp = 10.0;
    const double t_close = stamp + params.CloseOffset(exposure);
    const double t_open = t_close - exposure;
    EXPECT_NEAR(params.ExposureFromShutterOpen(stamp - t_open), exposure, 1e-12) << position;
  }
  params.stamp_position = ParseStampPosition("start");  // the stamp is t_o: nothing to read
  EXPECT_TRUE(std::isnan(params.ExposureFromShutterOpen(0.0)));
}

// The message of params.Check(), "" when it passes.
std::string CheckMessage(const NodeParameters& params) {
  try {
    params.Check();
  } catch (const InputError& error) {
    return error.what();
  }
  return "";
}

TEST(NodeParameters, ChecksEveryValue) {
  NodeParameters params;
  // exposure_time is required.
  EXPECT_EQ(CheckMessage(params), "exposure_time must be > 0, got 0");
  params.exposure_time = 0.02;
  EXPECT_EQ(CheckMessage(params), "");
  NodeParameters bad = params;
  bad.exposure_time = -1.0;
  EXPECT_EQ(CheckMessage(bad), "exposure_time must be > 0, got -1");
  bad.exposure_time = 20.0;
  EXPECT_EQ(CheckMessage(bad), "exposure_time must be in [0, 10], got 20");
  // auto (estimated from the blur) needs no seconds; a number replaces it.
  NodeParameters automatic;
  automatic.exposure_time.automatic = true;
  EXPECT_EQ(CheckMessage(automatic), "");
  automatic.exposure_time = 0.0;
  EXPECT_FALSE(automatic.exposure_time.automatic);
  EXPECT_EQ(CheckMessage(automatic), "exposure_time must be > 0, got 0");
  bad = params;
  bad.max_frame_gap = std::numeric_limits<double>::infinity();
  EXPECT_EQ(CheckMessage(bad), "max_frame_gap must be > 0, got inf");
  bad = params;
  bad.max_step_ratio = 1.0;
  EXPECT_EQ(CheckMessage(bad), "max_step_ratio must be > 1, got 1");
  bad = params;
  bad.points_stride = 0;
  EXPECT_EQ(CheckMessage(bad), "points_stride must be in [1, 64], got 0");
  bad = params;
  bad.max_path_length = 0;
  EXPECT_EQ(CheckMessage(bad), "max_path_length must be >= 1, got 0");
  bad = params;
  bad.camera_frame = bad.world_frame;
  EXPECT_EQ(CheckMessage(bad), "camera_frame must differ from world_frame");
  bad = params;
  bad.estimator.max_seconds = -1.0;
  EXPECT_EQ(CheckMessage(bad), "max_window_seconds must be >= 0, got -1");
  bad = params;
  bad.pose_prior_frame = bad.world_frame;
  EXPECT_EQ(CheckMessage(bad),
            "pose_prior_frame '" + bad.world_frame + "' must differ from world_frame and camera_frame");
  bad.pose_prior_frame = "odom";
  EXPECT_EQ(CheckMessage(bad), "");
  bad = params;
  bad.estimator.multi_frame_data.relative_weight = -1.0;
  EXPECT_EQ(CheckMessage(bad), "multi_frame_weight must be >= 0, got -1");
}

TEST(NodeParameters, ReconfigureAppliesTuningOrNothing) {
  NodeParameters params;
  params.exposure_time = 0.02;
  EstimatorConfig config = ConfigOf(params);
  config.lambda_i = 0.3;
  config.window_size = 8;
  config.multi_frame_weight = 0.0;  // the pass off
  const NodeParameters updated = WithConfig(params, config);
  EXPECT_DOUBLE_EQ(updated.estimator.image.lambda_i, 0.3);
  EXPECT_DOUBLE_EQ(updated.estimator.multi_frame_data.relative_weight, 0.0);
  EXPECT_DOUBLE_EQ(ConfigOf(updated).multi_frame_weight, 0.0);
  EXPECT_EQ(updated.stream.window_size, 8);
  config.window_overlap = 8;  // not < window_size
  EXPECT_THROW(WithConfig(params, config), InputError);
}

}  // namespace
}  // namespace ros_glue
}  // namespace deblur_sr_mvs

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::Time::init();
  return RUN_ALL_TESTS();
}
