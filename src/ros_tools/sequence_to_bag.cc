// sequence_to_bag: a sequence folder (docs/file_formats.md) -> a rosbag
// (docs/file_formats.md#sequences-as-rosbags).
//
//   sequence_to_bag --input SEQ --output BAG [--frame-id ID] [--image-topic T]
//                   [--info-topic T] [--exposure-topic T] [--readout-topic T]
//                   [--gt-namespace NS] [--world-frame F] [--no-ground-truth]
//                   [--compression none|bz2|lz4]
//
// Every message of frame i carries the header {stamp = t_c of frames.csv,
// frame_id = --frame-id}, and its bag time is that stamp, so `rosbag play`
// replays the sequence at its own rate:
//
//   /camera/image_raw    sensor_msgs/Image          mono8 (gray) or rgb8 (colour;
//                                                   the PNGs are BGR in OpenCV)
//   /camera/camera_info  sensor_msgs/CameraInfo     camera.yaml (width, height,
//                                                   K, D, R, P, distortion_model)
//   /camera/exposure     sensor_msgs/TimeReference  time_ref = shutter open time
//                                                   t_o, so exposure = stamp - time_ref
//   and, when the sequence has a rolling shutter (sensor.yaml, readout_time > 0):
//   /camera/readout_time std_msgs/Float64           ONE latched message, data =
//                                                   readout time in s, at the
//                                                   first frame's bag time
//   and, when the sequence has gt/ (unless --no-ground-truth):
//   /gt/image            sensor_msgs/Image          sharp HR image (mono8/rgb8)
//   /gt/depth            sensor_msgs/Image          32FC1 depth in m, 0/NaN unknown
//   /gt/camera_info      sensor_msgs/CameraInfo     gt/camera.yaml (HR)
//   /gt/pose             geometry_msgs/PoseStamped  T_world_camera, frame_id
//                                                   --world-frame, stamp of poses.txt
//
// camera_name of camera.yaml (which CameraInfo has no field for) travels in
// the connection header of the camera_info connections (field camera_name);
// the rolling-shutter row timing in that of the readout connection (field
// readout_convention). A global-shutter sequence gets no readout topic.
// ROS time has nanosecond resolution and cannot be negative: stamps are
// rounded to the nanosecond, and a sequence whose stamps or shutter-open
// times are negative, or whose stamps collide after rounding, is rejected.
//
// Exit code 0 on success, 2 with one line on stderr on bad input.
#include <cmath>
#include <cstdint>
#include <exception>
#include <filesystem>
#include <iostream>
#include <limits>
#include <string>

#include <console_bridge/console.h>
#include <cv_bridge/cv_bridge.h>
#include <geometry_msgs/PoseStamped.h>
#include <ros/message_traits.h>
#include <ros/time.h>
#include <rosbag/bag.h>
#include <rosbag/exceptions.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/TimeReference.h>
#include <sensor_msgs/image_encodings.h>
#include <std_msgs/Float64.h>
#include <boost/make_shared.hpp>
#include <opencv2/imgproc.hpp>

#include "bag_tool_main.h"
#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/io/sequence_io.h"

namespace {

namespace fs = std::filesystem;
using deblur_sr_mvs::CameraCalibration;
using deblur_sr_mvs::InputError;
using deblur_sr_mvs::Sequence;

constexpr char kDescription[] =
    "Writes a sequence folder (camera.yaml, frames.csv, images/, optional gt/) as a\n"
    "rosbag. Every message of a frame is stamped with the frame's stamp (shutter\n"
    "close time t_c); the bag time is the stamp. A rolling-shutter sequence\n"
    "(sensor.yaml) gets one latched readout-time message.";

struct Options {
  std::string input;
  std::string output;
  std::string frame_id = "camera";
  std::string image_topic = "/camera/image_raw";
  std::string info_topic = "/camera/camera_info";
  std::string exposure_topic = "/camera/exposure";
  std::string readout_topic = "/camera/readout_time";
  std::string gt_namespace = "/gt";
  std::string world_frame = "world";
  bool ground_truth = true;
  rosbag::compression::CompressionType compression = rosbag::compression::Uncompressed;
};

std::string StampText(double stamp) {
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), "%.9f", stamp);
  return buffer;
}

