// The .vxc section container (byte layout: include/voxcast/container.hpp).
//
// ContainerReader accepts exactly the canonical layout of each version:
// every offset, size and count must be the one a writer would have produced
// for the directory's sections, so together with the hashes any corruption
// of a written file is detected before the sections are interpreted.
#include "voxcast/container.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>
#include <xxhash.h>

#include <algorithm>
#include <bit>
#include <cerrno>
#include <cstring>
#include <string>
#include <unordered_set>

#include "io/atomic_file.hpp"
#include "voxcast/error.hpp"
#include "voxcast/progress.hpp"

namespace voxcast {
namespace {

using namespace container_layout;

static_assert(std::endian::native == std::endian::little,
              "the format is little-endian and read by memcpy, as on x86-64");

uint64_t align8(uint64_t x) {
  return (x + 7) & ~uint64_t(7);
}

[[noreturn]] void corrupt(const std::string& what) {
  throw Error("corrupt scene: " + what);
}

/// Chunks a section of `size` bytes takes at `chunk_bytes` per chunk.
uint64_t chunks_for(uint64_t size, uint64_t chunk_bytes) {
  return size == 0 ? 1 : (size - 1) / chunk_bytes + 1;
}

}  // namespace

std::string fourcc_name(uint32_t id) {
  std::string s;
  for (int i = 0; i < 4; ++i) {
    const char c = char((id >> (8 * i)) & 0xFF);
    s += (c >= 0x20 && c < 0x7F) ? c : '?';
  }
  return s;
}

// ---------------------------------------------------------------- reading

class ContainerReader::Source {
 public:
  virtual ~Source() = default;
  virtual uint64_t size() const = 0;
  /// Exactly n bytes at offset (the caller checked the range against size()).
  virtual void read(uint64_t offset, void* dst, size_t n) const = 0;
};

namespace {

class MemorySource final : public ContainerReader::Source {
 public:
  MemorySource(const uint8_t* data, size_t size) : data_(data), size_(size) {}
  explicit MemorySource(std::vector<uint8_t> bytes)
      : owned_(std::move(bytes)), data_(owned_.data()), size_(owned_.size()) {}
  uint64_t size() const override { return size_; }
  void read(uint64_t offset, void* dst, size_t n) const override {
    if (n) std::memcpy(dst, data_ + offset, n);
  }

 private:
  std::vector<uint8_t> owned_;
  const uint8_t* data_;
  size_t size_;
};

class FileSource final : public ContainerReader::Source {
 public:
  explicit FileSource(const std::filesystem::path& path) : name_(path.string()) {
    std::error_code ec;
    const auto status = std::filesystem::status(path, ec);
    if (!std::filesystem::exists(status))
      throw Error("cannot open scene file '" + name_ + "': no such file");
    if (std::filesystem::is_directory(status))
      throw Error("cannot open scene file '" + name_ + "': it is a directory");
    fd_ = ::open(name_.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd_ < 0) throw Error("cannot open scene file '" + name_ + "': " + std::strerror(errno));
    struct stat st;
    if (::fstat(fd_, &st) != 0 || !S_ISREG(st.st_mode) || st.st_size < 0) {
      ::close(fd_);
      throw Error("cannot read scene file '" + name_ + "': not a regular file");
    }
    size_ = uint64_t(st.st_size);
  }
  ~FileSource() override { ::close(fd_); }
  uint64_t size() const override { return size_; }
  void read(uint64_t offset, void* dst, size_t n) const override {
    auto* p = static_cast<char*>(dst);
    while (n > 0) {
      const ssize_t got = ::pread(fd_, p, n, off_t(offset));
      if (got < 0 && errno == EINTR) continue;
      if (got < 0) throw Error("cannot read scene file '" + name_ + "': " + std::strerror(errno));
      if (got == 0) throw Error("cannot read scene file '" + name_ + "': it shrank while open");
      p += got;
      offset += uint64_t(got);
      n -= size_t(got);
    }
  }

