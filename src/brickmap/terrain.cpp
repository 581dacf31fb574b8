// Procedural terrain into brickmap chunks (brickmap_terrain.hpp documents
// the density function and the file; the sections are format.cpp's).
#include <xxhash.h>

#include <algorithm>
#include <atomic>
#include <bit>
#include <cmath>
#include <nlohmann/json.hpp>
#include <thread>
#include <vector>

#include "brickmap/codec.hpp"
#include "io/meta_json.hpp"
#include "voxcast/brickmap.hpp"
#include "voxcast/brickmap_file.hpp"
#include "voxcast/brickmap_terrain.hpp"
#include "voxcast/container.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo.hpp"
#include "voxcast/progress.hpp"

namespace voxcast::brickmap {
namespace {

using namespace codec;

// ---- Integer value noise ----

// MurmurHash3's 64-bit finalizer.
inline uint64_t mix64(uint64_t h) {
  h = (h ^ (h >> 33)) * 0xff51afd7ed558ccdull;
  h = (h ^ (h >> 33)) * 0xc4ceb9fe1a85ec53ull;
  return h ^ (h >> 33);
}

// Lattice value in [-32768, 32767].
inline int64_t lattice(uint64_t seed, uint64_t salt, int64_t i, int64_t j, int64_t k) {
  const uint64_t h =
      mix64(seed * 0x9E3779B97F4A7C15ull ^ salt * 0xD6E8FEB86659FD93ull ^
            uint64_t(i) * 0xA0761D6478BD642Full ^ uint64_t(j) * 0xE7037ED1A0B428DBull ^
            uint64_t(k) * 0x8EBC6AF09C88C6E3ull);
  return int64_t(h >> 48) - 32768;
}

// Smoothstep weight in [0, 65536] of the offset `frac` in a cell of 2^p.
inline int64_t weight(int64_t frac, int p) {
  const int64_t t = frac << (16 - p);
  return ((t * t) >> 16) * (3 * 65536 - 2 * t) >> 16;
}

inline int64_t lerp(int64_t a, int64_t b, int64_t s) {
  return a + (((b - a) * s) >> 16);
}

int64_t noise2(uint64_t seed, uint64_t salt, int64_t x, int64_t z, int p) {
  const int64_t i = x >> p, k = z >> p, m = (int64_t(1) << p) - 1;
  const int64_t sx = weight(x & m, p), sz = weight(z & m, p);
  const int64_t a = lerp(lattice(seed, salt, i, 0, k), lattice(seed, salt, i + 1, 0, k), sx);
  const int64_t b =
      lerp(lattice(seed, salt, i, 0, k + 1), lattice(seed, salt, i + 1, 0, k + 1), sx);
  return lerp(a, b, sz);
}

int64_t noise3(uint64_t seed, uint64_t salt, int64_t x, int64_t y, int64_t z, int p) {
  const int64_t i = x >> p, j = y >> p, k = z >> p, m = (int64_t(1) << p) - 1;
  const int64_t sx = weight(x & m, p), sy = weight(y & m, p), sz = weight(z & m, p);
  int64_t v[2];
  for (int dz = 0; dz < 2; ++dz) {
    const int64_t a =
        lerp(lattice(seed, salt, i, j, k + dz), lattice(seed, salt, i + 1, j, k + dz), sx);
    const int64_t b =
        lerp(lattice(seed, salt, i, j + 1, k + dz), lattice(seed, salt, i + 1, j + 1, k + dz), sx);
    v[dz] = lerp(a, b, sy);
  }
  return lerp(v[0], v[1], sz);
}

// ---- The density function (brickmap_terrain.hpp) ----

constexpr int64_t kFix = 256;  // fixed point: 1/256 voxel
constexpr uint64_t kSaltHeight = 1, kSaltMountain = 2, kSaltOverhang = 3, kSaltCaveA = 4,
                   kSaltCaveB = 5, kSaltJitter = 6;
constexpr int kOverhangLog2 = 5, kCaveLog2 = 6;
constexpr int64_t kCaveWidth = 3900;  // |noise| below this on both cave fields: a tunnel
constexpr int64_t kCaveFloor = 4;     // no caves below this y (bedrock)

struct Params {
  uint64_t seed;
  int64_t size[3];
  int top_log2;        // period of the largest height octave
  int64_t base, amp0;  // height field base and first-octave amplitude (fixed point)
  int64_t mountain;    // mountain term amplitude
  int64_t overhang;    // overhang amplitude

