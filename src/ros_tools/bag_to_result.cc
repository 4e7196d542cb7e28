// bag_to_result: the estimator node's recorded outputs -> a result folder
// (docs/file_formats.md#result-folder), so that evaluate_sequence and make_comparison_figure judge
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
#include "deblur_sr_mvs/ros/conversions.h"
#include "status_report.h"
#include "tool_main.h"

namespace dsm = deblur_sr_mvs;

namespace {

constexpr char kDescription[] =
    "Converts the estimator node's recorded outputs (NS/restored/image, NS/restored/camera_info,\n"
    "NS/depth/image, NS/pose, NS/status; NS default /deblur_sr_mvs) into a result folder for\n"
    "the frames of SEQ/frames.csv.";

int64_t StampNs(double seconds) {
  return static_cast<int64_t>(std::llround(seconds * 1e9));
}

// The node's outputs in the bag, by header stamp (ns).
struct NodeOutputs {
  std::map<int64_t, sensor_msgs::ImageConstPtr> restored, depth;
  std::map<int64_t, sensor_msgs::CameraInfoConstPtr> infos;
  std::map<int64_t, geometry_msgs::PoseStampedConstPtr> poses;
  std::vector<deblur_sr_mvs::EstimatorStatusConstPtr> statuses;
};

NodeOutputs ReadNodeOutputs(const std::string& bag_path, const std::string& ns) {
  NodeOutputs outputs;
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
        auto& images = topic == ns + "/restored/image" ? outputs.restored : outputs.depth;
        images[static_cast<int64_t>(image->header.stamp.toNSec())] = image;
      } else if (topic == ns + "/restored/camera_info") {
        const auto info = message.instantiate<sensor_msgs::CameraInfo>();
        if (info) outputs.infos[static_cast<int64_t>(info->header.stamp.toNSec())] = info;
      } else if (topic == ns + "/pose") {
        const auto pose = message.instantiate<geometry_msgs::PoseStamped>();
        if (pose) outputs.poses[static_cast<int64_t>(pose->header.stamp.toNSec())] = pose;
      } else if (topic == ns + "/status") {
        const auto status = message.instantiate<deblur_sr_mvs::EstimatorStatus>();
        if (status) outputs.statuses.push_back(status);
      }
    }
  } catch (const rosbag::BagException& error) {
    throw dsm::InputError(bag_path + ": unreadable bag: " + dsm::OneLine(error.what()));
  }
  return outputs;
}

// One frame's restored image, depth map and pose into the result (and the
// calibration from the first frame's camera_info).
void AddFrame(const NodeOutputs& outputs, int64_t key, const dsm::FrameRecord& frame,
              const std::string& bag_path, const std::string& ns, dsm::SequenceResult* result) {
  dsm::ros_glue::ImageFamily family;
  const cv::Mat latent01 = dsm::ros_glue::ImageToFloat01(*outputs.restored.at(key), &family);
  if (family == dsm::ros_glue::ImageFamily::kMono16) {
    throw dsm::InputError(bag_path + ": mono16 restored images do not fit the 8-bit result folder");
  }
  result->latent.push_back(dsm::ToImage8(latent01));
  const sensor_msgs::Image& depth_image = *outputs.depth.at(key);
  if (depth_image.encoding != "32FC1" || depth_image.step != depth_image.width * 4 ||
      depth_image.data.size() != static_cast<size_t>(depth_image.step) * depth_image.height) {
    throw dsm::InputError(bag_path + ": " + ns + "/depth/image must be dense 32FC1");
  }
  cv::Mat depth_map(depth_image.height, depth_image.width, CV_32FC1);
  std::memcpy(depth_map.data, depth_image.data.data(), depth_image.data.size());
  result->depth.push_back(depth_map);
  const geometry_msgs::Pose& pose = outputs.poses.at(key)->pose;
  const Eigen::Quaterniond q(pose.orientation.w, pose.orientation.x, pose.orientation.y, pose.orientation.z);
  result->poses.push_back(dsm::StampedPose{
      frame.stamp,
      dsm::SE3(q.normalized(), Eigen::Vector3d(pose.position.x, pose.position.y, pose.position.z))});
  if (result->latent.size() == 1) {
    const sensor_msgs::CameraInfo& info = *outputs.infos.at(key);
    const dsm::PinholeCamera camera = dsm::ros_glue::CameraFromInfo(info, info.width, info.height,
                                                                    dsm::ros_glue::DistortionPolicy::kReject);
    result->calibration = dsm::CameraCalibration::FromCamera(camera, "deblur_sr_mvs_restored");
  }
}

int Run(int argc, char** argv) {
  std::string bag_path, sequence_dir, output_dir, ns = "/deblur_sr_mvs";
  dsm::ToolCommandLine cli("bag_to_result", kDescription);
  cli.add_option("--input", bag_path, "bag recorded from the node")->required();
  cli.add_option("--sequence", sequence_dir, "sequence folder the node was fed (its frames.csv)")->required();
  cli.add_option("--output", output_dir, "result folder to write")->required();
  cli.add_option("--namespace", ns, "the node's topic namespace (default /deblur_sr_mvs)");
  if (!cli.Parse(argc, argv)) return 0;
  if (!ns.empty() && ns.back() == '/') ns.pop_back();
  const std::vector<dsm::FrameRecord> frames = dsm::ReadFramesCsv(sequence_dir + "/frames.csv");
  const NodeOutputs outputs = ReadNodeOutputs(bag_path, ns);

  dsm::SequenceResult result;
  result.frames = frames;
  int missing = 0;
  std::string first_missing;
  for (const dsm::FrameRecord& frame : frames) {
    const int64_t key = StampNs(frame.stamp);
    if (!outputs.restored.count(key) || !outputs.depth.count(key) || !outputs.poses.count(key) ||
        !outputs.infos.count(key)) {
      if (missing++ == 0) first_missing = std::to_string(frame.index);
      continue;
    }
    AddFrame(outputs, key, frame, bag_path, ns, &result);
  }
  if (missing > 0) {
    throw dsm::InputError(bag_path + ": " + std::to_string(missing) + " of " + std::to_string(frames.size()) +
                          " frames have no restored image, depth, camera_info or pose (first: frame " +
                          first_missing + ")");
  }
  result.report_json = dsm::JsonText(dsm::StatusReportJson(outputs.statuses));
  dsm::WriteResult(output_dir, result);
  std::cout << "bag_to_result: " << frames.size() << " frames from " << outputs.statuses.size()
            << " windows -> " << output_dir << "\n";
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  return dsm::BagToolMain("bag_to_result", Run, argc, argv);
}
