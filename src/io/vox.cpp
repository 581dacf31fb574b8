// MagicaVoxel .vox in and out (voxel_io.hpp). The file is RIFF-like: "VOX ",
// a version, then a MAIN chunk whose children are SIZE/XYZI model pairs, the
// RGBA palette and, since 0.99, a scene graph (nTRN transforms, nGRP groups,
// nSHP shapes). Every count and size is read as a signed 32-bit value and
// checked against the bytes that remain before it is used.
#include <fmt/format.h>

#include <algorithm>
#include <bit>
#include <cstring>
#include <fstream>
#include <iterator>
#include <map>
#include <optional>
#include <set>

#include "io/voxel_io_internal.hpp"
#include "voxcast/error.hpp"
#include "voxcast/image.hpp"
#include "voxcast/morton.hpp"
#include "voxcast/solid.hpp"
#include "voxcast/system.hpp"
#include "voxcast/voxel_io.hpp"

namespace voxcast {

uint32_t vox_default_palette(int index) {
  if (index <= 0 || index > 255) return 0;
  auto rgba = [](uint32_t r, uint32_t g, uint32_t b) { return 0xff000000u | b << 16 | g << 8 | r; };
  if (index <= 215) {
    const int k = index - 1;  // blue fastest, then green, then red
    const uint32_t b = 0xff - 0x33 * uint32_t(k % 6), g = 0xff - 0x33 * uint32_t(k / 6 % 6),
                   r = 0xff - 0x33 * uint32_t(k / 36);
    return rgba(r, g, b);
  }
  static constexpr uint32_t kRamp[10] = {0xee, 0xdd, 0xbb, 0xaa, 0x88,
                                         0x77, 0x55, 0x44, 0x22, 0x11};
  const int ramp = (index - 216) / 10, step = (index - 216) % 10;
  const uint32_t v = kRamp[step];
  switch (ramp) {
    case 0:
      return rgba(v, 0, 0);
    case 1:
      return rgba(0, v, 0);
    case 2:
      return rgba(0, 0, v);
    default:
      return rgba(v, v, v);
  }
}

namespace detail {

uint64_t voxel_budget(const VoxelReadOptions& options) {
  if (options.memory_budget) return options.memory_budget;
  const uint64_t avail = available_memory_bytes();
  // Unknown free memory: a generous fixed bound rather than none.
  return avail ? uint64_t(double(avail) * 0.9) : (uint64_t(16) << 30);
}

void check_voxel_count(uint64_t voxels, uint64_t budget, const char* what) {
  if (voxels > budget / kVoxelSetBytesPerVoxel)
    throw Error(fmt::format("{}: {} voxels need {} bytes, more than the {} byte memory budget",
                            what, voxels, voxels * kVoxelSetBytesPerVoxel, budget));
}

std::vector<uint8_t> read_file_bytes(const std::filesystem::path& path, uint64_t budget) {
  std::error_code ec;
  const auto size = std::filesystem::file_size(path, ec);
  if (ec) throw Error(fmt::format("cannot read '{}': {}", path.string(), ec.message()));
  if (size > budget)
    throw Error(fmt::format("'{}' is {} bytes, more than the {} byte memory budget", path.string(),
                            size, budget));
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error(fmt::format("cannot open '{}'", path.string()));
  std::vector<uint8_t> bytes((std::istreambuf_iterator<char>(in)),
                             std::istreambuf_iterator<char>());
  if (in.bad()) throw Error(fmt::format("cannot read '{}'", path.string()));
  return bytes;
}

void finish_voxel_set(VoxelSet& set) {
  set.normals = occupancy_normals(set);
  set.weights.assign(set.codes.size(), 1.f);
}

GridTransform unit_grid(uint32_t extent) {
  GridTransform g;
  g.resolution = std::bit_ceil(std::max<uint32_t>(extent, 1));
  g.levels = std::countr_zero(g.resolution);
  g.voxel_size = 1.0;
  return g;
}

Bounds3 occupied_bounds(const VoxelSet& set) {
  Bounds3 b;
  for (uint64_t code : set.codes) {
    const MortonCoord c = morton_decode(code);
    const uint32_t v[3] = {c.x, c.y, c.z};
    for (int a = 0; a < 3; ++a) {
      b.lo[a] = std::min(b.lo[a], v[a]);
      b.hi[a] = std::max(b.hi[a], v[a]);
    }
  }
  return b;
}

}  // namespace detail

namespace {

using detail::check_voxel_count;

/// Bounds-checked little-endian reader over one chunk's content.
struct Cursor {
  const uint8_t* p;
  size_t left;
  const char* chunk;