  explicit Params(const TerrainOptions& o) : seed(o.seed) {
    for (int a = 0; a < 3; ++a) size[a] = o.size[a];
    const int64_t hf = size[1] * kFix;
    const int w = int(std::bit_width(uint64_t(std::min(size[0], size[2])))) - 1;  // floor log2
    top_log2 = std::clamp(w - 1, 3, 10);
    base = hf * 26 / 100;
    amp0 = hf * 16 / 100;
    mountain = hf * 45 / 100;
    overhang = hf * 5 / 100;
  }

  bool inside_xz(int64_t x, int64_t z) const {
    return x >= 0 && z >= 0 && x < size[0] && z < size[2];
  }

  int64_t height(int64_t x, int64_t z) const {
    int64_t h = base, amp = amp0;
    for (int p = top_log2; p >= 3; --p, amp >>= 1)
      h += amp * noise2(seed, kSaltHeight + uint64_t(p) * 16, x, z, p) / 32768;
    const int64_t m = std::max<int64_t>(0, noise2(seed, kSaltMountain, x, z, top_log2));
    return h + mountain * (m * m >> 15) / 32768;
  }

  bool cave(int64_t x, int64_t y, int64_t z) const {
    if (y < kCaveFloor) return false;
    const int64_t a = noise3(seed, kSaltCaveA, x, 2 * y, z, kCaveLog2);
    if (a <= -kCaveWidth || a >= kCaveWidth) return false;
    const int64_t b = noise3(seed, kSaltCaveB, x, 2 * y, z, kCaveLog2);
    return b > -kCaveWidth && b < kCaveWidth;
  }

  // Full evaluation at a voxel inside the box, given height(x, z).
  int64_t density(int64_t h, int64_t x, int64_t y, int64_t z) const {
    const int64_t d = h - (y * kFix + kFix / 2) +
                      overhang * noise3(seed, kSaltOverhang, x, y, z, kOverhangLog2) / 32768;
    if (d <= 0) return d;
    return cave(x, y, z) ? -1 : d;
  }

  // The same predicate with the shortcut the generator takes: far above the
  // surface no noise can make a voxel solid (|overhang term| <= overhang).
  bool solid_fast(int64_t h, int64_t x, int64_t y, int64_t z) const {
    if (y < 0) return true;
    if (y >= size[1] || !inside_xz(x, z)) return false;
    if (y * kFix + kFix / 2 > h + overhang) return false;
    return density(h, x, y, z) > 0;
  }

