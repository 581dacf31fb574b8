// Slices on disk (esvo §7 "Storage on disk", §7.1 split planning): the slice
// file of an in-core octree, and reading it back (header + directory
// verified at open, slice data on demand). Layout: include/voxcast/esvo_slices.hpp.
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>
#include <xxhash.h>

#include <algorithm>
#include <bit>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <sstream>

#include "esvo/compress.hpp"
#include "esvo/layout_internal.hpp"
#include "esvo/slice_plan.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo_slices.hpp"
#include "voxcast/morton.hpp"
#include "voxcast/progress.hpp"

namespace voxcast::esvo {
namespace sl = slice_layout;

namespace {

/// One descriptor of the in-core octree at some level, with what its slice
/// record holds.
struct LevelNode {
  uint64_t code;   // Morton code at its level
  uint32_t slot;   // descriptor slot in the octree
  uint32_t bytes;  // its slice record: 4 + 8 per child + 4 per contour
};

/// Raw attribute words (color, normal) of child c of the descriptor at
/// `slot`: lookup entry -> value (esvo.hpp "Raw attribute attachment"),
/// reached from the slot's page header like EsvoOctree::attributes.
void raw_attribute_words(const uint32_t* w, uint32_t slot, int c, uint32_t* color,
                         uint32_t* normal) {
  const size_t page = size_t(slot & ~(kPageSlots - 1)) * 2;
  const size_t info = size_t(int64_t(page) + int32_t(w[page]));
  const size_t block_first = size_t(int64_t(info) + int32_t(w[info + 1]));
  uint32_t type = 0;
  const size_t attach = detail::find_color_attachment(w, info, &type);
  const size_t rel = size_t(slot) - block_first / 2;
  const uint32_t slots = w[attach];
  const uint32_t entry = w[attach + 2 + rel];
  const uint32_t mask = layout::AttributeMask::get(entry);
  const size_t value =
      layout::ValuePointer::get(entry) + uint32_t(std::popcount(mask & ((1u << c) - 1)));
  const size_t at = attach + 2 + slots + 2 * value;
  *color = w[at];
  *normal = w[at + 1];
}

uint32_t descriptor_word(const uint32_t* w, uint32_t slot, bool contours) {
  const uint32_t w0 = w[size_t(slot) * 2], w1 = w[size_t(slot) * 2 + 1];
  return sl::SliceValid::put(detail::valid_mask(w0)) | sl::SliceLeaf::put(detail::leaf_mask(w0)) |
         (contours ? sl::SliceContourMask::put(detail::contour_mask(w1)) : 0u);
}

/// The descriptors of every level in Morton order: level n + 1 lists the
/// subdivided children of level n's descriptors, in order and slot order.
std::vector<std::vector<LevelNode>> octree_levels(const EsvoOctree& octree, bool contours,
                                                  bool compressed) {
  const uint32_t* w = octree.words.data();
  std::vector<std::vector<LevelNode>> levels;
  auto record = [&](uint64_t code, uint32_t slot) {
    const uint32_t d = descriptor_word(w, slot, contours);
    return LevelNode{
        code, slot,
        detail::slice_record_bytes(std::popcount(sl::SliceValid::get(d)),
                                   std::popcount(sl::SliceContourMask::get(d)), compressed)};
  };
  levels.push_back({record(0, octree.root_slot())});
  while (true) {
    std::vector<LevelNode> next;
    for (const LevelNode& n : levels.back()) {
      const uint32_t w0 = w[size_t(n.slot) * 2];
      const uint32_t sub = detail::non_leaf_mask(w0);
      if (sub == 0) continue;
      const uint32_t first = detail::child_group(w, n.slot);
      uint32_t rank = 0;
      for (int c = 0; c < 8; ++c)
        if (sub >> c & 1u) next.push_back(record(n.code << 3 | uint64_t(c), first + rank++));
    }
    if (next.empty()) break;
    levels.push_back(std::move(next));
  }
  return levels;
}

/// [lo, hi) of the nodes of `level` (node level n) inside the region cube
/// (depth r <= n, code R).
std::pair<size_t, size_t> region_range(const std::vector<LevelNode>& level, int n, int r,
                                       uint64_t R) {
  const int shift = 3 * (n - r);
  const uint64_t lo = R << shift, hi = (R + 1) << shift;
  auto cmp = [](const LevelNode& a, uint64_t v) { return a.code < v; };
  const size_t a = size_t(std::lower_bound(level.begin(), level.end(), lo, cmp) - level.begin());
  const size_t b = size_t(std::lower_bound(level.begin(), level.end(), hi, cmp) - level.begin());
  return {a, b};
}

void write_all(std::ofstream& out, const void* data, size_t bytes) {
  out.write(static_cast<const char*>(data), std::streamsize(bytes));
}

std::string io_error(const std::filesystem::path& path, const std::string& what) {
  return "slice file '" + path.string() + "': " + what;
}

}  // namespace

namespace detail {

void plan_child_slices(std::span<const PlanNode> next, int n, int r, uint32_t parent,
                       uint64_t slice_bytes, std::vector<sl::SliceEntry>* out) {
  if (next.empty()) return;
  // Shallowest split depth k at which every non-empty sub-cube fits.
  int k = r;
  for (; k <= n + 1; ++k) {
    bool fits = true;
    const int shift = 3 * (n + 1 - k);
    for (size_t a = 0; a < next.size() && fits;) {
      const uint64_t key = next[a].code >> shift;
      uint64_t bytes = 0, count = 0;
      size_t b = a;
      for (; b < next.size() && (next[b].code >> shift) == key; ++b)
        bytes += next[b].bytes, ++count;
      fits = bytes <= slice_bytes && count <= sl::kMaxSliceNodes;
      a = b;
    }
    if (fits) break;
  }
  k = std::min(k, n + 1);
  const int shift = 3 * (n + 1 - k);
  for (size_t a = 0; a < next.size();) {
    const uint64_t key = next[a].code >> shift;
    size_t b = a;
    while (b < next.size() && (next[b].code >> shift) == key) ++b;
    sl::SliceEntry e{};
    e.region_code = key;
    e.parent = parent;
    e.node_level = uint8_t(n + 1);
    e.region_depth = uint8_t(k);
    out->push_back(e);
    a = b;
  }
}

std::vector<uint32_t> compress_slice_attributes(std::span<const uint32_t> descriptors,
                                                std::span<const uint32_t> raw) {
  const size_t n = descriptors.size();
  std::vector<uint32_t> blocks(kCompressedBlockWords * ((n + 1) / 2));
  size_t at = 0;  // raw value of the next child
  uint64_t values[16];
  for (size_t k = 0; 2 * k < n; ++k) {
    uint32_t used = 0;
    int count = 0;
    for (size_t d = 2 * k; d < std::min(n, 2 * k + 2); ++d) {
      const uint32_t valid = sl::SliceValid::get(descriptors[d]);
      used |= valid << ((d & 1) * 8);
      for (int c = 0; c < std::popcount(valid); ++c, ++at) {
        if (2 * at + 2 > raw.size()) throw Error("slices: fewer attributes than children");
        values[count++] = uint64_t(raw[2 * at]) | uint64_t(raw[2 * at + 1]) << 32;
      }
    }
    encode_block_from_raw(values, used, &blocks[kCompressedBlockWords * k]);
  }
  if (2 * at != raw.size()) throw Error("slices: more attributes than children");
  return blocks;
}

std::vector<uint32_t> decode_slice_attributes(std::span<const uint32_t> descriptors,
                                              const uint32_t* blocks) {
  std::vector<uint32_t> raw;
  for (size_t d = 0; d < descriptors.size(); ++d) {
    const uint32_t valid = sl::SliceValid::get(descriptors[d]);
    const uint32_t* block = blocks + kCompressedBlockWords * (d >> 1);
    for (int c = 0; c < 8; ++c) {
      if ((valid >> c & 1u) == 0) continue;
      Color color;
      Vec3 normal;
      decode_compressed_slot(block, int((d & 1) * 8) + c, &color, &normal);
      raw.push_back(encode_color_abgr(color));
      raw.push_back(encode_normal_cube(normal));
    }
  }
  return raw;
}

sl::FileHeader slice_file_header(const GridTransform& grid, bool contours, bool compressed,
                                 uint64_t slice_bytes, const std::vector<sl::SliceEntry>& slices) {
  sl::FileHeader h{};
  std::memcpy(h.magic, sl::kMagic, sizeof h.magic);
  h.version = sl::kVersion;
  h.header_bytes = sizeof(sl::FileHeader);
  h.entry_bytes = sizeof(sl::SliceEntry);
  h.flags = (contours ? sl::kFlagContours : 0u) | (compressed ? sl::kFlagCompressed : 0u);
  h.slice_count = uint32_t(slices.size());
  h.levels = uint32_t(grid.levels);
  h.resolution = grid.resolution;
  h.voxel_size = grid.voxel_size;
  h.origin[0] = grid.origin.x;
  h.origin[1] = grid.origin.y;
  h.origin[2] = grid.origin.z;
  h.slice_bytes = slice_bytes;
  h.data_offset = sizeof(sl::FileHeader) + sizeof(sl::SliceEntry) * slices.size();
  h.file_bytes = h.data_offset;
  for (const sl::SliceEntry& e : slices) {
    h.file_bytes += e.data_bytes;
    h.total_nodes += e.node_count;
    h.total_voxels += e.voxel_count;
  }
  XXH64_state_t* state = XXH64_createState();
  XXH64_reset(state, 0);
  XXH64_update(state, &h, sl::kHashedHeaderBytes);
  XXH64_update(state, slices.data(), slices.size() * sizeof(sl::SliceEntry));
  h.directory_hash = XXH64_digest(state);
  XXH64_freeState(state);
  return h;
}

}  // namespace detail

void write_slices(const EsvoOctree& octree, const std::filesystem::path& path,
                  const SliceOptions& options) {
  if (octree.attribute_format() != AttributeFormat::Raw)
    throw Error("slices: the octree has compressed attributes (esvo §5.5); build it with raw ones");
  if (options.slice_bytes < 64) throw Error("slices: the slice size must be at least 64 bytes");
  const bool contours = octree.has_contours(), compressed = options.compressed;
  const std::vector<std::vector<LevelNode>> levels = octree_levels(octree, contours, compressed);

  // Plan the hierarchy breadth-first (§7.1: the parent decides how its next
  // level is split). Children of one slice are consecutive and sorted.
  std::vector<sl::SliceEntry> slices;
  sl::SliceEntry root{};
  root.parent = sl::kNoParent;
  slices.push_back(root);
  for (size_t i = 0; i < slices.size(); ++i) {
    const int n = slices[i].node_level, r = slices[i].region_depth;
    const uint64_t R = slices[i].region_code;
    if (size_t(n + 1) >= levels.size()) continue;
    const std::vector<LevelNode>& next = levels[size_t(n + 1)];
    const auto [lo, hi] = region_range(next, n + 1, r, R);
    if (lo == hi) continue;
    std::vector<detail::PlanNode> plan;
    for (size_t a = lo; a < hi; ++a) plan.push_back({next[a].code, next[a].bytes});
    slices[i].first_child = uint32_t(slices.size());
    detail::plan_child_slices(plan, n, r, uint32_t(i), options.slice_bytes, &slices);
    slices[i].child_count = uint32_t(slices.size()) - slices[i].first_child;
  }

  // Contents, then the header and directory in front of them.
  const std::filesystem::path tmp = path.string() + ".tmp";
  std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
  if (!out) throw Error(io_error(tmp, std::string("cannot create: ") + std::strerror(errno)));
  const uint64_t data_offset = sizeof(sl::FileHeader) + sizeof(sl::SliceEntry) * slices.size();
  out.seekp(std::streamoff(data_offset));
  const uint32_t* w = octree.words.data();
  uint64_t offset = data_offset;
  std::vector<uint32_t> data;
  for (sl::SliceEntry& e : slices) {
    const std::vector<LevelNode>& level = levels[e.node_level];
    const auto [lo, hi] = region_range(level, e.node_level, e.region_depth, e.region_code);
    std::vector<uint32_t> attrs, contour_values;
    data.clear();
    for (size_t a = lo; a < hi; ++a) {
      const uint32_t slot = level[a].slot;
      const uint32_t d = descriptor_word(w, slot, contours);
      data.push_back(d);
      const uint32_t valid = sl::SliceValid::get(d), cm = sl::SliceContourMask::get(d);
      e.link_count += uint32_t(std::popcount(valid & ~sl::SliceLeaf::get(d)));
      for (int c = 0; c < 8; ++c) {
        if (valid >> c & 1u) {
          uint32_t color, normal;
          raw_attribute_words(w, slot, c, &color, &normal);
          attrs.push_back(color);
          attrs.push_back(normal);
        }
      }
      const uint32_t w1 = w[size_t(slot) * 2 + 1];
      for (int c = 0, at = 0; c < 8; ++c)
        if (cm >> c & 1u)
          contour_values.push_back(w[size_t(slot) * 2 + detail::contour_pointer(w1) + at++]);
    }
    e.node_count = uint32_t(hi - lo);
    e.voxel_count = uint32_t(attrs.size() / 2);
    e.contour_count = uint32_t(contour_values.size());
    if (compressed) attrs = detail::compress_slice_attributes(data, attrs);
    data.insert(data.end(), attrs.begin(), attrs.end());
    data.insert(data.end(), contour_values.begin(), contour_values.end());
    e.data_offset = offset;
    e.data_bytes = uint32_t(data.size() * 4);
    e.hash = XXH64(data.data(), data.size() * 4, 0);
    write_all(out, data.data(), data.size() * 4);
    offset += e.data_bytes;
  }

  const sl::FileHeader h =
      detail::slice_file_header(octree.grid, contours, compressed, options.slice_bytes, slices);
  out.seekp(0);
  write_all(out, &h, sizeof h);
  write_all(out, slices.data(), slices.size() * sizeof(sl::SliceEntry));
  out.close();
  if (!out) throw Error(io_error(tmp, "write failed"));
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) throw Error(io_error(path, "cannot rename into place: " + ec.message()));
}

