#pragma once
// A file written under a temporary name beside its target and renamed into
// place by commit(), so readers see the old file or the whole new one, never
// a partial one. The temporary is `<target>.tmp.<pid>`: the name the CLI's
// output staging (apps/voxcast/cli_io.hpp) registers for cleanup on a signal.
// Used by write_file_atomic (image.hpp) and ContainerWriter (container.hpp).
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <string>

namespace voxcast::io {

class AtomicFile {
 public:
  /// Creates the temporary; throws voxcast::Error ("cannot write TARGET: ...").
  explicit AtomicFile(const std::filesystem::path& target);
  /// Without commit(): removes the temporary, the target is untouched.
  ~AtomicFile();
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;

  void write_at(uint64_t offset, const void* bytes, size_t size);
  /// fsync, close, rename onto the target, fsync its directory.
  void commit();

 private:
  [[noreturn]] void fail(const char* what, int err);
  std::filesystem::path path_;
  std::string target_, tmp_;
  int fd_ = -1;
};

}  // namespace voxcast::io
