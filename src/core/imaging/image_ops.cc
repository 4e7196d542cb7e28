#include "deblur_sr_mvs/core/imaging/image_ops.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "deblur_sr_mvs/core/common/errors.h"

namespace deblur_sr_mvs {

cv::Mat ToFloat01(const cv::Mat& image) {
  cv::Mat result;
  switch (image.depth()) {
    case CV_8U:
      image.convertTo(result, CV_32F, 1.0 / 255.0);
      break;
    case CV_16U:
      image.convertTo(result, CV_32F, 1.0 / 65535.0);
      break;
    case CV_32F:
      result = image.clone();
      break;
    default:
      throw InputError("ToFloat01: unsupported image depth");
  }
  return result;
}

cv::Mat ToImage8(const cv::Mat& image01) {
  cv::Mat clean = image01.clone();
  cv::patchNaNs(clean, 0.0);
  cv::Mat result;
  clean.convertTo(result, CV_8U, 255.0);  // saturate_cast rounds and clamps
  return result;
}

cv::Mat UpsampleBicubic(const cv::Mat& image, int scale) {
  cv::Mat result;
  cv::resize(image, result, cv::Size(image.cols * scale, image.rows * scale), 0, 0, cv::INTER_CUBIC);
  return result;
}

cv::Mat DownsampleBox(const cv::Mat& image, int scale) {
  if (scale < 1 || image.cols % scale != 0 || image.rows % scale != 0) {
    throw InputError("DownsampleBox: size must be divisible by the scale");
  }
  cv::Mat result;
  cv::resize(image, result, cv::Size(image.cols / scale, image.rows / scale), 0, 0, cv::INTER_AREA);
  return result;
}

cv::Mat ColorizeDepth(const cv::Mat& depth, double min_depth, double max_depth) {
  if (depth.type() != CV_32FC1) throw InputError("ColorizeDepth: depth must be CV_32FC1");
  if (min_depth <= 0.0 && max_depth <= 0.0) {
    std::vector<float> values;
    values.reserve(depth.total());
    for (int y = 0; y < depth.rows; ++y) {
      const float* row = depth.ptr<float>(y);
      for (int x = 0; x < depth.cols; ++x) {
        if (row[x] > 0.0f && std::isfinite(row[x])) values.push_back(row[x]);
      }
    }
    if (values.empty()) return cv::Mat(depth.size(), CV_8UC3, cv::Scalar::all(0));
    std::sort(values.begin(), values.end());
    min_depth = values[values.size() * 2 / 100];
    max_depth = values[values.size() * 98 / 100];
  }
  if (max_depth <= min_depth) max_depth = min_depth + 1e-6;
  cv::Mat normalized(depth.size(), CV_8UC1);
  cv::Mat invalid(depth.size(), CV_8UC1, cv::Scalar(0));
  for (int y = 0; y < depth.rows; ++y) {
    const float* row = depth.ptr<float>(y);
    uchar* out = normalized.ptr<uchar>(y);
    for (int x = 0; x < depth.cols; ++x) {
      if (!(row[x] > 0.0f) || !std::isfinite(row[x])) {
        out[x] = 0;
        invalid.at<uchar>(y, x) = 255;
        continue;
      }
      // Near is 255 (warm in TURBO), far is 0.
      const double t = (max_depth - row[x]) / (max_depth - min_depth);
      out[x] = cv::saturate_cast<uchar>(255.0 * std::clamp(t, 0.0, 1.0));
    }
  }
  cv::Mat colored;
  cv::applyColorMap(normalized, colored, cv::COLORMAP_TURBO);
  colored.setTo(cv::Scalar::all(0), invalid);
  return colored;
}

void PastePanel(const cv::Mat& panel, const std::string& caption, cv::Point origin, cv::Mat* canvas) {
  cv::Mat bgr;
  if (panel.channels() == 1) {
    cv::cvtColor(panel, bgr, cv::COLOR_GRAY2BGR);
  } else {
    bgr = panel;
  }
  const cv::Rect area(origin, bgr.size());
  bgr.copyTo((*canvas)(area));
  const int band = 22;
  cv::Mat top = (*canvas)(cv::Rect(origin.x, origin.y, bgr.cols, std::min(band, bgr.rows)));
  top *= 0.35;
  cv::putText(*canvas, caption, cv::Point(origin.x + 6, origin.y + 16), cv::FONT_HERSHEY_SIMPLEX, 0.5,
              cv::Scalar(255, 255, 255), 1, cv::LINE_AA);
}

}  // namespace deblur_sr_mvs
