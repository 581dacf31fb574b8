// Brickmap scene files (§4.5): a Container (scene_file.hpp) with
//
//   'META' UTF-8 JSON: {"format": "brickmap", "grid": {...}, "dims": [X,Y,Z],
//          "bricks": B, "leaf_voxels": V, "normals": bool, "chunk_log2": 4,
//          "source": ..., "voxelization": ..., "source_triangles": ...}
//   'BMGH' the brickgrid header, what a streaming reader loads first (§4.5:
//          "first stored the brickgrid, with a solid bit and a LOD color"):
//            +0  u32  raw size R = 4 X Y Z
//            +4  u32  LZ4 size S
//            +8  u64  xxh64 of the raw bytes (seed 0)
//            +16 S bytes: the LZ4 block of X Y Z u32 cells in brickgrid
//                order; each 0 (empty) or a not-resident cell (state 2,
//                flags 0) carrying the brick's LOD color
//   'BMCT' the chunk table (§4.5 "an array of offsets into the file"):
//            +0  u32  chunk count C = ceil(X/16) ceil(Y/16) ceil(Z/16)
//            +4  u32  0
//            +8  C entries of 24 bytes, chunks in (cx, cy, cz) order, cx fastest:
//                +0 u64 offset of the chunk's LZ4 block in BMCK
//                +8 u32 LZ4 size, +12 u32 raw size,
//                +16 u64 xxh64 of the LZ4 block (seed 0)
//                A chunk without bricks has the all-zero entry.
//   'BMCK' the chunks' LZ4 blocks, each compressed on its own so that a chunk
//          loads independently. A chunk's raw bytes: for every non-empty cell
//          of the chunk (16^3 cells, x fastest) the brick's 64-byte mask
//          (u64 words, brickmap.hpp), then one u32 ABGR8 color per solid voxel
//          in bit order, then (META "normals") one u32 cube-face normal each.
//
// Loading validates every size, offset, count and hash before using it and
// refuses a brick whose LOD color disagrees with the header, so a loaded
// world is exactly what was saved. Little-endian throughout.
#include <lz4.h>
#include <xxhash.h>

#include <algorithm>
#include <bit>
#include <cstring>
#include <nlohmann/json.hpp>
#include <string>

#include "io/meta_json.hpp"
#include "voxcast/brickmap.hpp"
#include "voxcast/error.hpp"

