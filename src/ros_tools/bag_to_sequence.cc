// bag_to_sequence: a rosbag -> a sequence folder (docs/file_formats.md, docs/tools.md); the
// inverse of sequence_to_bag.
//
//   bag_to_sequence --input BAG --output SEQ [--image-topic T] [--info-topic T]
//                   [--exposure-topic T] [--exposure SECONDS] [--readout-topic T]
//                   [--readout-time SECONDS] [--gt-namespace NS] [--no-ground-truth]
//
// Reads, in bag order:
//   /camera/image_raw    sensor_msgs/Image: mono8 (or 8UC1) -> gray PNG,
//                        rgb8 / bgr8 -> colour PNG. mono16/16UC1 is REJECTED:
//                        the sequence format is 8-bit and the 16 -> 8 bit
//                        scaling is unknown (convert the bag first).
//   /camera/camera_info  sensor_msgs/CameraInfo with the SAME stamp as each
//                        image; one calibration for the whole sequence.
//   /camera/exposure     sensor_msgs/TimeReference with the image's stamp:
//                        exposure = header.stamp - time_ref (time_ref = shutter
//                        open time), as sequence_to_bag writes it. Without this
//                        topic, --exposure SECONDS gives every frame the same
//                        exposure (it also overrides the topic); without either
//                        the tool fails.
//   /camera/readout_time std_msgs/Float64, optional: the rolling-shutter
//                        readout time in s (sequence_to_bag writes one latched
//                        message). Several messages must agree. Written as
//                        sensor.yaml when > 0; --readout-time SECONDS sets or
//                        overrides it (0: global shutter, no sensor.yaml).
//   /gt/image, /gt/depth (32FC1 m, or 16UC1 mm), /gt/camera_info, /gt/pose
//                        (PoseStamped, T_world_camera): restored as gt/ when
//                        present (all four, one per frame).
//
// Checks: every image has a camera_info (and exposure) with the same stamp,
// image stamps strictly increase, sizes and channel counts agree with each
// other and with camera_info, K is a pinhole matrix, 0 < exposure <= frame
// interval and 0 <= readout time <= the smallest frame interval, as
// ReadSensorYaml requires (an excess of up to 2 ns, from rounding the stamps
// to the ROS nanosecond, is clamped). The output folder must be new, empty
// or an existing sequence folder (has frames.csv), whose camera.yaml,
// frames.csv, sensor.yaml, images/ and gt/ are replaced.
//
// Exit code 0 on success, 2 with one line on stderr on bad input.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <iostream>
#include <limits>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include <console_bridge/console.h>
#include <cv_bridge/cv_bridge.h>
#include <geometry_msgs/PoseStamped.h>
#include <ros/time.h>
#include <rosbag/bag.h>
#include <rosbag/exceptions.h>
#include <rosbag/view.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/TimeReference.h>
#include <sensor_msgs/image_encodings.h>
#include <std_msgs/Float64.h>
#include <boost/endian/conversion.hpp>

#include "bag_tool_main.h"
#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/common/text.h"
#include "deblur_sr_mvs/core/io/sequence_io.h"

namespace {

namespace fs = std::filesystem;
namespace enc = sensor_msgs::image_encodings;
using deblur_sr_mvs::CameraCalibration;
using deblur_sr_mvs::InputError;
using deblur_sr_mvs::OneLine;
using deblur_sr_mvs::Sequence;
using deblur_sr_mvs::SizeText;

constexpr char kDescription[] =
    "Writes the images of a rosbag as a sequence folder (camera.yaml, frames.csv,\n"
    "images/, and gt/ when the bag has ground truth). Every image needs a\n"
    "CameraInfo with the same stamp; stamps must increase. A rolling-shutter\n"
    "readout time (topic or --readout-time) becomes sensor.yaml.";

struct Options {
  std::string input;
  std::string output;
  std::string image_topic = "/camera/image_raw";
  std::string info_topic = "/camera/camera_info";
  std::string exposure_topic = "/camera/exposure";
  std::string readout_topic = "/camera/readout_time";
  std::string gt_namespace = "/gt";
  bool ground_truth = true;
  std::optional<double> exposure;
  std::optional<double> readout_time;  // --readout-time, overrides the topic

  std::string GtTopic(const std::string& name) const {
    return (gt_namespace == "/" ? std::string() : gt_namespace) + "/" + name;
  }
};

std::string Seconds(double value) {
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), "%.9f", value);
  return buffer;
}

std::string StampText(const ros::Time& stamp) {
  return Seconds(stamp.toSec());
}

