// Test support: an image of uniformly random values.
#pragma once

#include <random>

#include <opencv2/core.hpp>

namespace deblur_sr_mvs {

// A (pixels x 1) CV_32FC(channels) image of values uniform in [low, high).
inline cv::Mat RandomValues(int pixels, int channels, float low, float high, std::mt19937* rng) {
  cv::Mat image(pixels, 1, CV_32FC(channels));
  std::uniform_real_distribution<float> value(low, high);
  float* p = image.ptr<float>();
  for (size_t i = 0; i < image.total() * channels; ++i) p[i] = value(*rng);
  return image;
}

}  // namespace deblur_sr_mvs
