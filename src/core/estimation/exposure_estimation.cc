#include "deblur_sr_mvs/core/estimation/exposure_estimation.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

#include <opencv2/imgproc.hpp>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/common/grid_minimum.h"
#include "deblur_sr_mvs/core/common/options_check.h"
#include "deblur_sr_mvs/core/common/runtime.h"

namespace deblur_sr_mvs {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

// One frame's blur evidence: its gradient and, per pixel, the unit direction
// u and length |v| of its image motion between two frames (NaN where unknown
// or below min_motion_px).
struct FrameEvidence {
  cv::Mat gx, gy;      // CV_32FC1 gradient of the grey frame
  cv::Mat ux, uy, vn;  // CV_32FC1 motion direction and length (LR px per interval)
};

cv::Mat Grey(const cv::Mat& image) {
  if (image.channels() == 1) return image;
  std::vector<cv::Mat> channels;
  cv::split(image, channels);
  cv::Mat sum = cv::Mat::zeros(image.size(), CV_32FC1);
  for (const cv::Mat& channel : channels) sum += channel;
  return sum / static_cast<double>(channels.size());
}

// The gradient (central differences) of the grey frame less its Gaussian
// blur: whitening flattens the sharp image's derivative autocorrelation,
// which would otherwise tilt the correlation and move its dip to longer
// lags (Dolls, ratio 0.5: +18 % with a plain Sobel gradient, -1 % so).
void WhitenedGradient(const cv::Mat& image, double sigma_px, FrameEvidence* evidence) {
  const cv::Mat grey = Grey(image);
  cv::Mat low;
  cv::GaussianBlur(grey, low, cv::Size(), sigma_px);
  const cv::Mat high = grey - low;
  const cv::Mat kernel = (cv::Mat_<float>(1, 3) << -0.5f, 0.0f, 0.5f);
  cv::filter2D(high, evidence->gx, CV_32F, kernel);
  cv::filter2D(high, evidence->gy, CV_32F, kernel.t());
}

// Image motion of frame t's pixels over one frame interval before t along
// its blur path `path` (SetBlurPath: P_{t-1} itself for t > 0; for frame 0
// the path extrapolated backwards), for depth `depth` (empty: at infinity);
// its sign does not matter to the correlation. With a rolling shutter
// (path.readout_time > 0), row y's interval ends RowDelay after the stamp,
// and the motion is mapped into the frame's rows (EstimateExposureFromMotion).
void FrameMotion(const PinholeCamera& camera, const cv::Mat& depth, const CaptureGeometry& path,
                 double interval, double min_motion_px, FrameEvidence* evidence) {
  const cv::Size size(camera.width, camera.height);
  evidence->ux.create(size, CV_32FC1);
  evidence->uy.create(size, CV_32FC1);
  evidence->vn.create(size, CV_32FC1);
  // The fraction of the interval between two rows' closing times: a motion
  // of m px per interval moves the image m x this per row.
  const bool rolling = path.readout_time > 0.0;
  const double interval_per_row = path.readout_time / interval / size.height;
  SE3 T_n_t = PoseAtTime(path, path.stamp - interval).Inverse() * path.T_world_cam;
  for (int y = 0; y < size.height; ++y) {
    if (rolling) {
      const double row_close = path.stamp + RowDelay(path, y, size.height);
      T_n_t = PoseAtTime(path, row_close - interval).Inverse() * PoseAtTime(path, row_close);
    }
    for (int x = 0; x < size.width; ++x) {
      const float d = depth.empty() ? 1.0f : depth.at<float>(y, x);
      float ux = kNaN, uy = kNaN, vn = kNaN;
      if (d > 0.0f && std::isfinite(d)) {
        const Eigen::Vector3d ray = camera.Ray(x, y);
        const Eigen::Vector3d seen =
            depth.empty() ? Eigen::Vector3d(T_n_t.rotation() * ray) : Eigen::Vector3d(T_n_t * (d * ray));
        if (seen.z() > 0.0) {
          Eigen::Vector2d motion = Eigen::Vector2d(x, y) - camera.Project(seen);
          const double sx = motion.x() * interval_per_row, sy = motion.y() * interval_per_row;
          // J^-1 grows without bound as s_y nears 1 (the image keeps pace
          // with the readout); past half of it the lag is left unmapped.
          if (rolling && sy < 0.5) {
            motion = Eigen::Vector2d(motion.x() + sx * motion.y() / (1.0 - sy), motion.y() / (1.0 - sy));
          }
          if (motion.norm() >= min_motion_px) {
            vn = static_cast<float>(motion.norm());
            ux = static_cast<float>(motion.x() / motion.norm());
            uy = static_cast<float>(motion.y() / motion.norm());
          }
        }
      }
      evidence->ux.at<float>(y, x) = ux;
      evidence->uy.at<float>(y, x) = uy;
      evidence->vn.at<float>(y, x) = vn;
    }
  }
}

// Sums of the normalised correlation of dB(x) with dB(x - f v(x)), the
// derivatives along u(x), for one frame.
struct CorrelationSums {
  double ab = 0.0, aa = 0.0, bb = 0.0;
  double Value() const { return aa > 0.0 && bb > 0.0 ? ab / std::sqrt(aa * bb) : 0.0; }
};

void AddCorrelation(const FrameEvidence& e, double fraction, CorrelationSums* sums) {
  const cv::Size size = e.gx.size();
  cv::Mat map_x(size, CV_32FC1), map_y(size, CV_32FC1);
  for (int y = 0; y < size.height; ++y) {
    for (int x = 0; x < size.width; ++x) {
      const float lag = static_cast<float>(fraction) * e.vn.at<float>(y, x);  // NaN stays NaN
      const bool known = std::isfinite(lag);
      map_x.at<float>(y, x) = known ? x - lag * e.ux.at<float>(y, x) : -10.0f;
      map_y.at<float>(y, x) = known ? y - lag * e.uy.at<float>(y, x) : -10.0f;
    }
  }
  cv::Mat gx_lag, gy_lag;
  cv::remap(e.gx, gx_lag, map_x, map_y, cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar(kNaN));
  cv::remap(e.gy, gy_lag, map_x, map_y, cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar(kNaN));
  for (int y = 0; y < size.height; ++y) {
    for (int x = 0; x < size.width; ++x) {
      const float ux = e.ux.at<float>(y, x), uy = e.uy.at<float>(y, x);
      const float b = ux * gx_lag.at<float>(y, x) + uy * gy_lag.at<float>(y, x);
      if (!std::isfinite(b)) continue;  // unknown motion or outside the frame
      const float a = ux * e.gx.at<float>(y, x) + uy * e.gy.at<float>(y, x);
      sums->ab += a * b;
      sums->aa += a * a;
      sums->bb += b * b;
    }
  }
}

double Median(std::vector<double> values) {
  const auto middle = values.begin() + values.size() / 2;
  std::nth_element(values.begin(), middle, values.end());
  return *middle;
}

// Depth and poses of the initialisation at the assumed exposure fraction
// (no depth and zero translations without parallax).
void InitialiseAtFraction(const EstimatorInput& input, const EstimatorOptions& estimator_options,
                          double fraction, std::vector<cv::Mat>* depth_lr, std::vector<SE3>* T_world_cam) {
  const std::vector<FrameRecord> frames = WithExposureFraction(input.frames, fraction);
  InitializerOptions init_options = estimator_options.initializer;
  init_options.num_threads = estimator_options.num_threads;
  try {
    const InitialStructure initial =
        InitializeStructure(input.images, input.camera, frames, init_options, input.readout_time);
    *depth_lr = initial.depth_lr;
    *T_world_cam = initial.T_world_cam;
  } catch (const NoParallaxError&) {
    const RotationOnlyMotion motion =
        EstimateRotationOnlyMotion(input.images, input.camera, frames, init_options);
    depth_lr->clear();
    T_world_cam->clear();
    for (const Eigen::Matrix3d& R_world_cam : motion.R_world_cam)
      T_world_cam->emplace_back(R_world_cam, Eigen::Vector3d::Zero());
  }
}

}  // namespace

