#include "voxcast/system.hpp"

#include <sys/stat.h>
#if defined(__linux__)
#include <sys/mman.h>
#endif

#include <cctype>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <string_view>

#include "voxcast/error.hpp"

namespace voxcast {

namespace {

// First "Key: N kB" value of /proc/meminfo, in bytes; 0 if absent.
uint64_t meminfo_bytes(const char* key) {
  FILE* f = std::fopen("/proc/meminfo", "r");
  if (!f) return 0;
  char line[256];
  uint64_t bytes = 0;
  const size_t key_len = std::strlen(key);
  while (std::fgets(line, sizeof line, f)) {
    unsigned long long v = 0;
    if (std::strncmp(line, key, key_len) == 0 && line[key_len] == ':' &&
        std::sscanf(line + key_len + 1, "%llu kB", &v) == 1) {
      bytes = uint64_t(v) * 1024;
      break;
    }
  }
  std::fclose(f);
  return bytes;
}

// A cgroup memory limit file holding a byte count ("max" or absent: 0).
uint64_t cgroup_limit(const char* path) {
  FILE* f = std::fopen(path, "r");
  if (!f) return 0;
  unsigned long long v = 0;
  const bool ok = std::fscanf(f, "%llu", &v) == 1;
  std::fclose(f);
  return ok ? uint64_t(v) : 0;
}

}  // namespace

uint64_t available_memory_bytes() {
  return meminfo_bytes("MemAvailable");
}

uint64_t physical_memory_bytes() {
  uint64_t total = meminfo_bytes("MemTotal");
  for (const char* path :
       {"/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"}) {
    const uint64_t limit = cgroup_limit(path);
    if (limit > 0 && (total == 0 || limit < total)) total = limit;
  }
  return total;
}

const char* file_type_name(uint32_t st_mode) {
  const mode_t mode = mode_t(st_mode);
  if (S_ISREG(mode)) return "a regular file";
  if (S_ISDIR(mode)) return "a directory";
  if (S_ISFIFO(mode)) return "a FIFO (named pipe)";
  if (S_ISCHR(mode)) return "a character device";
  if (S_ISBLK(mode)) return "a block device";
  if (S_ISSOCK(mode)) return "a socket";
  return "not a regular file";
}

uint64_t parse_byte_size(const char* text) {
  char* end = nullptr;
  double v = std::strtod(text, &end);
  if (end == text || !std::isfinite(v) || v <= 0)
    throw Error(std::string("'") + text + "' is not a size like 512M or 8G");
  std::string unit(end);
  for (auto& c : unit) c = char(std::toupper(static_cast<unsigned char>(c)));
  double mul = 1;
  if (unit.empty() || unit == "B")
    mul = 1;
  else if (unit == "K" || unit == "KB" || unit == "KIB")
    mul = 1024.0;
  else if (unit == "M" || unit == "MB" || unit == "MIB")
    mul = 1024.0 * 1024;
  else if (unit == "G" || unit == "GB" || unit == "GIB")
    mul = 1024.0 * 1024 * 1024;
  else if (unit == "T" || unit == "TB" || unit == "TIB")
    mul = 1024.0 * 1024 * 1024 * 1024;
  else
    throw Error(std::string("'") + text + "' is not a size like 512M or 8G");
  double bytes = v * mul;
  if (bytes >= 1.8e19) throw Error(std::string("'") + text + "' is too large a size");
  return uint64_t(bytes);
}

size_t advise_huge_pages(const void* data, size_t bytes, HugePages kind) {
#if defined(__linux__) && defined(MADV_HUGEPAGE)
  constexpr uintptr_t kHuge = uintptr_t(2) << 20;
  // The bulk arrays opt-in, the DAG's words opt-out (system.hpp HugePages):
  // on this project's VMs the first touch of huge pages for all ~3 GiB of a
  // 16384^3 scene cost up to 15 s of kernel time, the words' 204 MiB none
  // measurable (docs/BENCHMARKS.md, "16K³ against 2K³ at LOD 1").
  static const char* env = std::getenv("VOXCAST_HUGE_PAGES");
  static const bool bulk = env != nullptr && std::string_view(env) == "1";
  static const bool hot = env == nullptr || std::string_view(env) != "0";
  const bool on = kind == HugePages::kHot ? hot : bulk;
  const uintptr_t begin = (reinterpret_cast<uintptr_t>(data) + kHuge - 1) / kHuge * kHuge;
  const uintptr_t end = (reinterpret_cast<uintptr_t>(data) + bytes) / kHuge * kHuge;
  if (!on || data == nullptr || end <= begin) return 0;
  void* p = reinterpret_cast<void*>(begin);
  if (madvise(p, end - begin, MADV_HUGEPAGE) != 0) return 0;
  return size_t(end - begin);
#else
  (void)data, (void)bytes, (void)kind;
  return 0;
#endif
}

}  // namespace voxcast