  [[noreturn]] void truncated() const {
    throw Error(fmt::format("malformed .vox: {} chunk is truncated", chunk));
  }
  int32_t i32() {
    if (left < 4) truncated();
    uint32_t v = uint32_t(p[0]) | uint32_t(p[1]) << 8 | uint32_t(p[2]) << 16 | uint32_t(p[3]) << 24;
    p += 4, left -= 4;
    return int32_t(v);
  }
  /// A count or size: non-negative, and at most `left / min_item_bytes` items
  /// fit in what remains.
  uint32_t count(const char* what, size_t min_item_bytes) {
    const int32_t n = i32();
    if (n < 0 || uint64_t(n) * min_item_bytes > left)
      throw Error(fmt::format("malformed .vox: {} chunk: {} {} does not fit its {} bytes", chunk,
                              what, n, left));
    return uint32_t(n);
  }
  std::string str() {
    const uint32_t n = count("string size", 1);
    std::string s(reinterpret_cast<const char*>(p), n);
    p += n, left -= n;
    return s;
  }
  std::map<std::string, std::string> dict() {
    const uint32_t n = count("dictionary size", 8);
    std::map<std::string, std::string> d;
    for (uint32_t i = 0; i < n; ++i) {
      std::string k = str();
      d[k] = str();
    }
    return d;
  }
};

struct Model {
  int32_t size[3] = {0, 0, 0};
  std::vector<std::array<uint8_t, 4>> voxels;  // x, y, z, palette index
  bool has_voxels = false;
};

/// Signed permutation matrix, rows as (column index, sign).
struct Rotation {
  int col[3] = {0, 1, 2};
  int sign[3] = {1, 1, 1};
  std::array<int64_t, 3> apply(const std::array<int64_t, 3>& v) const {
    return {sign[0] * v[col[0]], sign[1] * v[col[1]], sign[2] * v[col[2]]};
  }
  Rotation then(const Rotation& outer) const {  // outer * this
    Rotation r;
    for (int i = 0; i < 3; ++i) {
      r.col[i] = col[outer.col[i]];
      r.sign[i] = outer.sign[i] * sign[outer.col[i]];
    }
    return r;
  }
};

struct Transform {
  Rotation rot;
  std::array<int64_t, 3> t{0, 0, 0};
};

Rotation parse_rotation(const std::string& text) {
  char* end = nullptr;
  const long v = std::strtol(text.c_str(), &end, 10);
  if (text.empty() || *end != 0 || v < 0 || v > 127)
    throw Error(fmt::format("malformed .vox: nTRN rotation '{}' is not a byte", text));
  Rotation r;
  r.col[0] = int(v & 3);
  r.col[1] = int(v >> 2 & 3);
  if (r.col[0] == 3 || r.col[1] == 3 || r.col[0] == r.col[1])
    throw Error(fmt::format("malformed .vox: nTRN rotation {} is not a rotation", v));
  r.col[2] = 3 - r.col[0] - r.col[1];
  for (int i = 0; i < 3; ++i) r.sign[i] = (v >> (4 + i) & 1) ? -1 : 1;
  return r;
}

std::array<int64_t, 3> parse_translation(const std::string& text) {
  std::array<int64_t, 3> t{};
  const char* s = text.c_str();
  for (int a = 0; a < 3; ++a) {
    char* end = nullptr;
    const long long v = std::strtoll(s, &end, 10);
    // Translations are int32 in MagicaVoxel; the grid limit is checked later.
    if (end == s || v < INT32_MIN || v > INT32_MAX)
      throw Error(fmt::format("malformed .vox: nTRN translation '{}' is not three integers", text));
    t[a] = v;
    s = end;
  }
  while (*s == ' ') ++s;
  if (*s)
    throw Error(fmt::format("malformed .vox: nTRN translation '{}' is not three integers", text));
  return t;
}

struct Node {
  enum Kind { Trn, Grp, Shp } kind;
  Transform transform;            // Trn
  std::vector<int32_t> children;  // Trn: one, Grp: any
  int32_t model = -1;             // Shp (frame 0's model)
};

struct Placement {
  int32_t model;
  Transform transform;
};

class SceneWalk {
 public:
  SceneWalk(const std::map<int32_t, Node>& nodes, const std::vector<Model>& models,
            uint64_t max_voxels)
      : nodes_(nodes), models_(models), max_voxels_(max_voxels) {}
  std::vector<Placement> run(int32_t root) {
    visit(root, Transform{});
    return std::move(out_);
  }

