#include "deblur_sr_mvs/core/estimation/depth_sweep.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <opencv2/imgproc.hpp>
#include <opencv2/ximgproc.hpp>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/common/options_check.h"
#include "deblur_sr_mvs/core/geometry/warp.h"

namespace deblur_sr_mvs {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

// The inverse-depth planes of the sweep: rho_i = rho_min + i * step.
struct SweepPlanes {
  int count = 0;
  double rho_min = 0.0;
  double step = 0.0;
  double Rho(double index) const { return rho_min + index * step; }
};

// The 1st to 99th percentile of the valid inverse depths, widened by
// `margin` of the span on each side (at least +-10 % of the median); none
// valid: count 0.
SweepPlanes PlanesOf(const cv::Mat& inverse_depth, const DepthSweepOptions& options) {
  std::vector<float> values;
  values.reserve(inverse_depth.total());
  for (int y = 0; y < inverse_depth.rows; ++y) {
    const float* row = inverse_depth.ptr<float>(y);
    for (int x = 0; x < inverse_depth.cols; ++x) {
      if (std::isfinite(row[x]) && row[x] > 0.0f) values.push_back(row[x]);
    }
  }
  SweepPlanes planes;
  if (values.size() < 2) return planes;
  auto percentile = [&values](double fraction) {
    const size_t k = static_cast<size_t>(fraction * (values.size() - 1));
    std::nth_element(values.begin(), values.begin() + k, values.end());
    return static_cast<double>(values[k]);
  };
  const double lo = percentile(0.01), hi = percentile(0.99), median = percentile(0.5);
  const double margin = std::max(options.range_margin * (hi - lo), 0.1 * median);
  planes.count = options.num_planes;
  planes.rho_min = std::max(lo - margin, 0.5 * lo);
  planes.step = (hi + margin - planes.rho_min) / (options.num_planes - 1);
  return planes;
}

// The homography that maps t's pixel x, on the plane of inverse depth rho,
// into s: K R K^-1 + rho K t e3^T (eq:warpingFunction for a fronto-parallel
// plane): t's pixel x is seen at H x in s.
cv::Matx33d PlaneHomography(const PixelTransfer& transfer, double rho) {
  cv::Matx33d h;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) h(r, c) = transfer.homography(r, c);
    h(r, 2) += rho * transfer.translation(r);
  }
  return h;
}

// Colour-averaged |reference(x) - source(H x)|, capped at `truncation`, added
// to *sum; where H x falls outside the source (or behind it): `truncation`.
// Coordinates of a row first (a loop the compiler vectorises), then the
// bilinear reads.
template <int kChannels>
void AddPlaneDifference(const cv::Mat& reference, const cv::Mat& source, const cv::Matx33d& homography,
                        float truncation, std::vector<float>* scratch, cv::Mat* sum) {
  const int width = reference.cols, height = reference.rows;
  const float max_x = static_cast<float>(width - 1), max_y = static_cast<float>(height - 1);
  scratch->resize(static_cast<size_t>(3) * width);
  float* su = scratch->data();
  float* sv = su + width;
  float* ok = sv + width;
  const float h0 = static_cast<float>(homography(0, 0)), h3 = static_cast<float>(homography(1, 0));
  const float h6 = static_cast<float>(homography(2, 0));
  const size_t stride = source.step1();
  for (int y = 0; y < height; ++y) {
    const float bx = static_cast<float>(homography(0, 1) * y + homography(0, 2));
    const float by = static_cast<float>(homography(1, 1) * y + homography(1, 2));
    const float bz = static_cast<float>(homography(2, 1) * y + homography(2, 2));
#pragma omp simd
    for (int x = 0; x < width; ++x) {
      const float xf = static_cast<float>(x);
      const float z = h6 * xf + bz;
      const float inv_z = 1.0f / z;
      const float u = (h0 * xf + bx) * inv_z, v = (h3 * xf + by) * inv_z;
      const bool inside = (z > 1e-9f) & (u >= 0.0f) & (v >= 0.0f) & (u <= max_x) & (v <= max_y);
      ok[x] = inside ? 1.0f : 0.0f;
      su[x] = inside ? u : 0.0f;
      sv[x] = inside ? v : 0.0f;
    }
    const float* a = reference.ptr<float>(y);
    float* out = sum->ptr<float>(y);
    for (int x = 0; x < width; ++x) {
      if (ok[x] == 0.0f) {
        out[x] += truncation;
        continue;
      }
      const int x0 = std::min(static_cast<int>(su[x]), width - 2), y0 = std::min(static_cast<int>(sv[x]), height - 2);
      const float fx = su[x] - x0, fy = sv[x] - y0;
      const float* s0 = source.ptr<float>(y0) + x0 * kChannels;
      float difference = 0.0f;
      for (int c = 0; c < kChannels; ++c) {
        const float top = s0[c] + fx * (s0[c + kChannels] - s0[c]);
        const float bottom = s0[c + stride] + fx * (s0[c + stride + kChannels] - s0[c + stride]);
        difference += std::abs(a[x * kChannels + c] - (top + fy * (bottom - top)));
      }
      out[x] += std::min(difference * (1.0f / kChannels), truncation);
    }
  }
}

