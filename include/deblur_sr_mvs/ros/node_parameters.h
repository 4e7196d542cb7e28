// The estimator node's private parameters (docs/ros_interface.md#parameters) and
// their translation into the core's Options structs: the one place where
// ~parameters become options, and the one source of their defaults
// (NodeParameters' initialisers; config/default.yaml, cfg/Estimator.cfg and
// the README's table are tested against them by test/ros/defaults_test.cc).
#pragma once

#include <string>

#include <ros/node_handle.h>

#include "deblur_sr_mvs/EstimatorConfig.h"
#include "deblur_sr_mvs/core/estimation/depth_confidence.h"
#include "deblur_sr_mvs/core/estimation/estimator.h"
#include "deblur_sr_mvs/core/estimation/stream.h"
#include "deblur_sr_mvs/ros/conversions.h"

namespace deblur_sr_mvs {
namespace ros_glue {

// Where the header stamp of a frame lies within its exposure.
enum class StampPosition { kStart, kMiddle, kEnd };
StampPosition ParseStampPosition(const std::string& text);  // InputError otherwise
const char* ToString(StampPosition position);               // "start" | "middle" | "end"

// The core's options of a stream window (StreamDefaultEstimatorOptions: the
// published depth re-swept and made consistent across neighbouring frames,
// ~depth_sweep, ~depth_consistency_radius) with the node's time cap of one
// window (~max_window_seconds): a live node must not stall on one window.
EstimatorOptions NodeEstimatorOptions();

// A parameter in seconds that may also be the text "auto": ~exposure_time
// (estimated from the blur of every window, EstimateExposure; the exposure
// topic wins over both) and ~readout_time (measured from the tracks of every
// window, EstimateReadoutTime).
struct SecondsOrAuto {
  double seconds = 0.0;    // unless automatic
  bool automatic = false;  // "auto"
  // A number of seconds (not automatic).
  SecondsOrAuto& operator=(double value) {
    seconds = value;
    automatic = false;
    return *this;
  }
};

struct NodeParameters {
  // --- Shutter: exposure time and what the header stamp marks.
  SecondsOrAuto exposure_time;  // s, > 0, or auto (required: the blur model needs it)
  StampPosition stamp_position = StampPosition::kEnd;
  // Rolling shutter (docs/file_formats.md#rolling-shutter): each row opens
  // readout_time * y / H after the first, whose exposure the stamp marks
  // (s, [0, 1]; 0: a global shutter), or auto: the median of the windows'
  // measurements so far, weighted by their sharpness (0 until one is measured).
  SecondsOrAuto readout_time;
  // A longer gap between two frames (dropped frames, a paused camera) breaks
  // the constant-velocity exposure model: the trajectory restarts (s).
  double max_frame_gap = 1.0;
  // --- Windows and the worker.
  StreamOptions stream;  // window_size, window_overlap, max_pending_windows
  // --- The estimator (mode, scale, samples, iterations, lambdas, threads,
  //     max_window_seconds -> estimator.max_seconds).
  EstimatorOptions estimator = NodeEstimatorOptions();
  // --- Outputs.
  std::string world_frame = "world";
  std::string camera_frame;  // empty: "<input frame_id>_estimated"
  bool publish_tf = true;
  // Fixed frame in which tf gives the camera's pose at the frame stamps
  // (wheel odometry, VIO, motion capture): the metric pose prior
  // (docs/ros_interface.md#pose-prior). Empty: none (monocular units).
  std::string pose_prior_frame;
  // Depth whose confidence (~depth/confidence, DepthConfidenceOptions) is
  // below this is published as NaN, in ~depth/image and ~points; 0: all depth.
  double depth_confidence_threshold = DepthConfidenceOptions().threshold;
  int points_stride = 4;        // every n-th pixel in x and y goes into ~points
  int max_path_length = 10000;  // poses kept in ~path (oldest dropped beyond)
  // A window whose largest camera step exceeds this many times its median
  // step is taken as a failed estimate (a pose jump): skipped, trajectory restarts.
  double max_step_ratio = 8.0;
  // --- Input.
  bool lazy_subscription = true;  // subscribe to the camera only while outputs are subscribed
  DistortionPolicy distortion = DistortionPolicy::kReject;  // ~assume_rectified