// A number flag that may be absent: `target` is set only when it is given.
void AddOptionalNumber(CLI::App* cli, const std::string& name, const std::string& help, double min,
                       std::optional<double>* target) {
  cli->add_option_function<double>(
         name, [target](const double& value) { *target = value; }, help)
      ->check(deblur_sr_mvs::FlagNumber(min));
}

// Parses the command line; false after --help.
bool ParseOptions(int argc, char** argv, Options* options) {
  bool no_ground_truth = false;
  deblur_sr_mvs::ToolCommandLine cli("bag_to_sequence", kDescription);
  cli.add_option("--input", options->input, "bag file to read")->required();
  cli.add_option("--output", options->output,
                 "sequence folder to write: new, empty or an existing sequence folder (its frames and gt/ "
                 "are replaced)")
      ->required();
  cli.add_option("--image-topic", options->image_topic,
                 "sensor_msgs/Image, mono8, rgb8 or bgr8 (default /camera/image_raw)");
  cli.add_option("--info-topic", options->info_topic, "sensor_msgs/CameraInfo (default /camera/camera_info)");
  cli.add_option("--exposure-topic", options->exposure_topic,
                 "sensor_msgs/TimeReference per frame: exposure = header.stamp - time_ref (default "
                 "/camera/exposure)");
  AddOptionalNumber(&cli, "--exposure",
                    "exposure of every frame in seconds, for bags without that topic (overrides the topic "
                    "when both are there)",
                    1e-6, &options->exposure);
  cli.add_option("--readout-topic", options->readout_topic,
                 "std_msgs/Float64: the rolling-shutter readout time in s, optional (default "
                 "/camera/readout_time)");
  AddOptionalNumber(&cli, "--readout-time",
                    "rolling-shutter readout time in seconds, at most the frame interval; 0 = global shutter "
                    "(overrides the topic)",
                    0.0, &options->readout_time);
  cli.add_option("--gt-namespace", options->gt_namespace,
                 "ground-truth topics NS/image, NS/depth, NS/camera_info, NS/pose (default /gt)");
  cli.add_flag("--no-ground-truth", no_ground_truth, "do not write gt/ even when the bag has it");
  if (!cli.Parse(argc, argv)) return false;
  options->ground_truth = !no_ground_truth;
  for (const std::string* topic : {&options->image_topic, &options->info_topic, &options->exposure_topic,
                                   &options->readout_topic, &options->gt_namespace}) {
    if (topic->empty()) throw InputError("topic names must not be empty");
  }
  while (options->gt_namespace.size() > 1 && options->gt_namespace.back() == '/') {
    options->gt_namespace.pop_back();
  }
  return true;
}

// ------------------------------------------------------------ bag contents

using StampKey = std::uint64_t;  // header stamp in nanoseconds

struct BagContents {
  std::vector<sensor_msgs::ImageConstPtr> images;  // bag order
  std::map<StampKey, sensor_msgs::CameraInfoConstPtr> infos;
  std::string camera_name;  // from the camera_info connection header, if any
  std::map<StampKey, sensor_msgs::TimeReferenceConstPtr> exposures;
  std::optional<double> readout_time;  // the readout topic's value, if any
  std::map<StampKey, sensor_msgs::ImageConstPtr> gt_images;
  std::map<StampKey, sensor_msgs::ImageConstPtr> gt_depths;
  std::map<StampKey, sensor_msgs::CameraInfoConstPtr> gt_infos;
  std::string gt_camera_name;
  std::map<StampKey, geometry_msgs::PoseStampedConstPtr> gt_poses;

  bool HasGroundTruth() const {
    return !gt_images.empty() || !gt_depths.empty() || !gt_infos.empty() || !gt_poses.empty();
  }
};

std::string TopicList(const std::map<std::string, std::set<std::string>>& types) {
  if (types.empty()) return "the bag has no messages";
  std::string text = "topics in the bag:";
  int shown = 0;
  for (const auto& entry : types) {
    if (++shown > 8) {
      text += " ...";
      break;
    }
    text += " " + entry.first;
  }
  return text;
}

template <class Message>
void CheckTopicType(const std::string& bag_path, const std::map<std::string, std::set<std::string>>& types,
                    const std::string& topic) {
  const auto it = types.find(topic);
  if (it == types.end()) return;
  const std::string expected = ros::message_traits::DataType<Message>::value();
  for (const std::string& type : it->second) {
    if (type != expected) {
      throw InputError(bag_path + ": topic " + topic + " has type " + type + ", expected " + expected);
    }
  }
}