// The guide of the aggregation: the image, in gray.
cv::Mat GrayGuide(const cv::Mat& image) {
  if (image.channels() == 1) return image.clone();
  cv::Mat gray;
  cv::cvtColor(image, gray, cv::COLOR_BGR2GRAY);
  return gray;
}

// The local standard deviation of the gray guide over the aggregation
// window ((2 r + 1)^2, the window's mean of I^2 minus its squared mean).
cv::Mat GuideStd(const cv::Mat& image, int radius) {
  const cv::Mat gray = GrayGuide(image);
  cv::Mat mean, mean_sq;
  const cv::Size window(2 * radius + 1, 2 * radius + 1);
  cv::boxFilter(gray, mean, CV_32F, window, cv::Point(-1, -1), true, cv::BORDER_REFLECT);
  cv::boxFilter(gray.mul(gray), mean_sq, CV_32F, window, cv::Point(-1, -1), true, cv::BORDER_REFLECT);
  cv::Mat variance = cv::max(mean_sq - mean.mul(mean), 0.0);
  cv::Mat std_dev;
  cv::sqrt(variance, std_dev);
  return std_dev;
}

// Running best plane per pixel and the costs of the planes either side of it
// (for the parabola), kept without the whole cost volume.
struct BestPlane {
  cv::Mat cost, index, before, after, previous;
  // The cost of the plane nearest each pixel's current inverse depth
  // (`current_index`, -1: outside the planes or unknown).
  cv::Mat current_index, current_cost;
  void Reset(cv::Size size, const cv::Mat& inverse_depth, const SweepPlanes& planes) {
    current_index.create(size, CV_32SC1);
    current_cost.create(size, CV_32FC1);
    current_cost.setTo(kNaN);
    for (int y = 0; y < size.height; ++y) {
      const float* rho = inverse_depth.ptr<float>(y);
      int* nearest = current_index.ptr<int>(y);
      for (int x = 0; x < size.width; ++x) {
        const double i = std::round((rho[x] - planes.rho_min) / planes.step);
        nearest[x] = std::isfinite(rho[x]) && i >= 0.0 && i < planes.count ? static_cast<int>(i) : -1;
      }
    }
    cost.create(size, CV_32FC1);
    cost.setTo(std::numeric_limits<float>::infinity());
    index.create(size, CV_32SC1);
    index.setTo(-1);
    before.create(size, CV_32FC1);
    after.create(size, CV_32FC1);
    previous.create(size, CV_32FC1);
    previous.setTo(kNaN);
  }
  void Add(int plane, const cv::Mat& plane_cost) {
    for (int y = 0; y < plane_cost.rows; ++y) {
      const float* c = plane_cost.ptr<float>(y);
      float* best = cost.ptr<float>(y);
      int* best_index = index.ptr<int>(y);
      float* lo = before.ptr<float>(y);
      float* hi = after.ptr<float>(y);
      const float* prev = previous.ptr<float>(y);
      const int* nearest = current_index.ptr<int>(y);
      float* at_current = current_cost.ptr<float>(y);
      for (int x = 0; x < plane_cost.cols; ++x) {
        if (nearest[x] == plane) at_current[x] = c[x];
        if (c[x] < best[x]) {
          best[x] = c[x];
          best_index[x] = plane;
          lo[x] = prev[x];
          hi[x] = kNaN;
        } else if (best_index[x] == plane - 1) {
          hi[x] = c[x];
        }
      }
    }
    plane_cost.copyTo(previous);
  }
  // The best plane's index refined by a parabola through its neighbours.
  double Refined(int y, int x) const {
    const double c0 = before.at<float>(y, x), c1 = cost.at<float>(y, x), c2 = after.at<float>(y, x);
    const double curvature = c0 - 2.0 * c1 + c2;
    const int i = index.at<int>(y, x);
    if (!(std::isfinite(c0) && std::isfinite(c2)) || !(curvature > 0.0)) return i;
    return i + std::clamp(0.5 * (c0 - c2) / curvature, -0.5, 0.5);
  }
};

// The guided filter of a cost slice p with a gray guide I (He et al., PAMI
// 2013; cv::ximgproc): per window the linear model q = a I + b that fits p
// best (a regularised by eps), averaged over the windows that cover a
// pixel. The guide's statistics are computed once per frame, when the
// filter is made.
class GuidedAggregation {
 public:
  GuidedAggregation(const cv::Mat& guide, int radius, double eps)
      : filter_(cv::ximgproc::createGuidedFilter(guide, radius, eps)) {}
  void Filter(const cv::Mat& p, cv::Mat* q) { filter_->filter(p, *q, CV_32F); }

