// bag_to_result: the estimator node's recorded outputs -> a result folder
// (SPEC section 3), so that evaluate_sequence and make_comparison_figure judge
// the node exactly as they judge the offline estimator.
//
//   bag_to_result --input BAG --sequence SEQ --output OUT [--namespace NS]
//
// Reads NS/restored/image, NS/restored/camera_info, NS/depth/image, NS/pose
// and NS/status (NS default /deblur_sr_mvs) from BAG, and the frames of SEQ's
// frames.csv: every frame (stamp rounded to the ROS nanosecond, as
// sequence_to_bag writes it) must have a restored image, a depth map and a
// pose. report.json lists the node's windows (status messages).
//
// Exit code 0 on success, 2 with one line on stderr on bad input.
#include <cmath>
#include <cstdint>
#include <cstring>
#include <iostream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include <geometry_msgs/PoseStamped.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>

#include "bag_tool_main.h"
#include "deblur_sr_mvs/EstimatorStatus.h"
#include "deblur_sr_mvs/core/imaging/image_ops.h"
#include "deblur_sr_mvs/core/io/result_io.h"
#include "deblur_sr_mvs/core/io/sequence_io.h"
#include "tool_main.h"
#include "deblur_sr_mvs/ros/conversions.h"

namespace dsm = deblur_sr_mvs;

