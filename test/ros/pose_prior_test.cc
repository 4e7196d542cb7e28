// rostest of the node's metric pose prior (test/ros/pose_prior.test,
// docs/ros_interface.md#pose-prior): nodelets loaded in this process get a
// small synthesized sequence as a camera and, on tf, the camera's pose in a
// fixed frame at every image stamp: the ground truth plus noise (a metric
// prior), the same in a world 20 times larger, the exact ground truth, or a
// prior that does not move (which cannot fix the scale).
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <mutex>
#include <random>
#include <string>
#include <vector>

#include <geometry_msgs/PoseStamped.h>
#include <gtest/gtest.h>
#include <nav_msgs/Path.h>
#include <nodelet/loader.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <tf2_msgs/TFMessage.h>
#include <tf2_ros/transform_listener.h>

#include "deblur_sr_mvs/EstimatorStatus.h"
#include "deblur_sr_mvs/core/evaluation/metrics.h"
#include "deblur_sr_mvs/core/imaging/image_ops.h"
#include "deblur_sr_mvs/core/io/sequence_io.h"
#include "deblur_sr_mvs/ros/conversions.h"
#include "loaded_nodelet.h"

namespace deblur_sr_mvs {
namespace {

constexpr int kFrames = 8;               // windows of 4 overlapping by 2: frames 0-3, 2-5, 4-7
constexpr double kPriorNoise = 0.01;     // m, RMS of the prior's 3D position noise
constexpr double kExactPositionBound = 0.01;  // m, with an exact prior
// Depth in metres without alignment may be this much worse (mean relative
// error, absolute) than after the best per-frame scale: the scale fitted on
// a noisy prior over a 7-17 cm path is a few percent off (the status'
// scale_note gives the fit's uncertainty, docs/ros_interface.md#pose-prior),
// so issue 11's 1.1 x criterion is printed, not asserted, with this prior;
// it is asserted with an exact prior, and with this prior over a path 20
// times longer. Unscaled
// (monocular units) the error would be |1/s - 1| for the fit's scale s:
// over 0.4 for this scene (median depth 1.7 m) in either gauge.
constexpr double kMetricDepthMargin = 0.10;
// A frame's depth scale is off by the prior fit's error (its uncertainty in
// the status) and by the frame's own scale error as estimated, which with an
// exact prior reaches 0.5 % (frames 5-7 of that run): allowed 1 % beside
// 3 of the fit's standard deviations.
constexpr double kFrameScaleError = 0.01;

const Sequence& TestSequence() {
  static const Sequence sequence = test::SynthesizedDolls(
      "prior", "--frames " + std::to_string(kFrames) +
                   " --subframes 60 --fps 30 --exposure-ratio 0.8 --hr-width 192 --hr-height 144");
  return sequence;
}

ros::Time FrameStamp(int t) {
  return ros::Time(100.0) + ros::Duration(TestSequence().frames[t].stamp);
}

// The rostest's nodelet with a prior frame.
class PriorNode : public test::LoadedNodelet {
 public:
  PriorNode(const std::string& ns, const std::string& prior_frame, int iterations)
      : LoadedNodelet(ns, {{"pose_prior_frame", prior_frame}, {"iterations", iterations}}) {}
  void SendFrame(int t, const std::string& frame_id) {
    Send(TestSequence().images[t], TestSequence().calibration.camera, FrameStamp(t), frame_id);
  }
};

// Publishes parent <- child transforms on /tf (after the node's listener is connected).
class PriorPublisher {
 public:
  PriorPublisher() : publisher_(ros::NodeHandle().advertise<tf2_msgs::TFMessage>("/tf", 100)) {}
  bool Connected() {
    return test::WaitFor([&] { return publisher_.getNumSubscribers() > 0; }, 30.0);
  }
  void Send(const std::string& parent, const std::string& child, const ros::Time& stamp, const SE3& pose) {
    tf2_msgs::TFMessage message;
    geometry_msgs::TransformStamped transform;
    transform.header.stamp = stamp;
    transform.header.frame_id = parent;
    transform.child_frame_id = child;
    transform.transform = ros_glue::TransformToMsg(pose);
    message.transforms.push_back(transform);
    publisher_.publish(message);
  }