  void Check() const;  // throws InputError naming the bad parameter
  // Shutter close time t_c minus the header stamp (s), for exposure_time or
  // for a frame's own exposure (from the exposure topic).
  double CloseOffset() const { return CloseOffset(exposure_time.seconds); }
  double CloseOffset(double exposure) const;
  // The exposure of a frame whose header stamp is `stamp_minus_open` seconds
  // after its shutter opened (sensor_msgs/TimeReference on ~exposure,
  // docs/ros_interface.md#exposure): stamp - t_o with `end`, twice that with
  // `middle`; NaN with `start` (the stamp is t_o: the message carries no exposure).
  double ExposureFromShutterOpen(double stamp_minus_open) const;
};

// Calls visit(name, member) for every private parameter of the node, in the
// order the node reads them: the one list of names. `Params` is NodeParameters
// or const NodeParameters; the enums are StampPosition (~stamp_position),
// EstimatorMode (~mode) and DistortionPolicy (~assume_rectified, a bool);
// SecondsOrAuto (~exposure_time, ~readout_time) is a number or "auto".
template <typename Params, typename Visitor>
void ForEachParameter(Params& params, Visitor&& visit) {
  visit("exposure_time", params.exposure_time);
  visit("stamp_position", params.stamp_position);
  visit("readout_time", params.readout_time);
  visit("max_frame_gap", params.max_frame_gap);
  visit("max_step_ratio", params.max_step_ratio);
  visit("window_size", params.stream.window_size);
  visit("window_overlap", params.stream.window_overlap);
  visit("max_pending_windows", params.stream.max_pending_windows);
  visit("mode", params.estimator.mode);
  visit("scale", params.estimator.scale);
  visit("samples", params.estimator.samples);
  visit("iterations", params.estimator.max_iterations);
  visit("lambda_s", params.estimator.lambda_s);
  visit("lambda_d", params.estimator.structure.lambda_d);
  visit("lambda_i", params.estimator.image.lambda_i);
  visit("multi_frame_weight", params.estimator.multi_frame_data.relative_weight);
  visit("threads", params.estimator.num_threads);
  visit("max_window_seconds", params.estimator.max_seconds);
  visit("gain_compensation", params.estimator.gain_compensation);
  visit("depth_sweep", params.estimator.depth_sweep.on_output);
  visit("depth_consistency_radius", params.estimator.depth_consistency.radius);
  visit("world_frame", params.world_frame);
  visit("camera_frame", params.camera_frame);
  visit("publish_tf", params.publish_tf);
  visit("pose_prior_frame", params.pose_prior_frame);
  visit("pose_prior_sigma", params.estimator.initializer.pose_prior_position_sigma);
  visit("pose_prior_rotation_sigma", params.estimator.initializer.pose_prior_rotation_sigma_deg);
  visit("depth_confidence_threshold", params.depth_confidence_threshold);
  visit("points_stride", params.points_stride);
  visit("max_path_length", params.max_path_length);
  visit("lazy_subscription", params.lazy_subscription);
  visit("assume_rectified", params.distortion);
}

// Reads every parameter from the private node handle (defaults above for
// missing ones) and checks them: throws InputError with one line.
NodeParameters ReadNodeParameters(const ros::NodeHandle& private_node);

// The tuning parameters of a dynamic_reconfigure request applied to `params`
// (returns the result, checked; InputError leaves nothing applied).
NodeParameters WithConfig(const NodeParameters& params, const EstimatorConfig& config);
// The tuning parameters of `params` as a config (to answer the server).
EstimatorConfig ConfigOf(const NodeParameters& params);

}  // namespace ros_glue
}  // namespace deblur_sr_mvs
