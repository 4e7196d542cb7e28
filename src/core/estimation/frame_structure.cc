#include "deblur_sr_mvs/core/estimation/frame_structure.h"

#include "deblur_sr_mvs/core/common/errors.h"

namespace deblur_sr_mvs {

CaptureGeometry MakeCaptureGeometry(const std::vector<FrameStructure>& frames, const PinholeCamera& camera_hr,
                                    int t, int source) {
  const int n = static_cast<int>(frames.size());
  if (n < 2 || t < 0 || t >= n || source < 0 || source >= n) {
    throw InputError("MakeCaptureGeometry: needs >= 2 frames and valid indices");
  }
  const int neighbour = t > 0 ? t - 1 : t + 1;
  CaptureGeometry geometry;
  geometry.camera_hr = camera_hr;
  geometry.depth_hr = frames[t].depth_hr;
  geometry.T_world_cam = frames[t].T_world_cam;
  geometry.T_world_neighbour = frames[neighbour].T_world_cam;
  geometry.stamp = frames[t].stamp;
  geometry.neighbour_stamp = frames[neighbour].stamp;
  geometry.exposure = frames[t].exposure;
  geometry.readout_time = frames[t].readout_time;
  if (source != t) geometry.T_world_source = frames[source].T_world_cam;
  return geometry;
}

CaptureGeometry CrossBlurGeometry(const std::vector<FrameStructure>& frames, const PinholeCamera& camera_hr,
                                  int frame, int kernel_frame) {
  CaptureGeometry geometry = MakeCaptureGeometry(frames, camera_hr, kernel_frame, frame);
  // kernel_frame's path, moved rigidly (and in time) onto `frame`.
  const FrameStructure& target = frames[frame];
  const FrameStructure& kernel = frames[kernel_frame];
  geometry.T_world_neighbour = target.T_world_cam * kernel.T_world_cam.Inverse() * geometry.T_world_neighbour;
  geometry.T_world_cam = target.T_world_cam;
  geometry.neighbour_stamp += target.stamp - kernel.stamp;
  geometry.stamp = target.stamp;
  geometry.depth_hr = target.depth_hr;
  geometry.readout_time = 0.0;
  geometry.T_world_source.reset();
  return geometry;
}

std::vector<int> Neighbours(int t, int num_frames, int radius) {
  std::vector<int> result;
  for (int s = t - radius; s <= t + radius; ++s) {
    if (s != t && s >= 0 && s < num_frames) result.push_back(s);
  }
  return result;
}

}  // namespace deblur_sr_mvs
