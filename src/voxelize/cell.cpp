// Cell-restricted surface voxelization for out-of-core DAG builds (svdag §3,
// "Implementation details": sub-volumes voxelized and reduced one at a time).
// See cell.hpp for the exactness contract; the rasterizer is voxelize/raster.hpp,
// the same one voxelize() uses, limited to the cell's box.
#include "voxelize/cell.hpp"

#include <fmt/format.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <unordered_map>
#include <vector>

#include "voxcast/error.hpp"
#include "voxcast/morton.hpp"
#include "voxelize/internal.hpp"
#include "voxelize/raster.hpp"

namespace voxcast::detail {

namespace {

using raster::ceil_clamped;
using raster::floor_clamped;
using raster::raster_triangle_box;

struct Pair {
  uint64_t code;
  uint32_t tri;
  bool operator<(const Pair& o) const { return code != o.code ? code < o.code : tri < o.tri; }
};

// Rasterizes the listed triangles into the box, in blocks of triangles run in
// parallel; the blocks are concatenated in block order (= triangle order).
template <class Rec, class Make>
std::vector<Rec> raster_cell(const Mesh& mesh, const std::vector<std::array<double, 3>>& gv,
                             const uint32_t* tris, size_t count, int n, bool six,
                             const int box_lo[3], const int box_hi[3], Make make) {
  constexpr size_t kBlock = 64;
  const size_t nblocks = (count + kBlock - 1) / kBlock;
  std::vector<std::vector<Rec>> blocks(nblocks);
  tbb::parallel_for(size_t(0), nblocks, [&](size_t b) {
    std::vector<Rec>& out = blocks[b];
    for (size_t i = b * kBlock, e = std::min(count, i + kBlock); i < e; ++i) {
      const uint32_t t = tris[i];
      double v[3][3];
      for (int k = 0; k < 3; ++k)
        for (int a = 0; a < 3; ++a)
          v[k][a] = gv[mesh.indices[3 * size_t(t) + size_t(k)]][size_t(a)];
      raster_triangle_box(v, n, six, box_lo, box_hi,
                          [&](uint64_t code) { out.push_back(make(code, t)); });
    }
  });
  size_t total = 0;
  for (const auto& b : blocks) total += b.size();
  std::vector<Rec> all;
  all.reserve(total);
  for (auto& b : blocks) {
    all.insert(all.end(), b.begin(), b.end());
    b = {};
  }
  return all;
}

}  // namespace

std::vector<std::array<double, 3>> grid_vertices(const Mesh& mesh, const GridTransform& grid) {
  // Same expression as voxelize.cpp step 0, so the rasterizer sees the same doubles.
  std::vector<std::array<double, 3>> gv(mesh.positions.size());
  const double inv = 1.0 / grid.voxel_size;
  tbb::parallel_for(tbb::blocked_range<size_t>(0, gv.size(), 1 << 14), [&](const auto& r) {
    for (size_t i = r.begin(); i < r.end(); ++i)
      for (int a = 0; a < 3; ++a)
        gv[i][size_t(a)] = (double(mesh.positions[i][a]) - double(grid.origin[a])) * inv;
  });
  return gv;
}

bool triangle_voxel_range(const std::vector<std::array<double, 3>>& gv, const Mesh& mesh, size_t t,
                          uint32_t resolution, uint32_t lo[3], uint32_t hi[3]) {
  const int n = int(resolution);
  for (int a = 0; a < 3; ++a) {
    double mn = gv[mesh.indices[3 * t]][size_t(a)], mx = mn;
    for (int k = 1; k < 3; ++k) {
      const double x = gv[mesh.indices[3 * t + size_t(k)]][size_t(a)];
      mn = std::min(mn, x);
      mx = std::max(mx, x);
    }
    const int l = std::max(0, ceil_clamped(mn, -4, n + 4) - 1);
    const int h = std::min(n - 1, floor_clamped(mx, -4, n + 4));
    if (l > h) return false;
    lo[a] = uint32_t(l);
    hi[a] = uint32_t(h);
  }
  return true;
}

std::vector<CellBin> bin_triangles(const Mesh& mesh, const std::vector<std::array<double, 3>>& gv,
                                   const GridTransform& grid, int bits) {
  std::vector<CellBin> bins;
  for (size_t t = 0; t < mesh.triangle_count(); ++t) {
    uint32_t lo[3], hi[3];
    if (!triangle_voxel_range(gv, mesh, t, grid.resolution, lo, hi)) continue;
    for (uint32_t z = lo[2] >> bits; z <= hi[2] >> bits; ++z)
      for (uint32_t y = lo[1] >> bits; y <= hi[1] >> bits; ++y)
        for (uint32_t x = lo[0] >> bits; x <= hi[0] >> bits; ++x)
          bins.push_back({morton_encode(x, y, z), uint32_t(t)});
  }
  tbb::parallel_sort(bins.begin(), bins.end());
  return bins;
}

double triangle_pairs(const double v[3][3]) {
  double e1[3], e2[3];
  for (int a = 0; a < 3; ++a) e1[a] = v[1][a] - v[0][a], e2[a] = v[2][a] - v[0][a];
  const double n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                       e1[0] * e2[1] - e1[1] * e2[0]};
  const double len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
  const double l1 = len > 0 ? (std::fabs(n[0]) + std::fabs(n[1]) + std::fabs(n[2])) / len : 1.0;
  double perim = 0;
  for (int k = 0; k < 3; ++k) {
    const double* p = v[k];
    const double* q = v[(k + 1) % 3];
    perim += std::sqrt((q[0] - p[0]) * (q[0] - p[0]) + (q[1] - p[1]) * (q[1] - p[1]) +
                       (q[2] - p[2]) * (q[2] - p[2]));
  }
  return 0.5 * len * l1 + 2.0 * perim + 4.0;
}