void ExposureEstimationOptions::Check() const {
  CheckInInterval("exposure min_fraction", min_fraction, 0.0, 1.0, Interval::kRightClosed);
  CheckInInterval("exposure max_fraction", max_fraction, min_fraction, 1.0, Interval::kRightClosed);
  CheckInInterval("exposure fraction_step", fraction_step, 0.0, 0.5, Interval::kRightClosed);
  CheckInInterval("exposure initial_fraction", initial_fraction, 0.0, 1.0, Interval::kRightClosed);
  CheckAtLeast("exposure min_motion_px", min_motion_px, 0.0);
  CheckInInterval("exposure highpass_sigma_px", highpass_sigma_px, 0.0, 100.0, Interval::kRightClosed);
}

std::vector<double> FrameIntervals(const std::vector<FrameRecord>& frames) {
  if (frames.size() < 2) throw InputError("exposure estimation: needs at least 2 frames");
  std::vector<double> intervals(frames.size());
  for (size_t t = 1; t < frames.size(); ++t) {
    intervals[t] = frames[t].stamp - frames[t - 1].stamp;
    if (!(intervals[t] > 0.0) || !std::isfinite(intervals[t])) {
      throw InputError("exposure estimation: frame stamps must increase");
    }
  }
  intervals[0] = intervals[1];
  return intervals;
}

