// ESVO builder, layout, attribute encoding, validation and statistics.
#include <gtest/gtest.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <map>
#include <random>
#include <vector>

#include "support/esvo_testing.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo.hpp"
#include "voxcast/morton.hpp"

namespace voxcast {
namespace {

using esvo::EsvoOctree;
using testing::make_random_voxels;
using testing::make_sphere_shell;

// ---- independent helpers (do not use the builder's internals) -------------

uint32_t child_group_of(const EsvoOctree& o, uint32_t slot) {
  const uint32_t w0 = o.slot_ptr(slot)[0];
  uint32_t p = slot + esvo::layout::ChildPointer::get(w0);
  if (esvo::layout::FarBit::test(w0)) p = uint32_t(int64_t(slot) + int32_t(o.slot_ptr(p)[0]));
  return p;
}

/// Descriptor slot of the node at `depth` with Morton code `code` (at that depth).
uint32_t descriptor_of(const EsvoOctree& o, uint64_t code, int depth) {
  uint32_t slot = o.root_slot();
  for (int t = 0; t < depth; ++t) {
    const int i = int(code >> (3 * (depth - 1 - t))) & 7;
    const uint32_t w0 = o.slot_ptr(slot)[0];
    const uint32_t nl = esvo::layout::ValidMask::get(w0) & ~esvo::layout::LeafMask::get(w0);
    EXPECT_TRUE(nl >> i & 1);
    slot = child_group_of(o, slot) + uint32_t(std::popcount(nl & ((1u << i) - 1)));
  }
  return slot;
}

std::vector<esvo::LevelStats> brute_force_levels(const VoxelSet& v) {
  const int L = v.grid.levels;
  std::vector<esvo::LevelStats> s(size_t(L) + 1);
  for (int d = 0; d <= L; ++d) {
    std::vector<uint64_t> c;
    for (uint64_t code : v.codes) c.push_back(code >> (3 * (L - d)));
    c.erase(std::unique(c.begin(), c.end()), c.end());
    s[size_t(d)].voxels = c.size();
    s[size_t(d)].non_leaf = d < L ? c.size() : 0;
  }
  return s;
}

double angle(Vec3 a, Vec3 b) {
  const double cx = double(a.y) * b.z - double(a.z) * b.y,
               cy = double(a.z) * b.x - double(a.x) * b.z,
               cz = double(a.x) * b.y - double(a.y) * b.x;
  const double d = double(a.x) * b.x + double(a.y) * b.y + double(a.z) * b.z;
  return std::atan2(std::sqrt(cx * cx + cy * cy + cz * cz), d);
}

double to_srgb(double c) {
  return c <= 0.0031308 ? 12.92 * c : 1.055 * std::pow(c, 1 / 2.4) - 0.055;
}

void check_octree(const VoxelSet& v, const EsvoOctree& o) {
  ASSERT_NO_THROW(o.validate());
  EXPECT_EQ(esvo::decode_leaves(o), v.codes);
  const auto ls = o.level_stats();
  const auto bf = brute_force_levels(v);
  ASSERT_EQ(ls.size(), bf.size());
  for (size_t d = 0; d < ls.size(); ++d) {
    EXPECT_EQ(ls[d].voxels, bf[d].voxels) << "level " << d;
    EXPECT_EQ(ls[d].non_leaf, bf[d].non_leaf) << "level " << d;
  }
  const esvo::MemoryStats m = o.memory_stats();
  EXPECT_EQ(m.total_bytes, o.words.size() * 4);
  EXPECT_EQ(m.descriptor_bytes + m.far_pointer_bytes + m.page_header_bytes + m.padding_bytes +
                m.info_bytes + m.attribute_lookup_bytes + m.attribute_value_bytes,
            m.total_bytes);
  uint64_t nodes = 0;
  for (const auto& l : bf) nodes += l.non_leaf;
  EXPECT_EQ(m.descriptor_bytes, nodes * 8);
  EXPECT_EQ(m.attribute_value_bytes, (v.codes.size() + nodes - 1) * 8);  // all but the root
  EXPECT_EQ(o.words.size() % esvo::kPageWords, 0u);
}

/// Every leaf's attributes, looked up through the layout, match the input
/// after one encode/decode round trip.
void check_leaf_attributes(const VoxelSet& v, const EsvoOctree& o) {
  std::vector<uint32_t> parents(v.codes.size());
  std::vector<uint8_t> children(v.codes.size());
  std::vector<Color> want_c(v.codes.size());
  std::vector<Vec3> want_n(v.codes.size());
  for (size_t i = 0; i < v.codes.size(); ++i) {
    const MortonCoord p = morton_decode(v.codes[i]);
    uint32_t parent = 0;
    int child = -1;
    ASSERT_TRUE(testing::query_leaf(o, p.x, p.y, p.z, &parent, &child));
    ASSERT_EQ(child, int(v.codes[i] & 7));
    Color c;
    Vec3 n;
    o.attributes(parent, child, &c, &n);
    const Color e = esvo::decode_color_abgr(esvo::encode_color_abgr(v.colors[i]));
    const Vec3 en = esvo::decode_normal_cube(esvo::encode_normal_cube(v.normals[i]));
    ASSERT_EQ(c.r, e.r);
    ASSERT_EQ(c.g, e.g);
    ASSERT_EQ(c.b, e.b);
    ASSERT_EQ(c.a, e.a);
    ASSERT_EQ(n.x, en.x);
    ASSERT_EQ(n.y, en.y);
    ASSERT_EQ(n.z, en.z);
    parents[i] = parent, children[i] = uint8_t(child), want_c[i] = e, want_n[i] = en;
  }
  // The batch lookup of all of them (Morton order: runs within a page, and
  // page and block changes between neighbours), the same floats.
  std::vector<Color> got_c(v.codes.size());
  std::vector<Vec3> got_n(v.codes.size());
  o.attributes(parents.data(), children.data(), v.codes.size(), got_c.data(), got_n.data());
  for (size_t i = 0; i < v.codes.size(); ++i) {
    ASSERT_EQ(std::memcmp(&got_c[i], &want_c[i], sizeof(Color)), 0) << "voxel " << i;
    ASSERT_EQ(std::memcmp(&got_n[i], &want_n[i], sizeof(Vec3)), 0) << "voxel " << i;
  }
}

// ---- structure ------------------------------------------------------------

TEST(EsvoBuild, RandomSetsRoundTrip) {
  for (int L = 1; L <= 10; ++L) {
    for (uint64_t seed : {1u, 2u}) {
      const size_t total = size_t(1) << (3 * std::min(L, 7));
      const size_t count = std::min<size_t>(total / (seed == 1 ? 2 : 9) + 1, 30000);
      const VoxelSet v = make_random_voxels(L, count, seed * 100 + uint64_t(L));
      SCOPED_TRACE(::testing::Message() << "levels " << L << " voxels " << v.size());
      const EsvoOctree o = esvo::build_octree(v);
      EXPECT_EQ(o.block_count, 1u);
      check_octree(v, o);
      check_leaf_attributes(v, o);
    }
  }
}

TEST(EsvoBuild, SphereShellsRoundTrip) {
  for (int L = 1; L <= 10; ++L) {
    const VoxelSet v = make_sphere_shell(L);
    SCOPED_TRACE(::testing::Message() << "levels " << L << " voxels " << v.size());
    if (v.codes.empty()) continue;  // tiny grids may have no voxel center on the shell
    const EsvoOctree o = esvo::build_octree(v);
    check_octree(v, o);
  }
}

TEST(EsvoBuild, SingleVoxelAndFullGrid) {
  VoxelSet one;
  one.grid = testing::unit_grid(3);
  one.codes = {morton_encode(5, 2, 7)};
  const EsvoOctree o1 = esvo::build_octree(one);  // no attributes: defaults
  check_octree(one, o1);
  uint32_t parent = 0;
  int child = 0;
  ASSERT_TRUE(testing::query_leaf(o1, 5, 2, 7, &parent, &child));
  Color c;
  Vec3 n;
  o1.attributes(parent, child, &c, &n);
  EXPECT_NEAR(c.r, 0.5f, 0.005f);
  EXPECT_NEAR(n.z, 1.f, 1e-6f);

  const VoxelSet full = testing::make_full_grid(4);
  check_octree(full, esvo::build_octree(full));
}

TEST(EsvoBuild, DenseGridPointQueries) {
  std::mt19937 rng(7);
  std::vector<uint8_t> occ(32 * 32 * 32);
  for (auto& b : occ) b = (rng() % 100) < 20;
  const auto occupied = [&](uint32_t x, uint32_t y, uint32_t z) {
    const double dx = x - 16.0, dy = y - 9.0, dz = z - 20.0;
    return occ[(z * 32 + y) * 32 + x] || dx * dx + dy * dy + dz * dz < 30.0;
  };
  const VoxelSet v = testing::make_dense_grid(5, occupied);
  for (const esvo::BuildOptions& opt : {esvo::BuildOptions{}, esvo::BuildOptions{64, 256}}) {
    const EsvoOctree o = esvo::build_octree(v, opt);
    ASSERT_NO_THROW(o.validate());
    for (uint32_t z = 0; z < 32; ++z)
      for (uint32_t y = 0; y < 32; ++y)
        for (uint32_t x = 0; x < 32; ++x)
          ASSERT_EQ(testing::query_leaf(o, x, y, z), occupied(x, y, z))
              << x << "," << y << "," << z;
  }
}

TEST(EsvoBuild, ParentAttributesAreWeightedAverages) {
  const VoxelSet v = make_random_voxels(6, 20000, 99);  // dense enough for many siblings
  const EsvoOctree o = esvo::build_octree(v);
  const int L = v.grid.levels;
  // Accumulate, per node at levels L-1 and L-2, the weighted sums from the input.
  struct Acc {
    double w = 0, c[4] = {0, 0, 0, 0}, n[3] = {0, 0, 0};
  };
  std::map<uint64_t, Acc> parents;
  for (size_t i = 0; i < v.size(); ++i) {
    Acc& a = parents[v.codes[i] >> 3];
    const double w = v.weights[i];
    a.w += w;
    a.c[0] += w * v.colors[i].r, a.c[1] += w * v.colors[i].g, a.c[2] += w * v.colors[i].b,
        a.c[3] += w * v.colors[i].a;
    a.n[0] += w * v.normals[i].x, a.n[1] += w * v.normals[i].y, a.n[2] += w * v.normals[i].z;
  }
  std::map<uint64_t, Acc> grand;  // colors add up linearly; normals are re-normalized per level
  for (const auto& [code, a] : parents) {
    Acc& g = grand[code >> 3];
    const double len = std::sqrt(a.n[0] * a.n[0] + a.n[1] * a.n[1] + a.n[2] * a.n[2]);
    g.w += a.w;
    for (int k = 0; k < 4; ++k) g.c[k] += a.c[k];
    for (int k = 0; k < 3; ++k) g.n[k] += a.w * a.n[k] / len;
  }
  const auto check = [&](const std::map<uint64_t, Acc>& nodes, int depth) {
    int checked = 0;
    for (const auto& [code, a] : nodes) {
      if (checked++ % 7) continue;  // a sample is enough
      const uint32_t parent = descriptor_of(o, code >> 3, depth - 1);
      Color c;
      Vec3 n;
      o.attributes(parent, int(code & 7), &c, &n);
      const double e[4] = {a.c[0] / a.w, a.c[1] / a.w, a.c[2] / a.w, a.c[3] / a.w};
      // 8-bit sRGB: half a code step plus float slack.
      EXPECT_NEAR(to_srgb(c.r), to_srgb(e[0]), 0.5 / 255 + 1e-4);
      EXPECT_NEAR(to_srgb(c.g), to_srgb(e[1]), 0.5 / 255 + 1e-4);
      EXPECT_NEAR(to_srgb(c.b), to_srgb(e[2]), 0.5 / 255 + 1e-4);
      EXPECT_NEAR(c.a, e[3], 0.5 / 255 + 1e-4);
      const Vec3 en{float(a.n[0]), float(a.n[1]), float(a.n[2])};
      EXPECT_LT(angle(n, normalize(en)), 1e-4);
    }
    EXPECT_GT(checked, 10);
  };
  check(parents, L - 1);
  check(grand, L - 2);
}

TEST(EsvoBuild, MultiBlockAndFarPointers) {
  // Tiny blocks: many block breaks, every cross-block child pointer is far.
  const VoxelSet v = make_random_voxels(9, 40000, 5);
  const EsvoOctree single = esvo::build_octree(v);
  const EsvoOctree multi = esvo::build_octree(v, {64, 256});
  EXPECT_EQ(single.block_count, 1u);
  EXPECT_GT(multi.block_count, 10u);
  EXPECT_GT(multi.memory_stats().far_pointer_bytes, 0u);
  check_octree(v, multi);
  check_leaf_attributes(v, multi);

  // Block limits on values only.
  const EsvoOctree by_values = esvo::build_octree(v, {1u << 20, 3000});
  EXPECT_GT(by_values.block_count, 10u);
  check_octree(v, by_values);
  check_leaf_attributes(v, by_values);

  // One block, but subtrees larger than the 15-bit pointer range.
  const VoxelSet shell = make_sphere_shell(9);
  const EsvoOctree big = esvo::build_octree(shell);
  EXPECT_EQ(big.block_count, 1u);
  EXPECT_GT(big.memory_stats().far_pointer_bytes, 0u);
  EXPECT_GT(big.memory_stats().page_header_bytes, 8u);
  check_octree(shell, big);
}

TEST(EsvoBuild, Deterministic) {
  const VoxelSet v = make_sphere_shell(8);
  EsvoOctree a, b;
  tbb::task_arena(1).execute([&] { a = esvo::build_octree(v); });
  tbb::task_arena(2).execute([&] { b = esvo::build_octree(v); });
  EXPECT_EQ(a.words, b.words);
  EXPECT_EQ(a.block_count, b.block_count);
}

TEST(EsvoBuild, RejectsBadInput) {
  VoxelSet v = make_random_voxels(4, 100, 3);
  VoxelSet empty = v;
  empty.codes.clear();
  empty.colors.clear();
  empty.normals.clear();
  empty.weights.clear();
  EXPECT_THROW(esvo::build_octree(empty), Error);
  VoxelSet zero = v;
  zero.grid = testing::unit_grid(0);
  EXPECT_THROW(esvo::build_octree(zero), Error);
  VoxelSet unsorted = v;
  std::swap(unsorted.codes[3], unsorted.codes[4]);
  EXPECT_THROW(esvo::build_octree(unsorted), Error);
  VoxelSet dup = v;
  dup.codes[4] = dup.codes[3];
  EXPECT_THROW(esvo::build_octree(dup), Error);
  VoxelSet outside = v;
  outside.codes.back() = uint64_t(1) << 12;
  EXPECT_THROW(esvo::build_octree(outside), Error);
  VoxelSet attr = v;
  attr.colors.pop_back();
  EXPECT_THROW(esvo::build_octree(attr), Error);
  try {
    esvo::build_octree(empty);
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("no voxels"), std::string::npos);
  }
}

// ---- validation -------------------------------------------------------------

TEST(EsvoValidate, DetectsCorruption) {
  const VoxelSet v = make_random_voxels(5, 3000, 11);
  const EsvoOctree good = esvo::build_octree(v, {64, 256});
  ASSERT_NO_THROW(good.validate());
  const uint32_t root = good.root_slot();
  const auto expect_invalid = [&](auto&& mutate, const char* what) {
    EsvoOctree o = good;
    mutate(o);
    EXPECT_THROW(o.validate(), Error) << what;
  };
  expect_invalid([&](EsvoOctree& o) { o.words[root * 2] &= ~esvo::layout::ChildPointer::mask; },
                 "zero child pointer");
  expect_invalid(
      [&](EsvoOctree& o) {
        o.words[root * 2] |= esvo::layout::ChildPointer::mask | esvo::layout::FarBit::mask;
      },
      "pointer out of range");
  expect_invalid([&](EsvoOctree& o) { o.words[0] += 2; }, "page header");
  expect_invalid([&](EsvoOctree& o) { o.words.resize(o.words.size() - esvo::kPageWords); },
                 "truncated");
  expect_invalid([&](EsvoOctree& o) { o.block_count += 1; }, "block count");
  expect_invalid([&](EsvoOctree& o) { o.grid = testing::unit_grid(4); }, "levels too small");
  expect_invalid([&](EsvoOctree& o) { o.grid = testing::unit_grid(6); }, "levels too large");
  // Make a leaf-parent's leaf mask exceed its valid mask.
  expect_invalid(
      [&](EsvoOctree& o) {
        const uint32_t s = descriptor_of(o, v.codes[0] >> 3, 4);
        const uint32_t valid = esvo::layout::ValidMask::get(o.words[s * 2]);
        o.words[s * 2] = esvo::layout::LeafMask::set(o.words[s * 2], 0xFFu);
        if (valid == 0xFF) o.words[s * 2] = esvo::layout::ValidMask::set(o.words[s * 2], 0xFEu);
      },
      "leaf mask");
  // Point two children at the same group: a descriptor reached twice.
  expect_invalid(
      [&](EsvoOctree& o) {
        const uint32_t g = child_group_of(o, root);
        using esvo::layout::ChildPointer, esvo::layout::FarBit;
        const uint32_t wg = o.words[g * 2];
        o.words[(g + 1) * 2] = ChildPointer::set(o.words[(g + 1) * 2], ChildPointer::get(wg) + 1);
        o.words[(g + 1) * 2] = FarBit::set(o.words[(g + 1) * 2], FarBit::get(wg));
        if (FarBit::test(wg))  // far: reuse the far pointer, corrected by one slot
          o.words[(g + 1) * 2] = ChildPointer::set(wg, ChildPointer::get(wg) - 1);
      },
      "shared descriptor");
  // Attribute value pointer past the value count.
  expect_invalid(
      [&](EsvoOctree& o) {
        const uint32_t info = o.words[0];
        const uint32_t attach = info + o.words[info + 5];
        o.words[attach + 2 + root] |= esvo::layout::ValuePointer::mask;
      },
      "value pointer");
}

// ---- attribute encoding -------------------------------------------------------

TEST(EsvoEncoding, ColorRoundTrip) {
  for (uint32_t k = 0; k < 256; ++k) {
    const uint32_t code = k | (255 - k) << 8 | ((k * 7) & 255) << 16 | k << 24;
    EXPECT_EQ(esvo::encode_color_abgr(esvo::decode_color_abgr(code)), code);
  }
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  for (int i = 0; i < 100000; ++i) {
    const Color c{u(rng), u(rng), u(rng), u(rng)};
    const Color d = esvo::decode_color_abgr(esvo::encode_color_abgr(c));
    ASSERT_NEAR(to_srgb(d.r), to_srgb(c.r), 0.5 / 255 + 1e-5);
    ASSERT_NEAR(to_srgb(d.g), to_srgb(c.g), 0.5 / 255 + 1e-5);
    ASSERT_NEAR(to_srgb(d.b), to_srgb(c.b), 0.5 / 255 + 1e-5);
    ASSERT_NEAR(d.a, c.a, 0.5 / 255 + 1e-5);
  }
  EXPECT_EQ(esvo::encode_color_abgr({1, 0, 0, 1}), 0xFF0000FFu);     // R in the low byte
  EXPECT_EQ(esvo::encode_color_abgr({-1, 2, NAN, 0}), 0x0000FF00u);  // clamped
}

TEST(EsvoEncoding, NormalErrorBound) {
  // Quantization moves u and v on the unit-distance face by at most half a
  // step (1/(2^14-1) and 1/(2^15-1)); the point (1,u,v) is at distance >= 1
  // from the origin, so the angular error is at most the hypotenuse of the
  // two half steps (~6.8e-5 rad = 0.0039 degrees), plus float rounding.
  const double bound = std::hypot(1.0 / 16383, 1.0 / 32767) + 2e-6;
  // `code >> 29`: the face, written from the documented layout (an oracle
  // independent of esvo::layout, pinned to it here).
  static_assert(esvo::layout::NormalFace::lo == 29 && esvo::layout::NormalFace::width == 3);
  const auto check = [&](Vec3 n) {
    n = normalize(n);
    const uint32_t code = esvo::encode_normal_cube(n);
    EXPECT_LE(code >> 29, 5u);
    const Vec3 d = esvo::decode_normal_cube(code);
    EXPECT_NEAR(length(d), 1.f, 1e-6f);
    EXPECT_LE(angle(n, d), bound) << n.x << " " << n.y << " " << n.z;
  };
  for (int axis = 0; axis < 3; ++axis)
    for (float sgn : {1.f, -1.f}) {
      Vec3 n{0, 0, 0};
      n[axis] = sgn;
      check(n);
      const uint32_t code = esvo::encode_normal_cube(n);
      EXPECT_EQ(code >> 29, uint32_t(axis * 2 + (sgn < 0)));
    }
  for (int a = -1; a <= 1; ++a)  // cube edges and corners
    for (int b = -1; b <= 1; ++b)
      for (int c = -1; c <= 1; ++c)
        if (a || b || c) check({float(a), float(b), float(c)});
  std::mt19937 rng(5);
  std::normal_distribution<float> g;
  double worst = 0;
  for (int i = 0; i < 200000; ++i) {
    Vec3 n = normalize(Vec3{g(rng), g(rng), g(rng)});
    if (i % 4 == 0)
      n.x = std::copysign(std::max(std::fabs(n.y), std::fabs(n.z)), n.x);  // face edges
    n = normalize(n);
    const Vec3 d = esvo::decode_normal_cube(esvo::encode_normal_cube(n));
    worst = std::max(worst, angle(n, d));
  }
  EXPECT_LE(worst, bound);
  EXPECT_GT(worst, 1e-5);  // the quantization is really 14/15 bits, not finer
}

// decode_normal_cubes (8 codes a vector) is decode_normal_cube bit for bit:
// every face value (6 and 7 are not encoded, but decode to +z), the u/v
// extremes, random codes, and counts that leave a scalar tail.
TEST(EsvoEncoding, BatchNormalDecodeIsBitIdentical) {
  std::vector<uint32_t> codes;
  for (uint32_t face = 0; face < 8; ++face)
    for (uint32_t u : {0u, 1u, 8191u, 8192u, 16383u})
      for (uint32_t v : {0u, 1u, 16383u, 16384u, 32767u}) codes.push_back(face << 29 | u << 15 | v);
  std::mt19937 rng(11);
  for (int i = 0; i < 100000; ++i) codes.push_back(uint32_t(rng()));
  for (size_t n : {codes.size(), size_t(0), size_t(1), size_t(7), size_t(8), size_t(13)}) {
    std::vector<Vec3> got(n, Vec3{-7.f, -7.f, -7.f});
    esvo::decode_normal_cubes(codes.data(), n, got.data());
    for (size_t i = 0; i < n; ++i) {
      const Vec3 want = esvo::decode_normal_cube(codes[i]);
      ASSERT_EQ(std::memcmp(&got[i], &want, sizeof want), 0)
          << "code " << std::hex << codes[i] << " (n " << std::dec << n << ")";
    }
  }
}

}  // namespace
}  // namespace voxcast
