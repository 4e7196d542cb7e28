#include "deblur_sr_mvs/core/geometry/camera.h"

#include <cmath>
#include <sstream>

namespace deblur_sr_mvs {

Eigen::Matrix3d PinholeCamera::K() const {
  Eigen::Matrix3d k;
  k << fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0;
  return k;
}

PinholeCamera PinholeCamera::Upscaled(int scale) const {
  const double s = scale;
  const double offset = (s - 1.0) / 2.0;
  return PinholeCamera(width * scale, height * scale, s * fx, s * fy, s * cx + offset, s * cy + offset);
}

PinholeCamera PinholeCamera::Downscaled(int scale) const {
  const double s = scale;
  const double offset = (s - 1.0) / 2.0;
  return PinholeCamera(width / scale, height / scale, fx / s, fy / s, (cx - offset) / s, (cy - offset) / s);
}

std::string PinholeCamera::Problem() const {
  std::ostringstream out;
  if (width <= 0 || height <= 0) {
    out << "image size " << width << "x" << height << " is not positive";
  } else if (!std::isfinite(fx) || !std::isfinite(fy) || !std::isfinite(cx) || !std::isfinite(cy)) {
    out << "intrinsics contain NaN or Inf";
  } else if (fx <= 0.0 || fy <= 0.0) {
    out << "focal length (" << fx << ", " << fy << ") is not positive";
  }
  return out.str();
}

}  // namespace deblur_sr_mvs