uint64_t mesh_bytes(const Mesh& m) {
  uint64_t b = m.positions.size() * sizeof(Vec3) + m.normals.size() * sizeof(Vec3) +
               m.colors.size() * sizeof(Color) + m.uvs.size() * sizeof(Vec2) +
               m.indices.size() * 4 + m.triangle_material.size() * 4;
  for (const Texture& t : m.textures) b += t.rgba.size();
  return b;
}

CellPlan plan_cells(const Mesh& mesh, const std::vector<std::array<double, 3>>& gv,
                    const GridTransform& grid, int bits, double bytes_per_pair) {
  CellPlan p;
  p.bits = bits;
  const double side = std::ldexp(1.0, bits);
  const double cap = 3.0 * side * side + 12.0 * side;  // a plane through the cube + edge band
  std::unordered_map<uint64_t, double> per_cell;
  for (size_t t = 0; t < mesh.triangle_count(); ++t) {
    uint32_t lo[3], hi[3];
    if (!triangle_voxel_range(gv, mesh, t, grid.resolution, lo, hi)) continue;
    double v[3][3];
    for (int k = 0; k < 3; ++k)
      for (int a = 0; a < 3; ++a) v[k][a] = gv[mesh.indices[3 * t + size_t(k)]][size_t(a)];
    const double share = std::min(triangle_pairs(v), cap);
    for (uint32_t z = lo[2] >> bits; z <= hi[2] >> bits; ++z)
      for (uint32_t y = lo[1] >> bits; y <= hi[1] >> bits; ++y)
        for (uint32_t x = lo[0] >> bits; x <= hi[0] >> bits; ++x) {
          ++p.bins;
          per_cell[morton_encode(x, y, z)] += share;
        }
  }
  for (const auto& [cell, pairs] : per_cell) p.max_cell_pairs = std::max(p.max_cell_pairs, pairs);
  p.fixed_bytes = mesh_bytes(mesh) + gv.size() * sizeof(gv[0]) + p.bins * sizeof(CellBin) +
                  per_cell.size() * 64;
  p.cell_bytes = uint64_t(p.max_cell_pairs * bytes_per_pair);
  return p;
}