 private:
  void visit(int32_t id, const Transform& parent) {
    auto it = nodes_.find(id);
    if (it == nodes_.end())
      throw Error(fmt::format("malformed .vox: scene graph refers to missing node {}", id));
    if (!on_path_.insert(id).second)
      throw Error(fmt::format("malformed .vox: scene graph is recursive (node {})", id));
    // The walk recurses: a long chain of nodes must not exhaust the stack
    // (MagicaVoxel writes a handful of levels).
    if (on_path_.size() > kMaxDepth)
      throw Error(fmt::format("malformed .vox: scene graph is deeper than {} nodes", kMaxDepth));
    // A group may list one subtree many times: instancing can multiply the
    // visits exponentially with depth, so they are bounded, not just cycles.
    if (++visits_ > kMaxVisits)
      throw Error(
          fmt::format("malformed .vox: scene graph expands to more than {} nodes", kMaxVisits));
    const Node& n = it->second;
    if (n.kind == Node::Trn) {
      Transform t;
      // world = parent.rot * (rot * x + t) + parent.t
      t.rot = n.transform.rot.then(parent.rot);
      const auto pt = parent.rot.apply(n.transform.t);
      for (int a = 0; a < 3; ++a) t.t[a] = pt[a] + parent.t[a];
      for (int a = 0; a < 3; ++a)
        if (t.t[a] < -kMaxOffset || t.t[a] > kMaxOffset)
          throw Error("malformed .vox: scene graph translations exceed the 2^20 voxel grid");
      for (int32_t c : n.children) visit(c, t);
    } else if (n.kind == Node::Grp) {
      for (int32_t c : n.children) visit(c, parent);
    } else {
      const Model& m = models_[size_t(n.model)];
      voxels_ += m.voxels.size();
      if (voxels_ > max_voxels_)
        throw Error(
            fmt::format(".vox scene places more than {} voxels, more than the memory budget allows",
                        max_voxels_));
      out_.push_back({n.model, parent});
    }
    on_path_.erase(id);
  }
  static constexpr uint64_t kMaxVisits = uint64_t(1) << 20;
  static constexpr size_t kMaxDepth = 1024;
  static constexpr int64_t kMaxOffset = int64_t(1) << 22;
  const std::map<int32_t, Node>& nodes_;
  const std::vector<Model>& models_;
  uint64_t max_voxels_;
  std::set<int32_t> on_path_;
  uint64_t visits_ = 0, voxels_ = 0;
  std::vector<Placement> out_;
};

uint32_t chunk_id(const char (&s)[5]) {
  return uint32_t(uint8_t(s[0])) | uint32_t(uint8_t(s[1])) << 8 | uint32_t(uint8_t(s[2])) << 16 |
         uint32_t(uint8_t(s[3])) << 24;
}

std::string id_text(const uint8_t* p) {
  std::string s;
  for (int i = 0; i < 4; ++i) {
    const char c = char(p[i]);
    if (c >= 32 && c < 127)
      s += c;
    else
      s += fmt::format("\\x{:02x}", p[i]);
  }
  return s;
}

std::map<std::string, std::string> first_frame(Cursor& c) {
  const uint32_t frames = c.count("frame count", 4);
  if (frames == 0) throw Error(fmt::format("malformed .vox: {} chunk has no frame", c.chunk));
  auto d = c.dict();
  for (uint32_t f = 1; f < frames; ++f) c.dict();
  return d;
}

void put_i32(std::vector<uint8_t>& out, int32_t v) {
  const uint32_t u = uint32_t(v);
  for (int k = 0; k < 4; ++k) out.push_back(uint8_t(u >> (8 * k)));
}
void put_id(std::vector<uint8_t>& out, const char (&id)[5]) {
  out.insert(out.end(), id, id + 4);
}
void put_str(std::vector<uint8_t>& out, const std::string& s) {
  put_i32(out, int32_t(s.size()));
  out.insert(out.end(), s.begin(), s.end());
}
/// A leaf chunk: id, content size, no children.
void put_chunk(std::vector<uint8_t>& out, const char (&id)[5],
               const std::vector<uint8_t>& content) {
  put_id(out, id);
  put_i32(out, int32_t(content.size()));
  put_i32(out, 0);
  out.insert(out.end(), content.begin(), content.end());
}

uint8_t srgb_byte(float linear) {
  const float s = linear_to_srgb(std::clamp(linear, 0.f, 1.f));
  return uint8_t(std::lround(std::clamp(s, 0.f, 1.f) * 255.f));
}

}  // namespace

VoxelSet parse_vox(std::span<const uint8_t> bytes, const VoxelReadOptions& options) {
  const uint64_t budget = detail::voxel_budget(options);
  if (bytes.size() < 8 || std::memcmp(bytes.data(), "VOX ", 4) != 0)
    throw Error("not a MagicaVoxel .vox file (no 'VOX ' signature)");
  Cursor head{bytes.data() + 4, 4, "header"};
  const int32_t version = head.i32();
  if (version != 150 && version != 200)
    throw Error(fmt::format("unsupported .vox version {} (150 and 200 are known)", version));
  const uint8_t* p = bytes.data() + 8;
  size_t left = bytes.size() - 8;
  if (left < 12 || std::memcmp(p, "MAIN", 4) != 0)
    throw Error("malformed .vox: the MAIN chunk is missing");
  Cursor main_head{p + 4, 8, "MAIN"};
  const int32_t main_content = main_head.i32(), main_children = main_head.i32();
  if (main_content < 0 || main_children < 0 ||
      uint64_t(main_content) + uint64_t(main_children) != left - 12)
    throw Error(fmt::format(
        "malformed .vox: MAIN chunk sizes ({} + {} bytes) do not match the {} bytes after it",
        main_content, main_children, left - 12));
  p += 12 + size_t(main_content);
  left = size_t(main_children);

  std::vector<Model> models;
  size_t xyzi_seen = 0;
  std::optional<int32_t> pack;
  std::array<uint32_t, 256> palette;
  for (int i = 0; i < 256; ++i) palette[size_t(i)] = vox_default_palette(i);
  std::map<int32_t, Node> nodes;
  bool scene_graph = false;

  while (left > 0) {
    if (left < 12) throw Error("malformed .vox: truncated chunk header");
    const std::string name = id_text(p);
    uint32_t id;
    std::memcpy(&id, p, 4);
    Cursor h{p + 4, 8, "chunk header"};
    const int32_t n = h.i32(), m = h.i32();
    if (n < 0 || m < 0 || uint64_t(n) + uint64_t(m) > left - 12)
      throw Error(
          fmt::format("malformed .vox: {} chunk ({} + {} bytes) overruns the file", name, n, m));
    // Children of anything but MAIN are not part of the format: skipped
    // along with the chunk.
    Cursor c{p + 12, size_t(n), nullptr};
    const std::string chunk_name = name;
    c.chunk = chunk_name.c_str();
    if (id == chunk_id("PACK")) {
      if (pack) throw Error("malformed .vox: more than one PACK chunk");
      pack = c.i32();
    } else if (id == chunk_id("SIZE")) {
      Model model;
      for (int a = 0; a < 3; ++a) {
        model.size[a] = c.i32();
        // Voxel coordinates are bytes: a model wider than 256 is meaningless.
        if (model.size[a] < 1 || model.size[a] > 256)
          throw Error(fmt::format("malformed .vox: model {} size {} is outside 1..256",
                                  models.size(), model.size[a]));
      }
      if (models.size() != xyzi_seen)
        throw Error("malformed .vox: SIZE chunk without its XYZI chunk");
      models.push_back(std::move(model));
    } else if (id == chunk_id("XYZI")) {
      if (models.size() != xyzi_seen + 1)
        throw Error("malformed .vox: XYZI chunk without a SIZE chunk before it");
      Model& model = models.back();
      const uint32_t count = c.count("voxel count", 4);
      check_voxel_count(count, budget, ".vox model");
      model.voxels.resize(count);
      for (uint32_t v = 0; v < count; ++v) {
        std::memcpy(model.voxels[v].data(), c.p + 4 * size_t(v), 4);
        const auto& xyzi = model.voxels[v];
        for (int a = 0; a < 3; ++a)
          if (xyzi[size_t(a)] >= model.size[a])
            throw Error(fmt::format(
                "malformed .vox: model {} voxel {} at ({}, {}, {}) is outside its {}x{}x{} size",
                models.size() - 1, v, xyzi[0], xyzi[1], xyzi[2], model.size[0], model.size[1],
                model.size[2]));
        if (xyzi[3] == 0)
          throw Error(fmt::format("malformed .vox: model {} voxel {} has palette index 0 (empty)",
                                  models.size() - 1, v));
      }
      ++xyzi_seen;
    } else if (id == chunk_id("RGBA")) {
      if (n < 1024) throw Error("malformed .vox: RGBA chunk holds fewer than 256 colors");
      // Entry i of the chunk is palette index i + 1; the 256th is unused.
      for (int i = 0; i < 255; ++i) {
        uint32_t v;
        std::memcpy(&v, c.p + 4 * i, 4);
        palette[size_t(i) + 1] = v;
      }
    } else if (id == chunk_id("nTRN") || id == chunk_id("nGRP") || id == chunk_id("nSHP")) {
      scene_graph = true;
      const int32_t node_id = c.i32();
      if (node_id < 0) throw Error(fmt::format("malformed .vox: {} node id {}", name, node_id));
      Node node{Node::Trn, {}, {}, -1};
      c.dict();  // node attributes (_name, _hidden): not geometry
      if (id == chunk_id("nTRN")) {
        node.children.push_back(c.i32());
        c.i32();  // reserved
        c.i32();  // layer
        const auto frame = first_frame(c);
        if (auto r = frame.find("_r"); r != frame.end())
          node.transform.rot = parse_rotation(r->second);
        if (auto t = frame.find("_t"); t != frame.end())
          node.transform.t = parse_translation(t->second);
      } else if (id == chunk_id("nGRP")) {
        node.kind = Node::Grp;
        const uint32_t k = c.count("child count", 4);
        for (uint32_t i = 0; i < k; ++i) node.children.push_back(c.i32());
      } else {
        node.kind = Node::Shp;
        const uint32_t k = c.count("model count", 8);
        if (k == 0) throw Error("malformed .vox: nSHP chunk has no model");
        node.model = c.i32();
        c.dict();
      }
      if (!nodes.emplace(node_id, std::move(node)).second)
        throw Error(fmt::format("malformed .vox: scene graph node {} appears twice", node_id));
    }
    // MATL, LAYR, rOBJ, rCAM, NOTE, IMAP, MATT and unknown chunks: not
    // voxels; skipped by their declared size.
    p += 12 + size_t(n) + size_t(m);
    left -= 12 + size_t(n) + size_t(m);
  }
  if (models.empty()) throw Error("malformed .vox: no model (SIZE/XYZI chunks)");
  if (xyzi_seen != models.size()) throw Error("malformed .vox: SIZE chunk without its XYZI chunk");
  if (pack && *pack != int32_t(models.size()))
    throw Error(fmt::format("malformed .vox: PACK announces {} models, the file has {}", *pack,
                            models.size()));
  for (const auto& [node_id, node] : nodes)
    if (node.kind == Node::Shp && (node.model < 0 || size_t(node.model) >= models.size()))
      throw Error(fmt::format("malformed .vox: shape node {} refers to model {} of {}", node_id,
                              node.model, models.size()));

  const uint64_t max_voxels = budget / kVoxelSetBytesPerVoxel;
  std::vector<Placement> placements;
  if (scene_graph) {
    SceneWalk walk(nodes, models, max_voxels);
    placements = walk.run(0);
  } else {
    placements.push_back({0, Transform{}});
  }
  if (placements.empty()) throw Error(".vox scene graph places no model");

  // World cell of model voxel p under (R, t): center R (p + 1/2 - pivot) + t,
  // in doubled integer coordinates so that the half voxels stay exact.
  auto place = [&](const Placement& pl, const int32_t* size, std::array<int64_t, 3> p) {
    std::array<int64_t, 3> c2;
    for (int a = 0; a < 3; ++a) c2[a] = 2 * p[a] + 1 - 2 * (size[a] / 2);
    c2 = pl.transform.rot.apply(c2);
    std::array<int64_t, 3> w;
    for (int a = 0; a < 3; ++a) w[a] = (c2[a] + 2 * pl.transform.t[a] - 1) / 2;
    // MagicaVoxel z-up -> voxcast y-up: (x, y, z) -> (x, z, -y - 1).
    return std::array<int64_t, 3>{w[0], w[2], -w[1] - 1};
  };
  std::array<int64_t, 3> lo{INT64_MAX, INT64_MAX, INT64_MAX}, hi{INT64_MIN, INT64_MIN, INT64_MIN};
  for (const Placement& pl : placements) {
    const Model& m = models[size_t(pl.model)];
    for (int corner = 0; corner < 8; ++corner) {
      std::array<int64_t, 3> p;
      for (int a = 0; a < 3; ++a) p[a] = (corner >> a & 1) ? m.size[a] - 1 : 0;
      const auto w = place(pl, m.size, p);
      for (int a = 0; a < 3; ++a) lo[a] = std::min(lo[a], w[a]), hi[a] = std::max(hi[a], w[a]);
    }
  }
  int64_t extent = 1;
  for (int a = 0; a < 3; ++a) extent = std::max(extent, hi[a] - lo[a] + 1);
  if (extent > (int64_t(1) << kMaxGridLevels))
    throw Error(fmt::format(".vox scene is {} voxels wide, more than the {} voxel grid limit",
                            extent, 1 << kMaxGridLevels));

  // (code, order, palette index); the last placement of a cell wins.
  struct Entry {
    uint64_t code;
    uint64_t order;
    uint8_t color;
  };
  std::vector<Entry> entries;
  uint64_t total = 0;
  for (const Placement& pl : placements) total += models[size_t(pl.model)].voxels.size();
  entries.reserve(total);
  for (const Placement& pl : placements) {
    const Model& m = models[size_t(pl.model)];
    for (const auto& v : m.voxels) {
      const auto w = place(pl, m.size, {v[0], v[1], v[2]});
      entries.push_back(
          {morton_encode(uint32_t(w[0] - lo[0]), uint32_t(w[1] - lo[1]), uint32_t(w[2] - lo[2])),
           entries.size(), v[3]});
    }
  }
  std::sort(entries.begin(), entries.end(), [](const Entry& a, const Entry& b) {
    return a.code != b.code ? a.code < b.code : a.order < b.order;
  });
  VoxelSet set;
  set.grid = detail::unit_grid(uint32_t(extent));
  for (size_t i = 0; i < entries.size(); ++i) {
    if (i + 1 < entries.size() && entries[i + 1].code == entries[i].code) continue;
    const uint32_t rgba = palette[entries[i].color];
    set.codes.push_back(entries[i].code);
    set.colors.push_back({srgb_to_linear(float(rgba & 0xff) / 255.f),
                          srgb_to_linear(float(rgba >> 8 & 0xff) / 255.f),
                          srgb_to_linear(float(rgba >> 16 & 0xff) / 255.f),
                          float(rgba >> 24) / 255.f});
  }
  if (set.codes.empty()) throw Error(".vox file holds no voxels");
  detail::finish_voxel_set(set);
  return set;
}

VoxelSet read_vox(const std::filesystem::path& path, const VoxelReadOptions& options) {
  return detail::read_voxel_file(
      path, options, [](auto bytes, const VoxelReadOptions& o) { return parse_vox(bytes, o); });
}

PaletteQuantization quantize_palette(std::span<const std::array<uint8_t, 4>> colors,
                                     size_t max_entries) {
  if (max_entries == 0) throw Error("a palette needs at least one entry");
  PaletteQuantization q;
  // Distinct colors with their counts, in ascending order (deterministic).
  std::map<std::array<uint8_t, 4>, uint64_t> counts;
  for (const auto& c : colors) ++counts[c];
  struct Item {
    std::array<uint8_t, 4> color;
    uint64_t count;
  };
  std::vector<Item> items;
  for (const auto& [c, k] : counts) items.push_back({c, k});
  if (items.size() <= max_entries) {
    for (const Item& it : items) q.palette.push_back(it.color);
  } else {
    // Weighted median cut: split the box whose widest channel is widest at
    // the count-weighted median of that channel, until max_entries boxes.
    struct Box {
      size_t begin, end;
      int channel = 0, range = 0;
    };
    auto measure = [&](Box& b) {
      b.range = -1;
      for (int ch = 0; ch < 4; ++ch) {
        int lo = 255, hi = 0;
        for (size_t i = b.begin; i < b.end; ++i)
          lo = std::min<int>(lo, items[i].color[size_t(ch)]),
          hi = std::max<int>(hi, items[i].color[size_t(ch)]);
        if (hi - lo > b.range) b.range = hi - lo, b.channel = ch;
      }
    };
    std::vector<Box> boxes{{0, items.size()}};
    measure(boxes[0]);
    while (boxes.size() < max_entries) {
      size_t pick = boxes.size();
      for (size_t i = 0; i < boxes.size(); ++i)
        if (boxes[i].end - boxes[i].begin > 1 &&
            (pick == boxes.size() || boxes[i].range > boxes[pick].range))
          pick = i;
      if (pick == boxes.size()) break;
      Box b = boxes[pick];
      const size_t ch = size_t(b.channel);
      std::stable_sort(items.begin() + ptrdiff_t(b.begin), items.begin() + ptrdiff_t(b.end),
                       [&](const Item& x, const Item& y) { return x.color[ch] < y.color[ch]; });
      uint64_t total = 0, run = 0;
      for (size_t i = b.begin; i < b.end; ++i) total += items[i].count;
      size_t split = b.begin + 1;
      for (size_t i = b.begin; i + 1 < b.end; ++i) {
        run += items[i].count;
        split = i + 1;
        if (2 * run >= total) break;
      }
      Box left{b.begin, split}, right{split, b.end};
      measure(left);
      measure(right);
      boxes[pick] = left;
      boxes.push_back(right);
    }
    for (const Box& b : boxes) {
      uint64_t sum[4] = {0, 0, 0, 0}, total = 0;
      for (size_t i = b.begin; i < b.end; ++i) {
        for (int ch = 0; ch < 4; ++ch)
          sum[ch] += uint64_t(items[i].color[size_t(ch)]) * items[i].count;
        total += items[i].count;
      }
      std::array<uint8_t, 4> mean;
      for (int ch = 0; ch < 4; ++ch) mean[size_t(ch)] = uint8_t((sum[ch] + total / 2) / total);
      q.palette.push_back(mean);
    }
    std::sort(q.palette.begin(), q.palette.end());
    q.palette.erase(std::unique(q.palette.begin(), q.palette.end()), q.palette.end());
  }
  // Nearest entry per distinct color, then per input color.
  std::map<std::array<uint8_t, 4>, uint32_t> nearest;
  for (const auto& [c, k] : counts) {
    uint32_t best = 0;
    int64_t best_d = INT64_MAX;
    for (size_t e = 0; e < q.palette.size(); ++e) {
      int64_t d = 0;
      for (int ch = 0; ch < 4; ++ch) {
        const int64_t diff = int64_t(c[size_t(ch)]) - int64_t(q.palette[e][size_t(ch)]);
        d += diff * diff;
      }
      if (d < best_d) best_d = d, best = uint32_t(e);
    }
    nearest[c] = best;
  }
  q.index.reserve(colors.size());
  for (const auto& c : colors) q.index.push_back(nearest[c]);
  return q;
}

std::vector<uint8_t> encode_vox(const VoxelSet& voxels) {
  if (voxels.codes.empty()) throw Error("cannot write .vox: the voxel set is empty");
  if (!voxels.colors.empty() && voxels.colors.size() != voxels.codes.size())
    throw Error("cannot write .vox: colors do not match the voxels");
  const detail::Bounds3 b = detail::occupied_bounds(voxels);
  // voxcast (x, y, z) y-up -> MagicaVoxel (x, -z, y) z-up, shifted to the box.
  auto to_vox = [&](const MortonCoord& c) {
    return std::array<uint32_t, 3>{c.x - b.lo[0], b.hi[2] - c.z, c.y - b.lo[1]};
  };
  const uint32_t ext[3] = {b.hi[0] - b.lo[0] + 1, b.hi[2] - b.lo[2] + 1, b.hi[1] - b.lo[1] + 1};
  uint32_t tiles[3];
  for (int a = 0; a < 3; ++a) tiles[a] = (ext[a] + 255) / 256;

  std::vector<std::array<uint8_t, 4>> srgb;
  srgb.reserve(voxels.codes.size());
  for (size_t i = 0; i < voxels.codes.size(); ++i) {
    if (voxels.colors.empty()) {
      srgb.push_back({255, 255, 255, 255});
    } else {
      const Color& c = voxels.colors[i];
      srgb.push_back({srgb_byte(c.r), srgb_byte(c.g), srgb_byte(c.b),
                      uint8_t(std::lround(std::clamp(c.a, 0.f, 1.f) * 255.f))});
    }
  }
  const PaletteQuantization q = quantize_palette(srgb, 255);

  // Voxels per tile, tiles in x-fastest order, voxels in Morton order.
  std::map<uint64_t, std::vector<std::array<uint8_t, 4>>> per_tile;
  for (size_t i = 0; i < voxels.codes.size(); ++i) {
    const auto v = to_vox(morton_decode(voxels.codes[i]));
    const uint64_t tile = (uint64_t(v[2] / 256) * tiles[1] + v[1] / 256) * tiles[0] + v[0] / 256;
    per_tile[tile].push_back(
        {uint8_t(v[0] % 256), uint8_t(v[1] % 256), uint8_t(v[2] % 256), uint8_t(q.index[i] + 1)});
  }
  const bool single = per_tile.size() == 1 && tiles[0] == 1 && tiles[1] == 1 && tiles[2] == 1;

  std::vector<uint8_t> children;
  std::vector<std::array<int32_t, 3>> origins, sizes;
  if (!single) {
    std::vector<uint8_t> pack;
    put_i32(pack, int32_t(per_tile.size()));
    put_chunk(children, "PACK", pack);
  }
  for (const auto& [tile, list] : per_tile) {
    const uint32_t t[3] = {uint32_t(tile % tiles[0]), uint32_t(tile / tiles[0] % tiles[1]),
                           uint32_t(tile / tiles[0] / tiles[1])};
    std::array<int32_t, 3> origin, size;
    for (int a = 0; a < 3; ++a) {
      origin[size_t(a)] = int32_t(256 * t[a]);
      size[size_t(a)] = int32_t(std::min<uint32_t>(256, ext[a] - 256 * t[a]));
    }
    origins.push_back(origin);
    sizes.push_back(size);
    std::vector<uint8_t> s, x;
    for (int a = 0; a < 3; ++a) put_i32(s, size[size_t(a)]);
    put_chunk(children, "SIZE", s);
    put_i32(x, int32_t(list.size()));
    for (const auto& v : list) x.insert(x.end(), v.begin(), v.end());
    put_chunk(children, "XYZI", x);
  }
  if (!single) {
    // nTRN 0 -> nGRP 1 -> (nTRN 2k+2 -> nSHP 2k+3 -> model k); the
    // translation puts model voxel p at p - floor(size/2) + t = origin + p.
    auto dict = [](std::vector<uint8_t>& out,
                   const std::vector<std::pair<std::string, std::string>>& kv) {
      put_i32(out, int32_t(kv.size()));
      for (const auto& [k, v] : kv) put_str(out, k), put_str(out, v);
    };
    auto trn = [&](int32_t id, int32_t child, int32_t layer, const std::string& t) {
      std::vector<uint8_t> c;
      put_i32(c, id);
      dict(c, {});
      put_i32(c, child);
      put_i32(c, -1);
      put_i32(c, layer);
      put_i32(c, 1);
      if (t.empty())
        dict(c, {});
      else
        dict(c, {{"_t", t}});
      put_chunk(children, "nTRN", c);
    };
    trn(0, 1, -1, "");
    std::vector<uint8_t> g;
    put_i32(g, 1);
    dict(g, {});
    put_i32(g, int32_t(origins.size()));
    for (size_t k = 0; k < origins.size(); ++k) put_i32(g, int32_t(2 * k + 2));
    put_chunk(children, "nGRP", g);
    for (size_t k = 0; k < origins.size(); ++k) {
      const auto& o = origins[k];
      const auto& s = sizes[k];
      trn(int32_t(2 * k + 2), int32_t(2 * k + 3), 0,
          fmt::format("{} {} {}", o[0] + s[0] / 2, o[1] + s[1] / 2, o[2] + s[2] / 2));
      std::vector<uint8_t> shp;
      put_i32(shp, int32_t(2 * k + 3));
      dict(shp, {});
      put_i32(shp, 1);
      put_i32(shp, int32_t(k));
      dict(shp, {});
      put_chunk(children, "nSHP", shp);
    }
  }
  std::vector<uint8_t> rgba;
  for (size_t i = 0; i < 256; ++i) {
    // Chunk entry i is palette index i + 1; unused entries black, opaque.
    const auto c = i < q.palette.size() ? q.palette[i] : std::array<uint8_t, 4>{0, 0, 0, 255};
    rgba.insert(rgba.end(), c.begin(), c.end());
  }
  put_chunk(children, "RGBA", rgba);

  std::vector<uint8_t> out;
  put_id(out, "VOX ");
  put_i32(out, 150);
  put_id(out, "MAIN");
  put_i32(out, 0);
  if (children.size() > size_t(INT32_MAX)) throw Error("cannot write .vox: more than 2 GiB");
  put_i32(out, int32_t(children.size()));
  out.insert(out.end(), children.begin(), children.end());
  return out;
}

void write_vox(const std::filesystem::path& path, const VoxelSet& voxels) {
  const auto bytes = encode_vox(voxels);
  write_file_atomic(path, bytes.data(), bytes.size());
}

}  // namespace voxcast