 private:
  std::string name_;
  int fd_ = -1;
  uint64_t size_ = 0;
};

}  // namespace

ContainerReader ContainerReader::open(const std::filesystem::path& path) {
  ContainerReader r;
  r.source_ = std::make_shared<FileSource>(path);
  r.load_directory();
  return r;
}

ContainerReader ContainerReader::from_bytes(std::vector<uint8_t> bytes) {
  ContainerReader r;
  r.source_ = std::make_shared<MemorySource>(std::move(bytes));
  r.load_directory();
  return r;
}

ContainerReader ContainerReader::from_memory(const uint8_t* data, size_t size) {
  ContainerReader r;
  r.source_ = std::make_shared<MemorySource>(data, size);
  r.load_directory();
  return r;
}

void ContainerReader::fetch(uint64_t offset, void* dst, size_t n) const {
  source_->read(offset, dst, n);
  bytes_read_ += n;
  if (progress_.p) progress_.p->advance(n);
}

void ContainerReader::load_directory() {
  file_bytes_ = source_->size();
  if (file_bytes_ < sizeof(FileHeaderV1)) throw Error("not a voxcast scene file (too short)");
  // The longer (version 2) header at once, as far as the file goes.
  head_bytes_ = size_t(std::min<uint64_t>(file_bytes_, sizeof head_));
  fetch(0, head_, head_bytes_);
  FileHeaderV1 h;
  std::memcpy(&h, head_, sizeof h);
  if (std::memcmp(h.magic, kMagic, 8) != 0) throw Error("not a voxcast scene file (bad magic)");
  version_ = h.version;
  if (version_ > kSceneFormatVersion)
    throw Error("scene file version " + std::to_string(version_) + " is newer than this voxcast (" +
                std::to_string(kSceneFormatVersion) + ")");
  if (version_ == 0) corrupt("version 0");
  if (version_ == 1)
    load_directory_v1();
  else
    load_directory_v2();
  verified_.assign(hashes_.size(), 0);
}

namespace {
/// Checks that [from, to) of the source is zero (the alignment padding,
/// at most 7 bytes, which no hash covers).
template <class Fetch>
void check_zero_padding(Fetch&& fetch, uint64_t from, uint64_t to, const std::string& where) {
  uint8_t pad[8] = {};
  if (to <= from) return;
  fetch(from, pad, size_t(to - from));
  for (uint64_t i = 0; i < to - from; ++i)
    if (pad[i] != 0) corrupt("non-zero padding " + where);
}
}  // namespace

void ContainerReader::load_directory_v1() {
  const uint64_t size = file_bytes_;
  FileHeaderV1 h;
  std::memcpy(&h, head_, sizeof h);
  const uint64_t count = h.section_count;
  if (count > (size - sizeof h) / sizeof(SectionEntryV1)) corrupt("section table truncated");
  std::vector<SectionEntryV1> table(static_cast<size_t>(count));
  if (count) fetch(sizeof h, table.data(), table.size() * sizeof(SectionEntryV1));
  auto get = [this](uint64_t o, void* d, size_t n) { fetch(o, d, n); };
  uint64_t expected = sizeof h + sizeof(SectionEntryV1) * count;  // canonical next offset
  for (uint64_t i = 0; i < count; ++i) {
    const SectionEntryV1& e = table[size_t(i)];
    const std::string name = fourcc_name(e.fourcc);
    if (i > 0 && e.fourcc == table[size_t(i - 1)].fourcc) corrupt("duplicate section " + name);
    if (i > 0 && e.fourcc < table[size_t(i - 1)].fourcc)
      corrupt("section table out of order at " + name);
    if (e.reserved != 0) corrupt("reserved field set in section " + name);
    check_zero_padding(get, expected, std::min<uint64_t>(align8(expected), size),
                       "before section " + name);
    expected = align8(expected);
    if (e.offset != expected) corrupt("section " + name + " at unexpected offset");
    if (e.offset > size || e.size > size - e.offset) corrupt("section " + name + " truncated");
    SectionInfo s;
    s.id = e.fourcc;
    s.offset = e.offset;
    s.size = e.size;
    s.chunk_bytes = e.size;
    s.chunk_count = 1;
    s.first_chunk = hashes_.size();
    sections_.push_back(s);
    hashes_.push_back(e.hash);
    expected = e.offset + e.size;
  }
  if (size < align8(expected)) corrupt("file truncated");
  if (size > align8(expected)) corrupt("trailing data after the last section");
  check_zero_padding(get, expected, size, "at the end of the file");
}

void ContainerReader::load_directory_v2() {
  const uint64_t size = file_bytes_;
  if (head_bytes_ < sizeof(FileHeader)) corrupt("header truncated");
  FileHeader h;
  std::memcpy(&h, head_, sizeof h);
  const uint64_t count = h.section_count;
  // Counts and sizes against the file before anything is allocated.
  if (h.directory_offset > size || h.directory_offset < sizeof h)
    corrupt("directory offset out of range");
  if (h.directory_bytes != size - h.directory_offset)
    corrupt("directory size does not match the file size");
  if (count > h.directory_bytes / sizeof(SectionEntry)) corrupt("section count too large");
  std::vector<uint8_t> dir(size_t(h.directory_bytes));
  if (!dir.empty()) fetch(h.directory_offset, dir.data(), dir.size());
  XXH64_state_t* state = XXH64_createState();
  XXH64_reset(state, 0);
  XXH64_update(state, &h, kHashedHeaderBytes);
  XXH64_update(state, dir.data(), dir.size());
  const uint64_t hash = XXH64_digest(state);
  XXH64_freeState(state);
  if (hash != h.directory_hash) corrupt("checksum mismatch in the section directory");

  auto get = [this](uint64_t o, void* d, size_t n) { fetch(o, d, n); };
  const uint64_t table_bytes = count * sizeof(SectionEntry);
  uint64_t hash_words = (h.directory_bytes - table_bytes) / 8;
  if ((h.directory_bytes - table_bytes) % 8 != 0) corrupt("chunk table size is not 8 * chunks");
  uint64_t expected = sizeof h;  // canonical offset of the next section
  std::unordered_set<uint32_t> seen;
  for (uint64_t i = 0; i < count; ++i) {
    SectionEntry e;
    std::memcpy(&e, dir.data() + i * sizeof e, sizeof e);
    const std::string name = fourcc_name(e.fourcc);
    if (!seen.insert(e.fourcc).second) corrupt("duplicate section " + name);
    check_zero_padding(get, expected, std::min(align8(expected), size), "before section " + name);
    expected = align8(expected);
    if (e.offset != expected) corrupt("section " + name + " at unexpected offset");
    if (e.offset > h.directory_offset || e.size > h.directory_offset - e.offset)
      corrupt("section " + name + " overlaps the directory");
    if (e.chunk_bytes == 0) corrupt("section " + name + " has chunks of 0 bytes");
    if (e.chunk_count != chunks_for(e.size, e.chunk_bytes))
      corrupt("section " + name + " chunk count does not match its size");
    if (e.chunk_count > hash_words) corrupt("chunk table truncated at section " + name);
    hash_words -= e.chunk_count;
    SectionInfo s;
    s.id = e.fourcc;
    s.offset = e.offset;
    s.size = e.size;
    s.chunk_bytes = e.chunk_bytes;
    s.chunk_count = e.chunk_count;
    s.first_chunk = hashes_.size();
    sections_.push_back(s);
    for (uint32_t c = 0; c < e.chunk_count; ++c) {
      uint64_t v;
      std::memcpy(&v, dir.data() + table_bytes + 8 * (s.first_chunk + c), 8);
      hashes_.push_back(v);
    }
    expected = e.offset + e.size;
  }
  if (hash_words != 0) corrupt("chunk table longer than the sections' chunks");
  check_zero_padding(get, expected, std::min(align8(expected), h.directory_offset),
                     "before the directory");
  if (h.directory_offset != align8(expected)) corrupt("directory at unexpected offset");
}

const SectionInfo* ContainerReader::find(uint32_t id) const {
  for (const SectionInfo& s : sections_)
    if (s.id == id) return &s;
  return nullptr;
}

const SectionInfo& ContainerReader::section(uint32_t id) const {
  const SectionInfo* s = find(id);
  if (!s) throw Error("scene file has no " + fourcc_name(id) + " section");
  return *s;
}

std::vector<uint32_t> ContainerReader::section_ids() const {
  std::vector<uint32_t> ids;
  for (const SectionInfo& s : sections_) ids.push_back(s.id);
  std::sort(ids.begin(), ids.end());
  return ids;
}

void ContainerReader::read_chunk_into(const SectionInfo& s, uint32_t chunk, uint8_t* dst) const {
  const uint64_t n = s.chunk_size(chunk);
  fetch(s.chunk_offset(chunk), dst, size_t(n));
  const size_t k = s.first_chunk + chunk;
  if (XXH64(dst, size_t(n), 0) != hashes_[k]) {
    if (s.chunk_count == 1) corrupt("checksum mismatch in section " + fourcc_name(s.id));
    corrupt("checksum mismatch in section " + fourcc_name(s.id) + " chunk " +
            std::to_string(chunk) + " of " + std::to_string(s.chunk_count));
  }
  verified_[k] = 1;
}

std::vector<uint8_t> ContainerReader::read(uint32_t id) const {
  std::vector<uint8_t> out(size_t(section(id).size));
  read_into(id, out.data(), out.size());
  return out;
}

void ContainerReader::read_into(uint32_t id, void* dst, uint64_t bytes) const {
  const SectionInfo& s = section(id);
  if (bytes != s.size)
    throw Error("section " + fourcc_name(id) + " holds " + std::to_string(s.size) +
                " bytes, not the " + std::to_string(bytes) + " asked for");
  uint8_t* out = static_cast<uint8_t*>(dst);
  for (uint32_t c = 0; c < s.chunk_count; ++c)
    read_chunk_into(s, c, out + uint64_t(c) * s.chunk_bytes);
}

std::vector<uint8_t> ContainerReader::read_chunk(uint32_t id, uint32_t chunk) const {
  const SectionInfo& s = section(id);
  if (chunk >= s.chunk_count)
    throw Error("section " + fourcc_name(id) + " has no chunk " + std::to_string(chunk) + " (" +
                std::to_string(s.chunk_count) + " chunks)");
  std::vector<uint8_t> out(size_t(s.chunk_size(chunk)));
  read_chunk_into(s, chunk, out.data());
  return out;
}

void ContainerReader::verify_all() const {
  std::vector<uint8_t> buffer;
  for (const SectionInfo& s : sections_)
    for (uint32_t c = 0; c < s.chunk_count; ++c) {
      if (verified_[s.first_chunk + c]) continue;
      buffer.resize(size_t(s.chunk_size(c)));
      read_chunk_into(s, c, buffer.data());
    }
}

// ---------------------------------------------------------------- writing

class ContainerWriter::Sink {
 public:
  virtual ~Sink() = default;
  virtual void write_at(uint64_t offset, const void* data, size_t size) = 0;
  virtual void commit() = 0;
};

struct ContainerWriter::HashState {
  HashState() : state(XXH64_createState()) { XXH64_reset(state, 0); }
  ~HashState() { XXH64_freeState(state); }
  HashState(const HashState&) = delete;
  HashState& operator=(const HashState&) = delete;
  XXH64_state_t* state;
};

namespace {

class FileSink final : public ContainerWriter::Sink {
 public:
  explicit FileSink(const std::filesystem::path& path) : file_(path) {}
  void write_at(uint64_t offset, const void* data, size_t size) override {
    file_.write_at(offset, data, size);
  }
  void commit() override { file_.commit(); }

