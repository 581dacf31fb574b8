// Brickmap scene files (§4.5): a Container (scene_file.hpp) with
//
//   'META' UTF-8 JSON: {"format": "brickmap", "grid": {...}, "dims": [X,Y,Z]
//          (X = Z = ceil(N / 8); Y <= X: a brickgrid cut off in y, World()),
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
//   'BMCV' (a generated terrain's world only, when edits carved it; World::
//          carved): +0 u64 count N, then N entries of 72 bytes in ascending
//          cell order: u64 brickgrid cell index, u64[8] carved-voxel mask
//          (Brick::mask's layout, never all zero).
//   META "terrain": {"size": [X, Y, Z], "seed": S} for a generated terrain
//          (brickmap_terrain.hpp): its density function is part of the world
//          (the hidden voxels it left out come back when an edit exposes
//          them); the grid must be terrain_grid() of it.
//
// Loading validates every size, offset, count and hash before using it and
// refuses a brick whose LOD color disagrees with the header, so a loaded
// world is exactly what was saved. Little-endian throughout.
#include <fmt/printf.h>
#include <xxhash.h>

#include <algorithm>
#include <cstring>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>

#include "brickmap/codec.hpp"
#include "io/meta_json.hpp"
#include "voxcast/brickmap.hpp"
#include "voxcast/brickmap_file.hpp"
#include "voxcast/brickmap_terrain.hpp"
#include "voxcast/error.hpp"
#include "voxcast/format_registry.hpp"

