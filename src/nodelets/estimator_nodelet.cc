#include "deblur_sr_mvs/ros/estimator_nodelet.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include <geometry_msgs/PoseStamped.h>
#include <geometry_msgs/TransformStamped.h>
#include <sensor_msgs/PointCloud2.h>
#include <pluginlib/class_list_macros.hpp>

#include "deblur_sr_mvs/core/common/text.h"
#include "deblur_sr_mvs/core/common/weighted_median.h"
#include "deblur_sr_mvs/core/estimation/depth_confidence.h"
#include "deblur_sr_mvs/core/estimation/exposure_estimation.h"
#include "deblur_sr_mvs/core/estimation/initializer.h"

namespace deblur_sr_mvs {

namespace {

constexpr double kMaxFutureSeconds = 10.0;        // stamps further ahead of the clock are rejected
constexpr double kMinImageDeviation = 1.0 / 512;  // below: a constant image (no texture at all)
constexpr size_t kMaxUnmatchedImages = 5;         // images waiting for their camera_info
constexpr size_t kMaxRecentInfos = 10;            // camera_infos waiting for their image
// Exposure messages kept for frames not yet taken by the worker (a window of
// up to 64 frames plus the pending windows).
constexpr size_t kMaxExposures = 512;
constexpr double kMaxExposureSeconds = 10.0;  // the range of exposure_time
// How long the worker waits for the exposure of a window's newest frame (the
// message may follow its image a little).
constexpr double kExposureWaitSeconds = 0.1;
const std::string kNoCameraInfo = "no camera_info with the image's stamp on ";
constexpr char kScaleNote[] =
    "monocular: poses and depths are in units where the median scene depth of the first window is 1, "
    "not metres";
// How long the worker waits for the pose prior's tf at a window's newest
// frame (tf may lag the images a little; the older frames' are there by then).
constexpr double kPriorWaitSeconds = 0.2;
// How long the prior's tf is kept: a window is looked up after it has waited
// in the queue and been estimated (seconds, up to max_window_seconds each).
constexpr double kPriorCacheSeconds = 120.0;

bool IsColour(ros_glue::ImageFamily family) {
  return family == ros_glue::ImageFamily::kRgb8 || family == ros_glue::ImageFamily::kBgr8;
}

// No texture at all (black, saturated or covered): every channel's standard
// deviation is below kMinImageDeviation.
bool IsConstant(const cv::Mat& image01) {
  cv::Scalar mean, deviation;
  cv::meanStdDev(image01, mean, deviation);
  double spread = 0.0;
  for (int c = 0; c < image01.channels(); ++c) spread = std::max(spread, deviation[c]);
  return spread < kMinImageDeviation;
}

// The exposure cannot exceed the frame interval (the shutter would still be
// open when the next frame starts): clamps it; true when any was clamped.
bool ClampExposures(StreamWindow* frames) {
  bool clamped = false;
  for (size_t i = 0; i < frames->size(); ++i) {
    const size_t j = i > 0 ? i - 1 : 1;
    const double interval = std::abs((*frames)[i].stamp_close - (*frames)[j].stamp_close);
    if ((*frames)[i].exposure > interval) {
      (*frames)[i].exposure = interval;
      clamped = true;
    }
  }
  return clamped;
}

ros::Time TimeFromNs(int64_t stamp_ns) {
  return ros::Time().fromNSec(static_cast<uint64_t>(stamp_ns));
}

std::string ScaleText(double scale) {
  char text[32];
  std::snprintf(text, sizeof(text), "%.4g", scale);
  return text;
}

// "2.1 %" for 0.021.
std::string PercentText(double fraction) {
  char text[32];
  std::snprintf(text, sizeof(text), "%.2g %%", 100.0 * fraction);
  return text;
}

}  // namespace

EstimatorNodelet::EstimatorNodelet() = default;

EstimatorNodelet::~EstimatorNodelet() {
  shutting_down_ = true;
  {
    std::lock_guard<std::mutex> lock(connect_mutex_);
    image_subscriber_.shutdown();
    info_subscriber_.shutdown();
    exposure_subscriber_.shutdown();
  }
  diagnostics_timer_.stop();
  if (queue_) queue_->Stop();
  if (worker_.joinable()) worker_.join();
}

void EstimatorNodelet::onInit() {
  ros::NodeHandle& node = getNodeHandle();
  ros::NodeHandle& private_node = getPrivateNodeHandle();

  status_publisher_ = node.advertise<EstimatorStatus>("status", 10, true);
  try {
    params_ = ros_glue::ReadNodeParameters(private_node);
  } catch (const std::exception& error) {
    NODELET_FATAL("deblur_sr_mvs: bad parameter: %s; the node stays idle", error.what());
    EstimatorStatus status;
    status.header.stamp = ros::Time::now();
    status.success = false;
    status.message = std::string("bad parameter: ") + error.what();
    status.scale_note = kScaleNote;
    status_publisher_.publish(status);
    return;
  }
  configured_ = true;
  windower_ = std::make_unique<FrameWindower>(params_.stream);
  queue_ = std::make_unique<DropOldestQueue<PendingWindow>>(params_.stream.max_pending_windows);
  stream_ = std::make_unique<StreamEstimator>(params_.estimator);
  stream_->SetCancelFlag(&shutting_down_);

  transport_ = std::make_shared<image_transport::ImageTransport>(node);
  image_topic_ = node.resolveName("image");
  info_topic_ = image_transport::getCameraInfoTopic(image_topic_);
  exposure_topic_ = node.resolveName("exposure");
  image_transport::SubscriberStatusCallback image_connect =
      [this](const image_transport::SingleSubscriberPublisher&) { ConnectCallback(); };
  ros::SubscriberStatusCallback ros_connect = [this](const ros::SingleSubscriberPublisher&) {
    ConnectCallback();
  };
  std::unique_lock<std::mutex> lock(connect_mutex_);  // no connect callback before all exist
  lazy_subscription_ = params_.lazy_subscription;
  // A window publishes its frames in a burst: the queues hold a whole window
  // (at most 64 frames) so that a subscriber keeping up on average loses none.
  constexpr int kQueue = 64;
  restored_publisher_ = transport_->advertiseCamera("restored/image", kQueue, image_connect, image_connect,
                                                    ros_connect, ros_connect);
  depth_publisher_ = transport_->advertiseCamera("depth/image", kQueue, image_connect, image_connect,
                                                 ros_connect, ros_connect);
  confidence_publisher_ = transport_->advertise("depth/confidence", kQueue, image_connect, image_connect);
  pose_publisher_ = node.advertise<geometry_msgs::PoseStamped>("pose", kQueue, ros_connect, ros_connect);
  path_publisher_ = node.advertise<nav_msgs::Path>("path", 1, ros_connect, ros_connect);
  points_publisher_ = node.advertise<sensor_msgs::PointCloud2>("points", 2, ros_connect, ros_connect);
  if (params_.publish_tf) tf_broadcaster_ = std::make_unique<tf2_ros::TransformBroadcaster>();
  if (!params_.pose_prior_frame.empty()) {
    tf_buffer_ = std::make_unique<tf2_ros::Buffer>(ros::Duration(kPriorCacheSeconds));
    tf_listener_ = std::make_unique<tf2_ros::TransformListener>(*tf_buffer_);
    aligner_ = std::make_unique<PosePriorAligner>(PosePriorOptions());
  }

  diagnostics_ = std::make_unique<diagnostic_updater::Updater>(node, private_node);
  diagnostics_->setHardwareID("deblur_sr_mvs estimator on " + image_topic_);
  diagnostics_->add("Window estimation", this, &EstimatorNodelet::Diagnose);
  diagnosed_at_ = ros::WallTime::now();
  diagnostics_timer_ = node.createWallTimer(ros::WallDuration(1.0), [this](const ros::WallTimerEvent&) {
    if (!shutting_down_) diagnostics_->update();
  });

  reconfigure_server_ =
      std::make_unique<dynamic_reconfigure::Server<EstimatorConfig>>(reconfigure_mutex_, private_node);
  reconfigure_server_->updateConfig(ros_glue::ConfigOf(params_));
  reconfigure_server_->setCallback(
      [this](EstimatorConfig& config, uint32_t level) { ReconfigureCallback(config, level); });

  worker_ = std::thread(&EstimatorNodelet::WorkerLoop, this);
  const std::string fallback = params_.exposure_time.automatic
                                   ? std::string("estimated from the blur (auto)")
                                   : std::to_string(params_.exposure_time.seconds) + " s";
  NODELET_INFO(
      "deblur_sr_mvs: windows of %d frames (overlap %d), x%d, exposure from %s else %s; input %s + %s%s",
      params_.stream.window_size, params_.stream.window_overlap, params_.estimator.scale,
      exposure_topic_.c_str(), fallback.c_str(), image_topic_.c_str(), info_topic_.c_str(),
      params_.lazy_subscription ? " (subscribed while outputs have subscribers)" : "");
  lock.unlock();
  ConnectCallback();  // eager mode subscribes at once
}

void EstimatorNodelet::ConnectCallback() {
  std::lock_guard<std::mutex> lock(connect_mutex_);
  if (!configured_ || shutting_down_) return;
  const bool wanted = !lazy_subscription_ || restored_publisher_.getNumSubscribers() > 0 ||
                      depth_publisher_.getNumSubscribers() > 0 ||
                      confidence_publisher_.getNumSubscribers() > 0 ||
                      pose_publisher_.getNumSubscribers() > 0 || path_publisher_.getNumSubscribers() > 0 ||
                      points_publisher_.getNumSubscribers() > 0 || status_publisher_.getNumSubscribers() > 0;
  if (wanted && !subscribed_) {
    ros::NodeHandle& node = getNodeHandle();
    image_transport::TransportHints hints("raw", ros::TransportHints(), getPrivateNodeHandle());
    image_subscriber_ = transport_->subscribe("image", 2, &EstimatorNodelet::ImageCallback, this, hints);
    info_subscriber_ = node.subscribe(info_topic_, 10, &EstimatorNodelet::InfoCallback, this);
    exposure_subscriber_ = node.subscribe(exposure_topic_, 20, &EstimatorNodelet::ExposureCallback, this);
    subscribed_ = true;
  } else if (!wanted && subscribed_) {
    image_subscriber_.shutdown();
    info_subscriber_.shutdown();
    exposure_subscriber_.shutdown();
    subscribed_ = false;
  }
}

void EstimatorNodelet::ImageCallback(const sensor_msgs::ImageConstPtr& image) {
  if (shutting_down_) return;
  ++frames_received_;
  std::lock_guard<std::mutex> lock(input_mutex_);
  for (auto it = recent_infos_.begin(); it != recent_infos_.end(); ++it) {
    if ((*it)->header.stamp == image->header.stamp) {
      const sensor_msgs::CameraInfoConstPtr info = *it;
      recent_infos_.erase(recent_infos_.begin(), it + 1);
      // Older images still waiting will not get their camera_info now.
      while (!unmatched_images_.empty() && unmatched_images_.front()->header.stamp < image->header.stamp) {
        unmatched_images_.pop_front();
        RejectUnmatchedImage();
      }
      AcceptFrame(image, info);
      return;
    }
  }
  unmatched_images_.push_back(image);
  while (unmatched_images_.size() > kMaxUnmatchedImages) {
    unmatched_images_.pop_front();
    RejectUnmatchedImage();
  }
}

void EstimatorNodelet::InfoCallback(const sensor_msgs::CameraInfoConstPtr& info) {
  if (shutting_down_) return;
  std::lock_guard<std::mutex> lock(input_mutex_);
  for (auto it = unmatched_images_.begin(); it != unmatched_images_.end(); ++it) {
    if ((*it)->header.stamp == info->header.stamp) {
      const sensor_msgs::ImageConstPtr image = *it;
      // Older unmatched images will never get their camera_info.
      for (auto old = unmatched_images_.begin(); old != it; ++old) RejectUnmatchedImage();
      unmatched_images_.erase(unmatched_images_.begin(), it + 1);
      AcceptFrame(image, info);
      return;
    }
  }
  recent_infos_.push_back(info);
  while (recent_infos_.size() > kMaxRecentInfos) recent_infos_.pop_front();
}

void EstimatorNodelet::ExposureCallback(const sensor_msgs::TimeReferenceConstPtr& message) {
  if (shutting_down_) return;
  std::lock_guard<std::mutex> lock(input_mutex_);
  const ros::Time& stamp = message->header.stamp;
  if (params_.stamp_position == ros_glue::StampPosition::kStart) {
    RejectExposure(
        "exposure message ignored: with stamp_position start the stamp is the shutter open "
        "time, so time_ref cannot give the exposure; using exposure_time");
    return;
  }
  if (stamp.isZero() || message->time_ref.isZero()) {
    RejectExposure("exposure message with a zero header.stamp or time_ref: not used");
    return;
  }
  const double exposure = params_.ExposureFromShutterOpen((stamp - message->time_ref).toSec());
  if (!(exposure > 0.0) || exposure > kMaxExposureSeconds) {
    RejectExposure("exposure message at " + std::to_string(stamp.toSec()) + " gives exposure " +
                   std::to_string(exposure) + " s (time_ref must be the shutter open time, 0 to " +
                   std::to_string(kMaxExposureSeconds) + " s before the shutter closes): not used");
    return;
  }
  exposures_.emplace_back(stamp, exposure);
  while (exposures_.size() > kMaxExposures) exposures_.pop_front();
  exposures_seen_ = true;
}

void EstimatorNodelet::RejectExposure(const std::string& why) {
  const uint64_t count = ++exposures_rejected_;
  if (count == 1) {
    NODELET_WARN("deblur_sr_mvs: %s (on %s)", why.c_str(), exposure_topic_.c_str());
  } else {
    NODELET_WARN_THROTTLE(10.0, "deblur_sr_mvs: %s (%lu exposure messages rejected so far)", why.c_str(),
                          static_cast<unsigned long>(count));
  }
}

void EstimatorNodelet::RejectFrame(const std::string& category, const std::string& reason) {
  ++frames_rejected_;
  const std::string why = OneLine(reason);
  // Counted per category (a fixed set), so that hours of bad input cannot grow the map.
  const uint64_t count = ++rejections_[category];
  if (count == 1) {
    NODELET_WARN("deblur_sr_mvs: %s", why.c_str());
  } else {
    NODELET_WARN_THROTTLE(10.0, "deblur_sr_mvs: %s (%s: %lu frames so far)", why.c_str(), category.c_str(),
                          static_cast<unsigned long>(count));
  }
  std::lock_guard<std::mutex> lock(health_mutex_);
  last_problem_ = why;
}

void EstimatorNodelet::RejectUnmatchedImage() {
  RejectFrame("no camera_info",
              kNoCameraInfo + info_topic_ + ": frame not used (the node never guesses intrinsics)");
}

void EstimatorNodelet::RestartStream(const std::string& why) {
  NODELET_WARN("deblur_sr_mvs: %s: the trajectory restarts", why.c_str());
  windower_->Reset();
  have_stream_ = false;
  ++epoch_;
  ++resets_;
  std::lock_guard<std::mutex> lock(health_mutex_);
  last_problem_ = why;
}

void EstimatorNodelet::AcceptFrame(const sensor_msgs::ImageConstPtr& image,
                                   const sensor_msgs::CameraInfoConstPtr& info) {
  ros_glue::ImageFamily family;
  cv::Mat image01;
  PinholeCamera camera;
  try {
    image01 = ros_glue::ImageToFloat01(*image, &family);
    camera = ros_glue::CameraFromInfo(*info, image01.cols, image01.rows, params_.distortion);
  } catch (const std::exception& error) {
    RejectFrame("bad image or camera_info", error.what());
    return;
  }
  const ros::Time stamp = image->header.stamp;
  if (!CheckStamp(stamp)) return;
  if (IsConstant(image01)) {
    RejectFrame("constant image", "image is constant (black, saturated or covered): frame not used");
    return;
  }
  RestartOnDiscontinuity(stamp, camera, family);
  if (!have_stream_) StartStream(stamp, camera, image->header.frame_id);
  stream_family_ = family;
  last_stamp_ = stamp;

  StreamFrame frame;
  frame.id = next_frame_id_++;
  frame.stamp_ns = static_cast<int64_t>(stamp.toNSec());
  frame.stamp_close = (stamp - epoch_origin_).toSec() + params_.CloseOffset();
  frame.exposure = params_.exposure_time.seconds;  // auto: set by the worker
  frame.readout_time = params_.readout_time.seconds;  // auto: set by the worker
  frame.image = image01;
  for (StreamWindow& frames : windower_->Add(std::move(frame))) QueueWindow(std::move(frames));
}

bool EstimatorNodelet::CheckStamp(const ros::Time& stamp) {
  if (stamp.isZero()) {
    RejectFrame("zero stamp", "image stamp is 0: frame not used (the stamps define the exposure timing)");
    return false;
  }
  const ros::Time now = ros::Time::now();
  if (!now.isZero() && stamp > now + ros::Duration(kMaxFutureSeconds)) {
    RejectFrame("future stamp", "image stamp is " + std::to_string((stamp - now).toSec()) +
                                    " s in the future (clock skew?): frame not used");
    return false;
  }
  if (have_stream_ && stamp == last_stamp_) {
    RejectFrame("duplicate stamp",
                "duplicate image stamp " + std::to_string(stamp.toSec()) + ": frame not used");
    return false;
  }
  return true;
}

void EstimatorNodelet::RestartOnDiscontinuity(const ros::Time& stamp, const PinholeCamera& camera,
                                              ros_glue::ImageFamily family) {
  if (!have_stream_) return;
  if (stamp < last_stamp_) {
    RestartStream("image stamp went back by " + std::to_string((last_stamp_ - stamp).toSec()) +
                  " s (bag loop or clock reset?)");
  } else if ((stamp - last_stamp_).toSec() > params_.max_frame_gap) {
    RestartStream("gap of " + std::to_string((stamp - last_stamp_).toSec()) +
                  " s between frames (> max_frame_gap " + std::to_string(params_.max_frame_gap) + " s)");
  }
  if (have_stream_ &&
      (camera.width != stream_camera_.width || camera.height != stream_camera_.height ||
       camera.fx != stream_camera_.fx || camera.fy != stream_camera_.fy || camera.cx != stream_camera_.cx ||
       camera.cy != stream_camera_.cy || IsColour(family) != IsColour(stream_family_))) {
    RestartStream("image size, intrinsics or colour changed");
  }
}

void EstimatorNodelet::StartStream(const ros::Time& stamp, const PinholeCamera& camera,
                                   const std::string& input_frame) {
  have_stream_ = true;
  epoch_origin_ = stamp;
  stream_camera_ = camera;
  stream_input_frame_ = input_frame;
  const std::string estimated =
      input_frame.empty() ? std::string("camera_estimated") : input_frame + "_estimated";
  stream_camera_frame_ = params_.camera_frame.empty() ? estimated : params_.camera_frame;
  // With a prior, tf already gives the real camera frame its parent
  // (docs/ros_interface.md#tf): the node must not give it a second one.
  if (!params_.pose_prior_frame.empty() && stream_camera_frame_ == input_frame) {
    NODELET_WARN(
        "deblur_sr_mvs: camera_frame '%s' is the input frame, which pose_prior_frame '%s' already "
        "parents in tf: publishing %s instead",
        input_frame.c_str(), params_.pose_prior_frame.c_str(), estimated.c_str());
    stream_camera_frame_ = estimated;
  }
}

void EstimatorNodelet::QueueWindow(StreamWindow frames) {
  PendingWindow window;
  window.frames = std::move(frames);
  window.camera = stream_camera_;
  window.family = stream_family_;
  window.camera_frame = stream_camera_frame_;
  window.input_frame = stream_input_frame_;
  window.epoch = epoch_;
  window.epoch_origin = epoch_origin_;
  window.completed = ros::WallTime::now();
  if (queue_->Push(std::move(window)) > 0) {
    NODELET_WARN_THROTTLE(5.0,
                          "deblur_sr_mvs: the worker is busy: dropped the oldest pending window "
                          "(%lu dropped so far; raise max_pending_windows or lower the rate)",
                          static_cast<unsigned long>(queue_->dropped()));
  }
}

void EstimatorNodelet::ReconfigureCallback(EstimatorConfig& config, uint32_t /*level*/) {
  std::lock_guard<std::mutex> lock(input_mutex_);
  try {
    params_ = ros_glue::WithConfig(params_, config);
  } catch (const std::exception& error) {
    NODELET_WARN("deblur_sr_mvs: reconfigure rejected: %s; keeping the previous values", error.what());
    config = ros_glue::ConfigOf(params_);
    return;
  }
  windower_->SetOptions(params_.stream);
  ++params_version_;
}

void EstimatorNodelet::WorkerLoop() {
  PendingWindow window;
  while (!shutting_down_ && queue_->Pop(&window)) {
    ProcessWindow(std::move(window));
    window = PendingWindow();
  }
}

void EstimatorNodelet::ProcessWindow(PendingWindow window) {
  const ros_glue::NodeParameters params = SyncWorker(window);
  ++window_index_;
  EstimatorStatus status;
  status.header.frame_id = params.world_frame;
  status.header.stamp = TimeFromNs(window.frames.back().stamp_ns);
  status.window_index = window_index_;
  for (const StreamFrame& frame : window.frames) status.frame_stamps.push_back(TimeFromNs(frame.stamp_ns));
  const ros::WallTime start = ros::WallTime::now();
  bool clamped = false;
  std::string prior_lookup;
  WindowEstimate estimate;
  try {
    clamped = ResolveExposures(params, &window, &status);
    ResolveReadout(params, &window, &status);
    prior_lookup = LookUpPriors(params, kPriorWaitSeconds, &window);
    estimate = stream_->Process(window.frames, window.camera);
  } catch (const EstimationCancelled&) {
    return;  // shutting down: publish nothing more
  } catch (const std::exception& error) {
    SkipWindow("window skipped: " + OneLine(error.what()), false, &status);
    return;
  }
  if (shutting_down_) return;
  // Never publish garbage: non-finite values or a pose jump skip the window
  // and restart the trajectory.
  const std::string problem = ProblemWithEstimate(estimate.result, params.max_step_ratio);
  if (!problem.empty()) {
    SkipWindow("window skipped: " + problem + "; the trajectory restarts", true, &status);
    return;
  }

  if (!estimate.continued) path_.poses.clear();
  // tf that arrived during the estimation still serves the alignment.
  if (!prior_lookup.empty()) prior_lookup = LookUpPriors(params, 0.0, &window);
  const OutputGauge gauge = PlaceInPrior(window, estimate, params, prior_lookup);
  // A path holds poses of one frame (the prior's once it is fitted).
  if (path_.header.frame_id != gauge.frame) path_.poses.clear();
  const std::vector<cv::Mat> confidence = DepthConfidenceOf(estimate.result, params);
  for (size_t i = static_cast<size_t>(estimate.first_new); i < window.frames.size(); ++i) {
    if (shutting_down_ || !ros::ok()) return;
    PublishFrame(window, estimate.result, confidence[i], i, estimate.stamps_ns[i], params, gauge);
  }
  PublishPath(params, gauge.frame, status.header.stamp);

  const double processing = (ros::WallTime::now() - start).toSec();
  const double latency = (ros::WallTime::now() - window.completed).toSec();
  ++windows_processed_;
  {
    std::lock_guard<std::mutex> lock(health_mutex_);
    last_latency_ = latency;
    last_processing_ = processing;
  }
  status.processing_seconds = processing;
  status.latency_seconds = latency;
  DescribeEstimate(estimate, clamped, &status);
  status.header.frame_id = gauge.frame;
  if (!gauge.note.empty()) status.message += "; " + gauge.note;
  if (gauge.metric) {
    status.scale_note =
        "metric: poses in " + gauge.frame + ", depths in metres (aligned to the pose prior; scale " +
        ScaleText(gauge.estimate_to_output.scale) + " +- " + PercentText(gauge.scale_uncertainty) + ")";
  }
  PublishStatus(status);
}

ros_glue::NodeParameters EstimatorNodelet::SyncWorker(const PendingWindow& window) {
  ros_glue::NodeParameters params;
  uint64_t version;
  {
    std::lock_guard<std::mutex> lock(input_mutex_);
    params = params_;
    version = params_version_;
  }
  if (version != worker_params_version_) {
    stream_->SetOptions(params.estimator);
    worker_params_version_ = version;
  }
  if (window.epoch != worker_epoch_) {
    stream_->Reset();
    path_.poses.clear();
    if (aligner_) aligner_->Reset();
    measured_readouts_.clear();
    worker_epoch_ = window.epoch;
  }
  return params;
}

bool EstimatorNodelet::ResolveExposures(const ros_glue::NodeParameters& params, PendingWindow* window,
                                        EstimatorStatus* status) {
  StreamWindow& frames = window->frames;
  auto find = [this](const ros::Time& stamp) {  // the latest message for `stamp` (input_mutex_ held)
    return std::find_if(exposures_.rbegin(), exposures_.rend(),
                        [&](const std::pair<ros::Time, double>& entry) { return entry.first == stamp; });
  };
  const ros::Time newest = TimeFromNs(frames.back().stamp_ns);
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(kExposureWaitSeconds);
  std::unique_lock<std::mutex> lock(input_mutex_);
  while (exposures_seen_ && find(newest) == exposures_.rend() && !shutting_down_ &&
         ros::WallTime::now() < deadline) {
    lock.unlock();
    ros::WallDuration(0.005).sleep();
    lock.lock();
  }
  size_t from_topic = 0;
  for (StreamFrame& frame : frames) {
    const ros::Time stamp = TimeFromNs(frame.stamp_ns);
    const auto found = find(stamp);
    frame.exposure = found != exposures_.rend() ? found->second : params.exposure_time.seconds;
    from_topic += found != exposures_.rend();
    if (found == exposures_.rend() && params.exposure_time.automatic)
      frame.exposure = 0.0;  // estimated below
    // t_c follows the exposure unless the stamp is t_c (stamp_position end).
    frame.stamp_close = (stamp - window->epoch_origin).toSec() + params.CloseOffset(frame.exposure);
  }
  lock.unlock();
  std::string fallback = "parameter";
  if (params.exposure_time.automatic && from_topic < frames.size())
    fallback = EstimateExposures(params, window, status);
  const bool clamped = ClampExposures(&frames);
  for (const StreamFrame& frame : frames) status->frame_exposures.push_back(frame.exposure);
  if (from_topic == frames.size()) {
    status->exposure_source = "topic";
  } else if (from_topic == 0) {
    status->exposure_source = fallback;
  } else {
    status->exposure_source = "topic for " + std::to_string(from_topic) + " of " +
                              std::to_string(frames.size()) + " frames, " + fallback + " for the rest";
  }
  return clamped;
}

std::string EstimatorNodelet::EstimateExposures(const ros_glue::NodeParameters& params, PendingWindow* window,
                                                EstimatorStatus* status) {
  StreamWindow& frames = window->frames;
  EstimatorInput input;
  input.camera = window->camera;
  for (size_t i = 0; i < frames.size(); ++i) {
    input.images.push_back(frames[i].image);
    // Header stamps: their intervals are those of t_c at one exposure.
    const double stamp = (TimeFromNs(frames[i].stamp_ns) - window->epoch_origin).toSec();
    input.frames.push_back(FrameRecord{static_cast<int>(i), stamp, 0.0});
  }
  const ExposureEstimate estimate =
      EstimateExposure(input, params.estimator, ExposureEstimationOptions(), &shutting_down_);
  for (size_t i = 0; i < frames.size(); ++i) {
    if (frames[i].exposure > 0.0) continue;  // from the topic
    frames[i].exposure = estimate.frame_exposures[i];
    frames[i].stamp_close = input.frames[i].stamp + params.CloseOffset(frames[i].exposure);
  }
  status->exposure_fraction = estimate.fraction;
  status->exposure_estimation_seconds = estimate.elapsed_seconds;
  return estimate.measured ? "auto" : "auto (no blur to measure: assumed)";
}

void EstimatorNodelet::ResolveReadout(const ros_glue::NodeParameters& params, PendingWindow* window,
                                      EstimatorStatus* status) {
  StreamWindow& frames = window->frames;
  status->readout_measured = -1.0;
  if (!params.readout_time.automatic) {
    for (StreamFrame& frame : frames) frame.readout_time = params.readout_time.seconds;
    status->readout_time = params.readout_time.seconds;
    return;
  }
  EstimatorInput input;
  input.camera = window->camera;
  for (size_t i = 0; i < frames.size(); ++i) {
    input.images.push_back(frames[i].image);
    input.frames.push_back(FrameRecord{static_cast<int>(i), frames[i].stamp_close, frames[i].exposure});
  }
  const ros::WallTime start = ros::WallTime::now();
  try {
    const ReadoutEstimate estimate = EstimateReadoutTime(input.images, input.camera, input.frames,
                                                         params.estimator.initializer, ReadoutSearchOptions());
    // A global shutter measures 0, which counts too: the median is the
    // sensor's. A window whose motion barely changes measures the readout
    // poorly (a flat cost): the sharpness weighs it.
    measured_readouts_.emplace_back(estimate.seconds, estimate.sharpness);
    status->readout_measured = estimate.seconds;
  } catch (const InitializationError&) {
    // No geometry to measure it on (e.g. a rotation): the earlier measurements serve.
  }
  if (shutting_down_) throw EstimationCancelled();
  status->readout_estimation_seconds = (ros::WallTime::now() - start).toSec();
  const double used = WeightedMedian(measured_readouts_);
  for (StreamFrame& frame : frames) frame.readout_time = used;
  status->readout_time = used;
}

void EstimatorNodelet::SkipWindow(const std::string& message, bool restart, EstimatorStatus* status) {
  ++windows_failed_;
  status->success = false;
  status->message = message;
  NODELET_WARN("deblur_sr_mvs: %s", message.c_str());
  if (restart) {
    stream_->Reset();
    path_.poses.clear();
  }
  {
    std::lock_guard<std::mutex> lock(health_mutex_);
    last_problem_ = message;
  }
  PublishStatus(*status);
}

std::string EstimatorNodelet::LookUpPriors(const ros_glue::NodeParameters& params, double newest_wait,
                                           PendingWindow* window) {
  if (!aligner_) return "";
  const std::string& prior = params.pose_prior_frame;
  const size_t count = window->frames.size();
  size_t missing = 0;
  std::string why = "the images have no frame_id";
  // Newest first: only its tf may still be on its way.
  for (size_t k = 0; k < count && !window->input_frame.empty(); ++k) {
    StreamFrame& frame = window->frames[count - 1 - k];
    if (frame.T_prior_cam) continue;
    SE3 T_prior_cam;
    if (LookUpPrior(prior, window->input_frame, frame.stamp_ns, k == 0 ? newest_wait : 0.0, &T_prior_cam,
                    &why)) {
      frame.T_prior_cam = T_prior_cam;
    } else {
      ++missing;
    }
  }
  if (window->input_frame.empty()) missing = count;
  if (missing == 0) return "";
  return std::to_string(missing) + " of " + std::to_string(count) + " frames without tf " + prior + " <- " +
         (window->input_frame.empty() ? "?" : window->input_frame) + " (" + why + "); ";
}

EstimatorNodelet::OutputGauge EstimatorNodelet::PlaceInPrior(const PendingWindow& window,
                                                             const WindowEstimate& estimate,
                                                             const ros_glue::NodeParameters& params,
                                                             const std::string& lookup_note) {
  OutputGauge gauge;
  gauge.frame = params.world_frame;
  if (!aligner_) return gauge;
  // A new segment has a new world: the earlier correspondences do not apply.
  if (!estimate.continued) aligner_->Reset();
  const std::string& prior = params.pose_prior_frame;
  for (size_t i = 0; i < window.frames.size(); ++i) {
    if (window.frames[i].T_prior_cam) {
      aligner_->Add(estimate.ids[i], estimate.result.T_world_cam[i], *window.frames[i].T_prior_cam);
    }
  }
  gauge.note = "prior: " + lookup_note;
  PriorAlignment alignment;
  try {
    alignment = aligner_->Fit();
  } catch (const std::exception& error) {
    alignment.note = OneLine(error.what());
  }
  gauge.note += alignment.note;
  if (!alignment.valid) {
    gauge.note += "; poses in " + params.world_frame + " until a fit succeeds";
    return gauge;
  }
  gauge.frame = prior;
  gauge.estimate_to_output = alignment.estimate_to_prior;
  gauge.scale_uncertainty = alignment.scale_uncertainty;
  gauge.metric = true;
  return gauge;
}

bool EstimatorNodelet::LookUpPrior(const std::string& prior_frame, const std::string& input_frame,
                                   int64_t stamp_ns, double wait, SE3* T_prior_cam, std::string* why) {
  const ros::Time stamp = TimeFromNs(stamp_ns);
  // Polled on the wall clock: a paused sim clock must not hold the worker.
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(wait);
  std::string error;
  while (!tf_buffer_->canTransform(prior_frame, input_frame, stamp, &error)) {
    if (shutting_down_ || ros::WallTime::now() >= deadline) {
      *why = OneLine(error);
      return false;
    }
    error.clear();
    ros::WallDuration(0.01).sleep();
  }
  try {
    *T_prior_cam =
        ros_glue::TransformFromMsg(tf_buffer_->lookupTransform(prior_frame, input_frame, stamp).transform);
  } catch (const std::exception& lookup_error) {
    *why = OneLine(lookup_error.what());
    return false;
  }
  return true;
}

std::vector<cv::Mat> EstimatorNodelet::DepthConfidenceOf(const EstimatorResult& result,
                                                         const ros_glue::NodeParameters& params) {
  DepthConfidenceOptions options;
  options.neighbour_radius = params.estimator.neighbour_radius;
  options.visibility = params.estimator.visibility;
  options.threshold = params.depth_confidence_threshold;
  return ComputeDepthConfidence(result.camera_hr, result.latent, result.depth, result.T_world_cam, options);
}

void EstimatorNodelet::PublishFrame(const PendingWindow& window, const EstimatorResult& result,
                                    const cv::Mat& confidence, size_t i, int64_t stamp_ns,
                                    const ros_glue::NodeParameters& params, const OutputGauge& gauge) {
  std_msgs::Header header;
  header.stamp = TimeFromNs(stamp_ns);
  header.frame_id = window.camera_frame;
  const sensor_msgs::CameraInfo info =
      ros_glue::ScaledCameraInfo(window.camera, params.estimator.scale, header);
  restored_publisher_.publish(ros_glue::Float01ToImage(result.latent[i], window.family, header), info);
  // In the output gauge: depth scaled (metres with a prior), the pose moved;
  // NaN where the confidence is below the threshold (what is not known).
  const double scale = gauge.estimate_to_output.scale;
  cv::Mat depth = MaskUnconfidentDepth(result.depth[i], confidence, params.depth_confidence_threshold);
  if (scale != 1.0) depth *= scale;
  depth_publisher_.publish(ros_glue::DepthToImage(depth, header), info);
  confidence_publisher_.publish(ros_glue::Float32ToImage(confidence, header));
  const SE3 T_output_cam =
      gauge.metric ? TransformPose(gauge.estimate_to_output, result.T_world_cam[i]) : result.T_world_cam[i];

  geometry_msgs::PoseStamped pose;
  pose.header.stamp = header.stamp;
  pose.header.frame_id = gauge.frame;
  pose.pose = ros_glue::PoseToMsg(T_output_cam);
  pose_publisher_.publish(pose);
  path_.poses.push_back(pose);
  if (tf_broadcaster_) {
    geometry_msgs::TransformStamped transform;
    transform.header = pose.header;
    transform.child_frame_id = window.camera_frame;
    transform.transform = ros_glue::TransformToMsg(T_output_cam);
    tf_broadcaster_->sendTransform(transform);
  }
  if (points_publisher_.getNumSubscribers() > 0) {
    points_publisher_.publish(
        ros_glue::DepthToPoints(depth, result.latent[i], result.camera_hr, params.points_stride, header));
  }
  ++frames_published_;
}

void EstimatorNodelet::PublishPath(const ros_glue::NodeParameters& params, const std::string& frame,
                                   const ros::Time& stamp) {
  while (path_.poses.size() > static_cast<size_t>(params.max_path_length)) {
    path_.poses.erase(path_.poses.begin());
  }
  path_.header.frame_id = frame;
  path_.header.stamp = stamp;
  path_publisher_.publish(path_);
}

void EstimatorNodelet::DescribeEstimate(const WindowEstimate& estimate, bool clamped,
                                        EstimatorStatus* status) {
  const EstimatorResult& result = estimate.result;
  status->success = true;
  status->continued = estimate.continued;
  status->first_new = estimate.first_new;
  status->message = (estimate.note.empty() ? "" : estimate.note + "; ") + "exposure from " +
                    status->exposure_source + (clamped ? " (clamped to the frame interval)" : "");
  if (status->exposure_fraction > 0.0) {
    char text[96];
    std::snprintf(text, sizeof(text), " (estimated: %.3f of the frame interval, in %.1f s)",
                  status->exposure_fraction, status->exposure_estimation_seconds);
    status->message += text;
  }
  if (status->readout_estimation_seconds > 0.0) {
    char text[128];
    std::snprintf(text, sizeof(text),
                  "; readout %.4f s (auto: the weighted median of %zu measurements; this window's %s)",
                  status->readout_time, measured_readouts_.size(),
                  status->readout_measured >= 0.0 ? "measured" : "not measured");
    status->message += text;
  }
  for (const std::string& note : result.notes) status->message += "; " + note;
  for (const EnergyRecord& energy : result.energies) {
    status->energy_stages.push_back(energy.stage);
    status->energy_iterations.push_back(energy.iteration);
    status->energies.push_back(energy.total);
  }
  status->frame_gains = result.frame_gains;
  for (const StageTiming& timing : result.timings) {
    status->stage_names.push_back(timing.stage);
    status->stage_seconds.push_back(timing.seconds);
  }
}

void EstimatorNodelet::PublishStatus(EstimatorStatus status) {
  if (shutting_down_ || !ros::ok()) return;
  status.frames_received = frames_received_;
  status.frames_rejected = frames_rejected_;
  status.frames_published = frames_published_;
  status.windows_dropped = queue_->dropped();
  status.windows_failed = windows_failed_;
  status.resets = resets_;
  status.exposures_rejected = exposures_rejected_;
  if (status.scale_note.empty()) status.scale_note = kScaleNote;
  status_publisher_.publish(status);
}

void EstimatorNodelet::Diagnose(diagnostic_updater::DiagnosticStatusWrapper& status) {
  const ros::WallTime now = ros::WallTime::now();
  const uint64_t windows = windows_processed_;
  const uint64_t drops = queue_->dropped();
  const double elapsed = std::max(1e-6, (now - diagnosed_at_).toSec());
  const double rate = (windows - diagnosed_windows_) / elapsed;
  const bool new_drops = drops > diagnosed_drops_;
  std::string problem;
  double latency, processing;
  {
    std::lock_guard<std::mutex> lock(health_mutex_);
    problem = last_problem_;
    latency = last_latency_;
    processing = last_processing_;
  }
  if (new_drops) {
    status.summary(diagnostic_msgs::DiagnosticStatus::WARN, "dropping windows: the worker cannot keep up");
  } else if (frames_received_ > 0 && frames_published_ == 0 && frames_rejected_ > 0) {
    status.summary(diagnostic_msgs::DiagnosticStatus::ERROR, "every frame rejected: " + problem);
  } else {
    status.summary(diagnostic_msgs::DiagnosticStatus::OK, "running");
  }
  status.add("window rate (Hz)", rate);
  status.add("last latency (s)", latency);
  status.add("last window processing (s)", processing);
  status.add("windows processed", windows);
  status.add("windows dropped", drops);
  status.add("windows failed", static_cast<uint64_t>(windows_failed_));
  status.add("frames received", static_cast<uint64_t>(frames_received_));
  status.add("frames rejected", static_cast<uint64_t>(frames_rejected_));
  status.add("frames published", static_cast<uint64_t>(frames_published_));
  status.add("stream resets", static_cast<uint64_t>(resets_));
  status.add("pending windows", queue_->size());
  status.add("last problem", problem);
  diagnosed_at_ = now;
  diagnosed_windows_ = windows;
  diagnosed_drops_ = drops;
}

}  // namespace deblur_sr_mvs

PLUGINLIB_EXPORT_CLASS(deblur_sr_mvs::EstimatorNodelet, nodelet::Nodelet)
