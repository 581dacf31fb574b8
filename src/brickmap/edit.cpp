// Editing a brickmap world (§3.2.2, §4.4): brushes applied brick by brick.
// An edit is a write into the raw voxels: each brick the brush's voxel box
// overlaps is expanded into 512-entry arrays, changed, and stored back with
// World::set_brick (which releases the old pool slot and color run and
// recomputes the LOD color; the run is rewritten in place when its size
// class fits, and the occupancy and pyramid above the edited bricks are
// recomputed once per edit); the edited cells carry the Edited flag and are
// listed in the result, which is what a renderer with its own brick pool
// would invalidate and re-upload (§4.4).
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <map>
#include <optional>
#include <vector>

#include "voxcast/brickmap.hpp"
#include "voxcast/brickmap_terrain.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo.hpp"
#include "voxcast/morton.hpp"

namespace voxcast::brickmap {
namespace {

struct BrickVoxels {
  uint64_t mask[8] = {};
  std::array<uint32_t, kBrickVoxels> color{}, normal{};
};

void expand(const World& w, uint32_t cell, BrickVoxels* out) {
  *out = BrickVoxels{};
  if (cell_state(cell) != kStateResident) return;
  const Brick& b = w.brick(cell_brick(cell));
  std::copy(b.mask, b.mask + 8, out->mask);
  uint32_t k = b.color;
  for (uint32_t word = 0; word < 8; ++word)
    for (uint64_t m = b.mask[word]; m != 0; m &= m - 1, ++k) {
      const uint32_t bit = word * 64 + uint32_t(std::countr_zero(m));
      out->color[bit] = w.color_of(b, uint32_t(k - b.color));
      if (w.has_normals()) out->normal[bit] = w.normals()[k];
    }
}

void store(World& w, uint64_t index, const BrickVoxels& v) {
  std::array<uint32_t, kBrickVoxels> colors, normals;
  uint32_t k = 0;
  for (uint32_t word = 0; word < 8; ++word)
    for (uint64_t m = v.mask[word]; m != 0; m &= m - 1, ++k) {
      const uint32_t bit = word * 64 + uint32_t(std::countr_zero(m));
      colors[k] = v.color[bit];
      normals[k] = v.normal[bit];
    }
  w.set_brick(index, v.mask, colors.data(), normals.data(), kFlagEdited, nullptr,
              /*update_pyramid=*/false);
}

// One voxel of an edit: `op` on bit `bit` with color `abgr` and (Add)
// normal `normal`; true if the voxel changed.
bool apply_voxel(BrickVoxels& v, uint32_t bit, EditOp op, uint32_t abgr, uint32_t normal) {
  uint64_t& word = v.mask[bit >> 6];
  const uint64_t m = uint64_t(1) << (bit & 63);
  const bool solid = (word & m) != 0;
  if (op == EditOp::Remove) {
    if (!solid) return false;
    word &= ~m;
  } else if (op == EditOp::Paint) {
    if (!solid || v.color[bit] == abgr) return false;
    v.color[bit] = abgr;
  } else {
    if (solid && v.color[bit] == abgr && v.normal[bit] == normal) return false;
    word |= m;
    v.color[bit] = abgr;
    v.normal[bit] = normal;
  }
  return true;
}

// Changes `count` bricks, brick q in cell cell_of(q) through change(q, v)
// (which applies the voxels to the expanded copy v and returns how many
// changed), in batches: a batch changed in parallel (each brick reads the
// world and writes its own copy), then the changed bricks stored in order
// on this thread (the pool and the color allocator are not shared), so the
// world is the same whatever the threads; then the occupancy, pyramid and
// clearances once for all. select(q) false: brick q would not change, so it
// is not expanded.
template <class CellOf, class Change, class Select>
EditResult change_bricks(World& w, size_t count, const CellOf& cell_of, const Change& change,
                         const Select& select) {
  constexpr size_t kBatch = 512;  // 512 expanded bricks: about 2 MiB
  std::vector<BrickVoxels> batch(std::min(kBatch, count));
  std::vector<uint64_t> changed(batch.size());
  EditResult result;
  for (size_t first = 0; first < count; first += kBatch) {
    const size_t n = std::min(kBatch, count - first);
    tbb::parallel_for(size_t(0), n, [&](size_t q) {
      changed[q] = 0;
      if (!select(first + q)) return;
      expand(w, w.cell(cell_of(first + q)), &batch[q]);
      changed[q] = change(first + q, batch[q]);
    });
    try {
      for (size_t q = 0; q < n; ++q) {
        if (changed[q] == 0) continue;
        const uint64_t index = cell_of(first + q);
        store(w, index, batch[q]);
        result.voxels += changed[q];
        result.cells.push_back(index);
      }
    } catch (...) {
      // (The pool's limit, say:) the bricks stored so far stay consistent.
      w.update_occupancy(result.cells);
      throw;
    }
  }
  w.update_occupancy(result.cells);
  return result;
}
template <class CellOf, class Change>
EditResult change_bricks(World& w, size_t count, const CellOf& cell_of, const Change& change) {
  return change_bricks(w, count, cell_of, change, [](size_t) { return true; });
}

// ---- Refilling a terrain's hollow interior (World::terrain) ----
//
// The paper keeps "the entire world, including subsurface data" on disk (§3)
// and removes hidden voxels only on their way to the renderer (§3.2.1, §4.2);
// our terrain generator removes them already (brickmap_terrain.hpp), so its
// density function stands in for the subsurface data: without it a removal
// that opens the surface would look into a hollow interior. The solid set
// is the stored voxels plus the density's voxels not carved out
// (brickmap.hpp); a removal carves every voxel of the brush the density can
// make solid (below its column's top, terrain_column_top), and each voxel
// next to the brush that is solid but not stored was hidden until now: it is
// brought back with the generator's color and the normal of its new
// neighbourhood. A hidden voxel's six neighbours are all solid (else it
// would be stored), so only the brush's outer shell can become exposed.

using BrushCells = std::map<uint64_t, VoxelMask>;  // brush voxels per brickgrid cell

struct Refill {
  uint64_t cell = 0;
  std::vector<uint32_t> bits, colors, normals;  // the voxels brought back
};
struct Carve {
  std::vector<std::pair<uint64_t, VoxelMask>> carved;  // cells whose carved mask grows
  std::vector<Refill> refill;                          // in cell order
};

bool in_mask(const VoxelMask& m, uint32_t bit) {
  return (m[bit >> 6] >> (bit & 63)) & 1;
}

// What removing `brush` from the terrain world `w` carves and brings back,
// computed on the world before the removal (the shell lies outside the
// brush, so the removal does not change what it reads). Throws before
// anything changes when a brick it would touch is not resident.
Carve prepare_carve(const World& w, const BrushCells& brush) {
  TerrainOptions o;
  for (int a = 0; a < 3; ++a) o.size[a] = w.terrain()->size[size_t(a)];
  o.seed = w.terrain()->seed;
  const int64_t nx = w.grid().resolution, ny = int64_t(w.dims()[1]) * kBrickSide;
  const auto cell_of = [&](int64_t x, int64_t y, int64_t z) {
    return w.cell_index(uint32_t(x >> 3), uint32_t(y >> 3), uint32_t(z >> 3));
  };
  const auto in_brush = [&](int64_t x, int64_t y, int64_t z) {
    const auto it = brush.find(cell_of(x, y, z));
    return it != brush.end() &&
           in_mask(it->second, voxel_bit(uint32_t(x & 7), uint32_t(y & 7), uint32_t(z & 7)));
  };
  const auto inside = [&](int64_t x, int64_t y, int64_t z) {
    return x >= 0 && y >= 0 && z >= 0 && x < nx && y < ny && z < nx;
  };
  // The shell: 6-neighbours of brush voxels outside the brush, per cell.
  BrushCells shell;
  static constexpr int kDirs[6][3] = {{-1, 0, 0}, {1, 0, 0},  {0, -1, 0},
                                      {0, 1, 0},  {0, 0, -1}, {0, 0, 1}};
  // Only voxels the density can make solid need carving (the rest stay
  // empty whatever the carve says): the brush below each column's top.
  std::map<std::pair<int64_t, int64_t>, int64_t> tops;
  const auto column_top = [&](int64_t x, int64_t z) {
    const auto [it, fresh] = tops.try_emplace({x, z}, 0);
    if (fresh) it->second = terrain_column_top(o, x, z);
    return it->second;
  };
  Carve out;
  for (const auto& [cell, mask] : brush) {
    // (No lambda here: clang before 16 cannot capture a structured binding.)
    const auto carved_it = w.carved().find(cell);
    const VoxelMask old = carved_it == w.carved().end() ? VoxelMask{} : carved_it->second;
    VoxelMask grown = old;
    const int64_t i = int64_t(cell % w.dims()[0]), j = int64_t(cell / w.dims()[0] % w.dims()[1]),
                  k = int64_t(cell / w.dims()[0] / w.dims()[1]);
    for (uint32_t word = 0; word < 8; ++word)
      for (uint64_t m = mask[word]; m != 0; m &= m - 1) {
        const uint32_t bit = word * 64 + uint32_t(std::countr_zero(m));
        const int64_t x = i * 8 + (bit & 7), y = j * 8 + ((bit >> 3) & 7), z = k * 8 + (bit >> 6);
        if (y <= column_top(x, z)) grown[word] |= uint64_t(1) << (bit & 63);
        for (const auto& d : kDirs) {
          const int64_t ux = x + d[0], uy = y + d[1], uz = z + d[2];
          if (!inside(ux, uy, uz)) continue;
          const uint32_t ub = voxel_bit(uint32_t(ux & 7), uint32_t(uy & 7), uint32_t(uz & 7));
          const bool same = (ux >> 3) == i && (uy >> 3) == j && (uz >> 3) == k;
          if (same ? in_mask(mask, ub) : in_brush(ux, uy, uz)) continue;
          shell[cell_of(ux, uy, uz)][ub >> 6] |= uint64_t(1) << (ub & 63);
        }
      }
    if (grown != old) out.carved.push_back({cell, grown});
  }
  for (const BrushCells* cells : {&brush, static_cast<const BrushCells*>(&shell)})
    for (const auto& entry : *cells)
      if (cell_state(w.cell(entry.first)) == kStateNotResident)
        throw Error("brickmap edit: brick " + std::to_string(entry.first) +
                    " is not resident (its terrain would be refilled)");
  // The density is the cost: the shell's cells in parallel, each into its
  // own entry, so the result is the same whatever the threads.
  std::vector<std::pair<uint64_t, VoxelMask>> cand(shell.begin(), shell.end());
  out.refill.resize(cand.size());
  // Solid after the removal (World::terrain's definition, the brush empty).
  const auto solid_after = [&](int64_t x, int64_t y, int64_t z) {
    if (y < 0) return true;  // the ground goes on below the grid (terrain "outside" rule)
    if (!inside(x, y, z) || in_brush(x, y, z)) return false;
    return w.voxel(uint32_t(x), uint32_t(y), uint32_t(z)) ||
           (!w.carved_voxel(uint32_t(x), uint32_t(y), uint32_t(z)) && terrain_solid(o, x, y, z));
  };
  tbb::parallel_for(size_t(0), cand.size(), [&](size_t q) {
    const uint64_t cell = cand[q].first;
    Refill& r = out.refill[q];
    r.cell = cell;
    const int64_t i = int64_t(cell % w.dims()[0]), j = int64_t(cell / w.dims()[0] % w.dims()[1]),
                  k = int64_t(cell / w.dims()[0] / w.dims()[1]);
    for (uint32_t word = 0; word < 8; ++word)
      for (uint64_t m = cand[q].second[word]; m != 0; m &= m - 1) {
        const uint32_t bit = word * 64 + uint32_t(std::countr_zero(m));
        const int64_t x = i * 8 + (bit & 7), y = j * 8 + ((bit >> 3) & 7), z = k * 8 + (bit >> 6);
        // Hidden: solid, not stored, not carved.
        if (w.voxel(uint32_t(x), uint32_t(y), uint32_t(z)) ||
            w.carved_voxel(uint32_t(x), uint32_t(y), uint32_t(z)) || !terrain_solid(o, x, y, z))
          continue;
        r.bits.push_back(bit);
        r.colors.push_back(terrain_color(o, x, y, z));
        r.normals.push_back(neighbourhood_normal(
            [&](int dx, int dy, int dz) { return !solid_after(x + dx, y + dy, z + dz); }));
      }
  });
  std::erase_if(out.refill, [](const Refill& r) { return r.bits.empty(); });
  return out;
}

// The carve applied after the removal `removed`: the carved masks grown,
// the hidden voxels brought back; the result lists every cell the removal,
// the carve or the refill changed (the journal saves their chunks).
EditResult apply_carve(World& w, const Carve& c, EditResult removed) {
  for (const auto& [cell, mask] : c.carved) w.set_carved(cell, mask);
  EditResult r = change_bricks(
      w, c.refill.size(), [&](size_t q) { return c.refill[q].cell; },
      [&](size_t q, BrickVoxels& v) {
        const Refill& f = c.refill[q];
        for (size_t n = 0; n < f.bits.size(); ++n) {
          v.mask[f.bits[n] >> 6] |= uint64_t(1) << (f.bits[n] & 63);
          v.color[f.bits[n]] = f.colors[n];
          v.normal[f.bits[n]] = f.normals[n];
        }
        return uint64_t(f.bits.size());
      });
  removed.voxels += r.voxels;
  removed.cells.insert(removed.cells.end(), r.cells.begin(), r.cells.end());
  for (const auto& entry : c.carved) removed.cells.push_back(entry.first);
  std::sort(removed.cells.begin(), removed.cells.end());
  removed.cells.erase(std::unique(removed.cells.begin(), removed.cells.end()), removed.cells.end());
  return removed;
}

void add_to_brush(BrushCells& b, const World& w, uint32_t x, uint32_t y, uint32_t z) {
  const uint32_t bit = voxel_bit(x & 7, y & 7, z & 7);
  b[w.cell_index(x >> 3, y >> 3, z >> 3)][bit >> 6] |= uint64_t(1) << (bit & 63);
}

}  // namespace

bool Brush::contains(const Vec3d& p) const {
  if (shape == Shape::Sphere) {
    const Vec3d d = p - a;
    return dot(d, d) <= radius * radius;
  }
  return p.x >= a.x && p.x <= b.x && p.y >= a.y && p.y <= b.y && p.z >= a.z && p.z <= b.z;
}

EditResult edit(World& w, const Brush& brush, EditOp op, const Color& color) {
  const GridTransform& g = w.grid();
  Vec3d lo, hi;
  if (brush.shape == Brush::Shape::Sphere) {
    if (!is_finite(brush.a) || !std::isfinite(brush.radius) || !(brush.radius >= 0))
      throw Error("brickmap edit: the sphere needs a finite center and a radius >= 0");
    const Vec3d r{brush.radius, brush.radius, brush.radius};
    lo = brush.a - r, hi = brush.a + r;
  } else {
    if (!is_finite(brush.a) || !is_finite(brush.b) || !(brush.a.x <= brush.b.x) ||
        !(brush.a.y <= brush.b.y) || !(brush.a.z <= brush.b.z))
      throw Error("brickmap edit: the box needs finite corners with min <= max");
    lo = brush.a, hi = brush.b;
  }
  // Voxels whose centers can lie in the brush: [ceil(lo - 0.5), floor(hi - 0.5)]
  // in grid units, clipped to the grid.
  int64_t vlo[3], vhi[3];
  const double n = double(g.resolution);
  for (int a = 0; a < 3; ++a) {
    const double l = (lo[a] - double(g.origin[a])) / g.voxel_size - 0.5;
    const double h = (hi[a] - double(g.origin[a])) / g.voxel_size - 0.5;
    vlo[a] = int64_t(std::ceil(std::clamp(l, 0.0, n)));
    vhi[a] = int64_t(std::floor(std::clamp(h, -1.0, n - 1)));
    if (a == 1) vhi[a] = std::min<int64_t>(vhi[a], int64_t(w.dims()[1]) * kBrickSide - 1);
    if (vlo[a] > vhi[a]) return {};
  }
  const uint32_t abgr = esvo::encode_color_abgr(color);
  const Vec3d center = brush.shape == Brush::Shape::Sphere ? brush.a : (brush.a + brush.b) * 0.5;
  // The bricks the box overlaps, in cell order; a not-resident one refuses
  // the edit before anything changes.
  std::vector<std::array<int64_t, 3>> bricks;
  for (int64_t bk = vlo[2] >> kBrickLog2; bk <= vhi[2] >> kBrickLog2; ++bk)
    for (int64_t bj = vlo[1] >> kBrickLog2; bj <= vhi[1] >> kBrickLog2; ++bj)
      for (int64_t bi = vlo[0] >> kBrickLog2; bi <= vhi[0] >> kBrickLog2; ++bi) {
        const uint32_t cell = w.cell(w.cell_index(uint32_t(bi), uint32_t(bj), uint32_t(bk)));
        if (cell == 0 && op != EditOp::Add) continue;
        if (cell_state(cell) == kStateNotResident)
          throw Error("brickmap edit: brick (" + std::to_string(bi) + "," + std::to_string(bj) +
                      "," + std::to_string(bk) + ") is not resident");
        bricks.push_back({bi, bj, bk});
      }
  const auto voxel_center = [&](int64_t x, int64_t y, int64_t z) {
    return Vec3d{double(g.origin.x) + (double(x) + 0.5) * g.voxel_size,
                 double(g.origin.y) + (double(y) + 0.5) * g.voxel_size,
                 double(g.origin.z) + (double(z) + 0.5) * g.voxel_size};
  };
  // A removal from a terrain world carves the brush and refills what it
  // exposes (prepare_carve): decided before anything changes.
  std::optional<Carve> carve;
  if (op == EditOp::Remove && w.terrain()) {
    BrushCells inside;
    for (int64_t z = vlo[2]; z <= vhi[2]; ++z)
      for (int64_t y = vlo[1]; y <= vhi[1]; ++y)
        for (int64_t x = vlo[0]; x <= vhi[0]; ++x)
          if (brush.contains(voxel_center(x, y, z)))
            add_to_brush(inside, w, uint32_t(x), uint32_t(y), uint32_t(z));
    carve = prepare_carve(w, inside);
  }
  const auto cell_of = [&](size_t q) {
    return w.cell_index(uint32_t(bricks[q][0]), uint32_t(bricks[q][1]), uint32_t(bricks[q][2]));
  };
  // Paint and Remove change solid voxels only: the brush is tested at a
  // brick's solid voxels (a surface brick holds a fraction of its 512), and
  // a brick none of whose solid voxels lies in the brush is not expanded.
  // The same voxels change as when every voxel of the box is tested.
  const bool solid_only = op != EditOp::Add;
  std::vector<VoxelMask> in_brush(solid_only ? bricks.size() : 0);
  const auto select = [&](size_t q) {
    if (!solid_only) return true;
    const uint32_t cell = w.cell(cell_of(q));
    if (cell_state(cell) != kStateResident) return false;  // no solid voxel stored
    const Brick& b = w.brick(cell_brick(cell));
    const int64_t b0[3] = {bricks[q][0] << kBrickLog2, bricks[q][1] << kBrickLog2,
                           bricks[q][2] << kBrickLog2};
    VoxelMask m{};
    bool any = false;
    for (uint32_t word = 0; word < 8; ++word)
      for (uint64_t bits = b.mask[word]; bits != 0; bits &= bits - 1) {
        const uint32_t bit = word * 64 + uint32_t(std::countr_zero(bits));
        const int64_t x = b0[0] + (bit & 7), y = b0[1] + (bit >> 3 & 7), z = b0[2] + (bit >> 6);
        if (x < vlo[0] || x > vhi[0] || y < vlo[1] || y > vhi[1] || z < vlo[2] || z > vhi[2] ||
            !brush.contains(voxel_center(x, y, z)))
          continue;
        m[word] |= uint64_t(1) << (bit & 63);
        any = true;
      }
    in_brush[q] = m;
    return any;
  };
  const auto change = [&](size_t q, BrickVoxels& v) {
    uint64_t changed = 0;
    if (solid_only) {
      for (uint32_t word = 0; word < 8; ++word)
        for (uint64_t bits = in_brush[q][word]; bits != 0; bits &= bits - 1)
          changed += apply_voxel(v, word * 64 + uint32_t(std::countr_zero(bits)), op, abgr, 0);
      return changed;
    }
    const auto& bc = bricks[q];
    const int64_t b0[3] = {bc[0] << kBrickLog2, bc[1] << kBrickLog2, bc[2] << kBrickLog2};
    for (int64_t z = std::max(vlo[2], b0[2]); z <= std::min(vhi[2], b0[2] + 7); ++z)
      for (int64_t y = std::max(vlo[1], b0[1]); y <= std::min(vhi[1], b0[1] + 7); ++y)
        for (int64_t x = std::max(vlo[0], b0[0]); x <= std::min(vhi[0], b0[0] + 7); ++x) {
          const Vec3d p = voxel_center(x, y, z);
          if (!brush.contains(p)) continue;
          const uint32_t bit =
              voxel_bit(uint32_t(x - b0[0]), uint32_t(y - b0[1]), uint32_t(z - b0[2]));
          uint32_t nc = 0;
          if (op == EditOp::Add) {
            // Added voxels face away from the brush's center (a box's
            // or sphere's outward direction; +z at the very center).
            const Vec3d d = p - center;
            nc = esvo::encode_normal_cube(
                dot(d, d) > 0 ? Vec3(normalize(Vec3{float(d.x), float(d.y), float(d.z)}))
                              : Vec3{0, 0, 1});
          }
          changed += apply_voxel(v, bit, op, abgr, nc);
        }
    return changed;
  };
  EditResult result = change_bricks(w, bricks.size(), cell_of, change, select);
  return carve ? apply_carve(w, *carve, std::move(result)) : result;
}

EditResult stamp(World& w, const VoxelSet& voxels, EditOp op, const Color& color) {
  const GridTransform& g = w.grid();
  if (voxels.grid.resolution != g.resolution || voxels.grid.levels != g.levels ||
      voxels.grid.origin.x != g.origin.x || voxels.grid.origin.y != g.origin.y ||
      voxels.grid.origin.z != g.origin.z || voxels.grid.voxel_size != g.voxel_size)
    throw Error("brickmap stamp: the voxel set is not on the world's grid");
  const bool own = !voxels.colors.empty();
  const uint32_t fallback = esvo::encode_color_abgr(color);
  // The voxels grouped by brickgrid cell, in cell order.
  // (Voxels above a cut-off brickgrid are outside the world: ignored.)
  std::vector<std::pair<uint64_t, size_t>> order;
  order.reserve(voxels.size());
  for (size_t i = 0; i < voxels.size(); ++i) {
    const MortonCoord c = morton_decode(voxels.codes[i]);
    if ((c.y >> kBrickLog2) >= w.dims()[1]) continue;
    order.push_back({w.cell_index(c.x >> kBrickLog2, c.y >> kBrickLog2, c.z >> kBrickLog2), i});
  }
  tbb::parallel_sort(order.begin(), order.end());  // unique pairs: one order whatever the threads
  // The runs of one cell; a not-resident brick refuses the stamp before
  // anything changes.
  struct Run {
    uint64_t index;
    size_t begin, end;
  };
  std::vector<Run> runs;
  for (size_t at = 0; at < order.size();) {
    const uint64_t index = order[at].first;
    size_t end = at;
    while (end < order.size() && order[end].first == index) ++end;
    const uint32_t cell = w.cell(index);
    if (cell_state(cell) == kStateNotResident)
      throw Error("brickmap stamp: brick " + std::to_string(index) + " is not resident");
    if (cell != 0 || op == EditOp::Add) runs.push_back({index, at, end});
    at = end;
  }
  std::optional<Carve> carve;
  if (op == EditOp::Remove && w.terrain()) {
    BrushCells inside;
    for (const auto& entry : order) {
      const MortonCoord c = morton_decode(voxels.codes[entry.second]);
      add_to_brush(inside, w, c.x, c.y, c.z);
    }
    carve = prepare_carve(w, inside);
  }
  EditResult result = change_bricks(
      w, runs.size(), [&](size_t q) { return runs[q].index; },
      [&](size_t q, BrickVoxels& v) {
        uint64_t changed = 0;
        for (size_t k = runs[q].begin; k < runs[q].end; ++k) {
          const size_t i = order[k].second;
          const MortonCoord c = morton_decode(voxels.codes[i]);
          const uint32_t bit = voxel_bit(c.x & 7, c.y & 7, c.z & 7);
          const uint32_t abgr = own ? esvo::encode_color_abgr(voxels.colors[i]) : fallback;
          const uint32_t nc = op != EditOp::Add
                                  ? 0
                                  : esvo::encode_normal_cube(
                                        voxels.normals.empty() ? Vec3{0, 0, 1} : voxels.normals[i]);
          changed += apply_voxel(v, bit, op, abgr, nc);
        }
        return changed;
      });
  return carve ? apply_carve(w, *carve, std::move(result)) : result;
}

}  // namespace voxcast::brickmap