namespace voxcast::brickmap {
namespace {

using namespace codec;

constexpr uint32_t kHeaderSection = fourcc("BMGH");
constexpr uint32_t kTableSection = fourcc("BMCT");
constexpr uint32_t kChunkSection = fourcc("BMCK");
constexpr uint32_t kCarvedSection = fourcc("BMCV");
constexpr size_t kTablePrefix = 8, kEntryBytes = 24;

struct Section {
  uint32_t id;
  std::vector<uint8_t> bytes;
};

// The four sections of the world, in the order they are written.
std::vector<Section> world_sections(const World& w, const SceneInfo& info) {
  const WorldStats st = w.stats();
  const std::array<uint32_t, 3>& d = w.dims();
  for (uint32_t c : w.cells())
    if (c != 0 && cell_state(c) != kStateResident)
      throw Error("brickmap: cannot save a world with bricks that are not resident");
  std::vector<uint8_t> gh = encode_grid_header(w);
  const ChunkGrid cg = chunk_grid(d);
  std::vector<uint8_t> table, data, raw;
  put_le<uint32_t>(table, uint32_t(cg.count()));
  put_le<uint32_t>(table, 0);
  for (uint64_t chunk = 0; chunk < cg.count(); ++chunk) {
    encode_chunk(w, cg, chunk, &raw);
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
  if (w.terrain()) {
    const TerrainSource& t = *w.terrain();
    meta["terrain"] = {{"size", {t.size[0], t.size[1], t.size[2]}}, {"seed", t.seed}};
  }
  std::vector<Section> out;
  out.push_back({meta::kSection, meta::dump(meta)});
  out.push_back({kHeaderSection, std::move(gh)});
  out.push_back({kTableSection, std::move(table)});
  out.push_back({kChunkSection, std::move(data)});
  if (!w.carved().empty()) {
    std::vector<uint8_t> cv;
    put_le<uint64_t>(cv, w.carved().size());
    for (const auto& [cell, mask] : w.carved()) {
      put_le<uint64_t>(cv, cell);
      for (uint64_t m : mask) put_le<uint64_t>(cv, m);
    }
    out.push_back({kCarvedSection, std::move(cv)});
  }
  return out;
}

// Bytes [offset, offset + size) of BMCK read container chunk by container
// chunk; false when one of them fails its hash (the reader's message in *why).
bool read_chunk_bytes(const ContainerReader& c, uint64_t offset, uint64_t size,
                      std::vector<uint8_t>* out, std::string* why) {
  const SectionInfo& s = c.section(kChunkSection);
  out->resize(size_t(size));
  uint64_t done = 0;
  while (done < size) {
    const uint64_t at = offset + done;
    const uint32_t k = uint32_t(at / s.chunk_bytes);
    std::vector<uint8_t> piece;
    try {
      piece = c.read_chunk(kChunkSection, k);
    } catch (const Error& e) {
      *why = e.what();
      return false;
    }
    const uint64_t from = at - uint64_t(k) * s.chunk_bytes;
    const uint64_t n = std::min<uint64_t>(size - done, piece.size() - from);
    std::memcpy(out->data() + done, piece.data() + from, size_t(n));
    done += n;
  }
  return true;
}

}  // namespace

std::optional<TerrainSource> codec::meta_terrain(const nlohmann::json& meta,
                                                 const GridTransform& grid, uint32_t height_cells) {
  using namespace meta;
  if (!meta.contains("terrain")) return std::nullopt;
  const nlohmann::json& t = meta["terrain"];
  if (!t.is_object()) bad("'terrain' is not an object");
  const nlohmann::json& sj = field(t, "size");
  if (!sj.is_array() || sj.size() != 3) bad("'terrain.size' is not an array of 3 integers");
  TerrainSource out;
  TerrainOptions o;
  for (size_t a = 0; a < 3; ++a) {
    if (!sj[a].is_number_unsigned() || sj[a].get<uint64_t>() < 16 || sj[a].get<uint64_t>() > 65536)
      bad("'terrain.size' is not 3 integers in 16 .. 65536");
    out.size[a] = o.size[a] = uint32_t(sj[a].get<uint64_t>());
  }
  out.seed = o.seed = get_uint(t, "seed", 0, UINT64_MAX);
  // The density function is evaluated in the grid's voxel coordinates: the
  // grid must be the one the generator placed the terrain in.
  const GridTransform g = terrain_grid(o);
  if (g.resolution != grid.resolution || g.levels != grid.levels ||
      g.voxel_size != grid.voxel_size || g.origin.x != grid.origin.x ||
      g.origin.y != grid.origin.y || g.origin.z != grid.origin.z ||
      height_cells != (out.size[1] + kBrickSide - 1) / kBrickSide)
    bad("'terrain' does not match the grid");
  return out;
}

uint32_t codec::meta_height_cells(const nlohmann::json& meta, const GridTransform& grid) {
  using namespace meta;
  const nlohmann::json& dj = field(meta, "dims");
  if (!dj.is_array() || dj.size() != 3) bad("'dims' is not an array of 3 integers");
  uint64_t dims[3];
  for (size_t a = 0; a < 3; ++a) {
    if (!dj[a].is_number_unsigned()) bad("'dims' is not an array of 3 integers");
    dims[a] = dj[a].get<uint64_t>();
  }
  const uint64_t n = (uint64_t(grid.resolution) + kBrickSide - 1) >> kBrickLog2;
  if (dims[0] != n || dims[2] != n || dims[1] < 1 || dims[1] > n)
    bad("'dims' does not match the grid");
  return uint32_t(dims[1]);
}

Container save_world(const World& w, const SceneInfo& info) {
  Container c;
  for (Section& s : world_sections(w, info)) c.add(s.id, std::move(s.bytes));
  return c;
}

void write_world(ContainerWriter& out, const World& w, const SceneInfo& info) {
  for (const Section& s : world_sections(w, info)) out.add(s.id, s.bytes);
}

void save_scene(const std::filesystem::path& path, const World& world, const SceneInfo& info) {
  ContainerWriter writer(path);
  write_world(writer, world, info);
  writer.commit();
  remove_journal(path);  // of the world replaced
}

World load_world(const Container& in, SceneInfo* info) {
  return load_world(ContainerReader::from_bytes(in.serialize()), info);
}

World load_world(const ContainerReader& c, SceneInfo* info) {
  return read_world(c, info, nullptr);
}

World read_world(const ContainerReader& c, SceneInfo* info, std::vector<ChunkFailure>* refused,
                 const std::filesystem::path* file) {
  const nlohmann::json meta = meta::parse(c);
  GridTransform grid;
  SceneInfo si;
  bool normals = false;
  uint64_t bricks = 0, voxels = 0;
  uint32_t height_cells = 0;
  std::optional<TerrainSource> terrain;
  try {
    using namespace meta;
    if (get_string(meta, "format") != kFormatName) bad("format is not 'brickmap'");
    grid = grid_from_json(meta, 0);
    info_from_json(meta, &si);
    height_cells = meta_height_cells(meta, grid);
    bricks = get_uint(meta, "bricks", 0, kMaxBricks);
    voxels = get_uint(meta, "leaf_voxels", 0, bricks * kBrickVoxels);
    const nlohmann::json& nj = field(meta, "normals");
    if (!nj.is_boolean()) bad("'normals' is not a boolean");
    normals = nj.get<bool>();
    if (get_uint(meta, "chunk_log2", 0, 31) != uint64_t(kChunkLog2)) bad("'chunk_log2' is not 4");
    if (grid.placement_is_valid()) terrain = meta_terrain(meta, grid, height_cells);
  } catch (const nlohmann::json::exception& e) {
    throw Error("corrupt scene: META section: " + meta::json_error_text(e));
  }
  if (!grid.placement_is_valid()) meta::bad("'grid' is not a valid placement");
  World w(grid, normals, height_cells);  // throws for grids past kMaxGridCells
  w.set_terrain(terrain);
  if (c.has(kCarvedSection)) {
    if (!terrain) corrupt("BMCV section in a world that is no generated terrain");
    const std::vector<uint8_t> cv = c.read(kCarvedSection);
    if (cv.size() < 8) corrupt("BMCV section is too short");
    const uint64_t n = load_le<uint64_t>(cv.data());
    if (n > w.cells().size() || cv.size() != 8 + 72 * n)
      corrupt("BMCV section is not a list of " + std::to_string(n) + " carved cells");
    uint64_t last = 0;
    for (uint64_t e = 0; e < n; ++e) {
      const uint8_t* p = &cv[size_t(8 + 72 * e)];
      const uint64_t cell = load_le<uint64_t>(p);
      if (cell >= w.cells().size() || (e > 0 && cell <= last))
        corrupt("BMCV section: cell indices out of range or not ascending");
      VoxelMask m;
      for (size_t q = 0; q < 8; ++q) m[q] = load_le<uint64_t>(p + 8 + 8 * q);
      if (m == VoxelMask{}) corrupt("BMCV section lists a cell without carved voxels");
      w.set_carved(cell, m);
      last = cell;
    }
  }

  const std::vector<uint8_t> gh = c.read(kHeaderSection);
  const std::vector<uint32_t> header =
      decode_grid_header(gh.data(), gh.size(), w.cells().size(), "BMGH section");
  uint64_t listed = 0;
  for (uint32_t h : header) listed += h != 0;
  if (listed != bricks)
    corrupt("BMGH lists " + std::to_string(listed) + " bricks, META " + std::to_string(bricks));

  // Chunk table and chunks.
  const ChunkGrid cg = chunk_grid(w.dims());
  const std::vector<uint8_t> table = c.read(kTableSection);
  if (table.size() != kTablePrefix + kEntryBytes * cg.count() ||
      load_le<uint32_t>(&table[0]) != cg.count() || load_le<uint32_t>(&table[4]) != 0)
    corrupt("BMCT section is not a table of " + std::to_string(cg.count()) + " chunks");
  const uint64_t data_size = c.section(kChunkSection).size;
  // Strict: the whole section, every hash checked (load_scene's rule).
  std::vector<uint8_t> all;
  if (!refused) all = c.read(kChunkSection);
  std::vector<uint8_t> block;
  uint64_t loaded_voxels = 0;
  // The occupancy, pyramid and clearances once for all the loaded cells.
  std::vector<uint64_t> touched;
  for (uint64_t chunk = 0; chunk < cg.count(); ++chunk) {
    const uint64_t e = kTablePrefix + kEntryBytes * chunk;
    const std::string name = "BMCK " + chunk_name(cg, chunk);
    const uint64_t offset = load_le<uint64_t>(&table[e]);
    const uint64_t zs = load_le<uint32_t>(&table[e + 8]), rs = load_le<uint32_t>(&table[e + 12]);
    const uint64_t hash = load_le<uint64_t>(&table[e + 16]);
    bool any = false;
    for_chunk_cells(w, cg, chunk, [&](uint64_t ci, uint32_t) { any = any || header[ci] != 0; });
    if (!any) {
      if (offset != 0 || zs != 0 || rs != 0 || hash != 0)
        corrupt(name + " has data but no bricks in the brickgrid");
      continue;
    }
    // The table is validated for every chunk (a damaged table refuses the
    // world); a chunk's own bytes may be refused alone.
    if (zs == 0 || offset > data_size || zs > data_size - offset)
      corrupt(name + " lies outside the BMCK section");
    if (rs > kMaxChunkRaw) corrupt(name + " raw size is too large");
    try {
      const uint8_t* z;
      if (refused && file) {
        // Straight from the file: the chunk's own checksum decides, so one
        // damaged chunk does not take the others of its container chunk.
        std::ifstream in(*file, std::ios::binary);
        block.resize(size_t(zs));
        in.seekg(std::streamoff(c.section(kChunkSection).offset + offset));
        if (!in.read(reinterpret_cast<char*>(block.data()), std::streamsize(zs)))
          throw Error(name + " cannot be read from the file");
        z = block.data();
      } else if (refused) {
        std::string why;
        if (!read_chunk_bytes(c, offset, zs, &block, &why)) throw Error(why);
        z = block.data();
      } else {
        z = &all[size_t(offset)];
      }
      if (XXH64(z, size_t(zs), 0) != hash) corrupt(name + " checksum mismatch");
      const std::vector<uint8_t> raw = decompress(z, size_t(zs), size_t(rs), name);
      std::vector<ChunkBrick> got = decode_chunk(
          w, cg, chunk, raw, name, [&](uint64_t ci, uint32_t) { return header[ci] != 0; });
      for (ChunkBrick& b : got) {
        w.set_brick(b.cell, b.mask, b.colors.data(), b.normals.data(), 0, nullptr, false);
        touched.push_back(b.cell);
        if (CellPayload::get(w.brick(cell_brick(w.cell(b.cell))).lod) !=
            CellPayload::get(header[b.cell])) {
          // Undo the chunk's bricks before refusing it.
          for (const ChunkBrick& u : got)
            w.set_brick(u.cell, std::array<uint64_t, 8>{}.data(), nullptr, nullptr, 0, nullptr,
                        false);
          corrupt(name + " holds a brick whose LOD color differs from the brickgrid's");
        }
        loaded_voxels += b.colors.size();
      }
    } catch (const Error& err) {
      if (!refused) throw;
      refused->push_back({chunk, err.what()});
    }
  }
  w.update_occupancy(touched);
  if ((!refused || refused->empty()) && loaded_voxels != voxels)
    corrupt("the chunks hold " + std::to_string(loaded_voxels) + " voxels, META " +
            std::to_string(voxels));
  si.leaf_voxels = refused && !refused->empty() ? loaded_voxels : voxels;
  if (info) *info = std::move(si);
  return w;
}

namespace {

const World& world_of(const Structure& s) {
  const auto* b = dynamic_cast<const BrickmapStructure*>(&s);
  if (!b) throw Error("internal: the brickmap format was handed a " + s.name() + " structure");
  return b->world();
}

LoadedStructure as_structure(World w) {
  return std::make_unique<BrickmapStructure>(std::make_shared<const World>(std::move(w)));
}

// `voxcast info` for brickmap worlds: bricks and memory per component, the
// rows of brickmap §5.1 Table 2.
SceneDescription describe(const Structure& s, const DescribeStyle& style) {
  const World& w = world_of(s);
  const WorldStats st = w.stats();
  nlohmann::json j;
  j["leaf_voxels"] = st.voxels;
  j["bricks"] = st.bricks;
  j["brickgrid_dims"] = {w.dims()[0], w.dims()[1], w.dims()[2]};
  j["occupancy_dims"] = {w.occupancy_dims()[0], w.occupancy_dims()[1], w.occupancy_dims()[2]};
  j["normals"] = w.has_normals();
  j["memory"] = {{"brickgrid", st.grid_bytes},  {"occupancy", st.occupancy_bytes},
                 {"pyramid", st.pyramid_bytes}, {"clearance", st.clearance_bytes},
                 {"bricks", st.brick_bytes},    {"colors", st.color_bytes},
                 {"normals", st.normal_bytes},  {"total", st.total_bytes()}};
  j["bits_per_voxel"] = st.bits_per_voxel();
  SceneDescription out;
  out.grid = w.grid();
  out.json = j.dump();
  out.summary = fmt::sprintf(
      "structure   brickmap world: 8^3 brickmaps, brickgrid %ux%ux%u, occupancy %ux%ux%u, %s\n",
      w.dims()[0], w.dims()[1], w.dims()[2], w.occupancy_dims()[0], w.occupancy_dims()[1],
      w.occupancy_dims()[2], w.has_normals() ? "colors + normals per voxel" : "colors per voxel");
  out.voxels = fmt::sprintf("%llu in %llu bricks (%.1f per brick)", (unsigned long long)st.voxels,
                            (unsigned long long)st.bricks,
                            st.bricks ? double(st.voxels) / double(st.bricks) : 0.0);
  const double v = st.voxels ? double(st.voxels) : 1.0;
  std::string& t = out.details;
  t += "memory                    bytes   bits/voxel\n";
  const auto row = [&](const char* name, uint64_t bytes) {
    t += fmt::sprintf("  %-14s %14s  %10.3f\n", name, style.bytes(double(bytes)),
                      double(bytes) * 8 / v);
  };
  row("brickgrid", st.grid_bytes);
  row("occupancy", st.occupancy_bytes);
  row("pyramid", st.pyramid_bytes);
  row("clearance", st.clearance_bytes);
  row("bricks", st.brick_bytes);
  row("colors", st.color_bytes);
  row("normals", st.normal_bytes);
  row("total", st.total_bytes());
  return out;
}

}  // namespace

void register_format(FormatRegistry& registry) {
  SceneFormat f;
  f.name = kFormatName;
  f.description = "brickmap world (van Wingerden 2015)";
  // The builder fills gray for a voxel set without colors, but a world
  // always stores colors (edits paint them), so it is built with attributes.
  f.attributes_optional = false;
  f.build = [](const VoxelSet& voxels, const FormatBuildOptions&) -> LoadedStructure {
    return as_structure(build_world(voxels));
  };
  f.save = [](ContainerWriter& w, const Structure& s, const SceneInfo& info) {
    write_world(w, world_of(s), info);
  };
  f.load = [](const ContainerReader& r, SceneInfo* info) -> LoadedStructure {
    return as_structure(load_world(r, info));
  };
  // With the edit journal beside the file (brickmap_file.hpp): strict as
  // load, then the committed transactions.
  f.load_file = [](const std::filesystem::path& path, const ContainerReader& r,
                   SceneInfo* info) -> LoadedStructure {
    SceneInfo si;
    World w = read_world(r, &si, nullptr);
    replay_journal(path, w, &si, nullptr);
    if (info) *info = std::move(si);
    return as_structure(std::move(w));
  };
  f.occupied = [](const Structure& s) { return world_of(s).occupied_bounds(); };
  f.describe = describe;
  f.build_summary = [](const Structure& s, const SceneInfo& info, const DescribeStyle& style) {
    const World& w = world_of(s);
    const WorldStats st = w.stats();
    return fmt::sprintf(
        "%u^3 grid (%d levels), %llu leaf voxels, %llu bricks, %s (%.2f bits/leaf voxel)",
        w.grid().resolution, w.grid().levels, (unsigned long long)info.leaf_voxels,
        (unsigned long long)st.bricks, style.bytes(double(st.total_bytes())), st.bits_per_voxel());
  };
  registry.add(std::move(f));
}

}  // namespace voxcast::brickmap
