// deblur_sr_mvs/EstimatorNodelet: the streaming joint estimator on a camera
// (docs/ros_interface.md). The subscriber callbacks only check and buffer frames;
// complete windows go to a bounded queue that one worker thread empties by
// running the estimator (core/stream.h) and publishing its outputs.
#pragma once

#include <atomic>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <utility>

#include <diagnostic_updater/diagnostic_updater.h>
#include <dynamic_reconfigure/server.h>
#include <image_transport/camera_common.h>
#include <image_transport/image_transport.h>
#include <nav_msgs/Path.h>
#include <nodelet/nodelet.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/TimeReference.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/transform_broadcaster.h>
#include <tf2_ros/transform_listener.h>
#include <boost/thread/recursive_mutex.hpp>

#include "deblur_sr_mvs/EstimatorConfig.h"
#include "deblur_sr_mvs/EstimatorStatus.h"
#include "deblur_sr_mvs/core/estimation/stream.h"
#include "deblur_sr_mvs/core/geometry/pose_prior.h"
#include "deblur_sr_mvs/ros/conversions.h"
#include "deblur_sr_mvs/ros/node_parameters.h"

namespace deblur_sr_mvs {

class EstimatorNodelet : public nodelet::Nodelet {
 public:
  EstimatorNodelet();
  ~EstimatorNodelet() override;

 private:
  // A complete window and what the worker needs to publish it.
  struct PendingWindow {
    StreamWindow frames;
    PinholeCamera camera;  // LR intrinsics from camera_info
    ros_glue::ImageFamily family = ros_glue::ImageFamily::kMono8;
    std::string camera_frame;  // child frame of the outputs
    std::string input_frame;   // the images' frame_id (the real camera's)
    uint64_t epoch = 0;        // stream restarts so far
    ros::Time epoch_origin;    // the stamp whose StreamFrame::stamp_close is 0 (+ close offset)
    ros::WallTime completed;   // arrival of the window's last frame
  };

  void onInit() override;
  void ConnectCallback();
  void ImageCallback(const sensor_msgs::ImageConstPtr& image);
  void InfoCallback(const sensor_msgs::CameraInfoConstPtr& info);
  // A frame's exposure (docs/ros_interface.md#exposure): checked and kept by
  // stamp until the worker takes the frame's window.
  void ExposureCallback(const sensor_msgs::TimeReferenceConstPtr& message);
  void RejectExposure(const std::string& why);
  // ---- Input side (input_mutex_ held).
  // Checks one matched image + camera_info and buffers it.
  void AcceptFrame(const sensor_msgs::ImageConstPtr& image, const sensor_msgs::CameraInfoConstPtr& info);
  bool CheckStamp(const ros::Time& stamp);  // false: rejected (zero, future, duplicate)
  // Restarts the trajectory when time went back, a gap exceeds max_frame_gap,
  // or the camera (size, intrinsics, colour) changed.
  void RestartOnDiscontinuity(const ros::Time& stamp, const PinholeCamera& camera,
                              ros_glue::ImageFamily family);
  void StartStream(const ros::Time& stamp, const PinholeCamera& camera, const std::string& input_frame);
  void QueueWindow(StreamWindow frames);  // a complete window for the worker
  void RejectFrame(const std::string& category, const std::string& why);
  void RejectUnmatchedImage();  // an image whose camera_info never came
  void RestartStream(const std::string& why);

  // Where a window's outputs go: the estimator's world (world_frame, its
  // units) or, with a valid pose prior fit, the prior's frame in metres.
  struct OutputGauge {
    std::string frame;
    Sim3 estimate_to_output;  // applied to poses; its scale to depths
    bool metric = false;
    double scale_uncertainty = 0.0;  // PriorAlignment::scale_uncertainty when metric
    std::string note;                // what the pose prior did ("" without one)
  };

