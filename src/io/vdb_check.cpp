// The structure walk of a .vdb file before libopenvdb reads it
// (vdb_check.hpp). libopenvdb 10.0.1 trusts what a file declares: a string
// length is allocated before it is read, an uncompressed value block of a
// declared size is copied into a node buffer before its size is compared
// with the buffer's, a Blosc block is decoded up to the compressed size its
// own header declares, past the bytes read — a damaged file overflowed a
// heap buffer inside bloscFromStream (found by fuzz_vdb;
// tests/data/regress/vdb). This walk follows the layout io::File reads
// (the OpenVDB sources: io/Archive, io/File, io/GridDescriptor, io/Compression,
// MetaMap, Metadata, io/DelayedLoadMetadata, math/Transform and Maps,
// tree/RootNode, InternalNode, LeafNode, LeafNodeBool) for the grid types
// voxcast reads and refuses anything else.
#include "io/vdb_check.hpp"

#include <blosc.h>
#include <fmt/format.h>
#include <zlib.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cctype>
#include <cstring>
#include <vector>

#include "voxcast/error.hpp"

namespace voxcast::detail {

namespace {

constexpr uint32_t kZip = 0x1, kActiveMask = 0x2, kBlosc = 0x4;
constexpr int kPadBytes = 128;  // OpenVDB's BLOSC_PAD_BYTES

[[noreturn]] void fail(const std::string& what) {
  throw Error(what);
}

struct Reader {
  const uint8_t* data;
  size_t size;
  size_t at = 0;