template <class Message>
boost::shared_ptr<const Message> Instantiate(const rosbag::MessageInstance& message,
                                             const std::string& bag_path) {
  boost::shared_ptr<const Message> instance;
  try {
    instance = message.instantiate<Message>();
  } catch (const std::exception& error) {
    throw InputError(bag_path + ": " + message.getTopic() + ": the message at bag time " +
                     StampText(message.getTime()) + " cannot be read: " + error.what());
  }
  if (!instance) {
    throw InputError(bag_path + ": " + message.getTopic() + ": message of type " + message.getDataType() +
                     ", expected " + ros::message_traits::DataType<Message>::value());
  }
  return instance;
}

// Adds a message to a stamp-keyed map; two messages with one stamp are an error.
template <class Pointer>
void AddByStamp(const std::string& bag_path, const std::string& topic, const Pointer& message,
                std::map<StampKey, Pointer>* map) {
  const ros::Time& stamp = message->header.stamp;
  if (!map->emplace(stamp.toNSec(), message).second) {
    throw InputError(bag_path + ": " + topic + ": two messages with stamp " + StampText(stamp));
  }
}

std::string ConnectionField(const rosbag::MessageInstance& message, const std::string& field) {
  const boost::shared_ptr<const ros::M_string> header = message.getConnectionHeader();
  if (!header) return "";
  const auto it = header->find(field);
  return it == header->end() ? "" : it->second;
}

// The readout time of one message of the readout topic: valid on its own
// (finite, >= 0) and equal to any earlier one (a sequence has one).
void AddReadoutTime(const std::string& bag_path, const rosbag::MessageInstance& message,
                    std::optional<double>* readout_time) {
  const double value = Instantiate<std_msgs::Float64>(message, bag_path)->data;
  const std::string where =
      bag_path + ": " + message.getTopic() + ": the message at bag time " + StampText(message.getTime());
  const std::string problem = deblur_sr_mvs::ReadoutTimeProblem(value, {});
  if (!problem.empty()) throw InputError(where + ": " + problem);
  if (*readout_time && **readout_time != value) {
    throw InputError(where + ": readout_time " + Seconds(value) + " s differs from the earlier " +
                     Seconds(**readout_time) + " s (a sequence has one readout time)");
  }
  *readout_time = value;
}

using TopicTypes = std::map<std::string, std::set<std::string>>;  // topic -> message types

// Every topic of the bag with its types: the topics we read must carry the
// expected type, and the image and camera_info topics must be there.
void CheckTopics(const Options& options, rosbag::Bag& bag) {
  const std::string& path = options.input;
  TopicTypes types;
  rosbag::View everything(bag);
  for (const rosbag::ConnectionInfo* connection : everything.getConnections()) {
    types[connection->topic].insert(connection->datatype);
  }
  CheckTopicType<sensor_msgs::Image>(path, types, options.image_topic);
  CheckTopicType<sensor_msgs::CameraInfo>(path, types, options.info_topic);
  if (!options.exposure) {
    CheckTopicType<sensor_msgs::TimeReference>(path, types, options.exposure_topic);
  }
  if (!options.readout_time) CheckTopicType<std_msgs::Float64>(path, types, options.readout_topic);
  if (options.ground_truth) {
    CheckTopicType<sensor_msgs::Image>(path, types, options.GtTopic("image"));
    CheckTopicType<sensor_msgs::Image>(path, types, options.GtTopic("depth"));
    CheckTopicType<sensor_msgs::CameraInfo>(path, types, options.GtTopic("camera_info"));
    CheckTopicType<geometry_msgs::PoseStamped>(path, types, options.GtTopic("pose"));
  }
  if (types.count(options.image_topic) == 0) {
    throw InputError(path + ": no messages on the image topic " + options.image_topic + " (" +
                     TopicList(types) + "; see --image-topic)");
  }
  if (types.count(options.info_topic) == 0) {
    throw InputError(path + ": no messages on the camera_info topic " + options.info_topic +
                     ", every image needs a CameraInfo with its stamp (" + TopicList(types) +
                     "; see --info-topic)");
  }
}