bool is_slice_file(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  char magic[8] = {};
  if (!in.read(magic, sizeof magic)) return false;
  return std::memcmp(magic, sl::kMagic, sizeof magic) == 0;
}

// ---------------------------------------------------------------------------

namespace {

void pread_all(int fd, void* to, size_t bytes, uint64_t offset, const std::filesystem::path& path) {
  char* p = static_cast<char*>(to);
  while (bytes > 0) {
    const ssize_t got = ::pread(fd, p, bytes, off_t(offset));
    if (got < 0 && errno == EINTR) continue;
    if (got <= 0)
      throw Error(io_error(
          path, got == 0 ? "truncated" : std::string("read error: ") + std::strerror(errno)));
    p += got, bytes -= size_t(got), offset += uint64_t(got);
  }
}

}  // namespace

std::shared_ptr<SliceFile> SliceFile::open(const std::filesystem::path& path) {
  std::shared_ptr<SliceFile> f(new SliceFile());
  f->path_ = path;
  f->fd_ = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (f->fd_ < 0) throw Error(io_error(path, std::string("cannot open: ") + std::strerror(errno)));
  struct stat st {};
  if (::fstat(f->fd_, &st) != 0) throw Error(io_error(path, "cannot stat"));
  const uint64_t size = uint64_t(st.st_size);
  auto bad = [&](const std::string& why) { return Error(io_error(path, "corrupt: " + why)); };
  if (size < sizeof(sl::FileHeader)) throw bad("shorter than its header");
  sl::FileHeader& h = f->header_;
  pread_all(f->fd_, &h, sizeof h, 0, path);
  if (std::memcmp(h.magic, sl::kMagic, sizeof h.magic) != 0) throw bad("not a slice file (magic)");
  if (h.version != sl::kVersion)
    throw bad("version " + std::to_string(h.version) + " (this build reads 1)");
  if (h.header_bytes != sizeof(sl::FileHeader) || h.entry_bytes != sizeof(sl::SliceEntry))
    throw bad("header or entry size");
  if (h.slice_count == 0 || h.slice_count > (size - sizeof h) / sizeof(sl::SliceEntry))
    throw bad("slice count");
  if (h.data_offset != sizeof h + uint64_t(h.slice_count) * sizeof(sl::SliceEntry))
    throw bad("data offset");
  if (h.file_bytes != size) throw bad("file size " + std::to_string(size) + " is not the header's");
  if (h.levels < 1 || h.levels > 20 || h.resolution != (1u << h.levels)) throw bad("grid levels");
  if ((h.flags & ~(sl::kFlagContours | sl::kFlagCompressed)) != 0 || h.reserved0 || h.reserved1 ||
      h.reserved2 || h.reserved3)
    throw bad("reserved bits");
  f->slices_.resize(h.slice_count);
  pread_all(f->fd_, f->slices_.data(), f->slices_.size() * sizeof(sl::SliceEntry), sizeof h, path);
  XXH64_state_t* state = XXH64_createState();
  XXH64_reset(state, 0);
  XXH64_update(state, &h, sl::kHashedHeaderBytes);
  XXH64_update(state, f->slices_.data(), f->slices_.size() * sizeof(sl::SliceEntry));
  const uint64_t hash = XXH64_digest(state);
  XXH64_freeState(state);
  if (hash != h.directory_hash) throw bad("directory hash mismatch");
  if (!f->grid().placement_is_valid()) throw bad("grid placement");

  // The hierarchy: breadth-first, children consecutive, sorted, one region
  // depth each, nested in the parent's region; data contiguous in order.
  uint64_t offset = h.data_offset, nodes = 0, voxels = 0;
  const auto& s = f->slices_;
  for (uint32_t i = 0; i < h.slice_count; ++i) {
    const sl::SliceEntry& e = s[i];
    const std::string at = "slice " + std::to_string(i) + ": ";
    if (e.reserved0 || e.reserved1) throw bad(at + "reserved bits");
    if (e.data_offset != offset) throw bad(at + "data offset");
    if (uint64_t(e.data_bytes) !=
        detail::slice_data_bytes(e.node_count, e.voxel_count, e.contour_count, f->compressed()))
      throw bad(at + "data size");
    if (e.node_count == 0 || e.node_count > sl::kMaxSliceNodes) throw bad(at + "node count");
    if (e.voxel_count > 8 * uint64_t(e.node_count) || e.contour_count > e.voxel_count ||
        e.link_count > e.voxel_count)
      throw bad(at + "counts");
    if (e.node_level >= h.levels || e.region_depth > e.node_level) throw bad(at + "level");
    if (e.region_code >> (3 * e.region_depth) != 0) throw bad(at + "region code");
    if (i == 0) {
      if (e.parent != sl::kNoParent || e.node_level != 0 || e.node_count != 1)
        throw bad(at + "not a root slice");
    } else {
      const sl::SliceEntry& p = s[e.parent < i ? e.parent : 0];
      if (e.parent >= i || i < p.first_child || i >= uint64_t(p.first_child) + p.child_count)
        throw bad(at + "parent");
      if (e.node_level != p.node_level + 1 || e.region_depth < p.region_depth ||
          (e.region_code >> (3 * (e.region_depth - p.region_depth))) != p.region_code)
        throw bad(at + "not nested in its parent");
      if (i > p.first_child &&
          (s[i - 1].region_depth != e.region_depth || s[i - 1].region_code >= e.region_code))
        throw bad(at + "siblings out of order");
    }
    if (e.child_count > 0 &&
        (e.first_child <= i || uint64_t(e.first_child) + e.child_count > h.slice_count))
      throw bad(at + "children");
    if (e.child_count == 0 && e.first_child != 0) throw bad(at + "children");
    offset += e.data_bytes;
    nodes += e.node_count;
    voxels += e.voxel_count;
  }
  // Every slice but the root lies in its parent's children range (checked
  // above); with the ranges' lengths summing to slice_count - 1 it lies in
  // no other, so a walk down the ranges meets only the children it expects.
  uint64_t in_ranges = 0;
  for (const sl::SliceEntry& e : s) in_ranges += e.child_count;
  if (in_ranges != uint64_t(h.slice_count) - 1) throw bad("children ranges overlap");
  if (offset != size) throw bad("slice data does not end at the end of the file");
  if (nodes != h.total_nodes || voxels != h.total_voxels) throw bad("totals");
  return f;
}

