// The .vxc section container (layout: include/voxcast/scene_file.hpp).
//
//   offset 0   char[8]  magic "VOXCAST\0"
//          8   u32      version (kSceneFormatVersion)
//         12   u32      section count N
//         16   N x 32-byte table entries, ascending fourcc:
//                 +0 u32 fourcc  +4 u32 reserved (0)  +8 u64 offset
//                 +16 u64 size   +24 u64 xxh64(section bytes, seed 0)
//   16 + 32N   sections in table order, each starting at the next multiple
//              of 8 after the previous one; padding bytes are zero; the file
//              ends at the end of the last section rounded up to 8.
//
// parse() accepts exactly this canonical layout. Because every byte is then
// either checked against a fixed value or covered by a hash, any corruption
// of a written file is detected before the sections are interpreted.
#include <xxhash.h>

#include <algorithm>
#include <bit>
#include <cstring>
#include <fstream>
#include <string>

#include "voxcast/error.hpp"
#include "voxcast/image.hpp"
#include "voxcast/scene_file.hpp"

namespace voxcast {
namespace {

constexpr char kMagic[8] = {'V', 'O', 'X', 'C', 'A', 'S', 'T', '\0'};
constexpr size_t kHeaderBytes = 16, kEntryBytes = 32;

uint64_t align8(uint64_t x) {
  return (x + 7) & ~uint64_t(7);
}

template <class T>
T load_le(const uint8_t* p) {  // the format is little-endian, as is x86-64
  static_assert(std::endian::native == std::endian::little);
  T v;
  std::memcpy(&v, p, sizeof(T));
  return v;
}
template <class T>
void store_le(uint8_t* p, T v) {
  std::memcpy(p, &v, sizeof(T));
}

[[noreturn]] void corrupt(const std::string& what) {
  throw Error("corrupt scene: " + what);
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
  const uint64_t table_end = kHeaderBytes + kEntryBytes * sections_.size();
  uint64_t end = table_end;
  for (const auto& s : sections_) end = align8(end) + s.second.size();
  std::vector<uint8_t> out(size_t(align8(end)), 0);
  std::memcpy(out.data(), kMagic, 8);
  store_le<uint32_t>(&out[8], kSceneFormatVersion);
  store_le<uint32_t>(&out[12], uint32_t(sections_.size()));
  uint64_t pos = table_end;
  size_t e = kHeaderBytes;
  for (const auto& [id, bytes] : sections_) {
    pos = align8(pos);
    store_le<uint32_t>(&out[e], id);
    store_le<uint32_t>(&out[e + 4], 0);
    store_le<uint64_t>(&out[e + 8], pos);
    store_le<uint64_t>(&out[e + 16], bytes.size());
    store_le<uint64_t>(&out[e + 24], XXH64(bytes.data(), bytes.size(), 0));
    if (!bytes.empty()) std::memcpy(&out[size_t(pos)], bytes.data(), bytes.size());
    pos += bytes.size();
    e += kEntryBytes;
  }
  return out;
}

Container Container::parse(const uint8_t* data, size_t size) {
  if (size < kHeaderBytes) throw Error("not a voxcast scene file (too short)");
  if (std::memcmp(data, kMagic, 8) != 0) throw Error("not a voxcast scene file (bad magic)");
  const uint32_t version = load_le<uint32_t>(data + 8);
  if (version > kSceneFormatVersion)
    throw Error("scene file version " + std::to_string(version) + " is newer than this voxcast (" +
                std::to_string(kSceneFormatVersion) + ")");
  if (version == 0) corrupt("version 0");
  const uint64_t count = load_le<uint32_t>(data + 12);
  if (count > (size - kHeaderBytes) / kEntryBytes) corrupt("section table truncated");
  const uint64_t table_end = kHeaderBytes + kEntryBytes * count;

  Container c;
  uint64_t expected = table_end;  // canonical offset of the next section
  uint32_t previous_id = 0;
  for (uint64_t i = 0; i < count; ++i) {
    const uint8_t* e = data + kHeaderBytes + kEntryBytes * i;
    const uint32_t id = load_le<uint32_t>(e);
    const uint64_t offset = load_le<uint64_t>(e + 8), bytes = load_le<uint64_t>(e + 16);
    const std::string name = fourcc_name(id);
    if (i > 0 && id == previous_id) corrupt("duplicate section " + name);
    if (i > 0 && id < previous_id) corrupt("section table out of order at " + name);
    previous_id = id;
    if (load_le<uint32_t>(e + 4) != 0) corrupt("reserved field set in section " + name);
    // Padding in front of the section must be zero (it is not hashed).
    for (uint64_t p = expected; p < std::min<uint64_t>(align8(expected), size); ++p)
      if (data[p] != 0) corrupt("non-zero padding before section " + name);
    expected = align8(expected);
    if (offset != expected) corrupt("section " + name + " at unexpected offset");
    if (offset > size || bytes > size - offset) corrupt("section " + name + " truncated");
    if (XXH64(data + offset, size_t(bytes), 0) != load_le<uint64_t>(e + 24))
      corrupt("checksum mismatch in section " + name);
    c.sections_[id].assign(data + offset, data + offset + bytes);
    expected = offset + bytes;
  }
  if (size < align8(expected)) corrupt("file truncated");
  if (size > align8(expected)) corrupt("trailing data after the last section");
  for (uint64_t p = expected; p < size; ++p)
    if (data[p] != 0) corrupt("non-zero padding at the end of the file");
  return c;
}

void Container::write(const std::filesystem::path& path) const {
  const std::vector<uint8_t> bytes = serialize();
  write_file_atomic(path, bytes.data(), bytes.size());
}

Container Container::read(const std::filesystem::path& path) {
  std::error_code ec;
  const auto status = std::filesystem::status(path, ec);
  if (!std::filesystem::exists(status))
    throw Error("cannot open scene file '" + path.string() + "': no such file");
  if (std::filesystem::is_directory(status))
    throw Error("cannot open scene file '" + path.string() + "': it is a directory");
  std::ifstream in(path, std::ios::binary | std::ios::ate);
  if (!in) throw Error("cannot open scene file '" + path.string() + "'");
  const std::streamoff size = in.tellg();
  if (size < 0) throw Error("cannot read scene file '" + path.string() + "'");
  std::vector<uint8_t> bytes(static_cast<size_t>(size));
  in.seekg(0);
  if (size > 0 && !in.read(reinterpret_cast<char*>(bytes.data()), size))
    throw Error("cannot read scene file '" + path.string() + "'");
  return parse(bytes.data(), bytes.size());
}

}  // namespace voxcast
