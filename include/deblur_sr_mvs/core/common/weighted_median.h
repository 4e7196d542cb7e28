// The weighted median of (value, weight) samples.
#pragma once

#include <algorithm>
#include <utility>
#include <vector>

namespace deblur_sr_mvs {

// The value at which the weights of (value, weight) pairs reach half their
// sum, in increasing value (negative weights count as 0); the plain median
// when every weight is 0; 0 for none.
inline double WeightedMedian(std::vector<std::pair<double, double>> samples) {
  if (samples.empty()) return 0.0;
  std::sort(samples.begin(), samples.end());
  double total = 0.0;
  for (const auto& sample : samples) total += std::max(sample.second, 0.0);
  if (!(total > 0.0)) return samples[samples.size() / 2].first;
  double sum = 0.0;
  for (const auto& sample : samples) {
    sum += std::max(sample.second, 0.0);
    if (sum >= 0.5 * total) return sample.first;
  }
  return samples.back().first;
}

}  // namespace deblur_sr_mvs
