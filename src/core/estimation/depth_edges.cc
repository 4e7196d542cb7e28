#include "deblur_sr_mvs/core/estimation/depth_edges.h"

#include <cmath>
#include <mutex>

#include <opencv2/ximgproc.hpp>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/common/options_check.h"

namespace deblur_sr_mvs {
namespace {

constexpr uint64 kDepthEdgeClusteringSeed = 0x5eed5eedULL;

}  // namespace

void DepthEdgeOptions::Check() const {
  CheckInRange("depth_edge_radius", radius_px, 0, 50);
  CheckInRange("depth_edge_sigma", sigma, 1e-3, 1.0);
}

void RefineDepthEdges(const cv::Mat& guide, const DepthEdgeOptions& options, cv::Mat* inverse_depth) {
  if (options.radius_px <= 0) return;
  if (inverse_depth->type() != CV_32FC1 || guide.size() != inverse_depth->size() ||
      (guide.type() != CV_32FC1 && guide.type() != CV_32FC3)) {
    throw InputError("RefineDepthEdges: a CV_32FC1 inverse depth and a CV_32FC1/3 guide of its size");
  }
  // The filter's joint image is 8-bit: sigma follows the scale.
  cv::Mat guide8;
  guide.convertTo(guide8, CV_8U, 255.0);
  cv::Mat mask(inverse_depth->size(), CV_8UC1);
  cv::Mat source = inverse_depth->clone();
  bool any_invalid = false;
  for (int y = 0; y < source.rows; ++y) {
    float* row = source.ptr<float>(y);
    uchar* valid = mask.ptr<uchar>(y);
    for (int x = 0; x < source.cols; ++x) {
      valid[x] = std::isfinite(row[x]) && row[x] > 0.0f ? 1 : 0;
      if (!valid[x]) {
        row[x] = 0.0f;
        any_invalid = true;
      }
    }
  }
  // cv::ximgproc::weightedMedianFilter (OpenCV 4.6) is not reentrant: two
  // calls at once in one process crash (two threads, 320x240). One call at a
  // time, process-wide (streams of several nodelets share the process).
  static std::mutex filter_mutex;
  const std::lock_guard<std::mutex> lock(filter_mutex);
  // The filter clusters a colour guide's values with cv::kmeans, which
  // draws from OpenCV's generator: seeded here, so that the same input
  // gives the same depth (the generator's state is put back).
  cv::RNG& generator = cv::theRNG();
  const uint64 caller_state = generator.state;
  generator.state = kDepthEdgeClusteringSeed;
  cv::Mat filtered;
  cv::ximgproc::weightedMedianFilter(guide8, source, filtered, options.radius_px, 255.0 * options.sigma,
                                     cv::ximgproc::WMF_EXP, any_invalid ? mask : cv::noArray());
  generator.state = caller_state;
  filtered.copyTo(*inverse_depth, mask);
}

}  // namespace deblur_sr_mvs