SliceFile::~SliceFile() {
  if (fd_ >= 0) ::close(fd_);
}

GridTransform SliceFile::grid() const {
  GridTransform g;
  g.origin = {header_.origin[0], header_.origin[1], header_.origin[2]};
  g.voxel_size = header_.voxel_size;
  g.resolution = header_.resolution;
  g.levels = int(header_.levels);
  return g;
}

void SliceFile::read_stored(uint32_t i, std::vector<uint32_t>* words) const {
  const sl::SliceEntry& e = slices_.at(i);
  words->resize(e.data_bytes / 4);
  pread_all(fd_, words->data(), e.data_bytes, e.data_offset, path_);
  if (XXH64(words->data(), e.data_bytes, 0) != e.hash)
    throw Error(io_error(path_, "slice " + std::to_string(i) + ": hash mismatch"));
}

void SliceFile::verify_hashes(Progress* progress) const {
  std::vector<uint32_t> words;
  for (uint32_t i = 0; i < uint32_t(slices_.size()); ++i) {
    read_stored(i, &words);
    if (progress != nullptr) progress->add_units(slices_[i].data_bytes);
  }
}

std::vector<uint32_t> SliceFile::read(uint32_t i) const {
  const sl::SliceEntry& e = slices_.at(i);
  std::vector<uint32_t> words;
  read_stored(i, &words);
  if (!compressed()) return words;
  // Decoded into the raw layout (detail::decode_slice_attributes). The sizes
  // were checked at open (data_bytes); a valid-mask total other than the
  // directory's voxel count decodes as many values and the loader refuses
  // the slice.
  const size_t n = e.node_count;
  const uint32_t* block0 = words.data() + n;
  const uint32_t* contours = block0 + detail::kCompressedBlockWords * ((n + 1) / 2);
  const std::vector<uint32_t> attrs =
      detail::decode_slice_attributes(std::span<const uint32_t>(words.data(), n), block0);
  std::vector<uint32_t> raw;
  raw.reserve(n + attrs.size() + e.contour_count);
  raw.insert(raw.end(), words.begin(), words.begin() + std::ptrdiff_t(n));
  raw.insert(raw.end(), attrs.begin(), attrs.end());
  raw.insert(raw.end(), contours, contours + e.contour_count);
  return raw;
}