namespace {

constexpr char kUsage[] =
    "usage: bag_to_result --input BAG --sequence SEQ --output OUT [--namespace NS]\n"
    "Converts the estimator node's recorded outputs (NS/restored/image, NS/restored/camera_info,\n"
    "NS/depth/image, NS/pose, NS/status; NS default /deblur_sr_mvs) into a result folder for\n"
    "the frames of SEQ/frames.csv.\n";

int64_t StampNs(double seconds) { return static_cast<int64_t>(std::llround(seconds * 1e9)); }

std::string JsonString(const std::string& text) {
  std::string out = "\"";
  for (char c : text) {
    if (c == '"' || c == '\\') out += '\\';
    if (c == '\n') {
      out += "\\n";
      continue;
    }
    out += c;
  }
  return out + "\"";
}

std::string StatusJson(const std::vector<deblur_sr_mvs::EstimatorStatusConstPtr>& statuses) {
  std::ostringstream json;
  json.precision(9);
  json << "{\n  \"source\": \"deblur_sr_mvs estimator node (bag_to_result)\",\n  \"windows\": [";
  for (size_t i = 0; i < statuses.size(); ++i) {
    const auto& s = *statuses[i];
    json << (i ? "," : "") << "\n    {\"window_index\": " << s.window_index
         << ", \"success\": " << (s.success ? "true" : "false")
         << ", \"continued\": " << (s.continued ? "true" : "false") << ", \"frames\": " << s.frame_stamps.size()
         << ", \"first_new\": " << s.first_new << ", \"processing_seconds\": " << s.processing_seconds
         << ", \"latency_seconds\": " << s.latency_seconds << ", \"message\": " << JsonString(s.message)
         << ", \"energies\": [";
    for (size_t e = 0; e < s.energies.size(); ++e) json << (e ? ", " : "") << s.energies[e];
    json << "], \"stages\": {";
    for (size_t k = 0; k < s.stage_names.size(); ++k) {
      json << (k ? ", " : "") << JsonString(s.stage_names[k]) << ": " << s.stage_seconds[k];
    }
    json << "}}";
  }
  json << "\n  ]";
  if (!statuses.empty()) {
    const auto& last = *statuses.back();
    json << ",\n  \"frames_received\": " << last.frames_received << ",\n  \"frames_rejected\": "
         << last.frames_rejected << ",\n  \"frames_published\": " << last.frames_published
         << ",\n  \"windows_dropped\": " << last.windows_dropped << ",\n  \"windows_failed\": "
         << last.windows_failed << ",\n  \"scale_note\": " << JsonString(last.scale_note);
  }
  json << "\n}\n";
  return json.str();
}

int Run(int argc, char** argv) {
  std::map<std::string, std::string> flags{{"--namespace", "/deblur_sr_mvs"}};
  for (int i = 1; i < argc; ++i) {
    const std::string flag = argv[i];
    if (flag == "--help" || flag == "-h") {
      std::cout << kUsage;
      return 0;
    }
    if (flag != "--input" && flag != "--sequence" && flag != "--output" && flag != "--namespace") {
      throw dsm::InputError("unknown flag " + flag + " (see --help)");
    }
    if (i + 1 >= argc) throw dsm::InputError(flag + " needs a value");
    flags[flag] = argv[++i];
  }
  for (const char* required : {"--input", "--sequence", "--output"}) {
    if (!flags.count(required)) throw dsm::InputError(std::string(required) + " is required (see --help)");
  }
  std::string ns = flags["--namespace"];
  if (!ns.empty() && ns.back() == '/') ns.pop_back();
  const std::string bag_path = flags["--input"];
  const std::vector<dsm::FrameRecord> frames = dsm::ReadFramesCsv(flags["--sequence"] + "/frames.csv");

  std::map<int64_t, sensor_msgs::ImageConstPtr> restored, depth;
  std::map<int64_t, sensor_msgs::CameraInfoConstPtr> infos;
  std::map<int64_t, geometry_msgs::PoseStampedConstPtr> poses;
  std::vector<deblur_sr_mvs::EstimatorStatusConstPtr> statuses;
  rosbag::Bag bag;
  try {
    bag.open(bag_path, rosbag::bagmode::Read);
  } catch (const std::exception& error) {
    throw dsm::InputError(bag_path + ": cannot open the bag: " + dsm::OneLine(error.what()));
  }
  try {
    rosbag::View view(bag);
    for (const rosbag::MessageInstance& message : view) {
      const std::string& topic = message.getTopic();
      if (topic == ns + "/restored/image" || topic == ns + "/depth/image") {
        const auto image = message.instantiate<sensor_msgs::Image>();
        if (!image) throw dsm::InputError(bag_path + ": " + topic + " is not sensor_msgs/Image");
        (topic == ns + "/restored/image" ? restored : depth)[static_cast<int64_t>(image->header.stamp.toNSec())] = image;
      } else if (topic == ns + "/restored/camera_info") {
        const auto info = message.instantiate<sensor_msgs::CameraInfo>();
        if (info) infos[static_cast<int64_t>(info->header.stamp.toNSec())] = info;
      } else if (topic == ns + "/pose") {
        const auto pose = message.instantiate<geometry_msgs::PoseStamped>();
        if (pose) poses[static_cast<int64_t>(pose->header.stamp.toNSec())] = pose;
      } else if (topic == ns + "/status") {
        const auto status = message.instantiate<deblur_sr_mvs::EstimatorStatus>();
        if (status) statuses.push_back(status);
      }
    }
  } catch (const rosbag::BagException& error) {
    throw dsm::InputError(bag_path + ": unreadable bag: " + dsm::OneLine(error.what()));
  }

  dsm::SequenceResult result;
  result.frames = frames;
  int missing = 0;
  std::string first_missing;
  for (const dsm::FrameRecord& frame : frames) {
    const int64_t key = StampNs(frame.stamp);
    if (!restored.count(key) || !depth.count(key) || !poses.count(key) || !infos.count(key)) {
      if (missing++ == 0) first_missing = std::to_string(frame.index);
      continue;
    }
    dsm::ros_glue::ImageFamily family;
    const cv::Mat latent01 = dsm::ros_glue::ImageToFloat01(*restored[key], &family);
    if (family == dsm::ros_glue::ImageFamily::kMono16) {
      throw dsm::InputError(bag_path + ": mono16 restored images do not fit the 8-bit result folder");
    }
    result.latent.push_back(dsm::ToImage8(latent01));
    const sensor_msgs::Image& depth_image = *depth[key];
    if (depth_image.encoding != "32FC1" || depth_image.step != depth_image.width * 4 ||
        depth_image.data.size() != static_cast<size_t>(depth_image.step) * depth_image.height) {
      throw dsm::InputError(bag_path + ": " + ns + "/depth/image must be dense 32FC1");
    }
    cv::Mat depth_map(depth_image.height, depth_image.width, CV_32FC1);
    std::memcpy(depth_map.data, depth_image.data.data(), depth_image.data.size());
    result.depth.push_back(depth_map);
    const geometry_msgs::Pose& pose = poses[key]->pose;
    const Eigen::Quaterniond q(pose.orientation.w, pose.orientation.x, pose.orientation.y, pose.orientation.z);
    result.poses.push_back(dsm::StampedPose{
        frame.stamp, dsm::SE3(q.normalized(), Eigen::Vector3d(pose.position.x, pose.position.y, pose.position.z))});
    if (result.latent.size() == 1) {
      const sensor_msgs::CameraInfo& info = *infos[key];
      const dsm::PinholeCamera camera =
          dsm::ros_glue::CameraFromInfo(info, info.width, info.height, dsm::ros_glue::DistortionPolicy::kReject);
      result.calibration = dsm::CameraCalibration::FromCamera(camera, "deblur_sr_mvs_restored");
    }
  }
  if (missing > 0) {
    throw dsm::InputError(bag_path + ": " + std::to_string(missing) + " of " + std::to_string(frames.size()) +
                          " frames have no restored image, depth, camera_info or pose (first: frame " +
                          first_missing + ")");
  }
  result.report_json = StatusJson(statuses);
  dsm::WriteResult(flags["--output"], result);
  std::cout << "bag_to_result: " << frames.size() << " frames from " << statuses.size() << " windows -> "
            << flags["--output"] << "\n";
  return 0;
}

}  // namespace

int main(int argc, char** argv) { return dsm::BagToolMain("bag_to_result", Run, argc, argv); }