std::vector<FrameRecord> WithExposureFraction(const std::vector<FrameRecord>& frames, double fraction) {
  const std::vector<double> intervals = FrameIntervals(frames);
  std::vector<FrameRecord> result = frames;
  for (size_t t = 0; t < frames.size(); ++t) result[t].exposure = fraction * intervals[t];
  return result;
}

ExposureEstimate EstimateExposureFromMotion(const std::vector<cv::Mat>& images_lr,
                                            const PinholeCamera& camera_lr,
                                            const std::vector<FrameRecord>& frames,
                                            const std::vector<cv::Mat>& depth_lr,
                                            const std::vector<SE3>& T_world_cam,
                                            const ExposureEstimationOptions& options, double readout_time) {
  options.Check();
  const std::vector<double> intervals = FrameIntervals(frames);
  const size_t n = frames.size();
  if (images_lr.size() != n || T_world_cam.size() != n || (!depth_lr.empty() && depth_lr.size() != n)) {
    throw InputError("exposure estimation: images, frames, depths and poses differ in number");
  }
  const std::vector<double> stamps = FrameStamps(frames);
  std::vector<FrameEvidence> evidence(n);
  for (size_t t = 0; t < n; ++t) {
    WhitenedGradient(images_lr[t], options.highpass_sigma_px, &evidence[t]);
    CaptureGeometry path;
    SetBlurPath(T_world_cam, stamps, static_cast<int>(t), &path);
    path.readout_time = readout_time;
    FrameMotion(camera_lr, depth_lr.empty() ? cv::Mat() : depth_lr[t], path, intervals[t],
                options.min_motion_px, &evidence[t]);
  }
  ExposureEstimate estimate;
  const int steps = static_cast<int>(
      std::floor((options.max_fraction - options.min_fraction) / options.fraction_step + 1e-9));
  for (int i = 0; i <= steps; ++i) {
    const double fraction = options.min_fraction + i * options.fraction_step;
    CorrelationSums sums;
    for (const FrameEvidence& e : evidence) AddCorrelation(e, fraction, &sums);
    estimate.correlation.emplace_back(fraction, sums.Value());
  }
  const auto best = std::min_element(estimate.correlation.begin(), estimate.correlation.end(),
                                     [](const auto& a, const auto& b) { return a.second < b.second; });
  estimate.measured = best->second < 0.0;
  estimate.fraction = estimate.measured
                          ? RefinedGridMinimum(estimate.correlation, best - estimate.correlation.begin())
                          : options.initial_fraction;
  estimate.seconds = estimate.fraction * Median(intervals);
  for (double interval : intervals) estimate.frame_exposures.push_back(estimate.fraction * interval);
  char line[200];
  std::snprintf(line, sizeof(line),
                estimate.measured ? "exposure estimated from the blur: %.3f of the frame interval (%.6f s), "
                                    "correlation dip %.3f"
                                  : "exposure not measurable (no blur along the motion): assumed %.3f of the "
                                    "frame interval (%.6f s), correlation minimum %.3f",
                estimate.fraction, estimate.seconds, best->second);
  estimate.summary = line;
  return estimate;
}

ExposureEstimate EstimateExposure(const EstimatorInput& input, const EstimatorOptions& estimator_options,
                                  const ExposureEstimationOptions& options, const std::atomic<bool>* cancel) {
  options.Check();
  estimator_options.Check();
  const double start = NowMs();
  std::vector<cv::Mat> depth_lr;
  std::vector<SE3> T_world_cam;
  InitialiseAtFraction(input, estimator_options, options.initial_fraction, &depth_lr, &T_world_cam);
  if (cancel != nullptr && cancel->load()) throw EstimationCancelled();
  const double search_start = NowMs();
  ExposureEstimate estimate = EstimateExposureFromMotion(input.images, input.camera, input.frames, depth_lr,
                                                         T_world_cam, options, input.readout_time);
  estimate.elapsed_seconds = (NowMs() - start) / 1000.0;
  char time[96];
  std::snprintf(time, sizeof(time), "; %.2f s (initialisation %.2f s, search %.2f s)",
                estimate.elapsed_seconds, (search_start - start) / 1000.0, (NowMs() - search_start) / 1000.0);
  estimate.summary += time;
  return estimate;
}

}  // namespace deblur_sr_mvs