// The messages of the topics we read, in bag order.
void ReadMessages(const Options& options, rosbag::Bag& bag, BagContents* contents) {
  const std::string& path = options.input;
  const std::string gt_image = options.GtTopic("image");
  const std::string gt_depth = options.GtTopic("depth");
  const std::string gt_info = options.GtTopic("camera_info");
  const std::string gt_pose = options.GtTopic("pose");
  std::vector<std::string> topics = {options.image_topic, options.info_topic};
  if (!options.exposure) topics.push_back(options.exposure_topic);
  if (!options.readout_time) topics.push_back(options.readout_topic);
  if (options.ground_truth) topics.insert(topics.end(), {gt_image, gt_depth, gt_info, gt_pose});
  rosbag::View view(bag, rosbag::TopicQuery(topics));
  for (const rosbag::MessageInstance& message : view) {
    const std::string& topic = message.getTopic();
    if (topic == options.image_topic) {
      contents->images.push_back(Instantiate<sensor_msgs::Image>(message, path));
    } else if (topic == options.info_topic) {
      if (contents->infos.empty()) contents->camera_name = ConnectionField(message, "camera_name");
      AddByStamp(path, topic, Instantiate<sensor_msgs::CameraInfo>(message, path), &contents->infos);
    } else if (topic == options.exposure_topic) {
      AddByStamp(path, topic, Instantiate<sensor_msgs::TimeReference>(message, path), &contents->exposures);
    } else if (topic == options.readout_topic) {
      AddReadoutTime(path, message, &contents->readout_time);
    } else if (topic == gt_image) {
      AddByStamp(path, topic, Instantiate<sensor_msgs::Image>(message, path), &contents->gt_images);
    } else if (topic == gt_depth) {
      AddByStamp(path, topic, Instantiate<sensor_msgs::Image>(message, path), &contents->gt_depths);
    } else if (topic == gt_info) {
      if (contents->gt_infos.empty()) contents->gt_camera_name = ConnectionField(message, "camera_name");
      AddByStamp(path, topic, Instantiate<sensor_msgs::CameraInfo>(message, path), &contents->gt_infos);
    } else if (topic == gt_pose) {
      AddByStamp(path, topic, Instantiate<geometry_msgs::PoseStamped>(message, path), &contents->gt_poses);
    }
  }
}

BagContents ReadBag(const Options& options) {
  const std::string& path = options.input;
  std::error_code error;
  const fs::file_status status = fs::status(path, error);
  if (!fs::exists(status)) throw InputError(path + ": file not found");
  if (fs::is_directory(status)) throw InputError(path + ": is a folder, expected a bag file");

  BagContents contents;
  try {
    rosbag::Bag bag;
    bag.open(path, rosbag::bagmode::Read);
    CheckTopics(options, bag);
    ReadMessages(options, bag, &contents);
    bag.close();
  } catch (const InputError&) {
    throw;
  } catch (const rosbag::BagUnindexedException&) {
    throw InputError(path + ": the bag has no index (an interrupted recording?); try `rosbag reindex`");
  } catch (const std::exception& bag_error) {  // rosbag::BagException and kin
    throw InputError(path +
                     ": cannot read the bag (truncated or not a bag file?): " + OneLine(bag_error.what()));
  }
  if (contents.images.empty()) {
    throw InputError(path + ": no messages on the image topic " + options.image_topic);
  }
  return contents;
}

// ------------------------------------------------------------- conversions

// Rejects messages whose data is shorter than height * step (cv_bridge would
// read past the end).
void CheckLayout(const sensor_msgs::Image& image, int bytes_per_pixel, const std::string& where) {
  if (image.width == 0 || image.height == 0) {
    throw InputError(where + ": empty image (" + std::to_string(image.width) + "x" +
                     std::to_string(image.height) + ")");
  }
  const std::uint64_t row_bytes = static_cast<std::uint64_t>(image.width) * bytes_per_pixel;
  if (image.step < row_bytes) {
    throw InputError(where + ": step " + std::to_string(image.step) + " is less than width * " +
                     std::to_string(bytes_per_pixel) + " = " + std::to_string(row_bytes));
  }
  const std::uint64_t needed = static_cast<std::uint64_t>(image.step) * image.height;
  if (image.data.size() < needed) {
    throw InputError(where + ": data has " + std::to_string(image.data.size()) +
                     " bytes, expected step * height = " + std::to_string(needed));
  }
}

// mono8/8UC1 -> CV_8UC1; rgb8/bgr8 -> CV_8UC3 in OpenCV's BGR order.
cv::Mat DecodeImage8(const sensor_msgs::ImageConstPtr& image, const std::string& where) {
  const std::string& encoding = image->encoding;
  if (encoding == enc::MONO8 || encoding == enc::TYPE_8UC1) {
    CheckLayout(*image, 1, where);
    return cv_bridge::toCvCopy(image)->image;  // same encoding: a plain copy
  }
  if (encoding == enc::RGB8 || encoding == enc::BGR8) {
    CheckLayout(*image, 3, where);
    return cv_bridge::toCvCopy(image, enc::BGR8)->image;
  }
  if (encoding == enc::MONO16 || encoding == enc::TYPE_16UC1) {
    throw InputError(where + ": encoding " + encoding +
                     " is not supported: sequence images are 8-bit and the 16-to-8-bit scaling is "
                     "unknown (convert the images to mono8 first)");
  }
  throw InputError(where + ": encoding '" + encoding + "' is not supported (accepted: mono8, rgb8, bgr8)");
}