  // Color of a stored voxel from its height field value and whether the voxel
  // above it is empty.
  uint32_t color(int64_t h, int64_t x, int64_t y, int64_t z, bool top) const {
    float c[3];
    const int64_t yc = y * kFix + kFix / 2;
    const double hf = double(y) / double(size[1]);
    if (top) {
      if (hf < 0.22)
        c[0] = 0.76f, c[1] = 0.70f, c[2] = 0.50f;  // sand
      else if (hf < 0.50)
        c[0] = 0.23f, c[1] = 0.48f, c[2] = 0.16f;  // grass
      else if (hf < 0.66)
        c[0] = 0.46f, c[1] = 0.44f, c[2] = 0.40f;  // rock
      else
        c[0] = 0.93f, c[1] = 0.94f, c[2] = 0.97f;  // snow
    } else if (yc > h - 4 * kFix) {
      c[0] = 0.42f, c[1] = 0.30f, c[2] = 0.19f;  // dirt just below the surface
    } else if (yc > h - 14 * kFix) {
      c[0] = 0.50f, c[1] = 0.48f, c[2] = 0.45f;  // rock walls, overhangs
    } else {
      c[0] = 0.36f, c[1] = 0.33f, c[2] = 0.34f;  // deep stone, caves
    }
    // Brightness jitter of +-8 %.
    const int64_t j = int64_t(mix64(uint64_t(lattice(seed, kSaltJitter, x, y, z))) & 255) - 128;
    const float f = 1.f + float(j) / 1600.f;
    return esvo::encode_color_abgr({c[0] * f, c[1] * f, c[2] * f, 1.f});
  }
};

// The normal of a stored voxel from the emptiness of its 26 neighbours.
template <class Empty>
uint32_t normal_of(Empty&& empty) {
  int n[3] = {0, 0, 0};
  for (int dz = -1; dz <= 1; ++dz)
    for (int dy = -1; dy <= 1; ++dy)
      for (int dx = -1; dx <= 1; ++dx)
        if ((dx | dy | dz) != 0 && empty(dx, dy, dz)) n[0] += dx, n[1] += dy, n[2] += dz;
  if (n[0] == 0 && n[1] == 0 && n[2] == 0) n[1] = 1;
  const float l = std::sqrt(float(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]));
  return esvo::encode_normal_cube({float(n[0]) / l, float(n[1]) / l, float(n[2]) / l});
}

constexpr int kSideV = int(kChunkSide) * kBrickSide;  // voxels per chunk side (128)
constexpr int kSlab = kSideV + 2;                     // with a one-voxel margin

// One generated chunk.
struct ChunkOut {
  uint64_t index = 0;
  std::vector<uint8_t> z;  // LZ4 block (empty: no bricks)
  uint32_t raw = 0;
  uint64_t hash = 0;
  uint64_t voxels = 0;
  std::vector<std::pair<uint64_t, uint32_t>> cells;  // brickgrid cell, LOD ABGR
};

struct Generator {
  Params p;
  std::array<uint32_t, 3> dims;  // brickgrid
  ChunkGrid cg;

  uint64_t cell_index(uint32_t i, uint32_t j, uint32_t k) const {
    return i + uint64_t(dims[0]) * (j + uint64_t(dims[1]) * k);
  }

  // The chunks of column (cx, cz), bottom to top.
  std::vector<ChunkOut> column(uint32_t cx, uint32_t cz) const {
    std::vector<ChunkOut> out;
    const int64_t x0 = int64_t(cx) * kSideV, z0 = int64_t(cz) * kSideV;
    std::vector<int64_t> h(size_t(kSlab) * kSlab);
    for (int z = 0; z < kSlab; ++z)
      for (int x = 0; x < kSlab; ++x)
        h[size_t(z) * kSlab + size_t(x)] = p.height(x0 + x - 1, z0 + z - 1);
    std::vector<uint8_t> solid(size_t(kSlab) * kSlab * kSlab);
    std::vector<uint8_t> raw;
    std::vector<uint32_t> colors, normals;
    for (uint32_t cy = 0; cy < cg.n[1]; ++cy) {
      const int64_t y0 = int64_t(cy) * kSideV;
      for (int z = 0; z < kSlab; ++z)
        for (int y = 0; y < kSlab; ++y)
          for (int x = 0; x < kSlab; ++x)
            solid[(size_t(z) * kSlab + size_t(y)) * kSlab + size_t(x)] =
                p.solid_fast(h[size_t(z) * kSlab + size_t(x)], x0 + x - 1, y0 + y - 1, z0 + z - 1);
      const auto at = [&](int x, int y, int z) {  // chunk-local voxel, -1 .. 128
        return solid[(size_t(z + 1) * kSlab + size_t(y + 1)) * kSlab + size_t(x + 1)] != 0;
      };
      ChunkOut c;
      c.index = cg.index(cx, cy, cz);
      raw.clear();
      const uint32_t jmax = std::min(dims[1], (cy + 1) * kChunkSide);
      for (uint32_t k = cz * kChunkSide; k < (cz + 1) * kChunkSide; ++k)
        for (uint32_t j = cy * kChunkSide; j < jmax; ++j)
          for (uint32_t i = cx * kChunkSide; i < (cx + 1) * kChunkSide; ++i) {
            uint64_t mask[8] = {};
            colors.clear(), normals.clear();
            const int bx = int(i - cx * kChunkSide) * 8, by = int(j - cy * kChunkSide) * 8,
                      bz = int(k - cz * kChunkSide) * 8;
            for (int vz = 0; vz < 8; ++vz)
              for (int vy = 0; vy < 8; ++vy)
                for (int vx = 0; vx < 8; ++vx) {
                  const int x = bx + vx, y = by + vy, z = bz + vz;
                  if (!at(x, y, z)) continue;
                  if (at(x - 1, y, z) && at(x + 1, y, z) && at(x, y - 1, z) && at(x, y + 1, z) &&
                      at(x, y, z - 1) && at(x, y, z + 1))
                    continue;  // hidden
                  mask[vz] |= uint64_t(1) << (vx + 8 * vy);
                  const int64_t gx = x0 + x, gy = y0 + y, gz = z0 + z;
                  colors.push_back(p.color(h[size_t(z + 1) * kSlab + size_t(x + 1)], gx, gy, gz,
                                           !at(x, y + 1, z)));
                  normals.push_back(normal_of(
                      [&](int dx, int dy, int dz) { return !at(x + dx, y + dy, z + dz); }));
                }
            if (colors.empty()) continue;
            append_brick(&raw, mask, colors.data(), normals.data(), colors.size());
            c.cells.push_back({cell_index(i, j, k), mean_color_abgr(colors.data(), colors.size())});
            c.voxels += colors.size();
          }
      if (!raw.empty()) {
        c.z = compress(raw.data(), raw.size());
        c.raw = uint32_t(raw.size());
        c.hash = XXH64(c.z.data(), c.z.size(), 0);
      }
      out.push_back(std::move(c));
    }
    return out;
  }
};

void check_size(const TerrainOptions& o) {
  for (int a = 0; a < 3; ++a)
    if (o.size[a] < 16 || o.size[a] > 65536)
      throw Error("terrain: every size must be 16 .. 65536 voxels");
}

}  // namespace

