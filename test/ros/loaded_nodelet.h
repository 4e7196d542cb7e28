// Test support for the rostests that load the estimator nodelet in their own
// process: a synthesized sequence, camera messages, and a nodelet on its own
// namespace and camera topics with everything it publishes collected.
#pragma once

#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <map>
#include <mutex>
#include <string>
#include <vector>

#include <geometry_msgs/PoseStamped.h>
#include <gtest/gtest.h>
#include <nav_msgs/Path.h>
#include <nodelet/loader.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/TimeReference.h>

#include "deblur_sr_mvs/EstimatorStatus.h"
#include "deblur_sr_mvs/core/imaging/image_ops.h"
#include "deblur_sr_mvs/core/io/sequence_io.h"
#include "deblur_sr_mvs/ros/conversions.h"

namespace deblur_sr_mvs {
namespace test {

template <typename Predicate>
bool WaitFor(Predicate done, double seconds) {
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(seconds);
  while (ros::ok() && ros::WallTime::now() < deadline) {
    if (done()) return true;
    ros::WallDuration(0.02).sleep();
  }
  return done();
}

// A Dolls sequence from synthesize_sequence with `flags` (and ground truth).
inline Sequence SynthesizedDolls(const std::string& tag, const std::string& flags) {
  const std::string folder = "/tmp/dsm_rostest_" + tag + "_" + std::to_string(getpid());
  const std::string command = std::string(DSM_SYNTHESIZE_SEQUENCE) + " --scene " + DSM_SOURCE_DIR +
                              "/data/middlebury/Dolls --output " + folder + " " + flags + " > /dev/null";
  EXPECT_EQ(std::system(command.c_str()), 0) << command;
  Sequence read = ReadSequence(folder, true);
  std::filesystem::remove_all(folder);
  return read;
}

inline sensor_msgs::ImagePtr Rgb8Message(const cv::Mat& bgr, const ros::Time& stamp,
                                         const std::string& frame_id) {
  std_msgs::Header header;
  header.stamp = stamp;
  header.frame_id = frame_id;
  return boost::make_shared<sensor_msgs::Image>(
      ros_glue::Float01ToImage(ToFloat01(bgr), ros_glue::ImageFamily::kRgb8, header));
}

inline sensor_msgs::CameraInfoPtr InfoMessage(const PinholeCamera& camera, const ros::Time& stamp,
                                              const std::string& frame_id) {
  std_msgs::Header header;
  header.stamp = stamp;
  header.frame_id = frame_id;
  return boost::make_shared<sensor_msgs::CameraInfo>(ros_glue::ScaledCameraInfo(camera, 1, header));
}

// A copy of a 32FC1 depth image.
inline cv::Mat DepthOf(const sensor_msgs::Image& image) {
  return cv::Mat(image.height, image.width, CV_32FC1, const_cast<uint8_t*>(image.data.data()), image.step)
      .clone();
}

// The nodelet at `ns`/estimator, reading `ns`_camera/image + camera_info (+ exposure),
// with cheap settings (windows of 4 overlapping by 2, M 16) that `params`
// (private parameter -> value) override.
class LoadedNodelet {
 public:
  LoadedNodelet(const std::string& ns, const std::map<std::string, XmlRpc::XmlRpcValue>& params) : ns_(ns) {
    std::map<std::string, XmlRpc::XmlRpcValue> all{
        {"exposure_time", 0.8 / 30.0}, {"window_size", 4}, {"window_overlap", 2},
        {"max_pending_windows", 4},    {"samples", 16},    {"lazy_subscription", false}};
    for (const auto& [name, value] : params) all[name] = value;
    for (const auto& [name, value] : all) ros::param::set(ns + "/estimator/" + name, value);
    nodelet::M_string remappings{{ns + "/image", ns + "_camera/image"},
                                 {ns + "/camera_info", ns + "_camera/camera_info"},
                                 {ns + "/exposure", ns + "_camera/exposure"}};
    loaded_ = loader_.load(ns + "/estimator", "deblur_sr_mvs/EstimatorNodelet", remappings, {});
    ros::NodeHandle node;
    subscribers_.push_back(node.subscribe<sensor_msgs::Image>(
        ns + "/restored/image", 20, [this](const sensor_msgs::ImageConstPtr& m) { Keep(&restored, m); }));
    subscribers_.push_back(node.subscribe<sensor_msgs::Image>(
        ns + "/depth/image", 20, [this](const sensor_msgs::ImageConstPtr& m) { Keep(&depths, m); }));
    subscribers_.push_back(node.subscribe<geometry_msgs::PoseStamped>(
        ns + "/pose", 20, [this](const geometry_msgs::PoseStampedConstPtr& m) { Keep(&poses, m); }));
    subscribers_.push_back(node.subscribe<EstimatorStatus>(
        ns + "/status", 20, [this](const EstimatorStatusConstPtr& m) { Keep(&statuses, m); }));
    subscribers_.push_back(
        node.subscribe<nav_msgs::Path>(ns + "/path", 5, [this](const nav_msgs::PathConstPtr& m) {
          std::lock_guard<std::mutex> lock(mutex);
          path = m;
        }));
    images = node.advertise<sensor_msgs::Image>(ns + "_camera/image", 50);
    infos = node.advertise<sensor_msgs::CameraInfo>(ns + "_camera/camera_info", 50);
    exposures = node.advertise<sensor_msgs::TimeReference>(ns + "_camera/exposure", 50);
  }
  ~LoadedNodelet() { loader_.unload(ns_ + "/estimator"); }