 private:
  cv::Ptr<cv::ximgproc::GuidedFilter> filter_;
};

// The sweep's per-plane cost: each side's (earlier / later sources) mean
// truncated difference, aggregated by the guided filter, the smaller side.
class PlaneCost {
 public:
  PlaneCost(const std::vector<cv::Mat>& images, const PinholeCamera& camera, const std::vector<SE3>& T_world_cam,
            int t, const std::vector<int>& sources, const DepthSweepOptions& options)
      : images_(images),
        t_(t),
        truncation_(static_cast<float>(options.cost_truncation)),
        filter_(GrayGuide(images[t]), options.aggregation_radius_px, options.aggregation_eps) {
    for (int s : sources) {
      const int side = s < t ? 0 : 1;
      sources_[side].push_back(s);
      transfers_[side].emplace_back(camera, T_world_cam[s].Inverse() * T_world_cam[t]);
    }
  }

  // The cost of the plane rho into *cost (CV_32FC1).
  void Compute(double rho, cv::Mat* cost) {
    const cv::Size size = images_[t_].size();
    bool first = true;
    for (int side = 0; side < 2; ++side) {
      if (sources_[side].empty()) continue;
      side_sum_.create(size, CV_32FC1);
      side_sum_.setTo(0.0f);
      for (size_t k = 0; k < sources_[side].size(); ++k) {
        const cv::Mat& source = images_[sources_[side][k]];
        const cv::Matx33d homography = PlaneHomography(transfers_[side][k], rho);
        if (source.channels() == 3) {
          AddPlaneDifference<3>(images_[t_], source, homography, truncation_, &row_, &side_sum_);
        } else {
          AddPlaneDifference<1>(images_[t_], source, homography, truncation_, &row_, &side_sum_);
        }
      }
      side_sum_ *= 1.0 / sources_[side].size();
      filter_.Filter(side_sum_, &aggregated_);
      if (first) {
        aggregated_.copyTo(*cost);
        first = false;
      } else {
        cv::min(*cost, aggregated_, *cost);
      }
    }
  }

 private:
  const std::vector<cv::Mat>& images_;
  const int t_;
  const float truncation_;
  GuidedAggregation filter_;
  std::vector<int> sources_[2];
  std::vector<PixelTransfer> transfers_[2];
  cv::Mat side_sum_, aggregated_;
  std::vector<float> row_;
};

// The sweep's outcome per pixel: the best plane's refined inverse depth,
// its aggregated cost and that of the plane nearest the current inverse
// depth (NaN: not judged), on the grid the sweep ran on.
struct SweepMaps {
  cv::Mat swept_rho, best_cost, current_cost;
  double step = 0.0;  // plane spacing (inverse depth)
};

// The sweep of frame t on the images' grid; empty maps when there is
// nothing to sweep.
SweepMaps Sweep(const std::vector<cv::Mat>& images, const PinholeCamera& camera, const std::vector<SE3>& T_world_cam,
                int t, const std::vector<int>& sources, const DepthSweepOptions& options,
                const cv::Mat& inverse_depth) {
  SweepMaps maps;
  const SweepPlanes planes = PlanesOf(inverse_depth, options);
  if (sources.empty() || planes.count == 0) return maps;
  const cv::Size size = inverse_depth.size();
  PlaneCost plane_cost(images, camera, T_world_cam, t, sources, options);
  BestPlane best;
  best.Reset(size, inverse_depth, planes);
  cv::Mat cost;
  for (int i = 0; i < planes.count; ++i) {
    plane_cost.Compute(planes.Rho(i), &cost);
    best.Add(i, cost);
  }
  maps.swept_rho.create(size, CV_32FC1);
  for (int y = 0; y < size.height; ++y) {
    float* swept = maps.swept_rho.ptr<float>(y);
    for (int x = 0; x < size.width; ++x) swept[x] = static_cast<float>(planes.Rho(best.Refined(y, x)));
  }
  maps.best_cost = best.cost;
  maps.current_cost = best.current_cost;
  maps.step = planes.step;
  return maps;
}

