#include "deblur_sr_mvs/ros/node_parameters.h"

#include <cmath>

namespace deblur_sr_mvs {
namespace ros_glue {

StampPosition ParseStampPosition(const std::string& text) {
  if (text == "start") return StampPosition::kStart;
  if (text == "middle") return StampPosition::kMiddle;
  if (text == "end") return StampPosition::kEnd;
  throw InputError("stamp_position must be start, middle or end, got '" + text + "'");
}

void NodeParameters::Check() const {
  if (!(exposure_time > 0.0) || !std::isfinite(exposure_time) || exposure_time > 10.0) {
    throw InputError("exposure_time must be in (0, 10] s (the shutter time of the camera), got " +
                     std::to_string(exposure_time));
  }
  if (!(max_frame_gap > 0.0) || !std::isfinite(max_frame_gap)) throw InputError("max_frame_gap must be > 0 s");
  if (!(max_step_ratio > 1.0) || !std::isfinite(max_step_ratio)) throw InputError("max_step_ratio must be > 1");
  stream.Check();
  estimator.Check();
  if (world_frame.empty()) throw InputError("world_frame must not be empty");
  if (!camera_frame.empty() && camera_frame == world_frame) {
    throw InputError("camera_frame must differ from world_frame");
  }
  if (points_stride < 1 || points_stride > 64) throw InputError("points_stride must be in [1, 64]");
  if (max_path_length < 1) throw InputError("max_path_length must be >= 1");
}

double NodeParameters::CloseOffset() const {
  switch (stamp_position) {
    case StampPosition::kStart: return exposure_time;
    case StampPosition::kMiddle: return 0.5 * exposure_time;
    case StampPosition::kEnd: return 0.0;
  }
  return 0.0;
}

namespace {

template <typename T>
void Read(const ros::NodeHandle& node, const std::string& name, T* value) {
  if (!node.hasParam(name)) return;
  if (!node.getParam(name, *value)) {
    throw InputError("parameter ~" + name + " has the wrong type");
  }
}

}  // namespace

NodeParameters ReadNodeParameters(const ros::NodeHandle& node) {
  NodeParameters params;
  params.estimator.max_seconds = 60.0;  // the node's default cap (config/default.yaml)
  Read(node, "exposure_time", &params.exposure_time);
  std::string stamp_position = "end";
  Read(node, "stamp_position", &stamp_position);
  params.stamp_position = ParseStampPosition(stamp_position);
  Read(node, "max_frame_gap", &params.max_frame_gap);
  Read(node, "max_step_ratio", &params.max_step_ratio);
  Read(node, "window_size", &params.stream.window_size);
  Read(node, "window_overlap", &params.stream.window_overlap);
  Read(node, "max_pending_windows", &params.stream.max_pending_windows);
  std::string mode = "joint";
  Read(node, "mode", &mode);
  params.estimator.mode = ParseEstimatorMode(mode);
  Read(node, "scale", &params.estimator.scale);
  Read(node, "samples", &params.estimator.samples);
  Read(node, "iterations", &params.estimator.max_iterations);
  Read(node, "lambda_s", &params.estimator.lambda_s);
  Read(node, "lambda_d", &params.estimator.structure.lambda_d);
  Read(node, "lambda_i", &params.estimator.image.lambda_i);
  Read(node, "threads", &params.estimator.num_threads);
  Read(node, "max_window_seconds", &params.estimator.max_seconds);
  Read(node, "world_frame", &params.world_frame);
  Read(node, "camera_frame", &params.camera_frame);
  Read(node, "publish_tf", &params.publish_tf);
  Read(node, "points_stride", &params.points_stride);
  Read(node, "max_path_length", &params.max_path_length);
  Read(node, "lazy_subscription", &params.lazy_subscription);
  bool assume_rectified = false;
  Read(node, "assume_rectified", &assume_rectified);
  params.distortion = assume_rectified ? DistortionPolicy::kAssumeRectified : DistortionPolicy::kReject;
  params.Check();
  return params;
}

NodeParameters WithConfig(const NodeParameters& params, const EstimatorConfig& config) {
  NodeParameters updated = params;
  updated.stream.window_size = config.window_size;
  updated.stream.window_overlap = config.window_overlap;
  updated.estimator.scale = config.scale;
  updated.estimator.samples = config.samples;
  updated.estimator.max_iterations = config.iterations;
  updated.estimator.lambda_s = config.lambda_s;
  updated.estimator.structure.lambda_d = config.lambda_d;
  updated.estimator.image.lambda_i = config.lambda_i;
  updated.points_stride = config.points_stride;
  updated.Check();
  return updated;
}

EstimatorConfig ConfigOf(const NodeParameters& params) {
  EstimatorConfig config = EstimatorConfig::__getDefault__();
  config.window_size = params.stream.window_size;
  config.window_overlap = params.stream.window_overlap;
  config.scale = params.estimator.scale;
  config.samples = params.estimator.samples;
  config.iterations = params.estimator.max_iterations;
  config.lambda_s = params.estimator.lambda_s;
  config.lambda_d = params.estimator.structure.lambda_d;
  config.lambda_i = params.estimator.image.lambda_i;
  config.points_stride = params.points_stride;
  return config;
}

}  // namespace ros_glue
}  // namespace deblur_sr_mvs
