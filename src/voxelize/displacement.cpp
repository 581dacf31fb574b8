// Displacement mapping (esvo §7.4): displacement primitives split until
// their displaced bound is below a voxel, bounded by the height map's min/max
// mip-maps. Contract and definitions: include/voxcast/displacement.hpp.
#include "voxcast/displacement.hpp"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <string>

#include "voxcast/error.hpp"
#include "voxcast/morton.hpp"
#include "voxelize/displacement_cells.hpp"

namespace voxcast {

DisplacementMap::DisplacementMap(const Image& image) {
  if (image.width < 1 || image.height < 1 || image.channels < 1)
    throw Error("displacement map: empty image");
  width_ = image.width;
  height_ = image.height;
  Level base{width_, height_, {}, {}};
  base.lo.resize(size_t(width_) * size_t(height_));
  for (int y = 0; y < height_; ++y)
    for (int x = 0; x < width_; ++x) {
      const float h = image.at(x, y)[0];
      if (!(h >= 0.f && h <= 1.f))
        throw Error("displacement map: height outside [0,1] at texel " + std::to_string(x) + "," +
                    std::to_string(y));
      base.lo[size_t(y) * size_t(width_) + size_t(x)] = h;
    }
  base.hi = base.lo;
  levels_.push_back(std::move(base));
  // Level k: cells of 2^k x 2^k texels (power-of-two squares of the map).
  while (levels_.back().w > 1 || levels_.back().h > 1) {
    const Level& f = levels_.back();
    Level c{(f.w + 1) / 2, (f.h + 1) / 2, {}, {}};
    c.lo.assign(size_t(c.w) * size_t(c.h), INFINITY);
    c.hi.assign(size_t(c.w) * size_t(c.h), -INFINITY);
    for (int y = 0; y < f.h; ++y)
      for (int x = 0; x < f.w; ++x) {
        const size_t from = size_t(y) * size_t(f.w) + size_t(x);
        const size_t to = size_t(y / 2) * size_t(c.w) + size_t(x / 2);
        c.lo[to] = std::min(c.lo[to], f.lo[from]);
        c.hi[to] = std::max(c.hi[to], f.hi[from]);
      }
    levels_.push_back(std::move(c));
  }
}

namespace {
int64_t wrap(int64_t i, int n) {
  const int64_t m = i % n;
  return m < 0 ? m + n : m;
}
double finite_or_zero(double x) {
  return std::isfinite(x) ? x : 0.0;
}
}  // namespace

float DisplacementMap::sample(Vec2 uv) const {
  const double X = finite_or_zero(double(uv.x)) * width_ - 0.5;
  const double Y = finite_or_zero(double(uv.y)) * height_ - 0.5;
  const double fx0 = std::floor(X), fy0 = std::floor(Y);
  const float fx = float(X - fx0), fy = float(Y - fy0);
  const int64_t x0 = wrap(int64_t(fx0), width_), x1 = wrap(int64_t(fx0) + 1, width_);
  const int64_t y0 = wrap(int64_t(fy0), height_), y1 = wrap(int64_t(fy0) + 1, height_);
  const float a = texel(int(x0), int(y0)), b = texel(int(x1), int(y0));
  const float c = texel(int(x0), int(y1)), d = texel(int(x1), int(y1));
  return (a * (1 - fx) + b * fx) * (1 - fy) + (c * (1 - fx) + d * fx) * fy;
}

void DisplacementMap::texel_range(int64_t x0, int64_t y0, int64_t x1, int64_t y1, float* lo,
                                  float* hi) const {
  // Wrap-around: at most two intervals per axis (or the whole axis).
  auto split = [](int64_t a, int64_t b, int n, int64_t out[2][2]) {
    if (b - a + 1 >= n) {
      out[0][0] = 0, out[0][1] = n - 1;
      return 1;
    }
    const int64_t s = wrap(a, n), e = s + (b - a);
    if (e < n) {
      out[0][0] = s, out[0][1] = e;
      return 1;
    }
    out[0][0] = s, out[0][1] = n - 1, out[1][0] = 0, out[1][1] = e - n;
    return 2;
  };
  int64_t xs[2][2], ys[2][2];
  const int nx = split(x0, x1, width_, xs), ny = split(y0, y1, height_, ys);
  for (int i = 0; i < nx; ++i)
    for (int j = 0; j < ny; ++j) {
      // The finest level whose cells (power-of-two squares) cover the
      // rectangle with at most 2 x 2 of them.
      size_t k = 0;
      while (k + 1 < levels_.size() &&
             (((xs[i][1] >> k) - (xs[i][0] >> k)) > 1 || ((ys[j][1] >> k) - (ys[j][0] >> k)) > 1))
        ++k;
      const Level& L = levels_[k];
      for (int64_t y = ys[j][0] >> k; y <= std::min<int64_t>(ys[j][1] >> k, L.h - 1); ++y)
        for (int64_t x = xs[i][0] >> k; x <= std::min<int64_t>(xs[i][1] >> k, L.w - 1); ++x) {
          const size_t at = size_t(y) * size_t(L.w) + size_t(x);
          *lo = std::min(*lo, L.lo[at]);
          *hi = std::max(*hi, L.hi[at]);
        }
    }
}

void DisplacementMap::range(double u0, double v0, double u1, double v1, float* lo,
                            float* hi) const {
  *lo = INFINITY;
  *hi = -INFINITY;
  u0 = finite_or_zero(u0), u1 = finite_or_zero(u1), v0 = finite_or_zero(v0),
  v1 = finite_or_zero(v1);
  const double X0 = u0 * width_ - 0.5, X1 = u1 * width_ - 0.5;
  const double Y0 = v0 * height_ - 0.5, Y1 = v1 * height_ - 0.5;
  const double fx0 = std::floor(X0), fx1 = std::floor(X1), fy0 = std::floor(Y0),
               fy1 = std::floor(Y1);
  if (fx1 - fx0 <= 1 && fy1 - fy0 <= 1) {
    // Within 2 x 2 bilinear cells: the extremes are on the corners of the
    // rectangle's parts in each cell (a bilinear patch is monotone along
    // each axis on a cell).
    const double xs[3] = {X0, fx1 > fx0 ? fx1 : X0, X1};
    const double ys[3] = {Y0, fy1 > fy0 ? fy1 : Y0, Y1};
    for (double y : ys)
      for (double x : xs) {
        const float h =
            sample({float((x + 0.5) / double(width_)), float((y + 0.5) / double(height_))});
        *lo = std::min(*lo, h);
        *hi = std::max(*hi, h);
      }
    // The float round trip of the points above may step off the exact
    // extreme by an ulp: widen by the float precision of a height.
    *lo = std::max(0.f, *lo - 1e-6f);
    *hi = std::min(1.f, *hi + 1e-6f);
    return;
  }
  texel_range(int64_t(fx0), int64_t(fy0), int64_t(fx1) + 1, int64_t(fy1) + 1, lo, hi);
}

namespace {

struct Corner {
  double u, v;  // barycentric (w = 1 - u - v at vertex 0)
};

struct Triangle {
  Vec3d p[3], n[3];
  double t[3][2];
  Vec3d at(const Vec3d (&x)[3], Corner b) const {
    return x[0] * (1 - b.u - b.v) + x[1] * b.u + x[2] * b.v;
  }
  void uv(Corner b, double* u, double* v) const {
    const double w = 1 - b.u - b.v;
    *u = t[0][0] * w + t[1][0] * b.u + t[2][0] * b.v;
    *v = t[0][1] * w + t[1][1] * b.u + t[2][1] * b.v;
  }
};

struct Mark {
  uint64_t code;
  float r, g, b, a;  // color times weight
  Vec3 n;            // normal times weight
  float w;           // area in voxel units^2
};

Triangle triangle_of(const Mesh& mesh, size_t t, const GridTransform& grid) {
  Triangle tri;
  const double inv = 1.0 / grid.voxel_size;
  const bool normals = mesh.normals.size() == mesh.positions.size();
  const bool uvs = mesh.uvs.size() == mesh.positions.size();
  const Vec3 fn = mesh.surface_normal(t, 1.f / 3.f, 1.f / 3.f);
  for (int k = 0; k < 3; ++k) {
    const uint32_t i = mesh.indices[3 * t + size_t(k)];
    const Vec3 p = mesh.positions[i];
    // Grid units: the displacement (world) is scaled the same way.
    tri.p[k] = Vec3d{(double(p.x) - grid.origin.x) * inv, (double(p.y) - grid.origin.y) * inv,
                     (double(p.z) - grid.origin.z) * inv};
    const Vec3 n = normals ? mesh.normals[i] : fn;
    tri.n[k] = Vec3d{double(n.x) * inv, double(n.y) * inv, double(n.z) * inv};
    tri.t[k][0] = uvs ? double(mesh.uvs[i].x) : 0.0;
    tri.t[k][1] = uvs ? double(mesh.uvs[i].y) : 0.0;
  }
  return tri;
}

}  // namespace

Aabb displaced_bounds(const Mesh& mesh, const DisplacementMap& map, float scale) {
  (void)map;  // heights are in [0,1]: the bound holds for any map
  Aabb box;
  const bool normals = mesh.normals.size() == mesh.positions.size();
  for (size_t t = 0; t < mesh.triangle_count(); ++t)
    for (int k = 0; k < 3; ++k) {
      const uint32_t i = mesh.indices[3 * t + size_t(k)];
      const Vec3 p = mesh.positions[i];
      const Vec3 n = normals ? mesh.normals[i] : mesh.surface_normal(t, 0.f, 0.f);
      box.extend(p);
      box.extend(p + n * scale);
    }
  return box;
}

// A piece stops splitting when its bound is below this many voxels a side:
// then it spans at most two voxels per axis, so every voxel it marks is
// within one voxel (per axis) of a point of the surface inside it.
constexpr double kStop = 0.99;

namespace detail {

namespace {

/// The displaced bound (grid units) of `piece` of `tri`: the box around its
/// corners displaced by the least and the largest height of its footprint.
void piece_bound(const Triangle& tri, const DisplacementMap& map, float scale,
                 const std::array<Corner, 3>& piece, Vec3d* lo_out, Vec3d* hi_out) {
  double u0 = INFINITY, v0 = INFINITY, u1 = -INFINITY, v1 = -INFINITY;
  for (const Corner& b : piece) {
    double u, v;
    tri.uv(b, &u, &v);
    u0 = std::min(u0, u), u1 = std::max(u1, u), v0 = std::min(v0, v), v1 = std::max(v1, v);
  }
  float hlo, hhi;
  map.range(u0, v0, u1, v1, &hlo, &hhi);
  const double d0 = double(scale) * hlo, d1 = double(scale) * hhi;
  Vec3d lo{INFINITY, INFINITY, INFINITY}, hi{-INFINITY, -INFINITY, -INFINITY};
  for (const Corner& b : piece) {
    const Vec3d p = tri.at(tri.p, b), n = tri.at(tri.n, b);
    for (const double d : {d0, d1}) {
      const Vec3d q = p + n * d;
      lo = Vec3d{std::min(lo.x, q.x), std::min(lo.y, q.y), std::min(lo.z, q.z)};
      hi = Vec3d{std::max(hi.x, q.x), std::max(hi.y, q.y), std::max(hi.z, q.z)};
    }
  }
  *lo_out = lo, *hi_out = hi;
}

/// Whether the bound [lo, hi], widened by one voxel, misses the voxels
/// [c0, c1) per axis. A sub-piece's bound lies inside its piece's up to the
/// float rounding of the height ranges (about 1e-6 of the relief), far
/// below the voxel of slack, so a culled piece marks nothing in the cube.
bool misses(const Vec3d& lo, const Vec3d& hi, const uint32_t c0[3], const uint32_t c1[3]) {
  const double l[3] = {lo.x, lo.y, lo.z}, h[3] = {hi.x, hi.y, hi.z};
  for (int k = 0; k < 3; ++k)
    if (h[k] + 1.0 < double(c0[k]) || l[k] - 1.0 >= double(c1[k])) return true;
  return false;
}

}  // namespace

struct DisplacedVoxelizer::Task {
  uint32_t t;
  std::array<Corner, 3> piece;
};

DisplacedVoxelizer::DisplacedVoxelizer(const Mesh& mesh, const DisplacementMap& map, float scale,
                                       const GridTransform& grid)
    : mesh_(mesh), map_(map), scale_(scale), grid_(grid) {
  if (map.width() < 1) throw Error("displacement map: empty");
  // Tasks: every triangle cut (midpoint splits, no bound yet) into pieces of
  // at most about 64 voxels a side, so that a large triangle is spread over
  // the threads; marks are concatenated in task order (deterministic).
  for (size_t t = 0; t < mesh.triangle_count(); ++t) {
    const Triangle tri = triangle_of(mesh, t, grid);
    double edge = 0;
    for (int k = 0; k < 3; ++k) edge = std::max(edge, length(tri.p[(k + 1) % 3] - tri.p[k]));
    int depth = 0;
    while (depth < 8 && edge > 64.0) edge /= 2, ++depth;
    std::vector<std::array<Corner, 3>> level{{Corner{0, 0}, Corner{1, 0}, Corner{0, 1}}};
    for (int d = 0; d < depth; ++d) {
      std::vector<std::array<Corner, 3>> next;
      for (const auto& q : level) {
        const Corner m01{(q[0].u + q[1].u) / 2, (q[0].v + q[1].v) / 2};
        const Corner m12{(q[1].u + q[2].u) / 2, (q[1].v + q[2].v) / 2};
        const Corner m20{(q[2].u + q[0].u) / 2, (q[2].v + q[0].v) / 2};
        next.push_back({q[0], m01, m20});
        next.push_back({m01, q[1], m12});
        next.push_back({m20, m12, q[2]});
        next.push_back({m01, m12, m20});
      }
      level = std::move(next);
    }
    for (const auto& q : level) tasks_.push_back({uint32_t(t), q});
  }
  if (tasks_.size() > size_t(UINT32_MAX)) throw Error("displacement: more than 2^32-1 pieces");
}

DisplacedVoxelizer::~DisplacedVoxelizer() = default;

size_t DisplacedVoxelizer::task_count() const {
  return tasks_.size();
}

std::vector<CellBin> DisplacedVoxelizer::bin(int bits) const {
  const double N = double(grid_.resolution);
  std::vector<std::vector<CellBin>> per(tasks_.size());
  tbb::parallel_for(size_t(0), tasks_.size(), [&](size_t c) {
    const Triangle tri = triangle_of(mesh_, tasks_[c].t, grid_);
    Vec3d lo, hi;
    piece_bound(tri, map_, scale_, tasks_[c].piece, &lo, &hi);
    if (!(hi.x >= 0 && hi.y >= 0 && hi.z >= 0 && lo.x <= N && lo.y <= N && lo.z <= N)) return;
    // The cells the widened bound touches (misses() is the per-piece test).
    auto cell = [&](double x) { return uint32_t(std::clamp(std::floor(x), 0.0, N - 1)) >> bits; };
    const uint32_t x0 = cell(lo.x - 1), x1 = cell(hi.x + 1), y0 = cell(lo.y - 1),
                   y1 = cell(hi.y + 1), z0 = cell(lo.z - 1), z1 = cell(hi.z + 1);
    for (uint32_t z = z0; z <= z1; ++z)
      for (uint32_t y = y0; y <= y1; ++y)
        for (uint32_t x = x0; x <= x1; ++x) per[c].push_back({morton_encode(x, y, z), uint32_t(c)});
  });
  std::vector<CellBin> bins;
  for (auto& p : per) bins.insert(bins.end(), p.begin(), p.end());
  std::sort(bins.begin(), bins.end());
  return bins;
}

VoxelSet DisplacedVoxelizer::voxelize(const uint32_t* tasks, size_t task_count,
                                      const uint32_t cube_lo[3], uint32_t cube_size,
                                      const VoxelizeOptions& options,
                                      DisplacementStats* stats) const {
  const Mesh& mesh = mesh_;
  const DisplacementMap& map = map_;
  const float scale = scale_;
  const GridTransform& grid = grid_;
  const double N = double(grid.resolution);
  const uint32_t c0[3] = {cube_lo[0], cube_lo[1], cube_lo[2]};
  const uint32_t c1[3] = {cube_lo[0] + cube_size, cube_lo[1] + cube_size, cube_lo[2] + cube_size};
  // Sorts the marks by code and adds up equal codes, in their order (a
  // left fold: merging early does not change the sums).
  auto merge = [](std::vector<Mark>& marks) {
    std::stable_sort(marks.begin(), marks.end(),
                     [](const Mark& a, const Mark& b) { return a.code < b.code; });
    size_t keep = 0;
    for (size_t i = 0; i < marks.size(); ++i) {
      if (keep > 0 && marks[keep - 1].code == marks[i].code) {
        Mark& m = marks[keep - 1];
        m.r += marks[i].r, m.g += marks[i].g, m.b += marks[i].b, m.a += marks[i].a;
        m.n = m.n + marks[i].n;
        m.w += marks[i].w;
      } else {
        marks[keep++] = marks[i];
      }
    }
    marks.resize(keep);
  };
  const size_t chunks = task_count;
  std::vector<std::vector<Mark>> out(chunks);
  std::vector<DisplacementStats> chunk_stats(chunks);
  tbb::parallel_for(size_t(0), chunks, [&](size_t c) {
    std::vector<Mark>& marks = out[c];
    DisplacementStats& st = chunk_stats[c];
    const Task& task = tasks_[tasks[c]];
    const size_t t = task.t;
    const Triangle tri = triangle_of(mesh, t, grid);
    std::vector<std::array<Corner, 3>> stack{task.piece};
    while (!stack.empty()) {
      // Bounded memory: duplicates merged as they pile up.
      if (marks.size() >= (size_t(1) << 20)) merge(marks);
      const std::array<Corner, 3> piece = stack.back();
      stack.pop_back();
      ++st.pieces;
      Vec3d lo, hi;
      piece_bound(tri, map, scale, piece, &lo, &hi);
      if (!(hi.x >= 0 && hi.y >= 0 && hi.z >= 0 && lo.x <= N && lo.y <= N && lo.z <= N) ||
          misses(lo, hi, c0, c1)) {
        ++st.culled;
        continue;
      }
      const double extent = std::max({hi.x - lo.x, hi.y - lo.y, hi.z - lo.z});
      const double piece_size =
          std::max({std::abs(piece[1].u - piece[0].u), std::abs(piece[2].v - piece[0].v),
                    std::abs(piece[2].u - piece[1].u), std::abs(piece[2].v - piece[1].v)});
      if (extent > kStop && piece_size > 1e-9) {
        // Split into four (the map footprint follows the triangle).
        const Corner m01{(piece[0].u + piece[1].u) / 2, (piece[0].v + piece[1].v) / 2};
        const Corner m12{(piece[1].u + piece[2].u) / 2, (piece[1].v + piece[2].v) / 2};
        const Corner m20{(piece[2].u + piece[0].u) / 2, (piece[2].v + piece[0].v) / 2};
        stack.push_back({m01, m12, m20});
        stack.push_back({m20, m12, piece[2]});
        stack.push_back({m01, piece[1], m12});
        stack.push_back({piece[0], m01, m20});
        continue;
      }
      // Half a voxel: mark every voxel the bound touches (those in the cube).
      Vec3d D[3];
      for (int k = 0; k < 3; ++k) {
        double u, v;
        tri.uv(piece[size_t(k)], &u, &v);
        const double h = map.sample({float(u), float(v)});
        D[k] = tri.at(tri.p, piece[size_t(k)]) + tri.at(tri.n, piece[size_t(k)]) * (scale * h);
      }
      const Vec3d cr = cross(D[1] - D[0], D[2] - D[0]);
      const double len = length(cr);
      const Corner mid{(piece[0].u + piece[1].u + piece[2].u) / 3,
                       (piece[0].v + piece[1].v + piece[2].v) / 3};
      Vec3 n = len > 1e-12 ? Vec3{float(cr.x / len), float(cr.y / len), float(cr.z / len)}
                           : mesh.surface_normal(t, float(mid.u), float(mid.v));
      const Color col = mesh.surface_color(t, float(mid.u), float(mid.v));
      auto cell = [&](double x) { return uint32_t(std::clamp(std::floor(x), 0.0, N - 1)); };
      const uint32_t x0 = cell(lo.x), x1 = cell(hi.x), y0 = cell(lo.y), y1 = cell(hi.y),
                     z0 = cell(lo.z), z1 = cell(hi.z);
      const float w = float(0.5 * len) / float((x1 - x0 + 1) * (y1 - y0 + 1) * (z1 - z0 + 1));
      for (uint32_t z = std::max(z0, c0[2]); z <= std::min(z1, c1[2] - 1); ++z)
        for (uint32_t y = std::max(y0, c0[1]); y <= std::min(y1, c1[1] - 1); ++y)
          for (uint32_t x = std::max(x0, c0[0]); x <= std::min(x1, c1[0] - 1); ++x) {
            marks.push_back(
                {morton_encode(x, y, z), col.r * w, col.g * w, col.b * w, col.a * w, n * w, w});
            ++st.emitted;
          }
    }
    merge(marks);
    marks.shrink_to_fit();  // every task's marks are held until all are done
  });
  std::vector<Mark> all;
  DisplacementStats total;
  for (size_t c = 0; c < chunks; ++c) {
    all.insert(all.end(), out[c].begin(), out[c].end());
    std::vector<Mark>().swap(out[c]);
    total.pieces += chunk_stats[c].pieces;
    total.culled += chunk_stats[c].culled;
    total.emitted += chunk_stats[c].emitted;
  }
  if (stats) *stats = total;
  std::stable_sort(all.begin(), all.end(),
                   [](const Mark& a, const Mark& b) { return a.code < b.code; });
  VoxelSet v;
  v.grid = grid;
  for (size_t i = 0; i < all.size();) {
    Mark m = all[i++];
    for (; i < all.size() && all[i].code == m.code; ++i) {
      m.r += all[i].r, m.g += all[i].g, m.b += all[i].b, m.a += all[i].a;
      m.n = m.n + all[i].n;
      m.w += all[i].w;
    }
    v.codes.push_back(m.code);
    if (!options.attributes) continue;
    const float inv = m.w > 0 ? 1.f / m.w : 0.f;
    v.colors.push_back(m.w > 0 ? Color{m.r * inv, m.g * inv, m.b * inv, m.a * inv} : Color{});
    const float nl = length(m.n);
    v.normals.push_back(nl > 1e-20f ? m.n / nl : Vec3{0, 0, 1});
    v.weights.push_back(m.w);
  }
  return v;
}

}  // namespace detail

VoxelSet voxelize_displaced(const Mesh& mesh, const DisplacementMap& map, float scale,
                            const GridTransform& grid, const VoxelizeOptions& options,
                            DisplacementStats* stats) {
  const detail::DisplacedVoxelizer dv(mesh, map, scale, grid);
  std::vector<uint32_t> all(dv.task_count());
  for (size_t i = 0; i < all.size(); ++i) all[i] = uint32_t(i);
  const uint32_t lo[3] = {0, 0, 0};
  return dv.voxelize(all.data(), all.size(), lo, grid.resolution, options, stats);
}

}  // namespace voxcast