// The sweep on the images and inverse depth box-downsampled by `factor`
// (the camera's grid cropped to a multiple of it), its maps resized back
// to the full grid (bilinear, docs/file_formats.md#scaling-rule; the
// cropped last columns / rows replicated).
SweepMaps SweepDownsampled(const std::vector<cv::Mat>& images, const PinholeCamera& camera,
                           const std::vector<SE3>& T_world_cam, int t, const std::vector<int>& sources,
                           const DepthSweepOptions& options, const cv::Mat& inverse_depth, int factor) {
  const int width = camera.width / factor, height = camera.height / factor;
  const cv::Rect crop(0, 0, width * factor, height * factor);
  const PinholeCamera small_camera =
      PinholeCamera(crop.width, crop.height, camera.fx, camera.fy, camera.cx, camera.cy).Downscaled(factor);
  std::vector<cv::Mat> small(images.size());
  std::vector<int> used = sources;
  used.push_back(t);
  for (int f : used) cv::resize(images[f](crop), small[f], cv::Size(width, height), 0, 0, cv::INTER_AREA);
  cv::Mat small_rho;
  cv::resize(inverse_depth(crop), small_rho, cv::Size(width, height), 0, 0, cv::INTER_AREA);
  SweepMaps maps = Sweep(small, small_camera, T_world_cam, t, sources, options, small_rho);
  if (maps.swept_rho.empty()) return maps;
  for (cv::Mat* map : {&maps.swept_rho, &maps.best_cost, &maps.current_cost}) {
    cv::Mat full;
    cv::resize(*map, full, crop.size(), 0, 0, cv::INTER_LINEAR);
    cv::copyMakeBorder(full, *map, 0, camera.height - crop.height, 0, camera.width - crop.width,
                       cv::BORDER_REPLICATE);
  }
  return maps;
}

}  // namespace

void DepthSweepOptions::Check() const {
  CheckInRange("depth_sweep_planes", num_planes, 3, 1024);
  CheckInRange("depth_sweep_range_margin", range_margin, 0.0, 10.0);
  CheckInRange("depth_sweep_radius", aggregation_radius_px, 1, 50);
  CheckInRange("depth_sweep_eps", aggregation_eps, 1e-8, 1.0);
  CheckInRange("depth_sweep_truncation", cost_truncation, 1e-3, 1.0);
  CheckInRange("depth_sweep_keep_steps", keep_steps, 0.0, 1024.0);
  CheckInRange("depth_sweep_min_cost_gain", min_cost_gain, 0.0, 0.99);
  CheckInRange("depth_sweep_min_guide_std", min_guide_std, 0.0, 1.0);
  CheckInRange("depth_sweep_neighbour_radius", neighbour_radius, 1, 5);
  CheckInRange("depth_sweep_downsample", downsample, 1, 4);
  CheckInRange("depth_sweep_before_last_structure_updates", before_last_structure_updates, 0, 1000);
}

void SweepInverseDepth(const std::vector<cv::Mat>& images, const PinholeCamera& camera,
                       const std::vector<SE3>& T_world_cam, int t, const std::vector<int>& sources,
                       const DepthSweepOptions& options, cv::Mat* inverse_depth) {
  const cv::Size size(camera.width, camera.height);
  if (inverse_depth->type() != CV_32FC1 || inverse_depth->size() != size) {
    throw InputError("SweepInverseDepth: a CV_32FC1 inverse depth of the camera's size");
  }
  for (const cv::Mat& image : images) {
    if (image.size() != size || (image.type() != CV_32FC1 && image.type() != CV_32FC3)) {
      throw InputError("SweepInverseDepth: CV_32FC1/3 images of the camera's size");
    }
  }
  const SweepMaps maps =
      options.downsample > 1
          ? SweepDownsampled(images, camera, T_world_cam, t, sources, options, *inverse_depth, options.downsample)
          : Sweep(images, camera, T_world_cam, t, sources, options, *inverse_depth);
  if (maps.swept_rho.empty()) return;
  const float min_std = static_cast<float>(options.min_guide_std);
  const cv::Mat guide_std = min_std > 0.0f ? GuideStd(images[t], options.aggregation_radius_px) : cv::Mat();
  const double keep = options.keep_steps * maps.step;
  const float gain = static_cast<float>(1.0 - options.min_cost_gain);
  for (int y = 0; y < size.height; ++y) {
    float* rho = inverse_depth->ptr<float>(y);
    const float* swept = maps.swept_rho.ptr<float>(y);
    const float* best = maps.best_cost.ptr<float>(y);
    const float* current = maps.current_cost.ptr<float>(y);
    const float* local_std = min_std > 0.0f ? guide_std.ptr<float>(y) : nullptr;
    for (int x = 0; x < size.width; ++x) {
      if (!(std::isfinite(rho[x]) && rho[x] > 0.0f)) continue;
      // Where the current inverse depth lies outside the planes (NaN) the
      // sweep is not judged.
      if (!(best[x] < gain * current[x])) continue;
      if (local_std != nullptr && !(local_std[x] >= min_std)) continue;
      if (std::abs(swept[x] - rho[x]) > keep && swept[x] > 0.0f) rho[x] = swept[x];
    }
  }
}

}  // namespace deblur_sr_mvs