GridTransform terrain_grid(const TerrainOptions& o) {
  check_size(o);
  const uint32_t r = std::bit_ceil(std::max({o.size[0], o.size[1], o.size[2]}));
  GridTransform g;
  g.resolution = std::max<uint32_t>(r, 128);  // at least one whole chunk
  g.levels = std::countr_zero(g.resolution);
  g.voxel_size = 1.0 / double(std::max(o.size[0], o.size[2]));
  g.origin = {float(-0.5 * o.size[0] * g.voxel_size), 0.f, float(-0.5 * o.size[2] * g.voxel_size)};
  const uint64_t n = g.resolution / kBrickSide, ny = (o.size[1] + kBrickSide - 1) / kBrickSide;
  if (n * n * ny > kMaxGridCells)
    throw Error("terrain: " + std::to_string(n * n * ny) + " brickgrid cells, more than the " +
                std::to_string(kMaxGridCells) + " supported");
  return g;
}

int64_t terrain_density(const TerrainOptions& o, int64_t x, int64_t y, int64_t z) {
  const Params p(o);
  if (y < 0) return 1;
  if (y >= p.size[1] || !p.inside_xz(x, z)) return -1;
  return p.density(p.height(x, z), x, y, z);
}

int64_t terrain_column_top(const TerrainOptions& o, int64_t x, int64_t z) {
  const Params p(o);
  if (!p.inside_xz(x, z)) return -1;
  // solid_fast's bound: y kFix + kFix / 2 <= height + overhang.
  const int64_t t = p.height(x, z) + p.overhang - kFix / 2;
  return std::min<int64_t>(p.size[1] - 1, t < 0 ? -1 : t / kFix);
}

bool terrain_solid(const TerrainOptions& o, int64_t x, int64_t y, int64_t z) {
  return terrain_density(o, x, y, z) > 0;
}

uint32_t terrain_color(const TerrainOptions& o, int64_t x, int64_t y, int64_t z) {
  const Params p(o);
  return p.color(p.height(x, z), x, y, z, !terrain_solid(o, x, y + 1, z));
}

uint32_t terrain_normal(const TerrainOptions& o, int64_t x, int64_t y, int64_t z) {
  return normal_of(
      [&](int dx, int dy, int dz) { return !terrain_solid(o, x + dx, y + dy, z + dz); });
}

uint32_t neighbourhood_normal(const std::function<bool(int, int, int)>& empty) {
  return normal_of(empty);
}

