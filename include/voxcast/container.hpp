#pragma once
// The .vxc section container: a file of named sections (fourcc ids) that a
// reader opens by its directory alone and reads one section, or one chunk of
// a section, at a time; a writer that appends sections to a temporary file
// as they are produced and renames it into place. It knows no structure:
// scene formats (format_registry.hpp) give the sections their meaning.
//
// ---- Byte layout, version 2 (written today) ----
// All integers little-endian; the layout structs below are the definition.
//
//   offset 0          FileHeader (40 bytes)
//          40         the sections, in the order they were written, each
//                     starting at the next multiple of 8 after the previous
//                     one (the first at 40); padding bytes are zero
//          D          the directory, at the first multiple of 8 after the
//                     last section (40 when there are none):
//                       N x SectionEntry (32 bytes each, file order), then
//                       the chunk hash table: for each entry in order, its
//                       chunk_count u64 xxh64 hashes (seed 0), one per chunk
//          D + B      end of file (B = header.directory_bytes)
//
// A section of `size` bytes is stored as chunk_count = max(1,
// ceil(size / chunk_bytes)) chunks: chunk i starts at offset + i * chunk_bytes
// and every chunk but the last is chunk_bytes long. A section smaller than
// its chunk size (most) is one chunk; a large one can be read and verified a
// chunk at a time. header.directory_hash is the xxh64 of the header's first
// 32 bytes followed by the directory, so every byte of a file is either a
// fixed value (magic, padding), determined by the others (offsets, counts,
// sizes: ContainerReader checks they are the canonical ones) or covered by a
// hash. The directory sits at the end so that a writer never needs to know a
// section's size before producing it; the header is written last.
//
// ---- Version 1 (read, never written) ----
//   offset 0   FileHeaderV1 (16 bytes), then N x SectionEntryV1 (32 bytes,
//              ascending fourcc), then the sections in table order at the
//              next multiple of 8, zero padding, the file ends at the end of
//              the last section rounded up to 8. Each section is one chunk
//              whose hash sits in its entry.
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <map>
#include <memory>
#include <string>
#include <vector>

