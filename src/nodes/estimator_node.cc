// estimator_node: the EstimatorNodelet in a process of its own
// (image_pipeline's pattern: the node loads the nodelet, so both behave alike).
#include <nodelet/loader.h>
#include <ros/ros.h>

#include "deblur_sr_mvs/core/common/runtime.h"

int main(int argc, char** argv) {
  deblur_sr_mvs::KeepFreedMemoryForReuse();  // the estimator's buffers stay in the heap
  ros::init(argc, argv, "deblur_sr_mvs");
  nodelet::Loader loader(false);  // no nodelet-manager services
  const nodelet::M_string remappings(ros::names::getRemappings());
  const nodelet::V_string arguments(argv + 1, argv + argc);
  if (!loader.load(ros::this_node::getName(), "deblur_sr_mvs/EstimatorNodelet", remappings, arguments)) {
    ROS_FATAL("deblur_sr_mvs: could not load deblur_sr_mvs/EstimatorNodelet (is the workspace sourced?)");
    return 1;
  }
  ros::spin();
  return 0;
}
