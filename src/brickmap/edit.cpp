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
#include <vector>

#include "voxcast/brickmap.hpp"
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
// clearances once for all.
template <class CellOf, class Change>
EditResult change_bricks(World& w, size_t count, const CellOf& cell_of, const Change& change) {
  constexpr size_t kBatch = 512;  // 512 expanded bricks: about 2 MiB
  std::vector<BrickVoxels> batch(std::min(kBatch, count));
  std::vector<uint64_t> changed(batch.size());
  EditResult result;
  for (size_t first = 0; first < count; first += kBatch) {
    const size_t n = std::min(kBatch, count - first);
    tbb::parallel_for(size_t(0), n, [&](size_t q) {
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
  const auto cell_of = [&](size_t q) {
    return w.cell_index(uint32_t(bricks[q][0]), uint32_t(bricks[q][1]), uint32_t(bricks[q][2]));
  };
  return change_bricks(w, bricks.size(), cell_of, [&](size_t q, BrickVoxels& v) {
    const auto& bc = bricks[q];
    uint64_t changed = 0;
    const int64_t b0[3] = {bc[0] << kBrickLog2, bc[1] << kBrickLog2, bc[2] << kBrickLog2};
    for (int64_t z = std::max(vlo[2], b0[2]); z <= std::min(vhi[2], b0[2] + 7); ++z)
      for (int64_t y = std::max(vlo[1], b0[1]); y <= std::min(vhi[1], b0[1] + 7); ++y)
        for (int64_t x = std::max(vlo[0], b0[0]); x <= std::min(vhi[0], b0[0] + 7); ++x) {
          const Vec3d p{double(g.origin.x) + (double(x) + 0.5) * g.voxel_size,
                        double(g.origin.y) + (double(y) + 0.5) * g.voxel_size,
                        double(g.origin.z) + (double(z) + 0.5) * g.voxel_size};
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
  });
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
  return change_bricks(
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
}

}  // namespace voxcast::brickmap
