// Wall clock and thread-count helpers shared by the core stages.
#pragma once

#include <omp.h>

#include <cstdlib>  // defines __GLIBC__ on glibc

#if defined(__GLIBC__)
#include <malloc.h>
#endif

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

// Keeps the heap's freed memory for reuse, for processes that run the
// estimator (called once at start-up by estimate_sequence and the node).
// The stages allocate and free image- and operator-sized buffers (1-30 MB)
// again and again; glibc's defaults give such blocks back to the kernel
// (mmap / trim) on free, so every reuse page-faults and zero-fills fresh
// pages (about 7 % of a run's CPU time on the speed sequences, see
// BENCHMARKS.md "Freed memory kept for reuse"). Here blocks up to 32 MiB
// (glibc's largest mmap threshold) come from the heap, and the heap's top
// is trimmed only beyond 1 GiB of free memory. Results do not change; the
// peak resident size does not either (the freed blocks are what the next
// stage allocates). Returns false where the C library is not glibc (no
// effect) or it refused a setting.
inline bool KeepFreedMemoryForReuse() {
#if defined(__GLIBC__)
  constexpr int kMiB = 1 << 20;
  bool ok = mallopt(M_MMAP_THRESHOLD, 32 * kMiB) == 1;
  ok = mallopt(M_TRIM_THRESHOLD, 1024 * kMiB) == 1 && ok;
  ok = mallopt(M_TOP_PAD, 64 * kMiB) == 1 && ok;
  return ok;
#else
  return false;
#endif
}

}  // namespace deblur_sr_mvs