namespace voxcast::brickmap {
namespace {

constexpr uint32_t kHeaderSection = fourcc("BMGH");
constexpr uint32_t kTableSection = fourcc("BMCT");
constexpr uint32_t kChunkSection = fourcc("BMCK");
constexpr uint32_t kChunkSide = 1u << kChunkLog2;
constexpr size_t kHeaderPrefix = 16, kTablePrefix = 8, kEntryBytes = 24;
// Largest raw chunk: every cell a full brick with colors and normals.
constexpr uint64_t kMaxChunkRaw =
    uint64_t(kChunkSide) * kChunkSide * kChunkSide * (64 + kBrickVoxels * 8);
static_assert(kMaxChunkRaw < (uint64_t(1) << 31), "LZ4 sizes are ints");

static_assert(std::endian::native == std::endian::little, "scene files are little-endian");

template <class T>
T load_le(const uint8_t* p) {
  T v;
  std::memcpy(&v, p, sizeof(T));
  return v;
}
template <class T>
void put_le(std::vector<uint8_t>& out, T v) {
  const size_t at = out.size();
  out.resize(at + sizeof(T));
  std::memcpy(&out[at], &v, sizeof(T));
}

[[noreturn]] void corrupt(const std::string& what) {
  throw Error("corrupt scene: " + what);
}

std::vector<uint8_t> compress(const uint8_t* data, size_t size) {
  std::vector<uint8_t> out(static_cast<size_t>(LZ4_compressBound(int(size))));
  const int n =
      LZ4_compress_default(reinterpret_cast<const char*>(data), reinterpret_cast<char*>(out.data()),
                           int(size), int(out.size()));
  if (n <= 0) throw Error("brickmap: LZ4 compression failed");
  out.resize(size_t(n));
  return out;
}

// Decompresses exactly `raw` bytes from [src, src + size) or refuses.
std::vector<uint8_t> decompress(const uint8_t* src, size_t size, size_t raw, const char* what) {
  std::vector<uint8_t> out(raw);
  const int n = LZ4_decompress_safe(reinterpret_cast<const char*>(src),
                                    reinterpret_cast<char*>(out.data()), int(size), int(raw));
  if (n < 0 || size_t(n) != raw) corrupt(std::string(what) + " does not decompress to its size");
  return out;
}

struct ChunkGrid {
  uint32_t n[3];
  uint64_t count() const { return uint64_t(n[0]) * n[1] * n[2]; }
};
ChunkGrid chunk_grid(const std::array<uint32_t, 3>& dims) {
  ChunkGrid c;
  for (int a = 0; a < 3; ++a) c.n[a] = (dims[size_t(a)] + kChunkSide - 1) >> kChunkLog2;
  return c;
}

// Calls fn(cell index) for every brickgrid cell of chunk (cx, cy, cz), x fastest.
template <class Fn>
void for_chunk_cells(const World& w, uint32_t cx, uint32_t cy, uint32_t cz, Fn&& fn) {
  const std::array<uint32_t, 3>& d = w.dims();
  for (uint32_t k = cz * kChunkSide; k < std::min(d[2], (cz + 1) * kChunkSide); ++k)
    for (uint32_t j = cy * kChunkSide; j < std::min(d[1], (cy + 1) * kChunkSide); ++j)
      for (uint32_t i = cx * kChunkSide; i < std::min(d[0], (cx + 1) * kChunkSide); ++i)
        fn(w.cell_index(i, j, k));
}

}  // namespace

Container save_world(const World& w, const SceneInfo& info) {
  const WorldStats st = w.stats();
  const std::array<uint32_t, 3>& d = w.dims();
  // Brickgrid header: empty or not resident with the LOD color.
  std::vector<uint32_t> header(w.cells().size(), 0);
  for (size_t i = 0; i < header.size(); ++i) {
    const uint32_t c = w.cells()[i];
    if (c == 0) continue;
    header[i] = not_resident_cell(cell_state(c) == kStateResident ? w.brick(cell_brick(c)).lod
                                                                  : cell_lod_abgr(c));
    if (cell_state(c) != kStateResident)
      throw Error("brickmap: cannot save a world with bricks that are not resident");
  }
  const uint8_t* hb = reinterpret_cast<const uint8_t*>(header.data());
  const size_t hbytes = header.size() * 4;
  std::vector<uint8_t> gh;
  const std::vector<uint8_t> hz = compress(hb, hbytes);
  put_le<uint32_t>(gh, uint32_t(hbytes));
  put_le<uint32_t>(gh, uint32_t(hz.size()));
  put_le<uint64_t>(gh, XXH64(hb, hbytes, 0));
  gh.insert(gh.end(), hz.begin(), hz.end());

  const ChunkGrid cg = chunk_grid(d);
  std::vector<uint8_t> table, data, raw;
  put_le<uint32_t>(table, uint32_t(cg.count()));
  put_le<uint32_t>(table, 0);
  for (uint32_t cz = 0; cz < cg.n[2]; ++cz)
    for (uint32_t cy = 0; cy < cg.n[1]; ++cy)
      for (uint32_t cx = 0; cx < cg.n[0]; ++cx) {
        raw.clear();
        for_chunk_cells(w, cx, cy, cz, [&](uint64_t ci) {
          const uint32_t c = w.cell(ci);
          if (c == 0) return;
          const Brick& b = w.brick(cell_brick(c));
          const size_t count = size_t(brick_popcount(b));
          const size_t at = raw.size();
          raw.resize(at + 64 + count * (w.has_normals() ? 8 : 4));
          std::memcpy(&raw[at], b.mask, 64);
          std::memcpy(&raw[at + 64], &w.colors()[b.color], count * 4);
          if (w.has_normals())
            std::memcpy(&raw[at + 64 + count * 4], &w.normals()[b.color], count * 4);
        });
        if (raw.empty()) {
          put_le<uint64_t>(table, 0), put_le<uint32_t>(table, 0), put_le<uint32_t>(table, 0);
          put_le<uint64_t>(table, 0);
          continue;
        }
        const std::vector<uint8_t> z = compress(raw.data(), raw.size());
        put_le<uint64_t>(table, data.size());
        put_le<uint32_t>(table, uint32_t(z.size()));
        put_le<uint32_t>(table, uint32_t(raw.size()));
        put_le<uint64_t>(table, XXH64(z.data(), z.size(), 0));
        data.insert(data.end(), z.begin(), z.end());
      }

  nlohmann::json meta = meta::info_to_json(info);
  meta.update({{"format", kFormatName},
               {"grid", meta::grid_to_json(w.grid())},
               {"dims", {d[0], d[1], d[2]}},
               {"bricks", st.bricks},
               {"leaf_voxels", st.voxels},
               {"normals", w.has_normals()},
               {"chunk_log2", kChunkLog2}});
  Container c;
  c.add(meta::kSection, meta::dump(meta));
  c.add(kHeaderSection, std::move(gh));
  c.add(kTableSection, std::move(table));
  c.add(kChunkSection, std::move(data));
  return c;
}

void save_scene(const std::filesystem::path& path, const World& world, const SceneInfo& info) {
  save_world(world, info).write(path);
}

World load_world(const Container& c, SceneInfo* info) {
  const nlohmann::json meta = meta::parse(c);
  GridTransform grid;
  SceneInfo si;
  bool normals = false;
  uint64_t bricks = 0, voxels = 0;
  std::array<uint64_t, 3> dims{};
  try {
    using namespace meta;
    if (get_string(meta, "format") != kFormatName) bad("format is not 'brickmap'");
    grid = grid_from_json(meta, 0);
    info_from_json(meta, &si);
    const nlohmann::json& dj = field(meta, "dims");
    if (!dj.is_array() || dj.size() != 3) bad("'dims' is not an array of 3 integers");
    for (size_t a = 0; a < 3; ++a) {
      if (!dj[a].is_number_unsigned()) bad("'dims' is not an array of 3 integers");
      dims[a] = dj[a].get<uint64_t>();
    }
    bricks = get_uint(meta, "bricks", 0, kMaxBricks);
    voxels = get_uint(meta, "leaf_voxels", 0, bricks * kBrickVoxels);
    const nlohmann::json& nj = field(meta, "normals");
    if (!nj.is_boolean()) bad("'normals' is not a boolean");
    normals = nj.get<bool>();
    if (get_uint(meta, "chunk_log2", 0, 31) != uint64_t(kChunkLog2)) bad("'chunk_log2' is not 4");
  } catch (const nlohmann::json::exception& e) {
    throw Error("corrupt scene: META section: " + meta::json_error_text(e));
  }
  if (!grid.placement_is_valid()) meta::bad("'grid' is not a valid placement");
  World w(grid, normals);  // throws for grids past kMaxGridCells
  for (size_t a = 0; a < 3; ++a)
    if (dims[a] != w.dims()[a]) meta::bad("'dims' does not match the grid");

  // Brickgrid header.
  const std::vector<uint8_t>& gh = c.get(kHeaderSection);
  if (gh.size() < kHeaderPrefix) corrupt("BMGH section is shorter than its 16-byte prefix");
  const uint64_t raw_size = load_le<uint32_t>(&gh[0]), z_size = load_le<uint32_t>(&gh[4]);
  if (raw_size != w.cells().size() * 4)
    corrupt("BMGH raw size " + std::to_string(raw_size) + " is not 4 bytes per brickgrid cell");
  if (z_size != gh.size() - kHeaderPrefix) corrupt("BMGH LZ4 size does not match the section");
  const std::vector<uint8_t> hraw =
      decompress(&gh[kHeaderPrefix], size_t(z_size), size_t(raw_size), "BMGH brickgrid");
  if (XXH64(hraw.data(), hraw.size(), 0) != load_le<uint64_t>(&gh[8]))
    corrupt("BMGH brickgrid checksum mismatch");
  std::vector<uint32_t> header(w.cells().size());
  if (!header.empty()) std::memcpy(header.data(), hraw.data(), hraw.size());
  uint64_t listed = 0;
  for (uint32_t h : header) {
    if (h == 0) continue;
    if (cell_state(h) != kStateNotResident || CellFlags::get(h) != 0)
      corrupt("BMGH holds a cell that is neither empty nor a brick's LOD color");
    ++listed;
  }
  if (listed != bricks)
    corrupt("BMGH lists " + std::to_string(listed) + " bricks, META " + std::to_string(bricks));

  // Chunk table and chunks.
  const ChunkGrid cg = chunk_grid(w.dims());
  const std::vector<uint8_t>& table = c.get(kTableSection);
  const std::vector<uint8_t>& data = c.get(kChunkSection);
  if (table.size() != kTablePrefix + kEntryBytes * cg.count() ||
      load_le<uint32_t>(&table[0]) != cg.count() || load_le<uint32_t>(&table[4]) != 0)
    corrupt("BMCT section is not a table of " + std::to_string(cg.count()) + " chunks");
  std::vector<uint32_t> colors(kBrickVoxels), norms(kBrickVoxels);
  uint64_t loaded_voxels = 0;
  uint64_t e = kTablePrefix;
  for (uint32_t cz = 0; cz < cg.n[2]; ++cz)
    for (uint32_t cy = 0; cy < cg.n[1]; ++cy)
      for (uint32_t cx = 0; cx < cg.n[0]; ++cx, e += kEntryBytes) {
        const std::string name = "BMCK chunk (" + std::to_string(cx) + "," + std::to_string(cy) +
                                 "," + std::to_string(cz) + ")";
        const uint64_t offset = load_le<uint64_t>(&table[e]);
        const uint64_t zs = load_le<uint32_t>(&table[e + 8]),
                       rs = load_le<uint32_t>(&table[e + 12]);
        const uint64_t hash = load_le<uint64_t>(&table[e + 16]);
        bool any = false;
        for_chunk_cells(w, cx, cy, cz, [&](uint64_t ci) { any = any || header[ci] != 0; });
        if (!any) {
          if (offset != 0 || zs != 0 || rs != 0 || hash != 0)
            corrupt(name + " has data but no bricks in the brickgrid");
          continue;
        }
        if (zs == 0 || offset > data.size() || zs > data.size() - offset)
          corrupt(name + " lies outside the BMCK section");
        if (rs > kMaxChunkRaw) corrupt(name + " raw size is too large");
        if (XXH64(&data[size_t(offset)], size_t(zs), 0) != hash)
          corrupt(name + " checksum mismatch");
        const std::vector<uint8_t> raw =
            decompress(&data[size_t(offset)], size_t(zs), size_t(rs), name.c_str());
        size_t at = 0;
        for_chunk_cells(w, cx, cy, cz, [&](uint64_t ci) {
          if (header[ci] == 0) return;
          if (raw.size() - at < 64) corrupt(name + " ends inside a brick mask");
          uint64_t mask[8];
          std::memcpy(mask, &raw[at], 64);
          at += 64;
          size_t count = 0;
          for (uint64_t m : mask) count += size_t(std::popcount(m));
          if (count == 0) corrupt(name + " holds an empty brick");
          const size_t need = count * (normals ? 8 : 4);
          if (raw.size() - at < need) corrupt(name + " ends inside a brick's colors");
          std::memcpy(colors.data(), &raw[at], count * 4);
          if (normals) std::memcpy(norms.data(), &raw[at + count * 4], count * 4);
          at += need;
          w.set_brick(ci, mask, colors.data(), norms.data());
          if (CellPayload::get(w.brick(cell_brick(w.cell(ci))).lod) != CellPayload::get(header[ci]))
            corrupt(name + " holds a brick whose LOD color differs from the brickgrid's");
          loaded_voxels += count;
        });
        if (at != raw.size()) corrupt(name + " has bytes after its last brick");
      }
  if (loaded_voxels != voxels)
    corrupt("the chunks hold " + std::to_string(loaded_voxels) + " voxels, META " +
            std::to_string(voxels));
  si.leaf_voxels = voxels;
  if (info) *info = std::move(si);
  return w;
}

}  // namespace voxcast::brickmap