TerrainStats write_terrain(const std::filesystem::path& path, const TerrainOptions& o) {
  const GridTransform grid = terrain_grid(o);
  Generator gen{Params(o), {}, {}};
  const uint32_t n = grid.resolution / kBrickSide;
  gen.dims = {n, (o.size[1] + kBrickSide - 1) / kBrickSide, n};
  gen.cg = chunk_grid(gen.dims);
  // The chunk columns holding terrain, in (cz, cx) order.
  const uint32_t ncx = (o.size[0] + kSideV - 1) / kSideV, ncz = (o.size[2] + kSideV - 1) / kSideV;
  const uint64_t columns = uint64_t(ncx) * ncz;
  const int threads =
      o.threads > 0 ? o.threads : std::max(1, int(std::thread::hardware_concurrency()));
  const uint64_t window = uint64_t(threads) * 2;

  TerrainStats st;
  std::vector<uint32_t> header(size_t(uint64_t(n) * gen.dims[1] * n), 0);
  st.header_cells = header.size();
  // The chunk table (format.cpp): u32 count, u32 0, 24 B per chunk; the
  // all-zero entry for a chunk without bricks.
  std::vector<uint8_t> table(8 + 24 * size_t(gen.cg.count()), 0);
  const uint32_t chunk_count = uint32_t(gen.cg.count());
  std::memcpy(&table[0], &chunk_count, 4);
  ContainerWriter out(path);
  out.begin_section(fourcc("BMCK"));
  uint64_t offset = 0;
  for (uint64_t first = 0; first < columns; first += window) {
    const uint64_t count = std::min(window, columns - first);
    std::vector<std::vector<ChunkOut>> done(static_cast<size_t>(count));
    std::atomic<uint64_t> next{0};
    const auto work = [&] {
      for (uint64_t c; (c = next.fetch_add(1)) < count;) {
        const uint64_t col = first + c;
        done[size_t(c)] = gen.column(uint32_t(col % ncx), uint32_t(col / ncx));
      }
    };
    std::vector<std::thread> pool;
    for (int t = 1; t < std::min<int>(threads, int(count)); ++t) pool.emplace_back(work);
    work();
    for (std::thread& t : pool) t.join();
    for (std::vector<ChunkOut>& col : done) {
      for (ChunkOut& c : col) {
        if (c.z.empty()) continue;
        st.bricks += c.cells.size();
        if (st.bricks > kMaxBricks)
          throw Error("terrain: more than " + std::to_string(kMaxBricks) +
                      " bricks; make it smaller");
        st.voxels += c.voxels;
        ++st.chunks;
        st.raw_bytes += c.raw;
        st.chunk_bytes += c.z.size();
        for (const auto& [cell, lod] : c.cells) header[size_t(cell)] = not_resident_cell(lod);
        uint8_t* e = &table[8 + 24 * size_t(c.index)];
        const uint32_t zs = uint32_t(c.z.size());
        std::memcpy(e, &offset, 8);
        std::memcpy(e + 8, &zs, 4);
        std::memcpy(e + 12, &c.raw, 4);
        std::memcpy(e + 16, &c.hash, 8);
        out.append(c.z.data(), c.z.size());
        offset += c.z.size();
      }
      col.clear();
      if (o.progress) o.progress->advance();
    }
  }
  out.end_section();
  out.add(fourcc("BMCT"), table);
  out.add(fourcc("BMGH"), pack_grid_header(header));
  SceneInfo info;
  info.source = "terrain";
  info.leaf_voxels = st.voxels;
  nlohmann::json meta = meta::info_to_json(info);
  meta.update({{"format", kFormatName},
               {"grid", meta::grid_to_json(grid)},
               {"dims", {gen.dims[0], gen.dims[1], gen.dims[2]}},
               {"bricks", st.bricks},
               {"leaf_voxels", st.voxels},
               {"normals", true},
               {"chunk_log2", kChunkLog2},
               {"terrain", {{"size", {o.size[0], o.size[1], o.size[2]}}, {"seed", o.seed}}}});
  out.add(meta::kSection, meta::dump(meta));
  out.commit();
  remove_journal(path);  // of a world replaced (brickmap_file.hpp)
  return st;
}

}  // namespace voxcast::brickmap