 private:
  io::AtomicFile file_;
};

class MemorySink final : public ContainerWriter::Sink {
 public:
  explicit MemorySink(std::vector<uint8_t>* out) : out_(out) { out_->clear(); }
  void write_at(uint64_t offset, const void* data, size_t size) override {
    if (out_->size() < offset + size) out_->resize(size_t(offset + size));
    if (size) std::memcpy(out_->data() + offset, data, size);
  }
  void commit() override {}

 private:
  std::vector<uint8_t>* out_;
};

}  // namespace

ContainerWriter::ContainerWriter(const std::filesystem::path& path, uint64_t chunk_bytes)
    : sink_(std::make_unique<FileSink>(path)), default_chunk_bytes_(chunk_bytes) {
  if (chunk_bytes == 0) throw Error("ContainerWriter: chunk size 0");
  position_ = sizeof(FileHeader);  // written by commit()
}

ContainerWriter::ContainerWriter(std::vector<uint8_t>* out, uint64_t chunk_bytes)
    : sink_(std::make_unique<MemorySink>(out)), default_chunk_bytes_(chunk_bytes) {
  if (chunk_bytes == 0) throw Error("ContainerWriter: chunk size 0");
  position_ = sizeof(FileHeader);
}

ContainerWriter::~ContainerWriter() = default;  // the FileSink removes an uncommitted temporary

void ContainerWriter::put(const void* data, size_t size) {
  sink_->write_at(position_, data, size);
  position_ += size;
  if (progress_) progress_->advance(size);
}

void ContainerWriter::begin_section(uint32_t id, uint64_t chunk_bytes) {
  if (committed_) throw Error("ContainerWriter: section after commit()");
  if (open_) throw Error("ContainerWriter: section " + fourcc_name(id) + " begun inside another");
  for (const SectionEntry& e : entries_)
    if (e.fourcc == id) throw Error("ContainerWriter: duplicate section " + fourcc_name(id));
  static const uint8_t kZeros[8] = {};
  put(kZeros, size_t(align8(position_) - position_));
  current_ = SectionEntry{};
  current_.fourcc = id;
  current_.offset = position_;
  current_.chunk_bytes = chunk_bytes ? chunk_bytes : default_chunk_bytes_;
  hash_ = std::make_unique<HashState>();
  chunk_fill_ = 0;
  open_ = true;
}

void ContainerWriter::finish_chunk() {
  hashes_.push_back(XXH64_digest(hash_->state));
  XXH64_reset(hash_->state, 0);
  chunk_fill_ = 0;
}

void ContainerWriter::append(const void* data, size_t size) {
  if (!open_) throw Error("ContainerWriter: append outside a section");
  const auto* p = static_cast<const uint8_t*>(data);
  while (size > 0) {
    // A full chunk is closed only when more bytes follow, so that a section
    // of exactly k chunks has k hashes (and an empty one has one).
    if (chunk_fill_ == current_.chunk_bytes) finish_chunk();
    const size_t n = size_t(std::min<uint64_t>(size, current_.chunk_bytes - chunk_fill_));
    XXH64_update(hash_->state, p, n);
    put(p, n);
    chunk_fill_ += n;
    current_.size += n;
    p += n;
    size -= n;
  }
}

void ContainerWriter::end_section() {
  if (!open_) throw Error("ContainerWriter: end_section without begin_section");
  finish_chunk();
  const uint64_t chunks = chunks_for(current_.size, current_.chunk_bytes);
  if (chunks > UINT32_MAX)
    throw Error("ContainerWriter: section " + fourcc_name(current_.fourcc) +
                " has more than 2^32 chunks; use larger chunks");
  current_.chunk_count = uint32_t(chunks);
  entries_.push_back(current_);
  hash_.reset();
  open_ = false;
}

void ContainerWriter::add(uint32_t id, const void* data, size_t size) {
  begin_section(id);
  append(data, size);
  end_section();
}

void ContainerWriter::commit() {
  if (open_)
    throw Error("ContainerWriter: commit() inside section " + fourcc_name(current_.fourcc));
  if (committed_) throw Error("ContainerWriter: commit() twice");
  static const uint8_t kZeros[8] = {};
  put(kZeros, size_t(align8(position_) - position_));
  FileHeader h{};
  std::memcpy(h.magic, kMagic, 8);
  h.version = kSceneFormatVersion;
  h.section_count = uint32_t(entries_.size());
  h.directory_offset = position_;
  h.directory_bytes = entries_.size() * sizeof(SectionEntry) + hashes_.size() * 8;
  HashState dir;
  XXH64_update(dir.state, &h, kHashedHeaderBytes);
  XXH64_update(dir.state, entries_.data(), entries_.size() * sizeof(SectionEntry));
  XXH64_update(dir.state, hashes_.data(), hashes_.size() * 8);
  h.directory_hash = XXH64_digest(dir.state);
  put(entries_.data(), entries_.size() * sizeof(SectionEntry));
  put(hashes_.data(), hashes_.size() * 8);
  sink_->write_at(0, &h, sizeof h);
  sink_->commit();
  committed_ = true;
}

// ---------------------------------------------------------------- in memory

void Container::add(uint32_t id, std::vector<uint8_t> bytes) {
  sections_[id] = std::move(bytes);
}

const std::vector<uint8_t>& Container::get(uint32_t id) const {
  auto it = sections_.find(id);
  if (it == sections_.end()) throw Error("scene file has no " + fourcc_name(id) + " section");
  return it->second;
}

std::vector<uint32_t> Container::section_ids() const {
  std::vector<uint32_t> ids;
  for (const auto& s : sections_) ids.push_back(s.first);
  return ids;
}

std::vector<uint8_t> Container::serialize() const {
  std::vector<uint8_t> out;
  ContainerWriter w(&out);
  for (const auto& [id, bytes] : sections_) w.add(id, bytes);
  w.commit();
  return out;
}

Container Container::from_reader(const ContainerReader& reader) {
  Container c;
  for (const SectionInfo& s : reader.sections()) c.sections_[s.id] = reader.read(s.id);
  return c;
}

Container Container::parse(const uint8_t* data, size_t size) {
  return from_reader(ContainerReader::from_memory(data, size));
}

void Container::write(const std::filesystem::path& path) const {
  ContainerWriter w(path);
  for (const auto& [id, bytes] : sections_) w.add(id, bytes);
  w.commit();
}

Container Container::read(const std::filesystem::path& path) {
  return from_reader(ContainerReader::open(path));
}

}  // namespace voxcast