// Parses the command line; false after --help.
bool ParseOptions(int argc, char** argv, Options* options) {
  bool no_ground_truth = false;
  std::string compression = "none";
  deblur_sr_mvs::ToolCommandLine cli("sequence_to_bag", kDescription);
  cli.add_option("--input", options->input, "sequence folder to read")
      ->required()
      ->check(CLI::ExistingDirectory);
  cli.add_option("--output", options->output, "bag file to write (replaced when it exists)")->required();
  cli.add_option("--frame-id", options->frame_id, "header.frame_id of the camera messages (default camera)");
  cli.add_option("--image-topic", options->image_topic,
                 "sensor_msgs/Image, mono8 or rgb8 (default /camera/image_raw)");
  cli.add_option("--info-topic", options->info_topic, "sensor_msgs/CameraInfo (default /camera/camera_info)");
  cli.add_option("--exposure-topic", options->exposure_topic,
                 "sensor_msgs/TimeReference: time_ref = shutter open time, exposure = header.stamp - "
                 "time_ref (default /camera/exposure)");
  cli.add_option("--readout-topic", options->readout_topic,
                 "std_msgs/Float64, one latched message: the rolling-shutter readout time in s, only "
                 "when sensor.yaml has readout_time > 0 (default /camera/readout_time)");
  cli.add_option("--gt-namespace", options->gt_namespace,
                 "ground-truth topics NS/image, NS/depth (32FC1), NS/camera_info, NS/pose (PoseStamped) "
                 "(default /gt)");
  cli.add_option("--world-frame", options->world_frame, "frame_id of the ground-truth poses (default world)");
  cli.add_flag("--no-ground-truth", no_ground_truth, "do not write gt/ even when the sequence has it");
  cli.add_option("--compression", compression, "chunk compression: none, bz2 or lz4 (default none)")
      ->check(CLI::IsMember({"none", "bz2", "lz4"}));
  if (!cli.Parse(argc, argv)) return false;
  options->ground_truth = !no_ground_truth;
  options->compression = compression == "bz2"   ? rosbag::compression::BZ2
                         : compression == "lz4" ? rosbag::compression::LZ4
                                                : rosbag::compression::Uncompressed;
  for (const std::string* topic : {&options->image_topic, &options->info_topic, &options->exposure_topic,
                                   &options->readout_topic, &options->gt_namespace}) {
    if (topic->empty()) throw InputError("topic names must not be empty");
  }
  while (options->gt_namespace.size() > 1 && options->gt_namespace.back() == '/') {
    options->gt_namespace.pop_back();
  }
  return true;
}

// ROS time: unsigned 32-bit seconds + nanoseconds, rounded to the nanosecond.
ros::Time ToRosTime(double seconds, const std::string& what) {
  if (!std::isfinite(seconds) || seconds < 0.0) {
    throw InputError(what + " " + StampText(seconds) +
                     " s is negative: ROS time cannot represent it (shift the stamps)");
  }
  if (seconds >= static_cast<double>(std::numeric_limits<std::uint32_t>::max())) {
    throw InputError(what + " " + StampText(seconds) + " s is beyond the range of ROS time");
  }
  return ros::Time().fromSec(seconds);
}

sensor_msgs::CameraInfo ToCameraInfo(const CameraCalibration& calibration, const std_msgs::Header& header) {
  const deblur_sr_mvs::PinholeCamera& camera = calibration.camera;
  sensor_msgs::CameraInfo info;
  info.header = header;
  info.width = static_cast<std::uint32_t>(camera.width);
  info.height = static_cast<std::uint32_t>(camera.height);
  info.distortion_model = calibration.distortion_model;
  info.D = calibration.distortion;
  info.K = {camera.fx, 0.0, camera.cx, 0.0, camera.fy, camera.cy, 0.0, 0.0, 1.0};
  Eigen::Matrix<double, 3, 4> projection = calibration.projection;
  if (projection.isZero(0.0)) {  // unset: [K | 0], as WriteCameraYaml writes it
    projection.leftCols<3>() = camera.K();
  }
  for (int row = 0; row < 3; ++row) {
    for (int col = 0; col < 3; ++col) info.R[row * 3 + col] = calibration.rectification(row, col);
    for (int col = 0; col < 4; ++col) info.P[row * 4 + col] = projection(row, col);
  }
  return info;
}

// 8-bit gray -> mono8, 8-bit colour (OpenCV BGR) -> rgb8, the usual order of
// ROS camera drivers; 32FC1 (depth) as is.
sensor_msgs::ImagePtr ToImageMessage(const cv::Mat& image, const std_msgs::Header& header,
                                     const std::string& what) {
  namespace enc = sensor_msgs::image_encodings;
  switch (image.type()) {
    case CV_8UC1:
      return cv_bridge::CvImage(header, enc::MONO8, image).toImageMsg();
    case CV_8UC3: {
      cv::Mat rgb;
      cv::cvtColor(image, rgb, cv::COLOR_BGR2RGB);
      return cv_bridge::CvImage(header, enc::RGB8, rgb).toImageMsg();
    }
    case CV_32FC1:
      return cv_bridge::CvImage(header, enc::TYPE_32FC1, image).toImageMsg();
    default:
      throw InputError(what + ": unsupported image type (expected 8-bit gray or colour)");
  }
}

