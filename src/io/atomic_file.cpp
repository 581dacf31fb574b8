#include "io/atomic_file.hpp"

#include <fcntl.h>
#include <fmt/format.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "voxcast/error.hpp"

namespace voxcast::io {

AtomicFile::AtomicFile(const std::filesystem::path& target)
    : path_(target), target_(target.string()), tmp_(fmt::format("{}.tmp.{}", target_, ::getpid())) {
  fd_ = ::open(tmp_.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0666);
  if (fd_ < 0) throw Error(fmt::format("cannot write {}: {}", target_, std::strerror(errno)));
}

AtomicFile::~AtomicFile() {
  if (fd_ >= 0) {
    ::close(fd_);
    ::unlink(tmp_.c_str());
  }
}

void AtomicFile::fail(const char* what, int err) {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
  ::unlink(tmp_.c_str());
  throw Error(fmt::format("cannot write {}: {} failed: {}", target_, what, std::strerror(err)));
}

void AtomicFile::write_at(uint64_t offset, const void* bytes, size_t size) {
  if (fd_ < 0) throw Error("cannot write " + target_ + ": the file is closed");
  const auto* p = static_cast<const char*>(bytes);
  while (size > 0) {
    const ssize_t n = ::pwrite(fd_, p, size, off_t(offset));
    if (n < 0) {
      if (errno == EINTR) continue;
      fail("write", errno);
    }
    p += n;
    offset += uint64_t(n);
    size -= size_t(n);
  }
}

void AtomicFile::commit() {
  if (fd_ < 0) throw Error("cannot write " + target_ + ": the file is closed");
  // fsync before rename: otherwise a crash can leave the new name pointing at
  // an empty file on filesystems that reorder metadata and data writes.
  if (::fsync(fd_) != 0) fail("fsync", errno);
  const int rc = ::close(fd_);
  fd_ = -1;
  if (rc != 0) {
    const int err = errno;
    ::unlink(tmp_.c_str());
    throw Error(fmt::format("cannot write {}: close failed: {}", target_, std::strerror(err)));
  }
  if (::rename(tmp_.c_str(), target_.c_str()) != 0) {
    const int err = errno;
    ::unlink(tmp_.c_str());
    throw Error(fmt::format("cannot write {}: rename failed: {}", target_, std::strerror(err)));
  }
  // Persist the rename itself; failure here does not undo the (already visible) write.
  std::filesystem::path dir = path_.parent_path();
  if (dir.empty()) dir = ".";
  const int dfd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dfd >= 0) {
    ::fsync(dfd);
    ::close(dfd);
  }
}

}  // namespace voxcast::io