void triangle_voxels_in_box(const double tri[3][3], uint32_t resolution, VoxelizationMode mode,
                            const int box_lo[3], const int box_hi[3], std::vector<uint64_t>& out) {
  if (resolution == 0 || !std::has_single_bit(resolution) || resolution > (1u << kMaxGridLevels))
    throw Error(fmt::format("grid resolution {} is not a power of two between 1 and {}", resolution,
                            1u << kMaxGridLevels));
  for (int a = 0; a < 3; ++a)
    if (box_lo[a] < 0 || box_hi[a] >= int(resolution))
      throw Error("triangle_voxels_in_box: box outside the grid");
  raster_triangle_box(tri, int(resolution), mode == VoxelizationMode::SixSeparating, box_lo, box_hi,
                      [&out](uint64_t code) { out.push_back(code); });
}

VoxelSet voxelize_cell(const Mesh& mesh, const GridTransform& grid,
                       const std::vector<std::array<double, 3>>& gv, const uint32_t* tris,
                       size_t tri_count, const uint32_t cell_lo[3], uint32_t cell_size,
                       const VoxelizeOptions& opt) {
  const int n = int(grid.resolution);
  const bool six = opt.mode == VoxelizationMode::SixSeparating;
  int box_lo[3], box_hi[3];
  for (int a = 0; a < 3; ++a) {
    box_lo[a] = int(cell_lo[a]);
    box_hi[a] = int(std::min<uint64_t>(uint64_t(cell_lo[a]) + cell_size, uint64_t(n)) - 1);
  }
  VoxelSet out;
  out.grid = grid;
  if (!opt.attributes) {
    std::vector<uint64_t> codes = raster_cell<uint64_t>(
        mesh, gv, tris, tri_count, n, six, box_lo, box_hi, [](uint64_t c, uint32_t) { return c; });
    tbb::parallel_sort(codes.begin(), codes.end());
    codes.erase(std::unique(codes.begin(), codes.end()), codes.end());
    codes.shrink_to_fit();
    out.codes = std::move(codes);
    return out;
  }

  // (code, triangle) pairs in (code, triangle) order: each voxel's triangles
  // are summed in ascending triangle order, as voxelize() does, so the float
  // results are identical.
  std::vector<Pair> pairs = raster_cell<Pair>(mesh, gv, tris, tri_count, n, six, box_lo, box_hi,
                                              [](uint64_t c, uint32_t t) {
                                                return Pair{c, t};
                                              });
  tbb::parallel_sort(pairs.begin(), pairs.end());
  std::vector<size_t> starts;  // first pair of every voxel
  for (size_t i = 0; i < pairs.size(); ++i)
    if (i == 0 || pairs[i].code != pairs[i - 1].code) starts.push_back(i);
  const size_t nvox = starts.size();
  starts.push_back(pairs.size());
  out.codes.resize(nvox);
  out.colors.resize(nvox);
  out.normals.resize(nvox);
  out.weights.resize(nvox);
  auto tri_verts = [&](uint32_t t, double v[3][3]) {
    for (int k = 0; k < 3; ++k)
      for (int a = 0; a < 3; ++a) v[k][a] = gv[mesh.indices[3 * size_t(t) + size_t(k)]][size_t(a)];
  };
  // Box filter, the same arithmetic in the same order as voxelize.cpp step 3.
  tbb::parallel_for(size_t(0), nvox, [&](size_t vox) {
    const uint64_t code = pairs[starts[vox]].code;
    const MortonCoord xyz = morton_decode(code);
    out.codes[vox] = code;
    box_filter_voxel(
        mesh, tri_verts, xyz.x, xyz.y, xyz.z, starts[vox + 1] - starts[vox],
        [&](size_t k) { return pairs[starts[vox] + k].tri; }, &out.colors[vox], &out.normals[vox],
        &out.weights[vox]);
  });
  return out;
}

}  // namespace voxcast::detail