  // ---- Worker side.
  void WorkerLoop();
  void ProcessWindow(PendingWindow window);
  // The parameters for `window`, applied to the estimator (reconfigured
  // since the last window); a new epoch resets the stream and the path.
  ros_glue::NodeParameters SyncWorker(const PendingWindow& window);
  // Each frame's exposure from the exposure topic (waiting briefly for the
  // newest frame's), else exposure_time (auto: EstimateExposures), clamped
  // to the frame interval (true when any was); says which in `status`.
  // Throws what the exposure estimation throws.
  bool ResolveExposures(const ros_glue::NodeParameters& params, PendingWindow* window,
                        EstimatorStatus* status);
  // exposure_time auto: the exposure of the window's frames without one
  // (0) estimated from the blur (EstimateExposure), their t_c moved with
  // it; the fraction and the time spent go into `status`. Returns the
  // source's name: "auto", or "auto (no blur to measure: assumed)".
  std::string EstimateExposures(const ros_glue::NodeParameters& params, PendingWindow* window,
                                EstimatorStatus* status);
  // Each frame's readout time: readout_time, or with readout_time auto the
  // median of the readout times measured so far, each weighted by its
  // sharpness (EstimateReadoutTime on this window first; 0 until one is
  // measured); says which in `status`.
  // Throws EstimationCancelled when shutting down.
  void ResolveReadout(const ros_glue::NodeParameters& params, PendingWindow* window, EstimatorStatus* status);
  // A failed window: counted, warned and said in `status`; `restart` also
  // restarts the trajectory.
  void SkipWindow(const std::string& message, bool restart, EstimatorStatus* status);
  // With pose_prior_frame: the T_prior_cam from tf of each frame that has
  // none yet (waiting up to newest_wait seconds for the newest), for the
  // estimation (the initialiser's bundle adjustment) and PlaceInPrior.
  // Returns "" or what is missing and why.
  std::string LookUpPriors(const ros_glue::NodeParameters& params, double newest_wait, PendingWindow* window);
  // The gauge of `estimate`: fits the pose prior (pose_prior_frame) on the
  // segment's frames so far (their T_prior_cam from LookUpPriors, whose note
  // is `lookup_note`).
  OutputGauge PlaceInPrior(const PendingWindow& window, const WindowEstimate& estimate,
                           const ros_glue::NodeParameters& params, const std::string& lookup_note);
  // T_prior_cam of the input frame at the stamp from tf; false when tf has
  // none (waits up to `wait` seconds).
  bool LookUpPrior(const std::string& prior_frame, const std::string& input_frame, int64_t stamp_ns,
                   double wait, SE3* T_prior_cam, std::string* why);
  // The depth confidence of every frame of the window (ComputeDepthConfidence).
  static std::vector<cv::Mat> DepthConfidenceOf(const EstimatorResult& result,
                                                const ros_glue::NodeParameters& params);
  // Image, depth (NaN below the confidence threshold), confidence, pose, tf
  // and points of window frame i.
  void PublishFrame(const PendingWindow& window, const EstimatorResult& result, const cv::Mat& confidence,
                    size_t i, int64_t stamp_ns, const ros_glue::NodeParameters& params,
                    const OutputGauge& gauge);
  void PublishPath(const ros_glue::NodeParameters& params, const std::string& frame, const ros::Time& stamp);
  // Success, energies, timings and notes of a published window.
  void DescribeEstimate(const WindowEstimate& estimate, bool clamped, EstimatorStatus* status);
  void PublishStatus(EstimatorStatus status);
  void ReconfigureCallback(EstimatorConfig& config, uint32_t level);
  void Diagnose(diagnostic_updater::DiagnosticStatusWrapper& status);

  // ---- Set in onInit, then read-only.
  std::string image_topic_, info_topic_, exposure_topic_;
  std::shared_ptr<image_transport::ImageTransport> transport_;
  image_transport::CameraPublisher restored_publisher_, depth_publisher_;
  image_transport::Publisher confidence_publisher_;  // ~depth/confidence
  ros::Publisher pose_publisher_, path_publisher_, points_publisher_, status_publisher_;
  std::unique_ptr<tf2_ros::TransformBroadcaster> tf_broadcaster_;
  std::unique_ptr<tf2_ros::Buffer> tf_buffer_;  // with pose_prior_frame only
  std::unique_ptr<tf2_ros::TransformListener> tf_listener_;
  std::unique_ptr<diagnostic_updater::Updater> diagnostics_;
  ros::WallTimer diagnostics_timer_;
  boost::recursive_mutex reconfigure_mutex_;
  std::unique_ptr<dynamic_reconfigure::Server<EstimatorConfig>> reconfigure_server_;
  bool configured_ = false;  // parameters valid: the node works

  // ---- Subscriptions (connect_mutex_).
  std::mutex connect_mutex_;
  bool subscribed_ = false;
  bool lazy_subscription_ = true;
  image_transport::Subscriber image_subscriber_;
  ros::Subscriber info_subscriber_, exposure_subscriber_;

  // ---- Input side (input_mutex_): parameters, matching, windowing.
  std::mutex input_mutex_;
  ros_glue::NodeParameters params_;
  uint64_t params_version_ = 0;
  std::deque<sensor_msgs::ImageConstPtr> unmatched_images_;
  std::deque<sensor_msgs::CameraInfoConstPtr> recent_infos_;
  // (image stamp, exposure s) of the exposure topic, the latest few hundred in arrival order.
  std::deque<std::pair<ros::Time, double>> exposures_;
  bool exposures_seen_ = false;  // an exposure was accepted: worth waiting for one
  std::unique_ptr<FrameWindower> windower_;
  bool have_stream_ = false;
  ros::Time last_stamp_, epoch_origin_;
  PinholeCamera stream_camera_;
  ros_glue::ImageFamily stream_family_ = ros_glue::ImageFamily::kMono8;
  std::string stream_camera_frame_, stream_input_frame_;
  uint64_t epoch_ = 0;
  uint64_t next_frame_id_ = 1;
  std::map<std::string, uint64_t> rejections_;  // category (a fixed set) -> count

  // ---- Worker side (the worker thread only).
  std::unique_ptr<DropOldestQueue<PendingWindow>> queue_;
  std::thread worker_;
  std::unique_ptr<StreamEstimator> stream_;
  uint64_t worker_params_version_ = 0;
  uint64_t worker_epoch_ = 0;
  nav_msgs::Path path_;
  std::unique_ptr<PosePriorAligner> aligner_;  // with pose_prior_frame only
  uint32_t window_index_ = 0;
  // readout_time auto: the windows' measurements (s) and their sharpness
  // (ReadoutEstimate::sharpness), this epoch.
  std::vector<std::pair<double, double>> measured_readouts_;

  // ---- Shared counters and health.
  std::atomic<bool> shutting_down_{false};
  std::atomic<uint64_t> frames_received_{0}, frames_rejected_{0}, frames_published_{0};
  std::atomic<uint64_t> windows_processed_{0}, windows_failed_{0}, resets_{0};
  std::atomic<uint64_t> exposures_rejected_{0};
  std::mutex health_mutex_;
  double last_latency_ = 0.0, last_processing_ = 0.0;
  std::string last_problem_;
  uint64_t diagnosed_windows_ = 0, diagnosed_drops_ = 0;
  ros::WallTime diagnosed_at_;
};

}  // namespace deblur_sr_mvs
