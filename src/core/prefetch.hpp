#pragma once
// A cache-line prefetch the compiler keeps.
//
// Why not _mm_prefetch / __builtin_prefetch: GCC 12 (Debian 12's compiler)
// deleted such calls in some callers at -O3: DagStructure::prefetch_attributes
// compiled to a bare `ret`, and the GigaVoxels march's brick prefetch to
// nothing, although both hints were reachable (found 2026-12-07 while
// measuring the DAG's batched attributes; docs/BENCHMARKS.md "DAG
// attributes in batches"). An asm statement with a memory operand is never
// removed and reads nothing.
namespace voxcast::detail {

/// Starts loading the cache line holding *p into every cache level (a hint:
/// no fault, no result). p need not be aligned.
[[gnu::always_inline]] inline void prefetch_line(const void* p) {
#if defined(__x86_64__)
  asm volatile("prefetcht0 %0" : : "m"(*static_cast<const char*>(p)));
#else
  __builtin_prefetch(p, 0, 3);
#endif
}

}  // namespace voxcast::detail