  const uint8_t* take(uint64_t n, const char* what) {
    if (n > size - at)
      fail(fmt::format("{} declares {} bytes at byte {}, where {} remain", what, n, at, size - at));
    const uint8_t* p = data + at;
    at += size_t(n);
    return p;
  }
  template <class T>
  T get(const char* what) {
    T v;
    std::memcpy(&v, take(sizeof v, what), sizeof v);
    return v;
  }
  bool boolean(const char* what) {
    const uint8_t b = get<uint8_t>(what);
    if (b > 1) fail(fmt::format("{} at byte {} is {}, not a bool", what, at - 1, b));
    return b != 0;
  }
  std::string string(const char* what) {
    const uint32_t n = get<uint32_t>(what);
    const uint8_t* p = take(n, what);
    return std::string(reinterpret_cast<const char*>(p), n);
  }
};

// The value type of a grid's tree: bytes per value, and bytes per value when
// saved as half floats (real types only).
struct ValueKind {
  const char* tree;
  uint32_t size;
  uint32_t half;  // 0: not a real type (HalfReader reads full values)
  bool is_bool;
};
constexpr ValueKind kKinds[] = {
    {"Tree_float_5_4_3", 4, 2, false},  {"Tree_double_5_4_3", 8, 2, false},
    {"Tree_int32_5_4_3", 4, 0, false},  {"Tree_int64_5_4_3", 8, 0, false},
    {"Tree_vec3i_5_4_3", 12, 0, false}, {"Tree_vec3s_5_4_3", 12, 6, false},
    {"Tree_vec3d_5_4_3", 24, 6, false}, {"Tree_bool_5_4_3", 1, 0, true},
};

struct GridWalk {
  const ValueKind* kind;
  bool half;
  uint32_t compression = 0;
  std::vector<uint8_t> scratch;
};

// Metadata types OpenVDB reads as a fixed-size value (TypedMetadata, which
// reads sizeof(T) whatever size the file declares: a different declared
// size would shift every later read).
struct FixedMeta {
  const char* name;
  uint32_t size;
};
constexpr FixedMeta kFixedMeta[] = {
    {"bool", 1},    {"double", 8},  {"float", 4},   {"int32", 4},       {"int64", 8},
    {"vec2i", 8},   {"vec2s", 8},   {"vec2d", 16},  {"vec3i", 12},      {"vec3s", 12},
    {"vec3d", 24},  {"vec4i", 16},  {"vec4s", 16},  {"vec4d", 32},      {"mat4s", 64},
    {"mat4d", 128}, {"ptidx32", 4}, {"ptidx64", 8}, {"ptdataidx32", 4}, {"ptdataidx64", 8},
};

// A Blosc block of `n` bytes at `src` that OpenVDB will decode: its header
// must declare exactly these `n` compressed bytes (Blosc reads as many as
// its header says) and an uncompressed size OpenVDB expects.
size_t blosc_block(const uint8_t* src, uint64_t n, const char* what) {
  size_t nbytes = 0;
  if (n < BLOSC_MIN_HEADER_LENGTH || blosc_cbuffer_validate(src, size_t(n), &nbytes) != 0)
    fail(fmt::format("{}: a damaged Blosc block of {} bytes", what, n));
  return nbytes;
}

// OpenVDB's DelayedLoadMetadata ("__delayedload"): per-leaf masks and
// compressed sizes, raw or as Blosc blocks, of `declared` bytes in all.
void delayed_load_metadata(Reader& r, uint32_t declared) {
  if (declared == 0) return;
  const size_t start = r.at;
  const uint32_t count = r.get<uint32_t>("delayed-load metadata");
  // One entry per leaf, and every leaf takes more than a byte of the file.
  if (count > r.size) fail(fmt::format("delayed-load metadata declares {} leaves", count));
  auto table = [&](uint32_t bytes, uint64_t expected) {
    if (bytes == 0) {
      r.take(expected, "delayed-load metadata");
      return;
    }
    const uint8_t* src = r.take(bytes, "delayed-load metadata");
    const size_t n = blosc_block(src, bytes, "delayed-load metadata");
    if (n != expected && !(n == size_t(kPadBytes) && expected <= size_t(kPadBytes)))
      fail(fmt::format("delayed-load metadata: a Blosc block of {} bytes where {} are expected", n,
                       expected));
  };
  table(r.get<uint32_t>("delayed-load metadata"), count);
  const uint32_t sizes = r.get<uint32_t>("delayed-load metadata");
  if (sizes != UINT32_MAX) table(sizes, uint64_t(count) * 8);
  const size_t used = r.at - start;
  if (used > declared)
    fail(fmt::format("delayed-load metadata holds {} bytes, {} declared", used, declared));
  r.take(declared - used, "delayed-load metadata");
}

void metadata(Reader& r, const std::function<bool(const std::string&)>& registered) {
  const uint32_t count = r.get<uint32_t>("metadata count");
  for (uint32_t i = 0; i < count; ++i) {
    const std::string name = r.string("metadata name");
    const std::string type = r.string("metadata type name");
    const uint32_t n = r.get<uint32_t>("metadata size");
    if (type == "string") {
      r.take(n, "metadata value");
    } else if (type == "__delayedload") {
      delayed_load_metadata(r, n);
    } else if (auto it = std::find_if(std::begin(kFixedMeta), std::end(kFixedMeta),
                                      [&](const FixedMeta& m) { return type == m.name; });
               it != std::end(kFixedMeta)) {
      if (n != it->size)
        fail(fmt::format("metadata '{}' of type {} declares {} bytes, not {}", name, type, n,
                         it->size));
      if (type == "bool")
        r.boolean("bool metadata");
      else
        r.take(n, "metadata value");
    } else if (registered(type)) {
      fail(fmt::format("metadata '{}' has type {}, which voxcast does not read", name, type));
    } else {
      r.take(n, "metadata value");  // unknown to OpenVDB too: kept as raw bytes
    }
  }
}

void transform(Reader& r) {
  const std::string type = r.string("transform type");
  // Bytes of each linear map: a 4x4 matrix, or 3-vectors of doubles.
  static constexpr std::pair<const char*, uint32_t> kMaps[] = {
      {"AffineMap", 128},
      {"UnitaryMap", 128},
      {"ScaleMap", 120},
      {"UniformScaleMap", 120},
      {"TranslationMap", 24},
      {"ScaleTranslateMap", 144},
      {"UniformScaleTranslateMap", 144},
  };
  for (const auto& [name, bytes] : kMaps)
    if (type == name) {
      r.take(bytes, "transform");
      return;
    }
  fail(fmt::format("transform of type '{}', not a linear map voxcast reads", type.substr(0, 64)));
}

void value(Reader& r, const GridWalk& g, const char* what) {
  if (g.kind->is_bool)
    r.boolean(what);
  else
    r.take(g.kind->size, what);
}

// One readData block of `bytes` bytes: raw, or (zlib/Blosc) an int64 size,
// negative for a raw block, then the compressed bytes. Decoded into
// g.scratch; the size must be exactly what OpenVDB decodes it into.
void data_block(Reader& r, GridWalk& g, uint64_t bytes, const char* what) {
  g.scratch.resize(size_t(bytes) + 1);
  uint8_t* out = g.scratch.data();
  if (!(g.compression & (kZip | kBlosc))) {
    std::memcpy(out, r.take(bytes, what), size_t(bytes));
    return;
  }
  const int64_t n = r.get<int64_t>(what);
  if (n <= 0) {
    const uint64_t raw = uint64_t(0) - uint64_t(n);
    if (raw != bytes)
      fail(fmt::format("{} at byte {}: an uncompressed block of {} bytes where {} are expected",
                       what, r.at, raw, bytes));
    std::memcpy(out, r.take(bytes, what), size_t(bytes));
    return;
  }
  const uint8_t* src = r.take(uint64_t(n), what);
  if (g.compression & kBlosc) {
    if (blosc_block(src, uint64_t(n), what) != bytes ||
        blosc_decompress_ctx(src, out, size_t(bytes), 1) != int64_t(bytes))
      fail(fmt::format("{} at byte {}: a Blosc block that does not decode to {} bytes", what, r.at,
                       bytes));
  } else {
    uLongf len = uLongf(bytes);
    const int status = uncompress(out, &len, src, uLong(n));
    if ((status != Z_OK && bytes != 0) || len != bytes)
      fail(fmt::format("{} at byte {}: a zlib block that does not decode to {} bytes", what, r.at,
                       bytes));
  }
}

uint64_t count_on(const uint8_t* mask, uint32_t bits) {
  uint64_t n = 0;
  for (uint32_t i = 0; i < bits / 8; ++i) n += uint64_t(std::popcount(mask[i]));
  return n;
}

// io::readCompressedValues for a node of `bits` values with value mask `mask`.
void compressed_values(Reader& r, GridWalk& g, const uint8_t* mask, uint32_t bits) {
  const uint8_t meta = r.get<uint8_t>("node value flags");
  if (meta > 6) fail(fmt::format("node value flags {} at byte {}", meta, r.at - 1));
  const int inactive = (meta == 2 || meta == 4) ? 1 : meta == 5 ? 2 : 0;
  for (int i = 0; i < inactive; ++i) value(r, g, "inactive value");
  if (meta >= 3 && meta <= 5) r.take(bits / 8, "selection mask");
  const uint64_t count = ((g.compression & kActiveMask) && meta != 6) ? count_on(mask, bits) : bits;
  const bool half = g.half && g.kind->half != 0;
  if (half && count == 0) return;  // HalfReader reads nothing then
  data_block(r, g, count * (half ? g.kind->half : g.kind->size), "node values");
  if (g.kind->is_bool)
    for (uint64_t i = 0; i < count; ++i)
      if (g.scratch[i] > 1) fail(fmt::format("a bool node value is {}", g.scratch[i]));
}

using Coord = std::array<int32_t, 3>;

struct Leaf {
  Coord origin;
  const uint8_t* mask;  // 512 bits
};

// InternalNode::readTopology (log2 5 or 4 of a 5-4-3 tree), collecting its
// leaves in the order readBuffers visits them.
void internal_node(Reader& r, GridWalk& g, int log2, Coord origin, std::vector<Leaf>& leaves) {
  const uint32_t bits = 1u << (3 * log2);
  const uint8_t* children = r.take(bits / 8, "child mask");
  const uint8_t* values = r.take(bits / 8, "value mask");
  compressed_values(r, g, values, bits);
  const int child_total = log2 == 5 ? 7 : 3;  // log2 of the child's extent in voxels
  for (uint32_t i = 0; i < bits; ++i) {
    if (!((children[i >> 3] >> (i & 7)) & 1)) continue;
    const int32_t x = int32_t(i >> (2 * log2)), y = int32_t((i >> log2) & ((1u << log2) - 1)),
                  z = int32_t(i & ((1u << log2) - 1));
    const Coord c{origin[0] + (x << child_total), origin[1] + (y << child_total),
                  origin[2] + (z << child_total)};
    if (log2 == 5)
      internal_node(r, g, 4, c, leaves);
    else
      leaves.push_back({c, r.take(64, "leaf value mask")});
  }
}

// Tree::readTopology then Tree::readBuffers.
void tree(Reader& r, GridWalk& g) {
  if (r.get<int32_t>("tree buffer count") != 1) fail("a tree with a buffer count other than 1");
  value(r, g, "background value");
  const uint32_t tiles = r.get<uint32_t>("root tile count");
  const uint32_t count = r.get<uint32_t>("root child count");
  constexpr int32_t kAlign = 4096 - 1;  // a root child spans 4096 voxels
  std::vector<Coord> keys;
  auto origin = [&](const char* what) {
    Coord c;
    std::memcpy(c.data(), r.take(12, what), 12);
    if ((c[0] & kAlign) || (c[1] & kAlign) || (c[2] & kAlign))
      fail(fmt::format("a root {} at ({}, {}, {}) is not on the 4096-voxel grid", what, c[0], c[1],
                       c[2]));
    keys.push_back(c);
    return c;
  };
  for (uint32_t i = 0; i < tiles; ++i) {
    origin("tile");
    value(r, g, "tile value");
    r.boolean("tile state");
  }
  std::vector<std::pair<Coord, std::vector<Leaf>>> children;
  for (uint32_t i = 0; i < count; ++i) {
    const Coord c = origin("child");
    std::vector<Leaf> leaves;
    internal_node(r, g, 5, c, leaves);
    children.emplace_back(c, std::move(leaves));
  }
  std::sort(keys.begin(), keys.end());
  if (std::adjacent_find(keys.begin(), keys.end()) != keys.end())
    fail("two root tiles or children at one place");
  // RootNode::readBuffers visits its children in coordinate order.
  std::sort(children.begin(), children.end(),
            [](const auto& a, const auto& b) { return a.first < b.first; });
  for (const auto& [c, leaves] : children)
    for (const Leaf& leaf : leaves) {
      const uint8_t* mask = r.take(64, "leaf value mask");
      if (!g.kind->is_bool) {
        // Skipped by the seekable reader, which keeps the topology's mask.
        compressed_values(r, g, leaf.mask, 512);
        continue;
      }
      // A bool leaf reads its mask and origin again, then its value bits.
      Coord at;
      std::memcpy(at.data(), r.take(12, "leaf origin"), 12);
      if (std::memcmp(mask, leaf.mask, 64) != 0 || at != leaf.origin)
        fail("a bool leaf whose buffer does not match its place in the tree");
      r.take(64, "leaf values");
    }
}

void grid(Reader& r, const ValueKind& kind, bool half, bool instance,
          const std::function<bool(const std::string&)>& registered) {
  GridWalk g{&kind, half, 0, {}};
  g.compression = r.get<uint32_t>("grid compression");
  if (g.compression & ~(kZip | kActiveMask | kBlosc))
    fail(fmt::format("unknown grid compression flags {:#x}", g.compression));
  metadata(r, registered);
  transform(r);
  if (!instance) tree(r, g);
}

}  // namespace

void check_vdb_bytes(const uint8_t* data, size_t size,
                     const std::function<bool(const std::string&)>& registered_metadata) {
  Reader r{data, size};
  if (size < 8 || r.get<uint64_t>("header") != 0x56444220) fail("not a VDB file");
  const uint32_t version = r.get<uint32_t>("header");
  if (version < 222 || version > 224)
    fail(fmt::format("file format version {}; voxcast reads versions 222 to 224 (OpenVDB 3 to 10)",
                     version));
  r.get<uint32_t>("header"), r.get<uint32_t>("header");  // library major and minor version
  const bool offsets = r.get<uint8_t>("header") != 0;
  const uint8_t* uuid = r.take(36, "header UUID");
  for (int i = 0; i < 36; ++i) {
    const bool dash = i == 8 || i == 13 || i == 18 || i == 23;
    if (dash ? uuid[i] != '-' : !std::isxdigit(uuid[i])) fail("a damaged header UUID");
  }
  metadata(r, registered_metadata);
  const int32_t grids = r.get<int32_t>("grid count");
  if (grids < 0) fail(fmt::format("grid count {}", grids));
  for (int32_t i = 0; i < grids; ++i) {
    const std::string name = r.string("grid name");
    std::string type = r.string("grid type name");
    const std::string instance = r.string("grid instance name");
    const std::string suffix = "_HalfFloat";
    const bool half = type.size() > suffix.size() && type.ends_with(suffix);
    if (half) type.resize(type.size() - suffix.size());
    const ValueKind* kind = nullptr;
    for (const ValueKind& k : kKinds)
      if (type == k.tree) kind = &k;
    if (!kind)
      fail(
          fmt::format("grid {} has type '{}'; voxcast reads float, double, int32, int64, vec3i, "
                      "vec3s, vec3d and bool grids",
                      i, type.substr(0, 64)));
    int64_t pos[3];  // grid, data block and end offsets
    std::memcpy(pos, r.take(sizeof pos, "grid descriptor"), sizeof pos);
    if (!offsets) {  // written as a stream: the grid follows its descriptor
      grid(r, *kind, half, !instance.empty(), registered_metadata);
      continue;
    }
    // (An instance grid has no data block: offset 0.)
    if (pos[0] < int64_t(r.at) || pos[2] < pos[0] || uint64_t(pos[2]) > size ||
        (pos[1] != 0 && (pos[1] < pos[0] || pos[1] > pos[2])))
      fail(fmt::format("grid {} has offsets {}, {}, {} outside the {}-byte file", i, pos[0], pos[1],
                       pos[2], size));
    // The grid's data lies between its start and end offsets; the next
    // descriptor follows at the end offset.
    Reader sub{data, size_t(pos[2]), size_t(pos[0])};
    grid(sub, *kind, half, !instance.empty(), registered_metadata);
    r.at = size_t(pos[2]);
  }
}

}  // namespace voxcast::detail
