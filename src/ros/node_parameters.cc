#include "deblur_sr_mvs/ros/node_parameters.h"

#include <limits>

#include "deblur_sr_mvs/core/common/options_check.h"

namespace deblur_sr_mvs {
namespace ros_glue {

StampPosition ParseStampPosition(const std::string& text) {
  if (text == "start") return StampPosition::kStart;
  if (text == "middle") return StampPosition::kMiddle;
  if (text == "end") return StampPosition::kEnd;
  throw InputError("stamp_position must be start, middle or end, got '" + text + "'");
}

const char* ToString(StampPosition position) {
  switch (position) {
    case StampPosition::kStart:
      return "start";
    case StampPosition::kMiddle:
      return "middle";
    case StampPosition::kEnd:
      return "end";
  }
  return "end";
}

EstimatorOptions NodeEstimatorOptions() {
  EstimatorOptions options = StreamDefaultEstimatorOptions();
  options.max_seconds = 60.0;
  return options;
}

void NodeParameters::Check() const {
  // (0, 10] s: the shutter time of the camera, unless estimated ("auto").
  if (!exposure_time.automatic) {
    CheckAbove("exposure_time", exposure_time.seconds, 0.0);
    CheckInRange("exposure_time", exposure_time.seconds, 0.0, 10.0);
  }
  if (!readout_time.automatic) CheckInRange("readout_time", readout_time.seconds, 0.0, 1.0);
  CheckAbove("max_frame_gap", max_frame_gap, 0.0);
  CheckAbove("max_step_ratio", max_step_ratio, 1.0);
  stream.Check();
  // The node's name for EstimatorOptions::max_seconds, checked first so that
  // the message names the parameter the user set.
  CheckAtLeast("max_window_seconds", estimator.max_seconds, 0.0);
  estimator.Check();
  if (world_frame.empty()) throw InputError("world_frame must not be empty");
  if (!camera_frame.empty() && camera_frame == world_frame) {
    throw InputError("camera_frame must differ from world_frame");
  }
  if (!pose_prior_frame.empty() && (pose_prior_frame == world_frame || pose_prior_frame == camera_frame)) {
    throw InputError("pose_prior_frame '" + pose_prior_frame +
                     "' must differ from world_frame and camera_frame");
  }
  CheckInRange("depth_confidence_threshold", depth_confidence_threshold, 0.0, 1.0);
  CheckInRange("points_stride", points_stride, 1, 64);
  CheckAtLeast("max_path_length", max_path_length, 1);
}

double NodeParameters::CloseOffset(double exposure) const {
  switch (stamp_position) {
    case StampPosition::kStart:
      return exposure;
    case StampPosition::kMiddle:
      return 0.5 * exposure;
    case StampPosition::kEnd:
      return 0.0;
  }
  return 0.0;
}

double NodeParameters::ExposureFromShutterOpen(double stamp_minus_open) const {
  switch (stamp_position) {
    case StampPosition::kStart:
      break;
    case StampPosition::kMiddle:
      return 2.0 * stamp_minus_open;
    case StampPosition::kEnd:
      return stamp_minus_open;
  }
  return std::numeric_limits<double>::quiet_NaN();
}

namespace {

template <typename T>
void Read(const ros::NodeHandle& node, const std::string& name, T* value) {
  if (!node.hasParam(name)) return;
  if (!node.getParam(name, *value)) {
    throw InputError("parameter ~" + name + " has the wrong type");
  }
}

// ForEachParameter's visitor of ReadNodeParameters: a missing parameter keeps
// the value it visits (the default); the enums are read as text or bool.
class ParameterReader {
 public:
  explicit ParameterReader(const ros::NodeHandle& node) : node_(node) {}

  template <typename T>
  void operator()(const char* name, T& value) const {
    Read(node_, name, &value);
  }
  void operator()(const char* name, StampPosition& position) const {
    std::string text = ToString(position);
    Read(node_, name, &text);
    position = ParseStampPosition(text);
  }
  void operator()(const char* name, EstimatorMode& mode) const {
    std::string text = ToString(mode);
    Read(node_, name, &text);
    mode = ParseEstimatorMode(text);
  }
  // A number of seconds, or the text "auto".
  void operator()(const char* name, SecondsOrAuto& value) const {
    std::string text;
    if (node_.getParam(name, text)) {
      if (text != "auto")
        throw InputError(std::string(name) + " must be a number of seconds or auto, got '" + text + "'");
      value.automatic = true;
      return;
    }
    Read(node_, name, &value.seconds);
  }
  void operator()(const char* name, DistortionPolicy& policy) const {
    bool assume_rectified = policy == DistortionPolicy::kAssumeRectified;
    Read(node_, name, &assume_rectified);
    policy = assume_rectified ? DistortionPolicy::kAssumeRectified : DistortionPolicy::kReject;
  }

 private:
  const ros::NodeHandle& node_;
};

}  // namespace

NodeParameters ReadNodeParameters(const ros::NodeHandle& node) {
  NodeParameters params;
  ForEachParameter(params, ParameterReader(node));
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
  updated.estimator.multi_frame_data.relative_weight = config.multi_frame_weight;
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
  config.multi_frame_weight = params.estimator.multi_frame_data.relative_weight;
  config.points_stride = params.points_stride;
  return config;
}

}  // namespace ros_glue
}  // namespace deblur_sr_mvs