Aabb SliceFile::occupied_bounds(int max_level) const {
  // A walk of the slices of node levels below max_level, as
  // esvo::occupied_bounds() walks the in-core octree: each voxel that ends
  // the walk (a leaf, or a subdivided voxel at depth max_level) extends the
  // box by its cube, with the same float arithmetic, so the two boxes are
  // equal bit for bit. A slice that cannot be read or does not match the
  // descriptors its parent implies ends the walk at those descriptors'
  // (coarser) cubes, as the streamed structure stops at them.
  const GridTransform g = grid();
  const double side = g.side();
  Aabb box;
  auto add_voxel = [&](uint64_t code, int depth) {
    const double size = side / double(uint64_t(1) << depth);
    const MortonCoord p = morton_decode(code);
    const Vec3 lo{float(g.origin.x + p.x * size), float(g.origin.y + p.y * size),
                  float(g.origin.z + p.z * size)};
    box.extend(lo);
    box.extend(lo + Vec3{float(size), float(size), float(size)});
  };
  if (max_level < 1) {
    add_voxel(0, 0);
    return box;
  }
  struct Item {
    uint32_t slice;
    std::vector<uint64_t> codes;  // the descriptors it holds: depth node_level, Morton order
  };
  std::vector<Item> stack;
  stack.push_back({0, {0}});
  std::vector<uint64_t> next;
  while (!stack.empty()) {
    const Item it = std::move(stack.back());
    stack.pop_back();
    const sl::SliceEntry& e = slices_[it.slice];
    const int n = e.node_level;
    std::vector<uint32_t> words;
    try {
      words = read(it.slice);
    } catch (const Error&) {
      words.clear();
    }
    if (words.size() < it.codes.size() || e.node_count != it.codes.size()) {
      for (const uint64_t c : it.codes) add_voxel(c, n);
      continue;
    }
    // The subdivided children at depth n + 1 to walk on, in Morton order.
    next.clear();
    for (size_t k = 0; k < it.codes.size(); ++k) {
      const uint32_t valid = sl::SliceValid::get(words[k]), leaf = sl::SliceLeaf::get(words[k]);
      for (int c = 0; c < 8; ++c) {
        if ((valid >> c & 1u) == 0) continue;
        const uint64_t code = it.codes[k] << 3 | uint64_t(c);
        if ((leaf >> c & 1u) != 0 || n + 1 >= max_level)
          add_voxel(code, n + 1);
        else
          next.push_back(code);
      }
    }
    if (next.empty()) continue;
    // Hand each child slice the codes inside its region; codes no child
    // slice covers (a damaged hierarchy) end at their cubes.
    // (Sibling regions are disjoint, so the ranges do not overlap.)
    std::vector<uint8_t> hit(next.size(), 0);
    for (uint32_t j = e.first_child; j < e.first_child + e.child_count; ++j) {
      const sl::SliceEntry& ce = slices_[j];
      if (ce.parent != it.slice || ce.node_level != n + 1) continue;  // (open() refuses it)
      const int shift = 3 * (n + 1 - ce.region_depth);
      const uint64_t lo = ce.region_code << shift, hi = (ce.region_code + 1) << shift;
      const auto a = std::lower_bound(next.begin(), next.end(), lo);
      const auto b = std::lower_bound(next.begin(), next.end(), hi);
      if (a == b) continue;
      std::fill(hit.begin() + (a - next.begin()), hit.begin() + (b - next.begin()), uint8_t(1));
      stack.push_back({j, std::vector<uint64_t>(a, b)});
    }
    for (size_t k = 0; k < next.size(); ++k)
      if (!hit[k]) add_voxel(next[k], n + 1);
  }
  return box;
}

