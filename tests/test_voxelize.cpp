// Voxelizer tests: exactness against a brute-force separating-axis oracle,
// 6-separating thinning, watertightness on closed meshes (flood fill),
// determinism across thread counts, box-filtered attributes, grid fitting.
#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <map>
#include <random>
#include <vector>

#include "support/sat_oracle.hpp"
#include "support/test_data.hpp"
#include "voxcast/error.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/morton.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast {
namespace {

using Tri = std::array<std::array<double, 3>, 3>;

std::vector<uint64_t> voxels_of(const Tri& t, uint32_t n, VoxelizationMode mode) {
  double v[3][3];
  for (int k = 0; k < 3; ++k)
    for (int a = 0; a < 3; ++a) v[k][a] = t[k][a];
  std::vector<uint64_t> out;
  triangle_voxels(v, n, mode, out);
  std::sort(out.begin(), out.end());
  out.erase(std::unique(out.begin(), out.end()), out.end());
  return out;
}

std::vector<uint64_t> oracle_of(const Tri& t, uint32_t n) {
  double v[3][3];
  for (int k = 0; k < 3; ++k)
    for (int a = 0; a < 3; ++a) v[k][a] = t[k][a];
  return testing::sat_triangle_voxels(v, n);
}

// Random triangles on a dyadic lattice (multiples of 1/64): every product
// the voxelizer and the oracle form is then exact in double, so "exactly the
// SAT result" is a well-defined, bit-exact requirement.
class TriangleGen {
 public:
  explicit TriangleGen(uint64_t seed) : rng_(seed) {}

  double q(double x) { return std::round(x * 64.0) / 64.0; }
  double uni(double a, double b) { return std::uniform_real_distribution<double>(a, b)(rng_); }
  int pick(int n) { return std::uniform_int_distribution<int>(0, n - 1)(rng_); }

  Tri make(uint32_t n) {
    const double N = n;
    int kind = pick(9);
    Tri t;
    double c[3] = {uni(-2, N + 2), uni(-2, N + 2), uni(-2, N + 2)};
    double size = kind < 2 ? uni(0.01, 0.4) : kind < 4 ? uni(0.5, 2.0) : uni(2.0, N * 0.6);
    for (auto& p : t)
      for (int a = 0; a < 3; ++a) p[a] = q(c[a] + uni(-size, size));
    switch (kind) {
      case 4:  // vertices on integer coordinates (voxel corners/edges/faces)
        for (auto& p : t)
          for (double& x : p) x = std::round(x);
        break;
      case 5: {  // axis-aligned: one coordinate shared, often on a voxel face
        int a = pick(3);
        double z = pick(2) ? std::round(t[0][a]) : t[0][a];
        for (auto& p : t) p[a] = z;
        break;
      }
      case 6: {  // degenerate: collinear, repeated vertex, or a single point
        int d = pick(3);
        if (d == 0) {
          double s = double(pick(17) - 4) / 8.0;
          for (int a = 0; a < 3; ++a) t[2][a] = t[0][a] + s * (t[1][a] - t[0][a]);
        } else if (d == 1) {
          t[2] = t[pick(2)];
        } else {
          t[1] = t[2] = t[0];
        }
        if (pick(2))
          for (auto& p : t)
            for (double& x : p) x = std::round(x);
        break;
      }
      case 7: {  // edge along an axis on integer lines (edge x axis tests vanish)
        int a = pick(3);
        for (int b = 0; b < 3; ++b)
          if (b != a) t[1][b] = t[0][b] = std::round(t[0][b]);
        break;
      }
      default:
        break;
    }
    return t;
  }