// 32FC1 metres as is; 16UC1 millimetres (REP 118) -> metres, 0 stays unknown.
cv::Mat DecodeDepth(const sensor_msgs::ImageConstPtr& image, const std::string& where) {
  const bool host_big_endian = boost::endian::order::native == boost::endian::order::big;
  if (image->encoding == enc::TYPE_32FC1) {
    CheckLayout(*image, 4, where);
    if (static_cast<bool>(image->is_bigendian) != host_big_endian) {
      throw InputError(where + ": depth with the other byte order (is_bigendian) is not supported");
    }
    return cv_bridge::toCvCopy(image)->image;
  }
  if (image->encoding == enc::TYPE_16UC1 || image->encoding == enc::MONO16) {
    CheckLayout(*image, 2, where);
    if (static_cast<bool>(image->is_bigendian) != host_big_endian) {
      throw InputError(where + ": depth with the other byte order (is_bigendian) is not supported");
    }
    cv::Mat depth;
    cv_bridge::toCvShare(image)->image.convertTo(depth, CV_32F, 1e-3);
    return depth;
  }
  throw InputError(where + ": depth encoding '" + image->encoding +
                   "' is not supported (accepted: 32FC1 in m, 16UC1 in mm)");
}

std::string MatrixText(const double* values, int rows, int cols) {
  std::string text = "[";
  for (int i = 0; i < rows * cols; ++i) {
    if (i > 0) text += (i % cols == 0) ? "; " : " ";
    char buffer[32];
    std::snprintf(buffer, sizeof(buffer), "%g", values[i]);
    text += buffer;
  }
  return text + "]";
}

CameraCalibration ToCalibration(const sensor_msgs::CameraInfo& info, const std::string& camera_name,
                                const std::string& where) {
  if (info.width == 0 || info.height == 0) {
    throw InputError(where + ": width and height must be set, got " + std::to_string(info.width) + "x" +
                     std::to_string(info.height));
  }
  if (info.width > static_cast<std::uint32_t>(std::numeric_limits<int>::max()) ||
      info.height > static_cast<std::uint32_t>(std::numeric_limits<int>::max())) {
    throw InputError(where + ": image size out of range");
  }
  const auto& k = info.K;
  const double tolerance = 1e-9 * std::max({1.0, std::abs(k[0]), std::abs(k[4])});
  const bool pinhole = std::abs(k[1]) <= tolerance && std::abs(k[3]) <= tolerance &&
                       std::abs(k[6]) <= tolerance && std::abs(k[7]) <= tolerance &&
                       std::abs(k[8] - 1.0) <= tolerance && k[0] > 0.0 && k[4] > 0.0;
  if (!pinhole) {
    throw InputError(where + ": K must be [fx 0 cx; 0 fy cy; 0 0 1] with fx, fy > 0, got " +
                     MatrixText(k.data(), 3, 3));
  }
  if (info.binning_x > 1 || info.binning_y > 1) {
    throw InputError(where + ": binning is not supported (binning_x " + std::to_string(info.binning_x) +
                     ", binning_y " + std::to_string(info.binning_y) + ")");
  }
  const sensor_msgs::RegionOfInterest& roi = info.roi;
  const bool full_roi =
      roi.x_offset == 0 && roi.y_offset == 0 &&
      ((roi.width == 0 && roi.height == 0) || (roi.width == info.width && roi.height == info.height));
  if (!full_roi) throw InputError(where + ": a region of interest (roi) is not supported");
  for (double value : info.D) {
    if (!std::isfinite(value)) throw InputError(where + ": D has a value that is not finite");
  }

  CameraCalibration calibration;
  calibration.camera = deblur_sr_mvs::PinholeCamera(static_cast<int>(info.width),
                                                    static_cast<int>(info.height), k[0], k[4], k[2], k[5]);
  const std::string problem = calibration.camera.Problem();
  if (!problem.empty()) throw InputError(where + ": " + problem);
  calibration.camera_name = camera_name.empty() ? std::string("camera") : camera_name;
  calibration.distortion_model = info.distortion_model;
  calibration.distortion = info.D;
  for (int row = 0; row < 3; ++row) {
    for (int col = 0; col < 3; ++col) calibration.rectification(row, col) = info.R[row * 3 + col];
    for (int col = 0; col < 4; ++col) calibration.projection(row, col) = info.P[row * 4 + col];
  }
  return calibration;
}

