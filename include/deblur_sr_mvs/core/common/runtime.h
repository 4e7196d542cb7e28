// Wall clock and thread-count helpers shared by the core stages.
#pragma once

#include <omp.h>

#include <algorithm>
#include <chrono>

namespace deblur_sr_mvs {

// Monotonic wall time in milliseconds (for stage timings).
inline double NowMs() {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

// Threads to use for an option value: > 0 as given, 0 = OpenMP's default.
inline int ResolveThreads(int requested) {
  return requested > 0 ? requested : std::max(1, omp_get_max_threads());
}

}  // namespace deblur_sr_mvs