// A connection header that rosbag stores as given: the fields it needs to
// read the messages back, plus our own (e.g. camera_name). Not latched
// unless `extra` says latching "1".
template <class Message>
boost::shared_ptr<ros::M_string> ConnectionHeader(const ros::M_string& extra) {
  auto header = boost::make_shared<ros::M_string>(extra);
  (*header)["type"] = ros::message_traits::DataType<Message>::value();
  (*header)["md5sum"] = ros::message_traits::MD5Sum<Message>::value();
  (*header)["message_definition"] = ros::message_traits::Definition<Message>::value();
  (*header)["callerid"] = "/sequence_to_bag";
  header->emplace("latching", "0");
  return header;
}

// The rolling-shutter readout time as one latched message, so that a
// subscriber that comes late still gets it (docs/file_formats.md#rolling-shutter).
void WriteReadoutTime(const Options& options, double readout_time, const ros::Time& bag_time,
                      rosbag::Bag* bag) {
  const auto header = ConnectionHeader<std_msgs::Float64>(
      {{"latching", "1"},
       {"readout_convention",
        "data = readout time in s; LR row y of H opens y*readout_time/H after row 0; stamps are row "
        "0's"}});
  std_msgs::Float64 message;
  message.data = readout_time;
  bag->write(options.readout_topic, bag_time, message, header);
}

std::string GtNamespace(const Options& options) {
  return options.gt_namespace == "/" ? std::string() : options.gt_namespace;
}

void CheckOutputPath(const std::string& path) {
  std::error_code error;
  if (fs::is_directory(path, error)) throw InputError(path + ": is a folder, expected a bag file name");
  const fs::path parent = fs::path(path).parent_path();
  if (!parent.empty()) {
    fs::create_directories(parent, error);
    if (error) throw InputError(path + ": cannot create folder " + parent.string() + ": " + error.message());
  }
}

// Writes every frame's messages (see the top of the file).
void WriteMessages(const Options& options, const Sequence& sequence, const std::vector<ros::Time>& stamps,
                   const std::vector<ros::Time>& shutter_open, const std::vector<ros::Time>& pose_stamps,
                   rosbag::Bag* bag_pointer) {
  rosbag::Bag& bag = *bag_pointer;
  bag.setCompression(options.compression);
  const std::size_t count = sequence.frames.size();
  const bool with_gt = !pose_stamps.empty();
  const auto info_header =
      ConnectionHeader<sensor_msgs::CameraInfo>({{"camera_name", sequence.calibration.camera_name}});
  const auto exposure_header = ConnectionHeader<sensor_msgs::TimeReference>(
      {{"exposure_convention",
        "header.stamp = shutter close time t_c (the image stamp); time_ref = shutter open time "
        "t_o; exposure = header.stamp - time_ref"}});
  boost::shared_ptr<ros::M_string> gt_info_header;
  if (with_gt) {
    gt_info_header = ConnectionHeader<sensor_msgs::CameraInfo>(
        {{"camera_name", sequence.ground_truth->calibration.camera_name}});
  }
  const std::string ns = GtNamespace(options);
  if (sequence.readout_time > 0.0) {
    WriteReadoutTime(options, sequence.readout_time, std::max(stamps.front(), ros::TIME_MIN), &bag);
  }

  for (std::size_t i = 0; i < count; ++i) {
    const std::string stem = deblur_sr_mvs::FrameStem(sequence.frames[i].index);
    std_msgs::Header header;
    header.seq = static_cast<std::uint32_t>(i);
    header.stamp = stamps[i];
    header.frame_id = options.frame_id;
    // rosbag refuses time 0 (ros::TIME_MIN is 1 ns); the header keeps the stamp.
    const ros::Time bag_time = std::max(stamps[i], ros::TIME_MIN);

    bag.write(options.image_topic, bag_time,
              ToImageMessage(sequence.images[i], header, "images/" + stem + ".png"));
    bag.write(options.info_topic, bag_time, ToCameraInfo(sequence.calibration, header), info_header);
    sensor_msgs::TimeReference exposure;
    exposure.header = header;
    exposure.time_ref = shutter_open[i];
    exposure.source = "shutter_open";
    bag.write(options.exposure_topic, bag_time, exposure, exposure_header);

    if (!with_gt) continue;
    const deblur_sr_mvs::SequenceGroundTruth& gt = *sequence.ground_truth;
    bag.write(ns + "/image", bag_time, ToImageMessage(gt.latent[i], header, "gt/latent/" + stem + ".png"));
    bag.write(ns + "/depth", bag_time, ToImageMessage(gt.depth[i], header, "gt/depth/" + stem + ".tiff"));
    bag.write(ns + "/camera_info", bag_time, ToCameraInfo(gt.calibration, header), gt_info_header);
    geometry_msgs::PoseStamped pose;
    pose.header.seq = header.seq;
    pose.header.stamp = pose_stamps[i];
    pose.header.frame_id = options.world_frame;
    const Eigen::Vector3d& t = gt.poses[i].T_world_cam.translation();
    Eigen::Quaterniond q = gt.poses[i].T_world_cam.quaternion();
    if (q.w() < 0.0) q.coeffs() = -q.coeffs();  // canonical sign, same rotation
    pose.pose.position.x = t.x();
    pose.pose.position.y = t.y();
    pose.pose.position.z = t.z();
    pose.pose.orientation.x = q.x();
    pose.pose.orientation.y = q.y();
    pose.pose.orientation.z = q.z();
    pose.pose.orientation.w = q.w();
    bag.write(ns + "/pose", std::max(pose_stamps[i], ros::TIME_MIN), pose);
  }
}