  // Loaded and subscribed to the camera.
  bool Connected() {
    return loaded_ &&
           WaitFor([&] { return images.getNumSubscribers() > 0 && infos.getNumSubscribers() > 0; }, 30.0);
  }
  // Frame `bgr` with its camera_info (same stamp).
  void Send(const cv::Mat& bgr, const PinholeCamera& camera, const ros::Time& stamp,
            const std::string& frame_id = "test_camera") {
    infos.publish(InfoMessage(camera, stamp, frame_id));
    images.publish(Rgb8Message(bgr, stamp, frame_id));
  }
  // The exposure of the frame at `stamp` as sequence_to_bag writes it
  // (docs/file_formats.md#exposure): time_ref = the shutter open time.
  void SendExposure(const ros::Time& stamp, double exposure) {
    sensor_msgs::TimeReference message;
    message.header.stamp = stamp;
    message.time_ref = stamp - ros::Duration(exposure);
    message.source = "shutter_open";
    exposures.publish(message);
  }
  size_t StatusCount() {
    std::lock_guard<std::mutex> lock(mutex);
    return statuses.size();
  }

  std::mutex mutex;  // guards the outputs below
  std::vector<sensor_msgs::ImageConstPtr> restored, depths;
  std::vector<geometry_msgs::PoseStampedConstPtr> poses;
  std::vector<EstimatorStatusConstPtr> statuses;
  nav_msgs::PathConstPtr path;
  ros::Publisher images, infos, exposures;

 private:
  template <typename List, typename Message>
  void Keep(List* list, const Message& message) {
    std::lock_guard<std::mutex> lock(mutex);
    list->push_back(message);
  }

  std::string ns_;
  nodelet::Loader loader_{false};
  bool loaded_ = false;
  std::vector<ros::Subscriber> subscribers_;
};

// main() of a rostest binary: gtest and ROS initialised, callbacks on a
// spinner of two threads while the tests run.
inline int RunRosTests(int argc, char** argv, const std::string& node_name) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, node_name);
  ros::AsyncSpinner spinner(2);
  spinner.start();
  const int result = RUN_ALL_TESTS();
  spinner.stop();
  ros::shutdown();
  return result;
}

}  // namespace test
}  // namespace deblur_sr_mvs
