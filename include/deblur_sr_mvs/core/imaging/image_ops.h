// Small image conversions shared by the tools and the estimator.
#pragma once

#include <string>

#include <opencv2/core.hpp>

namespace deblur_sr_mvs {

// 8-bit (or 16-bit) image -> CV_32FC(n) with values in [0, 1].
cv::Mat ToFloat01(const cv::Mat& image);
// Float image in [0, 1] -> 8-bit, rounded and clamped (NaN -> 0).
cv::Mat ToImage8(const cv::Mat& image01);

// Bicubic up-sampling by an integer factor with the pixel-centre convention
// of docs/file_formats.md#scaling-rule (cv::resize maps HR X to LR (X - (s-1)/2)/s as well).
cv::Mat UpsampleBicubic(const cv::Mat& image, int scale);
// Box down-sampling by an integer factor (size must be divisible).
cv::Mat DownsampleBox(const cv::Mat& image, int scale);

// Colour-mapped preview of a depth map (near = warm), NaN/<= 0 black; the
// range is [min_depth, max_depth], or the 2nd-98th percentiles when both are 0.
cv::Mat ColorizeDepth(const cv::Mat& depth, double min_depth = 0.0, double max_depth = 0.0);

// Copies `panel` (8-bit, 1 or 3 channels) into `canvas` at `origin` as BGR,
// with a caption in a dark band at its top.
void PastePanel(const cv::Mat& panel, const std::string& caption, cv::Point origin, cv::Mat* canvas);

}  // namespace deblur_sr_mvs