void WriteBag(const Options& options, const Sequence& sequence) {
  const std::size_t count = sequence.frames.size();
  const bool with_gt = options.ground_truth && sequence.ground_truth.has_value();
  const std::string frames_csv = (fs::path(options.input) / "frames.csv").string();

  // All stamps first: nothing is written for a sequence ROS time cannot hold.
  std::vector<ros::Time> stamps(count), shutter_open(count), pose_stamps;
  for (std::size_t i = 0; i < count; ++i) {
    const deblur_sr_mvs::FrameRecord& frame = sequence.frames[i];
    const std::string where = frames_csv + ": frame " + std::to_string(frame.index);
    stamps[i] = ToRosTime(frame.stamp, where + ": stamp");
    // t_o = t_c - exposure in integer nanoseconds: exact for epoch stamps too,
    // where a double holds t_c only to a fraction of a microsecond.
    const ros::Duration exposure(frame.exposure);
    if (exposure <= ros::Duration(0)) {
      throw InputError(where + ": exposure " + StampText(frame.exposure) + " s rounds to 0 ns");
    }
    if (exposure > stamps[i] - ros::Time(0)) {
      throw InputError(where +
                       ": shutter open time (stamp - exposure) = " + StampText(frame.stamp - frame.exposure) +
                       " s is negative: ROS time cannot represent it (shift the stamps)");
    }
    shutter_open[i] = stamps[i] - exposure;
    if (i > 0 && !(stamps[i] > stamps[i - 1])) {
      throw InputError(where + ": stamp " + StampText(frame.stamp) +
                       " is within 1 ns of the previous one (ROS stamps have 1 ns resolution)");
    }
  }
  if (with_gt) {
    const std::string poses_txt = (fs::path(options.input) / "gt" / "poses.txt").string();
    for (std::size_t i = 0; i < count; ++i) {
      pose_stamps.push_back(ToRosTime(sequence.ground_truth->poses[i].stamp,
                                      poses_txt + ": pose " + std::to_string(i) + ": stamp"));
    }
  }

  CheckOutputPath(options.output);
  rosbag::Bag bag;
  bag.open(options.output, rosbag::bagmode::Write);
  try {
    WriteMessages(options, sequence, stamps, shutter_open, pose_stamps, &bag);
    bag.close();
  } catch (const std::exception& error) {
    // A half-written bag is worse than none.
    bag.close();
    std::error_code ignored;
    fs::remove(options.output, ignored);
    if (dynamic_cast<const InputError*>(&error) != nullptr) throw;
    throw InputError(options.output + ": cannot write the bag: " + error.what());
  }

  const cv::Mat& first = sequence.images.front();
  std::cout << "wrote " << options.output << ": " << count << " frames " << first.cols << "x" << first.rows
            << " " << (first.channels() == 1 ? "mono8" : "rgb8") << " on " << options.image_topic << " + "
            << options.info_topic << ", exposures on " << options.exposure_topic;
  if (sequence.readout_time > 0.0) {
    std::cout << ", readout time " << sequence.readout_time << " s on " << options.readout_topic;
  }
  if (with_gt) {
    std::cout << ", ground truth on " << GtNamespace(options) << "/{image,depth,camera_info,pose}";
  } else if (sequence.ground_truth) {
    std::cout << " (ground truth left out)";
  }
  std::cout << "\n";
}

int Run(int argc, char** argv) {
  Options options;
  if (!ParseOptions(argc, argv, &options)) return 0;
  const Sequence sequence = deblur_sr_mvs::ReadSequence(options.input, options.ground_truth);
  if (sequence.frames.empty()) throw InputError(options.input + ": the sequence has no frames");
  WriteBag(options, sequence);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  return deblur_sr_mvs::BagToolMain("sequence_to_bag", Run, argc, argv);
}