namespace voxcast {

class Progress;

/// The version ContainerWriter writes; ContainerReader reads 1 and 2.
inline constexpr uint32_t kSceneFormatVersion = 2;
/// Default chunk size of written sections: a reader that wants one piece of
/// a large section reads and hashes at most this much more than it needs.
inline constexpr uint64_t kDefaultChunkBytes = uint64_t(1) << 20;

constexpr uint32_t fourcc(const char (&s)[5]) {
  return uint32_t(uint8_t(s[0])) | uint32_t(uint8_t(s[1])) << 8 | uint32_t(uint8_t(s[2])) << 16 |
         uint32_t(uint8_t(s[3])) << 24;
}

/// The four characters of a section id ('?' for unprintable bytes).
std::string fourcc_name(uint32_t fourcc);

namespace container_layout {
inline constexpr char kMagic[8] = {'V', 'O', 'X', 'C', 'A', 'S', 'T', '\0'};

struct FileHeader {           // version 2
  char magic[8];              // kMagic
  uint32_t version;           // 2
  uint32_t section_count;     // N
  uint64_t directory_offset;  // D
  uint64_t directory_bytes;   // 32 N + 8 (sum of chunk counts)
  uint64_t directory_hash;    // xxh64(header bytes 0..31, then the directory)
};
static_assert(sizeof(FileHeader) == 40 && offsetof(FileHeader, version) == 8 &&
              offsetof(FileHeader, section_count) == 12 &&
              offsetof(FileHeader, directory_offset) == 16 &&
              offsetof(FileHeader, directory_bytes) == 24 &&
              offsetof(FileHeader, directory_hash) == 32);
inline constexpr size_t kHashedHeaderBytes = offsetof(FileHeader, directory_hash);

struct SectionEntry {  // version 2
  uint32_t fourcc;
  uint32_t chunk_count;  // max(1, ceil(size / chunk_bytes))
  uint64_t offset;       // canonical: see the layout above
  uint64_t size;         // payload bytes
  uint64_t chunk_bytes;  // >= 1
};
static_assert(sizeof(SectionEntry) == 32 && offsetof(SectionEntry, chunk_count) == 4 &&
              offsetof(SectionEntry, offset) == 8 && offsetof(SectionEntry, size) == 16 &&
              offsetof(SectionEntry, chunk_bytes) == 24);

struct FileHeaderV1 {
  char magic[8];
  uint32_t version;  // 1
  uint32_t section_count;
};
static_assert(sizeof(FileHeaderV1) == 16 && offsetof(FileHeaderV1, section_count) == 12);

struct SectionEntryV1 {
  uint32_t fourcc;
  uint32_t reserved;  // 0
  uint64_t offset;
  uint64_t size;
  uint64_t hash;  // xxh64(section bytes, seed 0)
};
static_assert(sizeof(SectionEntryV1) == 32 && offsetof(SectionEntryV1, offset) == 8 &&
              offsetof(SectionEntryV1, size) == 16 && offsetof(SectionEntryV1, hash) == 24);
}  // namespace container_layout

/// One section as the directory describes it.
struct SectionInfo {
  uint32_t id = 0;
  uint64_t offset = 0, size = 0;
  uint64_t chunk_bytes = 0;  // version 1: the section size (one chunk)
  uint32_t chunk_count = 1;
  size_t first_chunk = 0;  // index of its first chunk in the reader's chunk list
  /// Offset and length of chunk `i` in the file.
  uint64_t chunk_offset(uint32_t i) const { return offset + uint64_t(i) * chunk_bytes; }
  uint64_t chunk_size(uint32_t i) const {
    return i + 1 == chunk_count ? size - uint64_t(i) * chunk_bytes : chunk_bytes;
  }
};

/// Reads a container by its directory: open() reads and fully validates the
/// header and directory (offsets, sizes, counts against the file size, no
/// overlaps, zero padding, the directory hash) and nothing else; sections
/// and chunks are read on demand (pread), each chunk checked against its
/// hash before it is handed out. Every failure is a one-line voxcast::Error.
/// Copies share the open file. Not for concurrent use from several threads
/// (the read counters are plain members).
class ContainerReader {
 public:
  /// Throws voxcast::Error naming the file when it cannot be opened.
  static ContainerReader open(const std::filesystem::path& path);
  /// A container in memory (the bytes are kept).
  static ContainerReader from_bytes(std::vector<uint8_t> bytes);
  /// A container in caller-owned memory that outlives the reader.
  static ContainerReader from_memory(const uint8_t* data, size_t size);

  uint32_t version() const { return version_; }
  uint64_t file_bytes() const { return file_bytes_; }
  bool has(uint32_t id) const { return find(id) != nullptr; }
  const SectionInfo* find(uint32_t id) const;
  /// Throws voxcast::Error ("scene file has no XXXX section") when missing.
  const SectionInfo& section(uint32_t id) const;
  std::vector<uint32_t> section_ids() const;  // ascending
  /// The directory in file order.
  const std::vector<SectionInfo>& sections() const { return sections_; }

  /// The whole section, every chunk verified.
  std::vector<uint8_t> read(uint32_t id) const;
  /// The whole section straight into caller memory of exactly the section's
  /// size (a structure's own storage: no second copy), every chunk verified.
  /// Throws voxcast::Error when `bytes` is not the section's size.
  void read_into(uint32_t id, void* dst, uint64_t bytes) const;
  /// One chunk, verified; reads nothing else.
  std::vector<uint8_t> read_chunk(uint32_t id, uint32_t chunk) const;
  /// Reads and verifies every chunk not yet verified (in pieces of at most
  /// one chunk): after it, every byte of the file has been checked.
  void verify_all() const;

  /// Bytes fetched from the file or buffer so far (header and directory
  /// included): what a streaming caller pays.
  uint64_t bytes_read() const { return bytes_read_; }
  /// Advance `progress` by every byte fetched from now on (optional; a copy
  /// of the reader does not report: it may outlive the bar).
  void set_progress(Progress* progress) const { progress_.p = progress; }

  class Source;  // the file or buffer (container.cpp)

