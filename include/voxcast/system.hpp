#pragma once
// Facts about the machine the process runs on.
#include <cstddef>
#include <cstdint>

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
/// Asks Linux to back the whole 2 MiB pages inside [data, data + bytes) with
/// transparent huge pages now (MADV_HUGEPAGE, then MADV_COLLAPSE, which
/// copies already-touched pages into huge ones): for large arrays read at
/// random, where 4 KiB pages miss the TLB on nearly every access. Advice
/// only: the same bytes either way; refused, failed or elsewhere a no-op,
/// as when the environment sets VOXCAST_NO_HUGE_PAGES (for comparisons).
/// Returns the bytes advised.
size_t advise_huge_pages(const void* data, size_t bytes);

}  // namespace voxcast
