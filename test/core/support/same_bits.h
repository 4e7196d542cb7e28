// Test support: images compared bit for bit (NaN payloads and the sign of
// zero included), for the tests that check a change leaves results exactly
// as they were.
#pragma once

#include <cstring>

#include <opencv2/core.hpp>

namespace deblur_sr_mvs {

// Same size, type and bytes, row by row (views into larger images too).
inline bool SameBits(const cv::Mat& a, const cv::Mat& b) {
  if (a.size() != b.size() || a.type() != b.type()) return false;
  for (int y = 0; y < a.rows; ++y) {
    if (std::memcmp(a.ptr(y), b.ptr(y), a.cols * a.elemSize()) != 0) return false;
  }
  return true;
}

}  // namespace deblur_sr_mvs