std::string SliceFile::describe() const {
  struct Row {
    uint64_t slices = 0, bytes = 0, min = UINT64_MAX, max = 0, nodes = 0, fanout = 0;
  };
  std::vector<Row> rows(header_.levels);
  for (const sl::SliceEntry& e : slices_) {
    Row& r = rows[e.node_level];
    ++r.slices;
    r.bytes += e.data_bytes;
    r.min = std::min<uint64_t>(r.min, e.data_bytes);
    r.max = std::max<uint64_t>(r.max, e.data_bytes);
    r.nodes += e.node_count;
    r.fanout = std::max<uint64_t>(r.fanout, e.child_count);
  }
  std::ostringstream o;
  o << "slice hierarchy (esvo §7): " << slices_.size() << " slices, target " << header_.slice_bytes
    << " B, " << header_.total_nodes << " descriptors, " << header_.total_voxels << " voxels"
    << (has_contours() ? ", contours" : "") << (compressed() ? ", compressed attributes" : "")
    << "\n";
  o << "  level   slices   descriptors        bytes    min B    mean B     max B  max children\n";
  for (size_t n = 0; n < rows.size(); ++n) {
    const Row& r = rows[n];
    if (r.slices == 0) continue;
    char line[160];
    std::snprintf(line, sizeof line, "  %5zu %8llu %13llu %12llu %8llu %9.0f %9llu %13llu\n", n,
                  (unsigned long long)r.slices, (unsigned long long)r.nodes,
                  (unsigned long long)r.bytes, (unsigned long long)r.min,
                  double(r.bytes) / double(r.slices), (unsigned long long)r.max,
                  (unsigned long long)r.fanout);
    o << line;
  }
  return o.str();
}

}  // namespace voxcast::esvo
