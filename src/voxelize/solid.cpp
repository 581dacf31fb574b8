// Occupancy normals and solid voxelization (solid.hpp).
#include "voxcast/solid.hpp"

#include <fmt/format.h>
#include <oneapi/tbb/combinable.h>
#include <oneapi/tbb/parallel_for.h>
#include <oneapi/tbb/parallel_sort.h>

#include <algorithm>
#include <atomic>
#include <numbers>

#include "voxcast/error.hpp"
#include "voxcast/morton.hpp"

namespace voxcast {

namespace {

bool occupied(const std::vector<uint64_t>& codes, int64_t x, int64_t y, int64_t z, int64_t n) {
  if (x < 0 || y < 0 || z < 0 || x >= n || y >= n || z >= n) return false;
  return std::binary_search(codes.begin(), codes.end(),
                            morton_encode(uint32_t(x), uint32_t(y), uint32_t(z)));
}

}  // namespace

std::vector<Vec3> occupancy_normals(const VoxelSet& voxels) {
  const std::vector<uint64_t>& codes = voxels.codes;
  const int64_t n = voxels.grid.resolution;
  std::vector<Vec3> normals(codes.size());
  tbb::parallel_for(tbb::blocked_range<size_t>(0, codes.size(), 4096), [&](const auto& r) {
    for (size_t i = r.begin(); i != r.end(); ++i) {
      const MortonCoord c = morton_decode(codes[i]);
      int sum[3] = {0, 0, 0};
      for (int dz = -1; dz <= 1; ++dz)
        for (int dy = -1; dy <= 1; ++dy)
          for (int dx = -1; dx <= 1; ++dx) {
            if (!dx && !dy && !dz) continue;
            if (occupied(codes, int64_t(c.x) + dx, int64_t(c.y) + dy, int64_t(c.z) + dz, n))
              continue;
            sum[0] += dx, sum[1] += dy, sum[2] += dz;
          }
      const float len = std::sqrt(float(sum[0] * sum[0] + sum[1] * sum[1] + sum[2] * sum[2]));
      normals[i] = len > 0 ? Vec3{float(sum[0]) / len, float(sum[1]) / len, float(sum[2]) / len}
                           : Vec3{0, 1, 0};
    }
  });
  return normals;
}

double winding_number(const Mesh& mesh, Vec3d p) {
  // Van Oosterom & Strackee: tan(omega/2) = det[a b c] /
  // (|a||b||c| + (a.b)|c| + (a.c)|b| + (b.c)|a|), a, b, c relative to p.
  double sum = 0;
  for (size_t t = 0; t < mesh.triangle_count(); ++t) {
    Vec3d v[3];
    double len[3];
    for (int k = 0; k < 3; ++k) {
      const Vec3& q = mesh.positions[mesh.indices[3 * t + size_t(k)]];
      v[k] = Vec3d{double(q.x) - p.x, double(q.y) - p.y, double(q.z) - p.z};
      len[k] = std::sqrt(dot(v[k], v[k]));
    }
    const double det = dot(v[0], cross(v[1], v[2]));
    const double den = len[0] * len[1] * len[2] + dot(v[0], v[1]) * len[2] +
                       dot(v[0], v[2]) * len[1] + dot(v[1], v[2]) * len[0];
    sum += 2.0 * std::atan2(det, den);
  }
  return sum / (4.0 * std::numbers::pi);
}

namespace {

struct Crossing {
  uint64_t column;  // x + N * y
  double z;         // grid units
  int8_t kind;      // +1: the triangle faces +z (the ray leaves), -1: it faces -z
  bool operator<(const Crossing& o) const {
    if (column != o.column) return column < o.column;
    if (z != o.z) return z < o.z;
    return kind < o.kind;
  }
};

struct P2 {
  double x, y;
};

/// Edge function of P against the edge {a, b}, computed from the edge's
/// lexicographically smaller endpoint so that the two triangles sharing an
/// edge get exactly opposite values (no point is on both sides of it).
double edge(P2 a, P2 b, P2 p) {
  const bool swap = b.x < a.x || (b.x == a.x && b.y < a.y);
  if (swap) std::swap(a, b);
  const double e = (b.x - a.x) * (p.y - a.y) - (b.y - a.y) * (p.x - a.x);
  return swap ? -e : e;
}

/// Top-left rule for a counter-clockwise triangle: a point exactly on edge
/// a -> b belongs to it if the edge is a top edge (horizontal, pointing -x)
/// or a left edge (pointing -y); a partition of the plane then assigns every
/// point to exactly one triangle.
bool owns(double e, P2 a, P2 b) {
  if (e != 0) return e > 0;
  return (a.y == b.y && b.x < a.x) || b.y < a.y;
}

}  // namespace

VoxelSet fill_solid(const Mesh& mesh, const VoxelSet& surface, SolidFillStats* stats,
                    uint64_t max_voxels) {
  const GridTransform& grid = surface.grid;
  const uint64_t n = grid.resolution;
  // Surface indices share 32 bits with the interior flag below.
  if (surface.codes.size() >= (uint64_t(1) << 31))
    throw Error("solid fill: more than 2^31 surface voxels");
  const double inv = 1.0 / grid.voxel_size;
  auto to_grid = [&](uint32_t index) {
    const Vec3& q = mesh.positions[index];
    return Vec3d{(double(q.x) - grid.origin.x) * inv, (double(q.y) - grid.origin.y) * inv,
                 (double(q.z) - grid.origin.z) * inv};
  };

  // 1. Every triangle's crossings with the z rays through the column centers.
  tbb::combinable<std::vector<Crossing>> local;
  tbb::parallel_for(tbb::blocked_range<size_t>(0, mesh.triangle_count(), 256), [&](const auto& r) {
    std::vector<Crossing>& out = local.local();
    for (size_t t = r.begin(); t != r.end(); ++t) {
      Vec3d v[3] = {to_grid(mesh.indices[3 * t]), to_grid(mesh.indices[3 * t + 1]),
                    to_grid(mesh.indices[3 * t + 2])};
      P2 p[3] = {{v[0].x, v[0].y}, {v[1].x, v[1].y}, {v[2].x, v[2].y}};
      const double area = edge(p[0], p[1], p[2]);
      if (area == 0) continue;  // seen edge-on by the rays: crossed through its neighbours
      const int8_t kind = area > 0 ? 1 : -1;
      if (area < 0) std::swap(p[1], p[2]), std::swap(v[1], v[2]);
      double lo[2] = {p[0].x, p[0].y}, hi[2] = {p[0].x, p[0].y};
      for (int k = 1; k < 3; ++k) {
        lo[0] = std::min(lo[0], p[k].x), hi[0] = std::max(hi[0], p[k].x);
        lo[1] = std::min(lo[1], p[k].y), hi[1] = std::max(hi[1], p[k].y);
      }
      // Columns whose center (i + 1/2) lies in [lo, hi].
      auto first = [&](double l) { return int64_t(std::max(0.0, std::ceil(l - 0.5))); };
      auto last = [&](double h) { return int64_t(std::min(double(n) - 1, std::floor(h - 0.5))); };
      for (int64_t j = first(lo[1]); j <= last(hi[1]); ++j)
        for (int64_t i = first(lo[0]); i <= last(hi[0]); ++i) {
          const P2 c{double(i) + 0.5, double(j) + 0.5};
          const double e0 = edge(p[1], p[2], c), e1 = edge(p[2], p[0], c), e2 = edge(p[0], p[1], c);
          if (!owns(e0, p[1], p[2]) || !owns(e1, p[2], p[0]) || !owns(e2, p[0], p[1])) continue;
          const double sum = e0 + e1 + e2;
          const double z = (e0 * v[0].z + e1 * v[1].z + e2 * v[2].z) / sum;
          out.push_back({uint64_t(i) + n * uint64_t(j), z, kind});
        }
    }
  });
  std::vector<Crossing> crossings;
  local.combine_each([&](const std::vector<Crossing>& v) {
    crossings.insert(crossings.end(), v.begin(), v.end());
  });
  tbb::parallel_sort(crossings.begin(), crossings.end());

  // Column starts.
  std::vector<size_t> starts;
  for (size_t i = 0; i < crossings.size(); ++i)
    if (i == 0 || crossings[i].column != crossings[i - 1].column) starts.push_back(i);
  starts.push_back(crossings.size());
  const size_t columns = starts.size() - 1;

  // Surface voxels by column (for the interior colors and to skip them).
  struct ColumnVoxel {
    uint64_t column;
    uint32_t z;
    uint32_t index;
    bool operator<(const ColumnVoxel& o) const {
      return column != o.column ? column < o.column : z < o.z;
    }
  };
  std::vector<ColumnVoxel> by_column(surface.codes.size());
  for (size_t i = 0; i < surface.codes.size(); ++i) {
    const MortonCoord c = morton_decode(surface.codes[i]);
    by_column[i] = {uint64_t(c.x) + n * uint64_t(c.y), c.z, uint32_t(i)};
  }
  tbb::parallel_sort(by_column.begin(), by_column.end());

  // 2. Per column: inside spans by parity, or by the winding number where
  // the crossings do not alternate.
  std::vector<std::vector<std::pair<uint64_t, uint32_t>>> interior(columns);  // (code, color from)
  std::atomic<uint64_t> added{0}, ambiguous{0}, windings{0};
  tbb::parallel_for(tbb::blocked_range<size_t>(0, columns, 16), [&](const auto& r) {
    for (size_t col = r.begin(); col != r.end(); ++col) {
      const Crossing* cs = crossings.data() + starts[col];
      const size_t count = starts[col + 1] - starts[col];
      const uint64_t column = cs[0].column;
      const uint32_t x = uint32_t(column % n), y = uint32_t(column / n);
      bool alternating = count % 2 == 0;
      for (size_t k = 1; k < count && alternating; ++k)
        if (cs[k].kind == cs[k - 1].kind) alternating = false;
      // Spans between consecutive crossings: [bound[s], bound[s+1]].
      std::vector<double> bounds;
      bounds.push_back(-1e300);
      for (size_t k = 0; k < count; ++k) bounds.push_back(cs[k].z);
      bounds.push_back(1e300);
      auto sv_begin =
          std::lower_bound(by_column.begin(), by_column.end(), ColumnVoxel{column, 0, 0});
      auto sv_end =
          std::lower_bound(by_column.begin(), by_column.end(), ColumnVoxel{column + 1, 0, 0});
      std::vector<std::pair<uint64_t, uint32_t>>& out = interior[col];
      if (!alternating) ambiguous.fetch_add(1, std::memory_order_relaxed);
      for (size_t s = 0; s + 1 < bounds.size(); ++s) {
        // Voxels whose centers k + 1/2 lie strictly inside the span.
        const double a = std::max(bounds[s], -1.0), b = std::min(bounds[s + 1], double(n) + 1);
        int64_t k0 = int64_t(std::floor(a - 0.5)) + 1, k1 = int64_t(std::ceil(b - 0.5)) - 1;
        k0 = std::max<int64_t>(k0, 0);
        k1 = std::min<int64_t>(k1, int64_t(n) - 1);
        if (k0 > k1) continue;
        bool inside;
        if (alternating) {
          inside = s % 2 == 1;
        } else {
          const int64_t mid = (k0 + k1) / 2;
          const Vec3d p{grid.origin.x + (double(x) + 0.5) * grid.voxel_size,
                        grid.origin.y + (double(y) + 0.5) * grid.voxel_size,
                        grid.origin.z + (double(mid) + 0.5) * grid.voxel_size};
          inside = std::fabs(winding_number(mesh, p)) > 0.5;
          windings.fetch_add(1, std::memory_order_relaxed);
        }
        if (!inside) continue;
        auto sv = sv_begin;
        for (int64_t k = k0; k <= k1; ++k) {
          while (sv != sv_end && int64_t(sv->z) < k) ++sv;
          if (sv != sv_end && int64_t(sv->z) == k) continue;  // a surface voxel already
          // Color source: the nearest surface voxel below in the column.
          const uint32_t from = sv != sv_begin ? std::prev(sv)->index
                                : sv != sv_end ? sv->index
                                               : UINT32_MAX;
          out.push_back({morton_encode(x, y, uint32_t(k)), from});
        }
      }
      const uint64_t total = added.fetch_add(out.size(), std::memory_order_relaxed) + out.size();
      if (max_voxels && total > max_voxels)
        throw Error(fmt::format(
            "solid fill: more than {} interior voxels, more than the memory budget allows; "
            "lower --resolution or raise --memory-budget",
            max_voxels));
    }
  });

  // 3. Merge the interior into the surface, in Morton order.
  std::vector<std::pair<uint64_t, uint32_t>>
      all;  // (code, surface index or interior source | flag)
  const uint32_t kInterior = 0x80000000u;
  all.reserve(surface.codes.size() + added.load());
  for (size_t i = 0; i < surface.codes.size(); ++i) all.push_back({surface.codes[i], uint32_t(i)});
  for (const auto& col : interior)
    for (const auto& [code, from] : col)
      all.push_back({code, from == UINT32_MAX ? UINT32_MAX : (from | kInterior)});
  tbb::parallel_sort(all.begin(), all.end());
  VoxelSet out;
  out.grid = grid;
  out.codes.reserve(all.size());
  for (const auto& e : all) out.codes.push_back(e.first);
  const bool attributes = !surface.colors.empty();
  if (attributes) {
    const std::vector<Vec3> occupancy = occupancy_normals(out);
    out.colors.resize(all.size());
    out.normals.resize(all.size());
    out.weights.resize(all.size());
    for (size_t i = 0; i < all.size(); ++i) {
      const uint32_t ref = all[i].second;
      if (ref != UINT32_MAX && !(ref & kInterior)) {
        out.colors[i] = surface.colors[ref];
        out.normals[i] = surface.normals.empty() ? occupancy[i] : surface.normals[ref];
        out.weights[i] = surface.weights.empty() ? 1.f : surface.weights[ref];
      } else {
        out.colors[i] = ref == UINT32_MAX ? Color{1, 1, 1, 1} : surface.colors[ref & ~kInterior];
        out.normals[i] = occupancy[i];
        out.weights[i] = 1.f;
      }
    }
  }
  if (stats) {
    stats->interior_voxels = added.load();
    stats->columns = columns;
    stats->ambiguous_columns = ambiguous.load();
    stats->winding_evaluations = windings.load();
  }
  return out;
}

}  // namespace voxcast