 private:
  ContainerReader() = default;
  void load_directory();
  void load_directory_v1();
  void load_directory_v2();
  void fetch(uint64_t offset, void* dst, size_t n) const;
  void read_chunk_into(const SectionInfo& s, uint32_t chunk, uint8_t* dst) const;

  std::shared_ptr<const Source> source_;
  uint8_t head_[sizeof(container_layout::FileHeader)] = {};  // the file's first bytes
  size_t head_bytes_ = 0;
  uint32_t version_ = 0;
  uint64_t file_bytes_ = 0;
  std::vector<SectionInfo> sections_;
  std::vector<uint64_t> hashes_;           // every chunk's, directory order
  mutable std::vector<uint8_t> verified_;  // per chunk
  mutable uint64_t bytes_read_ = 0;
  struct ProgressRef {  // not copied (see set_progress)
    Progress* p = nullptr;
    ProgressRef() = default;
    ProgressRef(const ProgressRef&) {}
    ProgressRef& operator=(const ProgressRef&) { return *this; }
  };
  mutable ProgressRef progress_;
};

/// Writes a container section by section without holding it: each section is
/// appended to a temporary file beside `path` (`<path>.tmp.<pid>`, the name
/// apps/voxcast/cli_io.hpp cleans up on a signal) as it is produced, with
/// its chunk hashes computed on the way; commit() appends the directory,
/// writes the header, fsyncs and renames onto `path`. Destroyed without
/// commit(), it removes the temporary and leaves `path` untouched.
class ContainerWriter {
 public:
  explicit ContainerWriter(const std::filesystem::path& path,
                           uint64_t chunk_bytes = kDefaultChunkBytes);
  /// Into memory: commit() leaves the file bytes in *out.
  explicit ContainerWriter(std::vector<uint8_t>* out, uint64_t chunk_bytes = kDefaultChunkBytes);
  ~ContainerWriter();
  ContainerWriter(const ContainerWriter&) = delete;
  ContainerWriter& operator=(const ContainerWriter&) = delete;

  /// A whole section at once.
  void add(uint32_t id, const void* data, size_t size);
  void add(uint32_t id, const std::vector<uint8_t>& bytes) { add(id, bytes.data(), bytes.size()); }
  /// A section produced in pieces: begin, append any number of times, end.
  /// `chunk_bytes` 0 = the writer's default.
  void begin_section(uint32_t id, uint64_t chunk_bytes = 0);
  void append(const void* data, size_t size);
  void end_section();
  void commit();

  uint64_t bytes_written() const { return position_; }
  /// Advance `progress` by every byte written from now on (optional).
  void set_progress(Progress* progress) { progress_ = progress; }

  class Sink;  // the temporary file or memory (container.cpp)

 private:
  void put(const void* data, size_t size);
  void finish_chunk();

  std::unique_ptr<Sink> sink_;
  uint64_t default_chunk_bytes_;
  uint64_t position_ = 0;
  std::vector<container_layout::SectionEntry> entries_;
  std::vector<uint64_t> hashes_;
  // The open section: its entry, its current chunk's hash state and fill.
  bool open_ = false;
  container_layout::SectionEntry current_{};
  struct HashState;
  std::unique_ptr<HashState> hash_;
  uint64_t chunk_fill_ = 0;
  bool committed_ = false;
  Progress* progress_ = nullptr;
};

/// A whole container in memory (tests, tools, small scenes): every section
/// held as bytes, ids unique.
class Container {
 public:
  void add(uint32_t fourcc, std::vector<uint8_t> bytes);
  bool has(uint32_t fourcc) const { return sections_.count(fourcc) != 0; }
  /// Throws voxcast::Error when missing.
  const std::vector<uint8_t>& get(uint32_t fourcc) const;
  std::vector<uint32_t> section_ids() const;

  /// Current-version file bytes (sections in ascending fourcc order).
  std::vector<uint8_t> serialize() const;
  static Container parse(const uint8_t* data, size_t size);  // throws voxcast::Error
  static Container from_reader(const ContainerReader& reader);
  void write(const std::filesystem::path& path) const;       // atomic
  static Container read(const std::filesystem::path& path);  // throws voxcast::Error

 private:
  std::map<uint32_t, std::vector<uint8_t>> sections_;
};

}  // namespace voxcast
