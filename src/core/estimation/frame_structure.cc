#include "deblur_sr_mvs/core/estimation/frame_structure.h"

#include <algorithm>

#include "deblur_sr_mvs/core/common/errors.h"

namespace deblur_sr_mvs {

CaptureGeometry MakeCaptureGeometry(const std::vector<FrameStructure>& frames, const PinholeCamera& camera_hr,
                                    int t, int source) {
  const int n = static_cast<int>(frames.size());
  if (n < 2 || t < 0 || t >= n || source < 0 || source >= n) {
    throw InputError("MakeCaptureGeometry: needs >= 2 frames and valid indices");
  }
  std::vector<SE3> T_world_cam;
  std::vector<double> stamps;
  for (const FrameStructure& frame : frames) {
    T_world_cam.push_back(frame.T_world_cam);
    stamps.push_back(frame.stamp);
  }
  CaptureGeometry geometry;
  geometry.camera_hr = camera_hr;
  geometry.depth_hr = frames[t].depth_hr;
  SetBlurPath(T_world_cam, stamps, t, &geometry);
  geometry.exposure = frames[t].exposure;
  geometry.readout_time = frames[t].readout_time;
  if (source != t) geometry.T_world_source = frames[source].T_world_cam;
  return geometry;
}

std::vector<int> CaptureGeometryFrames(int t, int source, int num_frames) {
  std::vector<int> result = {t};
  for (int frame : BlurPathFrames(t, num_frames)) result.push_back(frame);
  if (std::find(result.begin(), result.end(), source) == result.end()) result.push_back(source);
  return result;
}

CaptureGeometry CrossBlurGeometry(const std::vector<FrameStructure>& frames, const PinholeCamera& camera_hr,
                                  int frame, int kernel_frame) {
  CaptureGeometry geometry = MakeCaptureGeometry(frames, camera_hr, kernel_frame, frame);
  // kernel_frame's path, moved rigidly (and in time) onto `frame`.
  MoveBlurPath(frames[frame].T_world_cam, frames[frame].stamp, &geometry);
  geometry.depth_hr = frames[frame].depth_hr;
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