// A sequence has one camera.yaml: the calibration may not change.
bool SameCalibration(const sensor_msgs::CameraInfo& a, const sensor_msgs::CameraInfo& b) {
  return a.width == b.width && a.height == b.height && a.distortion_model == b.distortion_model &&
         a.D == b.D && a.K == b.K && a.R == b.R && a.P == b.P && a.binning_x == b.binning_x &&
         a.binning_y == b.binning_y && a.roi == b.roi;
}

void CheckSize(const cv::Mat& image, const sensor_msgs::CameraInfo& info, const std::string& where,
               const std::string& info_topic) {
  if (image.cols != static_cast<int>(info.width) || image.rows != static_cast<int>(info.height)) {
    throw InputError(where + ": image is " + SizeText(image.cols, image.rows) + " but " + info_topic +
                     " says " + SizeText(static_cast<int>(info.width), static_cast<int>(info.height)));
  }
}

// ---------------------------------------------------------- the sequence

// The exposure of the frame at stamp from the exposure topic: stamp - time_ref.
double TopicExposure(const Options& options, const BagContents& bag, const ros::Time& stamp,
                     const std::string& where) {
  const auto exposure_it = bag.exposures.find(stamp.toNSec());
  if (exposure_it == bag.exposures.end()) {
    throw InputError(where + ": no " + options.exposure_topic +
                     " message with the same stamp (every frame needs one, or pass --exposure "
                     "SECONDS)");
  }
  const ros::Time& shutter_open = exposure_it->second->time_ref;
  if (!(shutter_open < stamp)) {
    throw InputError(options.input + ": " + options.exposure_topic + " at stamp " + StampText(stamp) +
                     ": time_ref " + StampText(shutter_open) +
                     " (shutter open) must be before header.stamp (shutter close)");
  }
  return (stamp - shutter_open).toSec();
}

// What rounding the stamps to the ROS nanosecond may take off a frame
// interval: an exposure or readout time that filled it may exceed it by this.
constexpr double kRoundingSlack = 2e-9;

// 0 < exposure <= frame interval, as ReadFramesCsv requires (with its
// tolerance for decimal and epoch stamps). Stamps rounded to the nanosecond
// may shorten an interval by 1 ns against an exposure that filled it: such
// an excess (<= 2 ns) is clamped to the interval, anything more is an error.
void ClampExposures(const Options& options, Sequence* sequence) {
  const std::size_t count = sequence->frames.size();
  const bool exposure_from_topic = !options.exposure.has_value();
  for (std::size_t i = 0; i < count && count > 1; ++i) {
    deblur_sr_mvs::FrameRecord& frame = sequence->frames[i];
    const bool first = i == 0;
    const double a = first ? sequence->frames[0].stamp : sequence->frames[i - 1].stamp;
    const double b = first ? sequence->frames[1].stamp : frame.stamp;
    const double interval = b - a;
    const double reader_tolerance =
        1e-12 + 8.0 * std::numeric_limits<double>::epsilon() * std::max(std::abs(a), std::abs(b));
    if (frame.exposure <= interval + reader_tolerance) continue;
    if (frame.exposure <= interval + reader_tolerance + kRoundingSlack) {
      frame.exposure = interval;
      continue;
    }
    const std::string source =
        exposure_from_topic ? options.input + ": " + options.exposure_topic : std::string("--exposure");
    throw InputError(source + ": exposure " + Seconds(frame.exposure) + " s of the frame at stamp " +
                     Seconds(frame.stamp) + " exceeds the frame interval " + Seconds(interval) +
                     " s (gap to the " + (first ? "next" : "previous") + " stamp)");
  }
}

// The readout time (--readout-time, else the topic, else 0 = global shutter)
// within ReadSensorYaml's bounds; one that exceeds the smallest frame
// interval by at most kRoundingSlack is clamped to it, as exposures are.
double ReadoutTime(const Options& options, const BagContents& bag, const Sequence& sequence) {
  double readout_time = options.readout_time.value_or(bag.readout_time.value_or(0.0));
  const std::vector<deblur_sr_mvs::FrameRecord>& frames = sequence.frames;
  std::string problem = deblur_sr_mvs::ReadoutTimeProblem(readout_time, frames);
  if (!problem.empty() && std::isfinite(readout_time) && readout_time > 0.0) {
    double smallest = std::numeric_limits<double>::infinity();
    for (std::size_t i = 1; i < frames.size(); ++i) {
      smallest = std::min(smallest, frames[i].stamp - frames[i - 1].stamp);
    }
    if (readout_time <= smallest + kRoundingSlack) {
      readout_time = smallest;
      problem = deblur_sr_mvs::ReadoutTimeProblem(readout_time, frames);
    }
  }
  if (!problem.empty()) {
    const std::string source =
        options.readout_time ? std::string("--readout-time") : options.input + ": " + options.readout_topic;
    throw InputError(source + ": " + problem);
  }
  return readout_time;
}

