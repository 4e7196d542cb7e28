// Small text helpers for user-facing messages.
#pragma once

#include <string>

#include <opencv2/core.hpp>

namespace deblur_sr_mvs {

// `text` on one line (cv::Exception messages span several), trailing blanks removed.
inline std::string OneLine(const std::string& text) {
  std::string out;
  for (const char c : text) out += (c == '\n' || c == '\r') ? ' ' : c;
  while (!out.empty() && out.back() == ' ') out.pop_back();
  return out;
}

// "WIDTHxHEIGHT", as every size message writes it.
inline std::string SizeText(int width, int height) {
  return std::to_string(width) + "x" + std::to_string(height);
}
inline std::string SizeText(const cv::Size& size) {
  return SizeText(size.width, size.height);
}
inline std::string SizeText(const cv::Mat& image) {
  return SizeText(image.cols, image.rows);
}

}  // namespace deblur_sr_mvs