 private:
  ros::Publisher publisher_;
};

// Where "Frame <child> exists with parent <parent>." is in tf's frame list.
bool HasParent(const tf2_ros::Buffer& buffer, const std::string& child, const std::string& parent) {
  return buffer.allFramesAsString().find("Frame " + child + " exists with parent " + parent + ".") !=
         std::string::npos;
}

// The frames of one run: the prior's fixed frame and the camera frame it
// gives (each test its own, so that the runs' tf trees stay apart).
struct PriorFrames {
  std::string prior;   // e.g. "odom"
  std::string camera;  // e.g. "prior_camera"
};

// The estimated copy hangs under the prior's frame; the real camera keeps
// its one parent, the prior; the estimator's world is not in tf.
void ExpectTreeUnderThePrior(const tf2_ros::Buffer& buffer, const PriorFrames& names) {
  const std::string frames = buffer.allFramesAsString();
  EXPECT_TRUE(HasParent(buffer, names.camera + "_estimated", names.prior)) << frames;
  EXPECT_TRUE(HasParent(buffer, names.camera, names.prior)) << frames;
  EXPECT_EQ(frames.find("with parent world."), std::string::npos)
      << "the estimator's world is in tf: " << frames;
}

// The prior fit's relative scale uncertainty with which frame t was
// published: the "+- u %" of the scale_note of the first window whose stamp
// (its last frame's) is not before the frame's; NaN if none.
double PublishedScaleUncertainty(const std::vector<EstimatorStatusConstPtr>& statuses, int t) {
  for (const auto& status : statuses) {
    if (status->header.stamp < FrameStamp(t)) continue;
    const size_t at = status->scale_note.find(" +- ");
    return at == std::string::npos ? NAN : 0.01 * std::stod(status->scale_note.substr(at + 4));
  }
  return NAN;
}

// Every window was published in the prior's frame, in metres, with the
// fit's uncertainty.
void ExpectMetricStatuses(const std::vector<EstimatorStatusConstPtr>& statuses, const std::string& prior_frame) {
  for (const auto& status : statuses) {
    std::cout << "window " << status->window_index << ": " << status->message
              << "\n  scale_note: " << status->scale_note << "\n";
    EXPECT_TRUE(status->success) << status->message;
    EXPECT_EQ(status->header.frame_id, prior_frame) << status->message;
    EXPECT_EQ(status->scale_note.rfind("metric: poses in " + prior_frame + ", depths in metres", 0), 0u)
        << status->scale_note;
    EXPECT_NE(status->scale_note.find(" +- "), std::string::npos) << status->scale_note;
  }
}

// Mean depth rel. errors over the published frames.
struct MetricDepth {
  double in_metres = NAN;     // as published, no alignment
  double scale_aligned = NAN;  // after the best per-frame scale
};

// Plays the sequence to a node whose prior is the ground truth in a frame
// rotated and shifted from the synthesizer's world, with Gaussian position
// noise of `noise_rms` metres (3D RMS; 0: exact). Published poses must land
// on the prior's positions without any alignment (within 3 noise RMS, or 1
// cm for an exact prior), each frame's depth scale within 3 of the fit's
// uncertainties (and kFrameScaleError), and the tf tree and path in the
// prior's frame. `world_scale`: the synthesizer's world (positions and
// depths) that many times larger; the images are the same.
void RunWithPrior(const std::string& ns, const PriorFrames& names, double noise_rms, MetricDepth* result,
                  double world_scale = 1.0) {
  const Sequence& sequence = TestSequence();
  ASSERT_TRUE(sequence.ground_truth.has_value());
  tf2_ros::Buffer tf_buffer;
  tf2_ros::TransformListener tf_listener(tf_buffer);
  PriorNode node(ns, names.prior, 1);
  ASSERT_TRUE(node.Connected()) << "the nodelet did not load or subscribe";
  PriorPublisher prior;
  ASSERT_TRUE(prior.Connected());

  const SE3 T_odom_world(
      Eigen::Quaterniond(Eigen::AngleAxisd(0.5, Eigen::Vector3d(0.2, 0.3, 1.0).normalized())),
      Eigen::Vector3d(1.0, -2.0, 0.3));
  std::mt19937 random(7);
  std::normal_distribution<double> noise(0.0, noise_rms / std::sqrt(3.0));
  std::vector<Eigen::Vector3d> truth;  // camera positions in the prior's frame
  for (int t = 0; t < kFrames; ++t) {
    const SE3& T_world_cam = sequence.ground_truth->poses[t].T_world_cam;
    const SE3 T_odom_cam =
        T_odom_world * SE3(T_world_cam.rotation(), world_scale * T_world_cam.translation());
    truth.push_back(T_odom_cam.translation());
    const Eigen::Vector3d noisy =
        T_odom_cam.translation() + Eigen::Vector3d(noise(random), noise(random), noise(random));
    prior.Send(names.prior, names.camera, FrameStamp(t), SE3(T_odom_cam.rotation(), noisy));
    node.SendFrame(t, names.camera);
    ros::WallDuration(0.1).sleep();
  }
  ASSERT_TRUE(test::WaitFor(
      [&] {
        std::lock_guard<std::mutex> lock(node.mutex);
        return node.poses.size() >= kFrames && node.depths.size() >= kFrames && node.statuses.size() >= 3;
      },
      240.0))
      << "outputs for all " << kFrames << " frames did not arrive";
  ros::WallDuration(0.5).sleep();

  std::lock_guard<std::mutex> lock(node.mutex);
  ASSERT_EQ(node.poses.size(), static_cast<size_t>(kFrames)) << "each frame exactly once";
  ASSERT_EQ(node.depths.size(), static_cast<size_t>(kFrames));
  ExpectMetricStatuses(node.statuses, names.prior);
  DepthMetricOptions metres, aligned;
  metres.align_scale = false;
  double position_max = 0.0, position_sq = 0.0;
  result->in_metres = result->scale_aligned = 0.0;
  for (int t = 0; t < kFrames; ++t) {
    const geometry_msgs::PoseStamped& pose = *node.poses[t];
    EXPECT_EQ(pose.header.stamp, FrameStamp(t));
    EXPECT_EQ(pose.header.frame_id, names.prior);
    const double error = (ros_glue::PoseFromMsg(pose.pose).translation() - truth[t]).norm();
    position_max = std::max(position_max, error);
    position_sq += error * error;
    const cv::Mat depth = test::DepthOf(*node.depths[t]);
    const cv::Mat truth_depth = world_scale * sequence.ground_truth->depth[t];
    const DepthErrors in_metres = EvaluateDepth(depth, truth_depth, metres);
    const DepthErrors scaled = EvaluateDepth(depth, truth_depth, aligned);
    result->in_metres += in_metres.relative_error / kFrames;
    result->scale_aligned += scaled.relative_error / kFrames;
    // The published depth is 1 / scale times the truth: its scale error is
    // within 3 standard deviations of the fit that placed it.
    const double scale_error = 1.0 / scaled.scale - 1.0;
    const double uncertainty = PublishedScaleUncertainty(node.statuses, t);
    std::cout << "frame " << t << ": position error " << error << " m, depth rel. error "
              << in_metres.relative_error << " (metres) vs " << scaled.relative_error << " (aligned, scale "
              << scaled.scale << "); scale error " << scale_error << ", fit's uncertainty " << uncertainty
              << "\n";
    if (noise_rms > 0.0) {
      EXPECT_LE(std::abs(scale_error), 3.0 * uncertainty + kFrameScaleError) << "frame " << t;
    }
    EXPECT_TRUE(
        tf_buffer.canTransform(names.prior, names.camera + "_estimated", FrameStamp(t), ros::Duration(2.0)))
        << "tf " << names.prior << " -> " << names.camera << "_estimated at frame " << t;
  }
  std::cout << "positions vs the ground truth in " << names.prior << " (no alignment): rms "
            << std::sqrt(position_sq / kFrames) << " m, max " << position_max << " m; depth rel. error "
            << result->in_metres << " in metres, " << result->scale_aligned << " scale-aligned; issue 11's "
            << "criterion (metres <= 1.1 x aligned) "
            << (result->in_metres <= 1.1 * result->scale_aligned ? "met" : "missed") << "\n";
  EXPECT_LT(position_max, noise_rms > 0.0 ? 3.0 * noise_rms : kExactPositionBound);
  ASSERT_TRUE(node.path != nullptr);
  EXPECT_EQ(node.path->header.frame_id, names.prior);
  EXPECT_EQ(node.path->poses.size(), static_cast<size_t>(kFrames));
  ExpectTreeUnderThePrior(tf_buffer, names);
}

// 1 cm of prior noise: poses in the prior's frame, depth in metres up to the
// scale that the windows' noisy positions leave uncertain (see
// kMetricDepthMargin).
TEST(PosePrior, PosesInThePriorFrameAndDepthInMetres) {
  MetricDepth depth;
  RunWithPrior("/metric", {"odom", "prior_camera"}, kPriorNoise, &depth);
  EXPECT_LE(depth.in_metres, depth.scale_aligned + kMetricDepthMargin) << "depth is not in metres";
}

// An exact prior: issue 11's criterion, the depth in metres within 10 % of
// the scale-aligned error, in the node's windows.
TEST(PosePrior, ExactPriorGivesDepthInMetresWithinTenPercentOfTheAligned) {
  MetricDepth depth;
  RunWithPrior("/exact", {"exact_odom", "exact_camera"}, 0.0, &depth);
  EXPECT_LE(depth.in_metres, 1.1 * depth.scale_aligned);
}

// The same images in a world 20 times larger, as a vehicle's camera sees a
// scene 34 m away from a path of 1.4-3.4 m: 1 cm of prior noise is small
// against the path, the scale is fixed to a fraction of a percent, and
// issue 11's criterion (depth in metres within 10 % of the scale-aligned
// error) holds with the noisy prior as with the exact one.
TEST(PosePrior, NoisyPriorOverMetresGivesDepthInMetresWithinTenPercentOfTheAligned) {
  MetricDepth depth;
  RunWithPrior("/vehicle", {"vehicle_odom", "vehicle_camera"}, kPriorNoise, &depth, 20.0);
  EXPECT_LE(depth.in_metres, 1.1 * depth.scale_aligned);
}

// A prior that stays in one place cannot fix the scale, and a frame without
// a prior is left out: the node says so in status and publishes in its own
// world, as without a prior.
TEST(PosePrior, StillPriorIsReportedAndTheWorldIsKept) {
  const Sequence& sequence = TestSequence();
  PriorNode node("/still", "still_odom", 0);
  ASSERT_TRUE(node.Connected()) << "the nodelet did not load or subscribe";
  PriorPublisher prior;
  ASSERT_TRUE(prior.Connected());
  const SE3 fixed(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0.5, 0.0, 0.2));
  for (int t = 0; t < 4; ++t) {
    if (t < 3) prior.Send("still_odom", "still_camera", FrameStamp(t), fixed);  // none for frame 3
    node.SendFrame(t, "still_camera");
    ros::WallDuration(0.1).sleep();
  }
  ASSERT_TRUE(test::WaitFor([&] { return node.StatusCount() >= 1; }, 120.0)) << "no window was processed";
  ASSERT_TRUE(test::WaitFor(
      [&] {
        std::lock_guard<std::mutex> lock(node.mutex);
        return node.poses.size() >= 4;
      },
      10.0));
  std::lock_guard<std::mutex> lock(node.mutex);
  ASSERT_EQ(sequence.images.size(), static_cast<size_t>(kFrames));
  const EstimatorStatus& status = *node.statuses.front();
  std::cout << "still prior: " << status.message << "\n  scale_note: " << status.scale_note << "\n";
  EXPECT_TRUE(status.success) << status.message;
  EXPECT_NE(status.message.find("prior: "), std::string::npos) << status.message;
  EXPECT_NE(status.message.find("too small"), std::string::npos) << status.message;
  EXPECT_NE(status.message.find("1 of 4 frames without tf still_odom <- still_camera"), std::string::npos)
      << status.message;
  EXPECT_EQ(status.message.find('\n'), std::string::npos);
  EXPECT_EQ(status.header.frame_id, "world");
  EXPECT_EQ(status.scale_note.rfind("monocular:", 0), 0u) << status.scale_note;
  for (const auto& pose : node.poses) EXPECT_EQ(pose->header.frame_id, "world");
}

}  // namespace
}  // namespace deblur_sr_mvs

int main(int argc, char** argv) {
  return deblur_sr_mvs::test::RunRosTests(argc, argv, "pose_prior_test");
}
