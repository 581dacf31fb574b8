#pragma once
// Timing helpers shared by `voxcast bench` and the Embree reference so that
// every caster is timed the same way: rays handed out in fixed chunks by TBB,
// and timestamp-counter reads for the instrumented (single-threaded) profile.
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/partitioner.h>

#include <algorithm>
#include <chrono>
#include <cstddef>
#include <cstdint>

#if defined(__x86_64__) || defined(__i386__)
#include <x86intrin.h>
#endif

namespace voxcast::detail {

/// Calls body(begin, end) for consecutive chunks of [0, n) of `chunk` items in
/// parallel; returns the wall time in seconds.
template <class Body>
double for_each_chunk(size_t n, size_t chunk, const Body& body) {
  const size_t c = std::max<size_t>(1, chunk);
  const size_t chunks = (n + c - 1) / c;
  const auto t0 = std::chrono::steady_clock::now();
  tbb::parallel_for(
      tbb::blocked_range<size_t>(0, chunks, 1),
      [&](const tbb::blocked_range<size_t>& r) {
        for (size_t i = r.begin(); i != r.end(); ++i) body(i * c, std::min(n, (i + 1) * c));
      },
      tbb::simple_partitioner());
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

/// Timestamp counter (constant rate on current x86; not core cycles when the
/// core clock differs from the TSC rate, see tsc_hz()). 0 elsewhere.
/// Deliberately without lfence: fenced reads drain the pipeline at every
/// stage boundary and inflate short stages (ray generation read ~90-180 ticks
/// fenced vs ~25 unfenced on the bunny), while the unfenced stage sums match
/// the single-threaded throughput (ticks per ray = TSC rate / rays per second).
inline uint64_t ticks() {
#if defined(__x86_64__) || defined(__i386__)
  return __rdtsc();
#else
  return 0;
#endif
}

/// TSC ticks per second, measured against steady_clock over ~50 ms.
inline double tsc_hz() {
  const auto t0 = std::chrono::steady_clock::now();
  const uint64_t k0 = ticks();
  while (std::chrono::steady_clock::now() - t0 < std::chrono::milliseconds(50)) {
  }
  const uint64_t k1 = ticks();
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return double(k1 - k0) / s;
}

/// Ticks one back-to-back ticks() pair costs (subtracted per stage read).
inline uint64_t tick_overhead() {
  uint64_t best = UINT64_MAX;
  for (int i = 0; i < 1000; ++i) {
    const uint64_t a = ticks(), b = ticks();
    best = std::min(best, b - a);
  }
  return best;
}

}  // namespace voxcast::detail
