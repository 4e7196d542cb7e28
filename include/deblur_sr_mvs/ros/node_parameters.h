// The estimator node's private parameters (SPEC section 5, README table) and
// their translation into the core's Options structs: the one place where
// ~parameters become options.
#pragma once

#include <string>

#include <ros/node_handle.h>

#include "deblur_sr_mvs/EstimatorConfig.h"
#include "deblur_sr_mvs/core/estimation/estimator.h"
#include "deblur_sr_mvs/core/estimation/stream.h"
#include "deblur_sr_mvs/ros/conversions.h"

namespace deblur_sr_mvs {
namespace ros_glue {

// Where the header stamp of a frame lies within its exposure.
enum class StampPosition { kStart, kMiddle, kEnd };
StampPosition ParseStampPosition(const std::string& text);  // InputError otherwise

struct NodeParameters {
  // --- Shutter: exposure time and what the header stamp marks.
  double exposure_time = 0.0;      // s, > 0 (required: the blur model needs it)
  StampPosition stamp_position = StampPosition::kEnd;
  // A longer gap between two frames (dropped frames, a paused camera) breaks
  // the constant-velocity exposure model: the trajectory restarts (s).
  double max_frame_gap = 1.0;
  // --- Windows and the worker.
  StreamOptions stream;            // window_size, window_overlap, max_pending_windows
  // --- The estimator (mode, scale, samples, iterations, lambdas, threads,
  //     max_window_seconds -> estimator.max_seconds).
  EstimatorOptions estimator;
  // --- Outputs.
  std::string world_frame = "world";
  std::string camera_frame;        // empty: "<input frame_id>_estimated"
  bool publish_tf = true;
  int points_stride = 4;           // every n-th pixel in x and y goes into ~points
  int max_path_length = 10000;     // poses kept in ~path (oldest dropped beyond)
  // A window whose largest camera step exceeds this many times its median
  // step is taken as a failed estimate (a pose jump): skipped, trajectory restarts.
  double max_step_ratio = 8.0;
  // --- Input.
  bool lazy_subscription = true;   // subscribe to the camera only while outputs are subscribed
  DistortionPolicy distortion = DistortionPolicy::kReject;  // ~assume_rectified

  void Check() const;  // throws InputError naming the bad parameter
  // Shutter close time t_c minus the header stamp (s).
  double CloseOffset() const;
};

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