Sequence ToSequence(const Options& options, const BagContents& bag) {
  const std::string& path = options.input;
  Sequence sequence;
  const std::size_t count = bag.images.size();
  sequence.frames.resize(count);
  sequence.images.resize(count);

  const bool exposure_from_topic = !options.exposure.has_value();
  if (exposure_from_topic && bag.exposures.empty()) {
    throw InputError(path + ": no exposure: the bag has no " + options.exposure_topic +
                     " messages (sensor_msgs/TimeReference); pass --exposure SECONDS");
  }
  const sensor_msgs::CameraInfo* first_info = nullptr;
  for (std::size_t i = 0; i < count; ++i) {
    const sensor_msgs::ImageConstPtr& message = bag.images[i];
    const ros::Time& stamp = message->header.stamp;
    const std::string where = path + ": " + options.image_topic + " at stamp " + StampText(stamp);
    if (i > 0 && !(stamp > bag.images[i - 1]->header.stamp)) {
      throw InputError(where + ": stamp is not after the previous image's stamp " +
                       StampText(bag.images[i - 1]->header.stamp) + " (stamps must increase)");
    }
    cv::Mat image = DecodeImage8(message, where);
    if (i > 0) {
      const cv::Mat& first = sequence.images.front();
      if (image.size() != first.size() || image.channels() != first.channels()) {
        throw InputError(where + ": image is " + SizeText(image.cols, image.rows) + " with " +
                         std::to_string(image.channels()) + " channel(s) but the first is " +
                         SizeText(first.cols, first.rows) + " with " + std::to_string(first.channels()));
      }
    }

    const auto info_it = bag.infos.find(stamp.toNSec());
    if (info_it == bag.infos.end()) {
      throw InputError(where + ": no " + options.info_topic + " message with the same stamp");
    }
    const sensor_msgs::CameraInfo& info = *info_it->second;
    const std::string info_where = path + ": " + options.info_topic + " at stamp " + StampText(stamp);
    if (first_info == nullptr) {
      sequence.calibration = ToCalibration(info, bag.camera_name, info_where);
      first_info = &info;
    } else if (!SameCalibration(info, *first_info)) {
      throw InputError(info_where +
                       ": the calibration differs from the first camera_info (a sequence folder has "
                       "one camera.yaml)");
    }
    CheckSize(image, info, where, options.info_topic);

    deblur_sr_mvs::FrameRecord& frame = sequence.frames[i];
    frame.index = static_cast<int>(i);
    frame.stamp = stamp.toSec();
    frame.exposure = exposure_from_topic ? TopicExposure(options, bag, stamp, where) : *options.exposure;
    sequence.images[i] = std::move(image);
  }

  ClampExposures(options, &sequence);
  sequence.readout_time = ReadoutTime(options, bag, sequence);
  return sequence;
}