 private:
  std::mt19937_64 rng_;
};

std::string describe(const Tri& t) {
  std::string s;
  for (auto& p : t)
    s +=
        "(" + std::to_string(p[0]) + "," + std::to_string(p[1]) + "," + std::to_string(p[2]) + ") ";
  return s;
}

// (a) Conservative voxelization == brute-force 13-axis SAT, voxel for voxel.
TEST(TriangleVoxels, ConservativeEqualsSeparatingAxisOracle) {
  TriangleGen gen(12345);
  const uint32_t grids[] = {8, 16, 32, 64};
  int tested = 0, nonempty = 0;
  for (int it = 0; it < 6000; ++it) {
    uint32_t n = grids[gen.pick(4)];
    Tri t = gen.make(n);
    auto got = voxels_of(t, n, VoxelizationMode::Conservative);
    auto want = oracle_of(t, n);
    ASSERT_EQ(got, want) << "triangle " << describe(t) << " grid " << n << ": " << got.size()
                         << " voxels, oracle " << want.size();
    ++tested;
    nonempty += !want.empty();
  }
  EXPECT_EQ(tested, 6000);
  EXPECT_GT(nonempty, 4000);  // the generator mostly hits the grid
}

// Single hand-checked cases: touching a voxel corner, an edge, a face.
TEST(TriangleVoxels, ClosedBoxesTouchingCounts) {
  // A point on the corner shared by 8 voxels.
  Tri p{{{{4, 4, 4}}, {{4, 4, 4}}, {{4, 4, 4}}}};
  EXPECT_EQ(voxels_of(p, 8, VoxelizationMode::Conservative).size(), 8u);
  // A triangle in the plane z = 2 covering [0.25, 0.75]^2 in x,y: voxels
  // (0,0,1) and (0,0,2).
  Tri f{{{{0.25, 0.25, 2}}, {{0.75, 0.25, 2}}, {{0.25, 0.75, 2}}}};
  auto got = voxels_of(f, 8, VoxelizationMode::Conservative);
  std::vector<uint64_t> want = {morton_encode(0, 0, 1), morton_encode(0, 0, 2)};
  std::sort(want.begin(), want.end());
  EXPECT_EQ(got, want);
  // Outside the grid entirely: nothing; clipped at the grid boundary.
  Tri out{{{{-3, -3, -3}}, {{-2, -3, -3}}, {{-3, -2, -3}}}};
  EXPECT_TRUE(voxels_of(out, 8, VoxelizationMode::Conservative).empty());
  Tri big{{{{-100, -100, 3.5}}, {{300, -100, 3.5}}, {{-100, 300, 3.5}}}};
  EXPECT_EQ(voxels_of(big, 8, VoxelizationMode::Conservative).size(), 64u);
}

// (b) 6-separating is a subset of conservative, and really thinner.
TEST(TriangleVoxels, SixSeparatingIsSubsetOfConservative) {
  TriangleGen gen(777);
  const uint32_t grids[] = {8, 16, 32, 64};
  size_t total6 = 0, totalc = 0;
  for (int it = 0; it < 6000; ++it) {
    uint32_t n = grids[gen.pick(4)];
    Tri t = gen.make(n);
    auto c = voxels_of(t, n, VoxelizationMode::Conservative);
    auto s = voxels_of(t, n, VoxelizationMode::SixSeparating);
    ASSERT_TRUE(std::includes(c.begin(), c.end(), s.begin(), s.end()))
        << "triangle " << describe(t) << " grid " << n;
    total6 += s.size();
    totalc += c.size();
  }
  EXPECT_LT(double(total6), 0.8 * double(totalc));
  EXPECT_GT(total6, 0u);
}

// 6-separating along the dominant axis: a plane z = 0.3 x + 0.2 y + c gives
// exactly one or two voxels per column (S&S sec. 3.2).
TEST(TriangleVoxels, SixSeparatingOneOrTwoPerColumn) {
  Tri t{{{{-40, -40, 20 - 0.3 * 40 - 0.2 * 40}},
         {{100, -40, 20 + 0.3 * 100 - 0.2 * 40}},
         {{-40, 100, 20 - 0.3 * 40 + 0.2 * 100}}}};
  auto s = voxels_of(t, 32, VoxelizationMode::SixSeparating);
  std::map<std::pair<uint32_t, uint32_t>, int> per_column;
  for (uint64_t c : s) {
    MortonCoord m = morton_decode(c);
    ++per_column[{m.x, m.y}];
  }
  ASSERT_FALSE(per_column.empty());
  for (auto& [col, count] : per_column) {
    EXPECT_GE(count, 1);
    EXPECT_LE(count, 2) << "column " << col.first << "," << col.second;
  }
}

TEST(TriangleVoxels, RejectsBadInput) {
  double v[3][3] = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  std::vector<uint64_t> out;
  EXPECT_THROW(triangle_voxels(v, 3, VoxelizationMode::Conservative, out), Error);
  EXPECT_THROW(triangle_voxels(v, 0, VoxelizationMode::Conservative, out), Error);
  v[1][1] = NAN;
  EXPECT_THROW(triangle_voxels(v, 8, VoxelizationMode::Conservative, out), Error);
}

// ---------------------------------------------------------------------------
// Meshes built in code
// ---------------------------------------------------------------------------

// Icosphere (subdivided icosahedron), radius r around c, outward normals,
// rotated so that no symmetry plane is grid aligned.
Mesh make_icosphere(int subdiv, Vec3 c, float r) {
  const float t = (1.0f + std::sqrt(5.0f)) / 2.0f;
  std::vector<Vec3> p = {{-1, t, 0},  {1, t, 0},  {-1, -t, 0}, {1, -t, 0}, {0, -1, t},  {0, 1, t},
                         {0, -1, -t}, {0, 1, -t}, {t, 0, -1},  {t, 0, 1},  {-t, 0, -1}, {-t, 0, 1}};
  std::vector<uint32_t> idx = {0, 11, 5,  0, 5,  1, 0, 1, 7, 0, 7,  10, 0, 10, 11, 1, 5, 9, 5, 11,
                               4, 11, 10, 2, 10, 7, 6, 7, 1, 8, 3,  9,  4, 3,  4,  2, 3, 2, 6, 3,
                               6, 8,  3,  8, 9,  4, 9, 5, 2, 4, 11, 6,  2, 10, 8,  6, 7, 9, 8, 1};
  for (auto& q : p) q = normalize(q);
  for (int s = 0; s < subdiv; ++s) {
    std::map<std::pair<uint32_t, uint32_t>, uint32_t> mid;
    auto midpoint = [&](uint32_t a, uint32_t b) {
      auto key = std::minmax(a, b);
      auto it = mid.find(key);
      if (it != mid.end()) return it->second;
      p.push_back(normalize((p[a] + p[b]) * 0.5f));
      return mid[key] = uint32_t(p.size() - 1);
    };
    std::vector<uint32_t> next;
    for (size_t i = 0; i < idx.size(); i += 3) {
      uint32_t a = idx[i], b = idx[i + 1], d = idx[i + 2];
      uint32_t ab = midpoint(a, b), bd = midpoint(b, d), da = midpoint(d, a);
      next.insert(next.end(), {a, ab, da, b, bd, ab, d, da, bd, ab, bd, da});
    }
    idx.swap(next);
  }
  Mesh m;
  const float ca = std::cos(0.3f), sa = std::sin(0.3f), cb = std::cos(0.7f), sb = std::sin(0.7f);
  for (auto q : p) {
    Vec3 q1{ca * q.x - sa * q.y, sa * q.x + ca * q.y, q.z};
    Vec3 q2{q1.x, cb * q1.y - sb * q1.z, sb * q1.y + cb * q1.z};
    m.normals.push_back(normalize(q2));
    m.positions.push_back(c + q2 * r);
  }
  m.indices = idx;
  return m;
}

GridTransform unit_grid(uint32_t n) {
  GridTransform g;
  g.origin = {0, 0, 0};
  g.voxel_size = 1.0;
  g.resolution = n;
  g.levels = std::countr_zero(n);
  return g;
}

// Marks every empty voxel reachable from the grid boundary through
// 6-connected empty voxels. Returns the visited mask (x + n*(y + n*z)).
std::vector<uint8_t> flood_outside(const std::vector<uint64_t>& codes, uint32_t n) {
  const size_t nn = size_t(n);
  std::vector<uint8_t> state(nn * nn * nn, 0);  // 0 empty, 1 surface, 2 outside
  for (uint64_t c : codes) {
    MortonCoord m = morton_decode(c);
    state[m.x + nn * (m.y + nn * m.z)] = 1;
  }
  std::vector<size_t> stack;
  auto push = [&](size_t i) {
    if (state[i] == 0) state[i] = 2, stack.push_back(i);
  };
  for (size_t a = 0; a < nn; ++a)
    for (size_t b = 0; b < nn; ++b) {
      push(0 + nn * (a + nn * b)), push(nn - 1 + nn * (a + nn * b));
      push(a + nn * (0 + nn * b)), push(a + nn * (nn - 1 + nn * b));
      push(a + nn * (b + nn * 0)), push(a + nn * (b + nn * (nn - 1)));
    }
  while (!stack.empty()) {
    size_t i = stack.back();
    stack.pop_back();
    size_t x = i % nn, y = (i / nn) % nn, z = i / (nn * nn);
    if (x > 0) push(i - 1);
    if (x + 1 < nn) push(i + 1);
    if (y > 0) push(i - nn);
    if (y + 1 < nn) push(i + nn);
    if (z > 0) push(i - nn * nn);
    if (z + 1 < nn) push(i + nn * nn);
  }
  return state;
}

// (c) Closed surface: the outside flood fill never reaches the inside.
TEST(Voxelize, ClosedSphereIsWatertightInBothModes) {
  for (uint32_t n : {32u, 64u, 128u}) {
    const float c = float(n) * 0.5f + 0.137f;
    Mesh m = make_icosphere(4, {c, c - 0.31f, c + 0.05f}, float(n) * 0.37f);
    for (auto mode : {VoxelizationMode::Conservative, VoxelizationMode::SixSeparating}) {
      VoxelizeOptions opt;
      opt.mode = mode;
      opt.attributes = false;
      VoxelSet vs = voxelize(m, unit_grid(n), opt);
      ASSERT_GT(vs.size(), 0u);
      auto state = flood_outside(vs.codes, n);
      const size_t nn = n;
      size_t ci = size_t(c) + nn * (size_t(c - 0.31f) + nn * size_t(c + 0.05f));
      EXPECT_EQ(state[ci], 0) << "grid " << n << " mode " << int(mode) << ": the center leaked";
      size_t inside = std::count(state.begin(), state.end(), uint8_t(0));
      // No voxel whose center is inside the (polyhedral) sphere is reached.
      const Vec3 cc{c, c - 0.31f, c + 0.05f};
      size_t leaked = 0;
      for (uint32_t z = 0; z < n; ++z)
        for (uint32_t y = 0; y < n; ++y)
          for (uint32_t x = 0; x < n; ++x)
            if (state[x + nn * (y + nn * z)] == 2 &&
                length(Vec3{x + 0.5f, y + 0.5f, z + 0.5f} - cc) < 0.99f * float(n) * 0.37f)
              ++leaked;
      EXPECT_EQ(leaked, 0u) << "grid " << n << " mode " << int(mode);
      // The enclosed volume is about the ball's (minus the shell).
      double ball = 4.0 / 3.0 * M_PI * std::pow(n * 0.37, 3);
      EXPECT_GT(double(inside), 0.7 * ball) << "grid " << n;
      EXPECT_LT(double(inside), ball) << "grid " << n;
    }
  }
}

// A thin closed box (a tilted slab 1.7 voxels thick): its two sheets share
// voxels, the hard case for 6-separation. Criterion: no voxel whose center is
// strictly inside the solid is reached from outside through empty voxels.
TEST(Voxelize, ThinClosedSlabIsWatertight) {
  const float hx = 20, hy = 0.85f, hz = 20;
  const float a = 0.4f, b = 0.25f;
  const Vec3 offset{32.3f, 31.7f, 32.1f};
  auto to_world = [&](Vec3 p) {
    Vec3 q{std::cos(a) * p.x - std::sin(a) * p.y, std::sin(a) * p.x + std::cos(a) * p.y, p.z};
    Vec3 r{q.x, std::cos(b) * q.y - std::sin(b) * q.z, std::sin(b) * q.y + std::cos(b) * q.z};
    return r + offset;
  };
  auto to_local = [&](Vec3 r) {  // inverse rotation (transpose)
    r = r - offset;
    Vec3 q{r.x, std::cos(b) * r.y + std::sin(b) * r.z, -std::sin(b) * r.y + std::cos(b) * r.z};
    return Vec3{std::cos(a) * q.x + std::sin(a) * q.y, -std::sin(a) * q.x + std::cos(a) * q.y, q.z};
  };
  Mesh m;
  for (int i = 0; i < 8; ++i)
    m.positions.push_back(to_world({(i & 1) ? hx : -hx, (i & 2) ? hy : -hy, (i & 4) ? hz : -hz}));
  m.indices = {0, 2, 1, 1, 2, 3, 4, 5, 6, 5, 7, 6, 0, 1, 4, 1, 5, 4,
               2, 6, 3, 3, 6, 7, 0, 4, 2, 2, 4, 6, 1, 3, 5, 3, 7, 5};
  for (auto mode : {VoxelizationMode::Conservative, VoxelizationMode::SixSeparating}) {
    VoxelizeOptions opt;
    opt.mode = mode;
    opt.attributes = false;
    VoxelSet vs = voxelize(m, unit_grid(64), opt);
    auto state = flood_outside(vs.codes, 64);
    size_t inside_centers = 0, leaked = 0;
    for (uint32_t z = 0; z < 64; ++z)
      for (uint32_t y = 0; y < 64; ++y)
        for (uint32_t x = 0; x < 64; ++x) {
          Vec3 l = to_local({x + 0.5f, y + 0.5f, z + 0.5f});
          // Strictly inside, with a margin for float rounding.
          if (std::fabs(l.x) < hx - 1e-3f && std::fabs(l.y) < hy - 1e-3f &&
              std::fabs(l.z) < hz - 1e-3f) {
            ++inside_centers;
            leaked += state[x + 64 * (y + 64 * z)] == 2;
          }
        }
    EXPECT_GT(inside_centers, 100u);
    EXPECT_EQ(leaked, 0u) << "mode " << int(mode);
  }
}

// voxelize() is the union of triangle_voxels over the mesh, in grid units.
TEST(Voxelize, MatchesUnionOfTriangleVoxels) {
  Mesh m = make_icosphere(3, {20.3f, 19.9f, 21.1f}, 15.2f);
  GridTransform g = unit_grid(64);
  for (auto mode : {VoxelizationMode::Conservative, VoxelizationMode::SixSeparating}) {
    std::vector<uint64_t> want;
    for (size_t t = 0; t < m.triangle_count(); ++t) {
      double v[3][3];
      for (int k = 0; k < 3; ++k)
        for (int a = 0; a < 3; ++a) v[k][a] = m.positions[m.indices[3 * t + k]][a];
      triangle_voxels(v, 64, mode, want);
    }
    std::sort(want.begin(), want.end());
    want.erase(std::unique(want.begin(), want.end()), want.end());
    VoxelizeOptions opt;
    opt.mode = mode;
    VoxelSet vs = voxelize(m, g, opt);
    EXPECT_EQ(vs.codes, want);
    EXPECT_EQ(vs.colors.size(), vs.size());
    EXPECT_EQ(vs.normals.size(), vs.size());
    EXPECT_EQ(vs.weights.size(), vs.size());
  }
}

// At 2^20 voxels per axis (60-bit codes) the pair records no longer pack
// into 64 bits; the wide path must give the same answer.
TEST(Voxelize, HugeGridUsesWideRecordsCorrectly) {
  const uint32_t n = 1u << 20;
  Mesh m = make_icosphere(2, {1000.3f, 524288.7f, 1048500.2f}, 20.6f);  // 320 triangles
  GridTransform g = unit_grid(n);
  std::vector<uint64_t> want;
  for (size_t t = 0; t < m.triangle_count(); ++t) {
    double v[3][3];
    for (int k = 0; k < 3; ++k)
      for (int a = 0; a < 3; ++a) v[k][a] = m.positions[m.indices[3 * t + k]][a];
    triangle_voxels(v, n, VoxelizationMode::Conservative, want);
  }
  std::sort(want.begin(), want.end());
  want.erase(std::unique(want.begin(), want.end()), want.end());
  VoxelSet vs = voxelize(m, g, VoxelizeOptions{});
  EXPECT_EQ(vs.codes, want);
  ASSERT_GT(vs.size(), 1000u);
  for (float w : vs.weights) EXPECT_GT(w, 0.f);
}

// (d) Same result, byte for byte, with 1 and 2 threads.
TEST(Voxelize, DeterministicAcrossThreadCounts) {
  Mesh m = make_icosphere(4, {128.4f, 127.7f, 128.9f}, 100.3f);
  m.colors.resize(m.positions.size());
  for (size_t i = 0; i < m.positions.size(); ++i) {
    Vec3 p = m.positions[i];
    m.colors[i] = {p.x / 256.f, p.y / 256.f, p.z / 256.f, 1.f};
  }
  auto run = [&](int threads) {
    tbb::global_control gc(tbb::global_control::max_allowed_parallelism, threads);
    return voxelize(m, unit_grid(256), VoxelizeOptions{});
  };
  VoxelSet a = run(1), b = run(2);
  ASSERT_GT(a.size(), 50000u);
  ASSERT_EQ(a.codes, b.codes);
  ASSERT_EQ(a.colors.size(), b.colors.size());
  EXPECT_EQ(0, std::memcmp(a.colors.data(), b.colors.data(), a.colors.size() * sizeof(Color)));
  EXPECT_EQ(0, std::memcmp(a.normals.data(), b.normals.data(), a.normals.size() * sizeof(Vec3)));
  EXPECT_EQ(0, std::memcmp(a.weights.data(), b.weights.data(), a.weights.size() * sizeof(float)));
}

// A square [x0,x1] x [y0,y1] in a plane through `o` spanned by unit vectors
// s, t, split into cells x cells quads, with per-triangle-uniform colors by
// the side of s = 0 it lies on (vertices duplicated so colors never blend).
Mesh make_split_plane(Vec3 o, Vec3 s, Vec3 t, float half, int cells, Color left, Color right) {
  Mesh m;
  Vec3 nrm = normalize(cross(s, t));
  float step = 2 * half / float(cells);
  for (int i = 0; i < cells; ++i)
    for (int j = 0; j < cells; ++j) {
      float a0 = -half + i * step, a1 = a0 + step, b0 = -half + j * step, b1 = b0 + step;
      Color c = (a0 + a1) * 0.5f < 0 ? left : right;
      uint32_t base = uint32_t(m.positions.size());
      for (auto [a, b] : {std::pair{a0, b0}, {a1, b0}, {a1, b1}, {a0, b1}}) {
        m.positions.push_back(o + s * a + t * b);
        m.normals.push_back(nrm);
        m.colors.push_back(c);
      }
      m.indices.insert(m.indices.end(), {base, base + 1, base + 2, base, base + 2, base + 3});
    }
  return m;
}

// (e) Attributes: colors, normals, area weights.
TEST(Voxelize, AttributesColorsNormalsAndAreas) {
  const Vec3 s = normalize(Vec3{1, 0.2f, 0.3f});
  Vec3 t0 = normalize(Vec3{-0.1f, 1, 0.15f});
  const Vec3 t = normalize(t0 - s * dot(s, t0));
  const Vec3 o{32.2f, 31.9f, 32.4f};
  const Color red{1, 0, 0, 1}, blue{0, 0, 1, 1};
  Mesh m = make_split_plane(o, s, t, 24.0f, 12, red, blue);
  VoxelSet vs = voxelize(m, unit_grid(64), VoxelizeOptions{});
  ASSERT_GT(vs.size(), 1000u);

  const Vec3 nrm = normalize(cross(s, t));
  size_t red_seen = 0, blue_seen = 0, mixed = 0;
  double wsum = 0;
  for (size_t i = 0; i < vs.size(); ++i) {
    MortonCoord q = morton_decode(vs.codes[i]);
    // Signed coordinate along s of the voxel's 8 corners: fully on one side?
    float lo = INFINITY, hi = -INFINITY;
    for (int c = 0; c < 8; ++c) {
      Vec3 p{float(q.x + (c & 1)), float(q.y + ((c >> 1) & 1)), float(q.z + ((c >> 2) & 1))};
      float d = dot(p - o, s);
      lo = std::min(lo, d), hi = std::max(hi, d);
    }
    const Color& col = vs.colors[i];
    if (hi < 0) {
      EXPECT_NEAR(col.r, 1, 1e-5);
      EXPECT_NEAR(col.g, 0, 1e-5);
      EXPECT_NEAR(col.b, 0, 1e-5);
      ++red_seen;
    } else if (lo > 0) {
      EXPECT_NEAR(col.r, 0, 1e-5);
      EXPECT_NEAR(col.g, 0, 1e-5);
      EXPECT_NEAR(col.b, 1, 1e-5);
      ++blue_seen;
    } else if (col.r > 1e-3 && col.b > 1e-3) {
      ++mixed;
      EXPECT_NEAR(col.r + col.b, 1, 1e-5);
    }
    EXPECT_NEAR(col.a, 1, 1e-6);
    Vec3 n = vs.normals[i];
    EXPECT_NEAR(n.x, nrm.x, 1e-5);
    EXPECT_NEAR(n.y, nrm.y, 1e-5);
    EXPECT_NEAR(n.z, nrm.z, 1e-5);
    EXPECT_GT(vs.weights[i], 0.f);
    wsum += vs.weights[i];
  }
  EXPECT_GT(red_seen, 200u);
  EXPECT_GT(blue_seen, 200u);
  EXPECT_GT(mixed, 0u);  // voxels straddling the seam blend both colors
  // Total area of the mesh in voxel units^2 (voxel size 1).
  double area = 0;
  for (size_t tr = 0; tr < m.triangle_count(); ++tr) {
    Vec3 a = m.positions[m.indices[3 * tr]], b = m.positions[m.indices[3 * tr + 1]],
         c = m.positions[m.indices[3 * tr + 2]];
    area += 0.5 * length(cross(b - a, c - a));
  }
  EXPECT_NEAR(wsum / area, 1.0, 1e-6);
}

TEST(Voxelize, AreaWeightsOnSphereAndScaledGrid) {
  // World units differ from voxel units: weights must be in voxel units^2.
  Mesh m = make_icosphere(3, {1.5f, -2.0f, 0.25f}, 0.8f);
  GridTransform g = GridTransform::fit(m.bounds(), 128);
  VoxelSet vs = voxelize(m, g, VoxelizeOptions{});
  double area = 0;
  for (size_t tr = 0; tr < m.triangle_count(); ++tr) {
    double p[3][3];
    for (int k = 0; k < 3; ++k)
      for (int a = 0; a < 3; ++a)
        p[k][a] = (double(m.positions[m.indices[3 * tr + k]][a]) - g.origin[a]) / g.voxel_size;
    double e1[3], e2[3];
    for (int a = 0; a < 3; ++a) e1[a] = p[1][a] - p[0][a], e2[a] = p[2][a] - p[0][a];
    double cx = e1[1] * e2[2] - e1[2] * e2[1], cy = e1[2] * e2[0] - e1[0] * e2[2],
           cz = e1[0] * e2[1] - e1[1] * e2[0];
    area += 0.5 * std::sqrt(cx * cx + cy * cy + cz * cz);
  }
  double wsum = 0;
  for (float w : vs.weights) wsum += w;
  EXPECT_NEAR(wsum / area, 1.0, 1e-6);
  // Outward normals of a sphere point away from its center.
  for (size_t i = 0; i < vs.size(); ++i) {
    MortonCoord q = morton_decode(vs.codes[i]);
    Vec3 center{float(g.origin.x + (q.x + 0.5) * g.voxel_size),
                float(g.origin.y + (q.y + 0.5) * g.voxel_size),
                float(g.origin.z + (q.z + 0.5) * g.voxel_size)};
    Vec3 radial = normalize(center - Vec3{1.5f, -2.0f, 0.25f});
    EXPECT_GT(dot(radial, vs.normals[i]), 0.9f);
    EXPECT_NEAR(length(vs.normals[i]), 1.0f, 1e-5f);
  }
  // Without attributes only the codes.
  VoxelizeOptions no_attr;
  no_attr.attributes = false;
  VoxelSet bare = voxelize(m, g, no_attr);
  EXPECT_EQ(bare.codes, vs.codes);
  EXPECT_TRUE(bare.colors.empty() && bare.normals.empty() && bare.weights.empty());
}

TEST(Voxelize, DegenerateTrianglesStillVoxelize) {
  Mesh m;
  m.positions = {{1.5f, 1.5f, 1.5f}, {6.5f, 2.5f, 1.5f}, {4.0f, 2.0f, 1.5f}, {3.2f, 5.1f, 6.3f}};
  m.indices = {0, 1, 2, 3, 3, 3};  // a segment (collinear) and a point
  VoxelSet vs = voxelize(m, unit_grid(8), VoxelizeOptions{});
  // Segment from (1.5,1.5) to (6.5,2.5) at z=1.5 crosses x = 1..6 and y = 1..2.
  EXPECT_GE(vs.size(), 7u);
  EXPECT_TRUE(std::binary_search(vs.codes.begin(), vs.codes.end(), morton_encode(3, 5, 6)));
  for (size_t i = 0; i < vs.size(); ++i) {
    EXPECT_GT(vs.weights[i], 0.f);
    EXPECT_TRUE(std::isfinite(vs.colors[i].r));
    EXPECT_NEAR(length(vs.normals[i]), 1.0f, 1e-5f);
  }
}

TEST(Voxelize, RejectsBadGrid) {
  Mesh m = make_icosphere(1, {4, 4, 4}, 2);
  GridTransform g = unit_grid(8);
  g.resolution = 6;
  EXPECT_THROW(voxelize(m, g, {}), Error);
  g = unit_grid(8);
  g.voxel_size = 0;
  EXPECT_THROW(voxelize(m, g, {}), Error);
  g = unit_grid(8);
  g.levels = 2;
  EXPECT_THROW(voxelize(m, g, {}), Error);
  m.indices.push_back(1000);
  m.indices.push_back(0);
  m.indices.push_back(1);
  EXPECT_THROW(voxelize(m, unit_grid(8), {}), Error);
}

// A shipped closed mesh through load_mesh.
TEST(Voxelize, SharedClosedMeshesAreWatertight) {
  Mesh m = load_mesh(testing::test_mesh("armadillo.off"));
  for (auto mode : {VoxelizationMode::Conservative, VoxelizationMode::SixSeparating}) {
    VoxelizeOptions opt;
    opt.mode = mode;
    opt.attributes = false;
    VoxelSet vs = voxelize(m, GridTransform::fit(m.bounds(), 128), opt);
    auto state = flood_outside(vs.codes, 128);
    size_t inside = std::count(state.begin(), state.end(), uint8_t(0));
    // A leak floods the inside completely; the armadillo encloses thousands
    // of voxels at 128^3.
    EXPECT_GT(inside, 20000u) << "mode " << int(mode);
  }
}

// (f) Grid fitting.
TEST(GridTransform, FitPlacesCenteredPowerOfTwoCube) {
  Aabb b;
  b.extend({-1, 2, 3});
  b.extend({3, 2.5f, 4});
  GridTransform g = GridTransform::fit(b, 64);
  EXPECT_EQ(g.resolution, 64u);
  EXPECT_EQ(g.levels, 6);
  EXPECT_NEAR(g.side(), 4.0 * 1.001, 1e-4);
  for (int a = 0; a < 3; ++a) {
    EXPECT_LT(g.origin[a], b.lo[a]);
    EXPECT_GT(g.origin[a] + g.side(), b.hi[a]);
    EXPECT_NEAR(g.origin[a] + 0.5 * g.side(), 0.5 * (b.lo[a] + b.hi[a]), 1e-5);
  }
  EXPECT_EQ(GridTransform::fit(b, 1).levels, 0);
  EXPECT_EQ(GridTransform::fit(b, 1u << 20).levels, 20);
  // A flat mesh (zero extent on one axis) and a single point get a real cube.
  Aabb flat;
  flat.extend({0, 0, 5});
  flat.extend({2, 1, 5});
  EXPECT_GT(GridTransform::fit(flat, 8).voxel_size, 0);
  Aabb point;
  point.extend({7, 7, 7});
  GridTransform gp = GridTransform::fit(point, 8);
  EXPECT_GT(gp.voxel_size, 0);
  EXPECT_LE(gp.origin.x, 7.0f);
  EXPECT_GE(gp.origin.x + gp.side(), 7.0);
}

TEST(GridTransform, FitVoxelSizeRoundsUpToPowerOfTwo) {
  Aabb b;
  b.extend({0, 0, 0});
  b.extend({10, 5, 1});
  GridTransform g = GridTransform::fit_voxel_size(b, 0.1);
  EXPECT_EQ(g.resolution, 128u);  // 10.01 / 0.1 = 100.1 -> 128
  EXPECT_LE(g.voxel_size, 0.1);
  EXPECT_GE(g.side(), 10.0);
  EXPECT_EQ(GridTransform::fit_voxel_size(b, 100.0).resolution, 1u);
}

TEST(GridTransform, RejectsBadInput) {
  Aabb b;
  b.extend({0, 0, 0});
  b.extend({1, 1, 1});
  EXPECT_THROW(GridTransform::fit(b, 0), Error);
  EXPECT_THROW(GridTransform::fit(b, 3), Error);
  EXPECT_THROW(GridTransform::fit(b, 1u << 21), Error);
  Aabb nan = b;
  nan.hi.y = NAN;
  EXPECT_THROW(GridTransform::fit(nan, 8), Error);
  Aabb inf = b;
  inf.lo.x = -INFINITY;
  EXPECT_THROW(GridTransform::fit(inf, 8), Error);
  EXPECT_THROW(GridTransform::fit(Aabb{}, 8), Error);
  EXPECT_THROW(GridTransform::fit_voxel_size(b, 0.0), Error);
  EXPECT_THROW(GridTransform::fit_voxel_size(b, -1.0), Error);
  EXPECT_THROW(GridTransform::fit_voxel_size(b, NAN), Error);
  EXPECT_THROW(GridTransform::fit_voxel_size(b, 1e-9), Error);  // needs > 2^20 voxels
  EXPECT_THROW(GridTransform::fit_voxel_size(nan, 0.1), Error);
}

}  // namespace
}  // namespace voxcast
