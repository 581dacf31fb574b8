#pragma once
// Facts about the machine the process runs on.
#include <cstddef>
#include <cstdint>
#include <vector>

namespace voxcast {

/// Memory the kernel reports as available (MemAvailable), in bytes; 0 if unknown.
uint64_t available_memory_bytes();
/// Physical memory the process may use, in bytes: MemTotal, lowered to the
/// cgroup's memory limit when one is set (containers); 0 if unknown.
uint64_t physical_memory_bytes();
/// Parses "512M", "8G", "1.5GiB", "123456" (bytes) into bytes; throws voxcast::Error.
uint64_t parse_byte_size(const char* text);
/// What a stat() st_mode is, for messages: "a directory", "a FIFO (named
/// pipe)", "a character device", ..., "a regular file".
const char* file_type_name(uint32_t st_mode);
/// Which arrays a huge-page advice is for. kBulk: the large derived and
/// attribute arrays (prefix sums, LOD mean tables, attribute blocks);
/// advised only when the environment sets VOXCAST_HUGE_PAGES=1, since the
/// first touch of their huge pages cost up to 15 s of kernel time per
/// 16384^3 load (docs/BENCHMARKS.md, "16K³ against 2K³ at LOD 1"). kHot:
/// what every ray walks: a DAG's words (204 MiB at 16384^3, whose huge
/// pages measured no extra kernel time) and the GigaVoxels brick pool;
/// advised unless VOXCAST_HUGE_PAGES=0.
enum class HugePages { kBulk, kHot };

/// Asks Linux to back the whole 2 MiB pages inside [data, data + bytes) with
/// transparent huge pages (MADV_HUGEPAGE): for large arrays read at random,
/// where 4 KiB pages miss the TLB on nearly every access. Pages not yet
/// touched then get huge pages when first written (THP "madvise" mode), so
/// advise before filling (reserve_huge, assign_huge); pages already touched
/// stay small. Advice only: the same bytes either way. Gated by `kind`
/// (above); refused, failed or elsewhere a no-op. Returns the bytes advised.
size_t advise_huge_pages(const void* data, size_t bytes, HugePages kind = HugePages::kBulk);

/// Room for n elements in `v` (whose elements are kept), allocated and then
/// advised as huge pages before anything is written to it: fill it with
/// push_back/insert. Fresh storage only if the capacity was below n.
template <class T, class A>
void reserve_huge(std::vector<T, A>& v, size_t n, HugePages kind = HugePages::kBulk) {
  if (v.capacity() >= n) return;
  v.reserve(n);
  advise_huge_pages(v.data(), v.capacity() * sizeof(T), kind);
}

/// v = n copies of `value` in fresh storage advised as huge pages before the
/// copies are written (std::vector's own assign would touch it first).
template <class T, class A>
void assign_huge(std::vector<T, A>& v, size_t n, const T& value = T(),
                 HugePages kind = HugePages::kBulk) {
  v = std::vector<T, A>();
  reserve_huge(v, n, kind);
  v.assign(n, value);
}

}  // namespace voxcast