// gt/ from the ground-truth topics: one image, depth, camera_info (same stamp
// as the frame) and pose (within 1 us, ReadSequence's tolerance) per frame.
deblur_sr_mvs::SequenceGroundTruth ToGroundTruth(const Options& options, const BagContents& bag) {
  const std::string& path = options.input;
  deblur_sr_mvs::SequenceGroundTruth gt;
  const sensor_msgs::CameraInfo* first_info = nullptr;
  const auto missing = [&](const std::string& topic, const ros::Time& stamp) {
    return InputError(path + ": " + topic + ": no message for the frame at stamp " + StampText(stamp) +
                      " (ground truth needs one per frame; pass --no-ground-truth to leave it out)");
  };
  for (std::size_t i = 0; i < bag.images.size(); ++i) {
    const ros::Time& stamp = bag.images[i]->header.stamp;
    const StampKey key = stamp.toNSec();
    const std::string image_topic = options.GtTopic("image");
    const std::string depth_topic = options.GtTopic("depth");
    const std::string info_topic = options.GtTopic("camera_info");
    const std::string pose_topic = options.GtTopic("pose");
    const std::string at = " at stamp " + StampText(stamp);

    const auto image_it = bag.gt_images.find(key);
    if (image_it == bag.gt_images.end()) throw missing(image_topic, stamp);
    const auto depth_it = bag.gt_depths.find(key);
    if (depth_it == bag.gt_depths.end()) throw missing(depth_topic, stamp);
    const auto info_it = bag.gt_infos.find(key);
    if (info_it == bag.gt_infos.end()) throw missing(info_topic, stamp);
    constexpr StampKey kPoseTolerance = 1000;  // ns
    auto pose_it = bag.gt_poses.lower_bound(key >= kPoseTolerance ? key - kPoseTolerance : 0);
    if (pose_it == bag.gt_poses.end() || pose_it->first > key + kPoseTolerance) {
      throw missing(pose_topic + " (within 1 us)", stamp);
    }

    const std::string image_where = path + ": " + image_topic + at;
    cv::Mat latent = DecodeImage8(image_it->second, image_where);
    if (!gt.latent.empty() && latent.channels() != gt.latent.front().channels()) {
      throw InputError(image_where + ": image has " + std::to_string(latent.channels()) +
                       " channel(s) but the first has " + std::to_string(gt.latent.front().channels()));
    }
    const std::string depth_where = path + ": " + depth_topic + at;
    cv::Mat depth = DecodeDepth(depth_it->second, depth_where);

    const sensor_msgs::CameraInfo& info = *info_it->second;
    const std::string info_where = path + ": " + info_topic + at;
    if (first_info == nullptr) {
      gt.calibration = ToCalibration(info, bag.gt_camera_name, info_where);
      first_info = &info;
    } else if (!SameCalibration(info, *first_info)) {
      throw InputError(info_where + ": the calibration differs from the first one (gt/ has one camera.yaml)");
    }
    CheckSize(latent, info, image_where, info_topic);
    CheckSize(depth, info, depth_where, info_topic);

    const geometry_msgs::PoseStamped& pose = *pose_it->second;
    const std::string pose_where = path + ": " + pose_topic + " at stamp " + StampText(pose.header.stamp);
    const auto& p = pose.pose.position;
    const auto& o = pose.pose.orientation;
    const Eigen::Quaterniond q(o.w, o.x, o.y, o.z);
    const bool finite =
        std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z) && q.coeffs().allFinite();
    if (!finite || q.norm() < 1e-6) {
      throw InputError(pose_where + ": position and orientation must be finite, with a nonzero quaternion");
    }
    deblur_sr_mvs::StampedPose stamped_pose;
    stamped_pose.stamp = pose.header.stamp.toSec();
    stamped_pose.T_world_cam = deblur_sr_mvs::SE3(q.normalized(), Eigen::Vector3d(p.x, p.y, p.z));

    gt.latent.push_back(std::move(latent));
    gt.depth.push_back(std::move(depth));
    gt.poses.push_back(stamped_pose);
  }
  return gt;
}

// The output folder must be new, empty, or a sequence folder (frames.csv);
// a sequence folder's own files are replaced so that no stale frame or gt/
// survives. Nothing else in it is touched.
void PrepareOutputFolder(const std::string& folder) {
  const fs::path root(folder);
  std::error_code error;
  const fs::file_status status = fs::status(root, error);
  if (!fs::exists(status)) return;
  if (!fs::is_directory(status)) throw InputError(folder + ": exists and is not a folder");
  if (fs::is_empty(root, error)) return;
  if (!fs::exists(root / "frames.csv", error)) {
    throw InputError(folder +
                     ": folder is not empty and is not a sequence folder (no frames.csv); "
                     "refusing to write into it");
  }
  for (const char* name : {"camera.yaml", "frames.csv", "sensor.yaml", "images", "gt"}) {
    fs::remove_all(root / name, error);
    if (error) throw InputError((root / name).string() + ": cannot remove: " + error.message());
  }
}

int Run(int argc, char** argv) {
  Options options;
  if (!ParseOptions(argc, argv, &options)) return 0;
  const BagContents bag = ReadBag(options);
  Sequence sequence = ToSequence(options, bag);
  if (options.ground_truth && bag.HasGroundTruth()) {
    sequence.ground_truth = ToGroundTruth(options, bag);
  }
  PrepareOutputFolder(options.output);
  deblur_sr_mvs::WriteSequence(options.output, sequence);

  const cv::Mat& first = sequence.images.front();
  std::cout << "wrote " << options.output << ": " << sequence.frames.size() << " frames " << first.cols << "x"
            << first.rows << (first.channels() == 1 ? " gray" : " colour") << ", exposure from "
            << (options.exposure ? "--exposure" : options.exposure_topic);
  if (sequence.readout_time > 0.0) {
    std::cout << ", readout time " << sequence.readout_time << " s from "
              << (options.readout_time ? "--readout-time" : options.readout_topic);
  }
  std::cout << (sequence.ground_truth ? ", with gt/" : "") << "\n";
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  return deblur_sr_mvs::BagToolMain("bag_to_sequence", Run, argc, argv);
}
