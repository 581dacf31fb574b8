// Sparse voxel DAG (svdag §3-4): reduction is lossless, sharing happens,
// the DAG ray caster matches the ESVO caster hit for hit, attributes are
// indexed by Morton rank (Hitchhiker's guide "dynamic voxel indexing"),
// scene files are validated, builds are deterministic.
#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "support/cli_runner.hpp"
#include "support/esvo_testing.hpp"
#include "support/octree_rays.hpp"
#include "support/shared_meshes.hpp"
#include "support/test_data.hpp"
#include "voxcast/dag.hpp"
#include "voxcast/dag_format.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo_format.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/morton.hpp"
#include "voxcast/scene_file.hpp"

namespace voxcast {
namespace {

using dag::SparseVoxelDag;

// ---------------------------------------------------------------------------
// Lossless reduction.

void expect_decodes(const VoxelSet& set) {
  const SparseVoxelDag d = dag::build_dag(set);
  EXPECT_EQ(d.leaf_voxels, set.size());
  const std::vector<uint64_t> codes = d.decode_leaves();
  ASSERT_EQ(codes.size(), set.codes.size());
  EXPECT_TRUE(codes == set.codes) << "decoded voxels differ";
  // Per-level SVO counts against the ESVO octree's own level statistics.
  const esvo::EsvoOctree o = esvo::build_octree(set);
  const auto ol = o.level_stats();
  const dag::DagStats st = d.stats();
  ASSERT_EQ(ol.size(), st.levels.size());
  for (size_t l = 0; l < ol.size(); ++l)
    EXPECT_EQ(st.levels[l].svo_nodes, ol[l].voxels) << "level " << l;
  EXPECT_EQ(st.dag_bytes, d.words.size() * 4);
}

TEST(DagBuild, DecodesRandomSetsAndShells) {
  for (int L = 2; L <= 8; ++L) {
    SCOPED_TRACE("levels " + std::to_string(L));
    for (size_t count : {size_t(1), size_t(7), size_t(300), size_t(20000)})
      expect_decodes(testing::make_random_voxels(L, count, 31 * L + count));
    if (L >= 3) expect_decodes(testing::make_sphere_shell(L));
  }
  expect_decodes(testing::make_full_grid(5));
  expect_decodes(testing::make_sphere_shell(9));
}

// Every shared mesh at 1024^3 (and 256^3): the DAG decodes to exactly the
// voxel set the octree is built from, with the octree's node count per level.
class DagSharedMesh : public ::testing::TestWithParam<const char*> {};

TEST_P(DagSharedMesh, DecodesToTheVoxelSetOfTheOctree) {
  const std::filesystem::path path = testing::test_mesh(GetParam());
  const Mesh mesh = load_mesh(path);
  for (uint32_t res : {256u, 1024u}) {
    SCOPED_TRACE(std::string(GetParam()) + " " + std::to_string(res));
    VoxelizeOptions vo;
    vo.attributes = false;
    const VoxelSet set = voxelize(mesh, GridTransform::fit(mesh.bounds(), res), vo);
    const SparseVoxelDag d = dag::build_dag(set);
    EXPECT_EQ(d.leaf_voxels, set.size());
    EXPECT_TRUE(d.decode_leaves() == set.codes);
    const dag::DagStats st = d.stats();
    EXPECT_LT(st.dag_nodes, st.svo_nodes / 2) << "a surface should share nodes";
    const auto ol = esvo::build_octree(set).level_stats();
    ASSERT_EQ(ol.size(), st.levels.size());
    for (size_t l = 0; l < ol.size(); ++l)
      EXPECT_EQ(st.levels[l].svo_nodes, ol[l].voxels) << "level " << l;
  }
}

INSTANTIATE_TEST_SUITE_P(Shared, DagSharedMesh, testing::all_shared_meshes(),
                         testing::mesh_test_name);

TEST(DagBuild, RejectsUnsupportedInput) {
  EXPECT_THROW(dag::build_dag(testing::make_full_grid(1)), Error);  // 2^3 < one 4^3 leaf mask
  VoxelSet empty;
  empty.grid = testing::unit_grid(4);
  EXPECT_THROW(dag::build_dag(empty), Error);
}

// ---------------------------------------------------------------------------
// Sharing: self-similar sets whose DAG is known in closed form.

// Occupied iff every bit triple (x_i, y_i, z_i) is a slot of `allowed`: every
// subtree at every level is the same set, so the DAG has exactly one node per
// level (svdag §3), while the SVO has popcount(allowed)^l nodes at level l.
TEST(DagBuild, SelfSimilarSetReducesToOneNodePerLevel) {
  const uint32_t allowed = 0b10010111;  // slots 0, 1, 2, 4, 7
  const int k = std::popcount(allowed);
  for (int L = 2; L <= 7; ++L) {
    SCOPED_TRACE("levels " + std::to_string(L));
    const VoxelSet set = testing::make_dense_grid(L, [&](uint32_t x, uint32_t y, uint32_t z) {
      for (int i = 0; i < L; ++i) {
        const uint32_t slot = ((x >> i) & 1) | ((y >> i) & 1) << 1 | ((z >> i) & 1) << 2;
        if (!(allowed & (1u << slot))) return false;
      }
      return true;
    });
    const SparseVoxelDag d = dag::build_dag(set);
    EXPECT_EQ(d.words.size(), size_t(L - 2) * (1 + k) + 2);
    const dag::DagStats st = d.stats();
    uint64_t svo = 1;
    for (int l = 0; l <= L; ++l, svo *= uint64_t(k)) {
      if (l <= L - 2) {
        EXPECT_EQ(st.levels[size_t(l)].dag_nodes, 1u) << l;
      }
      EXPECT_EQ(st.levels[size_t(l)].svo_nodes, svo) << l;
    }
    EXPECT_EQ(d.leaf_voxels, set.size());
    EXPECT_TRUE(d.decode_leaves() == set.codes);
  }
}

// An 8^3 random tile repeated over the grid: level L-2 holds the distinct
// 4^3 blocks of the tile, level L-3 one node, every level above one node.
TEST(DagBuild, TiledPatternSharesEverythingAboveTheTile) {
  std::mt19937 rng(7);
  bool tile[8][8][8];
  for (auto& a : tile)
    for (auto& b : a)
      for (bool& v : b) v = (rng() % 3) == 0;
  tile[0][0][0] = true;
  std::set<uint64_t> blocks;  // the eight 4^3 sub-blocks as masks, counted independently
  int present_blocks = 0;
  for (int b = 0; b < 8; ++b) {
    uint64_t m = 0;
    for (int z = 0; z < 4; ++z)
      for (int y = 0; y < 4; ++y)
        for (int x = 0; x < 4; ++x)
          if (tile[4 * (b & 1) + x][4 * ((b >> 1) & 1) + y][4 * (b >> 2) + z])
            m |= 1ull << morton_encode(uint32_t(x), uint32_t(y), uint32_t(z));
    if (m) blocks.insert(m), ++present_blocks;
  }
  const int L = 6;
  const VoxelSet set = testing::make_dense_grid(
      L, [&](uint32_t x, uint32_t y, uint32_t z) { return tile[x & 7][y & 7][z & 7]; });
  const SparseVoxelDag d = dag::build_dag(set);
  const dag::DagStats st = d.stats();
  EXPECT_EQ(st.levels[size_t(L - 2)].dag_nodes, blocks.size());
  EXPECT_EQ(st.levels[size_t(L - 3)].dag_nodes, 1u);
  for (int l = 0; l < L - 3; ++l) EXPECT_EQ(st.levels[size_t(l)].dag_nodes, 1u);
  EXPECT_EQ(d.words.size(), size_t(L - 3) * 9 + (1 + size_t(present_blocks)) + 2 * blocks.size());
  EXPECT_TRUE(d.decode_leaves() == set.codes);
}

// ---------------------------------------------------------------------------
// Ray casting against the ESVO caster.

class RayGen : public testing::OctreeRayRng {
 public:
  using OctreeRayRng::OctreeRayRng;

  void next(Vec3* p, Vec3* d) {
    const int kind = pick(10);
    if (kind < 4) {
      *p = {uni(0.4f, 2.6f), uni(0.4f, 2.6f), uni(0.4f, 2.6f)};
      *d = sphere();
    } else if (kind < 7) {
      const Vec3 target{uni(1, 2), uni(1, 2), uni(1, 2)};
      *p = Vec3{1.5f, 1.5f, 1.5f} + sphere() * uni(1.0f, 2.5f);
      *d = normalize(target - *p);
    } else if (kind < 8) {  // axis-aligned with signed zeros
      *p = {uni(0.4f, 2.6f), uni(0.4f, 2.6f), uni(0.4f, 2.6f)};
      Vec3 v{signed_zero(), signed_zero(), signed_zero()};
      v[pick(3)] = pick(2) ? 1.f : -1.f;
      *d = v;
    } else if (kind < 9) {  // in a grid plane
      *p = {uni(0.6f, 2.4f), uni(0.6f, 2.4f), uni(0.6f, 2.4f)};
      const int a = pick(3);
      (*p)[a] = grid_line();
      Vec3 v = sphere();
      v[a] = 0.f;
      v = normalize(v);
      v[a] = signed_zero();
      *d = v;
    } else {  // through a grid corner
      const Vec3 q{grid_line(), grid_line(), grid_line()};
      *d = sphere();
      *p = q - *d * uni(0.f, 2.f);
    }
  }
};

struct Tally {
  uint64_t rays = 0, hits = 0, ties = 0, lod_hits = 0;
};

// Morton rank of the first leaf voxel inside the cube at `pos` (octree space) of `scale`.
uint32_t first_leaf_rank(const VoxelSet& set, Vec3 pos, int scale) {
  const int L = set.grid.levels;
  const int level = esvo::kMaxScale - scale;
  const double n = double(1u << level);
  const uint64_t cube = morton_encode(uint32_t((pos.x - 1) * n), uint32_t((pos.y - 1) * n),
                                      uint32_t((pos.z - 1) * n));
  const uint64_t first = cube << (3 * (L - level));
  return uint32_t(std::lower_bound(set.codes.begin(), set.codes.end(), first) - set.codes.begin());
}

void compare_casters(const VoxelSet& set, int rays, uint64_t seed, Tally* tally) {
  const esvo::EsvoOctree o = esvo::build_octree(set);
  const SparseVoxelDag d = dag::build_dag(set);
  RayGen gen(seed, set.grid.levels);
  for (int i = 0; i < rays; ++i) {
    Vec3 p, dir;
    gen.next(&p, &dir);
    // Every 4th ray with a footprint (LOD), every 5th with a finite tmax.
    const float bias = (i % 4 == 3) ? gen.uni(0.f, 0.2f) : 0.f;
    const float coef = (i % 4 == 3) ? gen.uni(0.f, 0.05f) : 0.f;
    const float tmax = (i % 5 == 4) ? gen.uni(0.f, 3.f) : INFINITY;
    const esvo::CastResult re = esvo::cast_ray(o, p, dir, tmax, coef, bias);
    const dag::CastResult rd = dag::cast_ray(d, p, dir, tmax, coef, bias);
    ++tally->rays;
    const bool same_voxel =
        re.hit == rd.hit && (!re.hit || (re.scale == rd.scale && re.pos.x == rd.pos.x &&
                                         re.pos.y == rd.pos.y && re.pos.z == rd.pos.z));
    if (!same_voxel) {
      // Tie (as in test_traversal.cpp): both hit, at the same entry t, cubes
      // of the same size sharing a face/edge/corner the ray passes through.
      ASSERT_TRUE(re.hit && rd.hit && re.scale == rd.scale &&
                  std::fabs(re.t - rd.t) <= 1e-6f * std::max(1.f, std::fabs(re.t)))
          << "DAG and ESVO disagree: p=(" << p.x << "," << p.y << "," << p.z << ") d=(" << dir.x
          << "," << dir.y << "," << dir.z << ") esvo hit " << re.hit << " dag hit " << rd.hit;
      ++tally->ties;
      continue;
    }
    // occluded() agrees with trace().
    ASSERT_EQ(dag::cast_occluded(d, p, dir, tmax, coef, bias), rd.hit);
    if (!rd.hit) continue;
    ++tally->hits;
    ASSERT_LE(std::fabs(re.t - rd.t), 1e-6f * std::max(1.f, std::fabs(re.t)));
    // The voxel index is the Morton rank of the cube's first leaf voxel, and
    // for leaves gives the same attributes as the ESVO's own lookup.
    ASSERT_EQ(rd.voxel_index, first_leaf_rank(set, rd.pos, rd.scale));
    if (rd.scale == esvo::kMaxScale - set.grid.levels) {
      Color ce, cd;
      Vec3 ne, nd;
      o.attributes(re.parent_slot, re.child, &ce, &ne);
      d.voxel_attributes(rd.voxel_index, &cd, &nd);
      ASSERT_EQ(ce.r, cd.r);
      ASSERT_EQ(ce.g, cd.g);
      ASSERT_EQ(ce.b, cd.b);
      ASSERT_EQ(ne.x, nd.x);
      ASSERT_EQ(ne.z, nd.z);
    } else {
      ++tally->lod_hits;
    }
  }
}

TEST(DagTraversal, MatchesEsvoOnRandomSetsAndShells) {
  Tally tally;
  for (int L = 2; L <= 9; ++L) {
    SCOPED_TRACE("levels " + std::to_string(L));
    const size_t counts[] = {0, 0, 20, 200, 1500, 3000, 20000, 40000, 60000, 60000};
    compare_casters(testing::make_random_voxels(L, counts[L], 500 + L), 4000, 3 + L, &tally);
    if (HasFatalFailure()) return;
    if (L >= 3) compare_casters(testing::make_sphere_shell(L), 4000, 77 + L, &tally);
    if (HasFatalFailure()) return;
  }
  std::printf("dag vs esvo: %llu rays, %llu hits (%llu LOD), %llu ties\n",
              (unsigned long long)tally.rays, (unsigned long long)tally.hits,
              (unsigned long long)tally.lod_hits, (unsigned long long)tally.ties);
  EXPECT_GE(tally.rays, 50000u);
  EXPECT_GE(tally.hits, tally.rays / 5);
  EXPECT_GT(tally.lod_hits, 1000u);
  EXPECT_LE(tally.ties, tally.rays / 1000);  // same arithmetic: expected 0
}

TEST(DagTraversal, StructureMatchesEsvoStructureAndOccluded) {
  TraceContext ctx;
  VoxelSet set = testing::make_sphere_shell(7);
  set.grid.origin = {-3.f, 2.f, 0.5f};
  set.grid.voxel_size = 0.03;
  const auto o = std::make_shared<esvo::EsvoOctree>(esvo::build_octree(set));
  const auto d = std::make_shared<SparseVoxelDag>(dag::build_dag(set));
  const esvo::EsvoStructure es(o);
  const dag::DagStructure ds(d);
  EXPECT_EQ(ds.name(), "dag");
  const Aabb b = ds.bounds();
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  int hits = 0;
  for (int i = 0; i < 20000; ++i) {
    Ray r;
    r.origin = b.center() + Vec3{u(rng), u(rng), u(rng)} * 6.f;
    const Vec3 target = b.center() + Vec3{u(rng), u(rng), u(rng)} * 2.f;
    r.dir = normalize(target - r.origin);
    r.tmax = (i % 3 == 0) ? 3.f + 3.f * u(rng) : INFINITY;
    LodFootprint lod;
    if (i % 2) lod.size_per_t = 0.01f;
    SurfaceHit he, hd;
    const bool ae = es.trace(r, lod, ctx, &he), ad = ds.trace(r, lod, ctx, &hd);
    ASSERT_EQ(ae, ad);
    ASSERT_EQ(ds.occluded(r, lod, ctx), ad);
    if (!ad) continue;
    ++hits;
    EXPECT_EQ(he.t, hd.t);
    EXPECT_EQ(he.level, hd.level);
    EXPECT_EQ(he.voxel_size, hd.voxel_size);
    EXPECT_EQ(he.position.x, hd.position.x);
    EXPECT_EQ(he.position.y, hd.position.y);
    EXPECT_EQ(he.position.z, hd.position.z);
    // The entered face is the one the hit point lies on (origin outside the cube).
    if (hd.t > 0) {
      const int axis = int((hd.child & 7) >> 1);  // above it: the voxel count
      const float side = hd.voxel_size;
      const float rel = (hd.position[axis] - b.lo[axis]) / side;
      const float frac = rel - std::floor(rel + 0.5f);
      EXPECT_NEAR(frac, 0.f, 1e-2f) << "face " << hd.child;
      EXPECT_EQ((hd.child & 1) != 0, r.dir[axis] > 0);
    }
  }
  EXPECT_GT(hits, 3000);
}

TEST(DagTraversal, GeometryOnlyShadesGrayWithFaceNormal) {
  TraceContext ctx;
  VoxelSet set = testing::make_sphere_shell(6);
  set.colors.clear(), set.normals.clear(), set.weights.clear();
  const auto d = std::make_shared<SparseVoxelDag>(dag::build_dag(set));
  ASSERT_FALSE(d->has_attributes());
  const dag::DagStructure ds(d);
  Ray r;
  r.origin = {0.5f, 0.5f, -1.f};
  r.dir = {0, 0, 1};
  SurfaceHit h;
  ASSERT_TRUE(ds.trace(r, {}, ctx, &h));
  Color c;
  Vec3 n;
  ds.attributes(h, ctx, &c, &n);
  EXPECT_EQ(c.r, 0.5f);
  EXPECT_EQ(n.z, -1.f);  // entered the -z face
  EXPECT_EQ(n.x, 0.f);
}

// ---------------------------------------------------------------------------
// Determinism and scene files.

TEST(DagBuild, DeterministicAcrossThreadCounts) {
  const VoxelSet set = testing::make_random_voxels(8, 60000, 99);
  std::vector<uint32_t> one, two;
  {
    tbb::global_control gc(tbb::global_control::max_allowed_parallelism, 1);
    one = dag::build_dag(set).words;
  }
  {
    tbb::global_control gc(tbb::global_control::max_allowed_parallelism, 2);
    two = dag::build_dag(set).words;
  }
  EXPECT_TRUE(one == two);
}

class DagScene : public ::testing::Test {
 protected:
  void SetUp() override {
    set_ = testing::make_sphere_shell(6);
    dag_ = dag::build_dag(set_);
    path_ = dir_.file("shell.vxc");
    SceneInfo info;
    info.source = "shell";
    info.voxelization = "conservative";
    info.leaf_voxels = set_.size();
    save_dag_scene(path_, dag_, info);
    original_ = Container::read(path_);
  }
  // A copy of the scene with the SDAG words replaced.
  Container with_words(const std::vector<uint32_t>& w) const {
    Container c;
    for (uint32_t id : original_.section_ids()) {
      if (id == fourcc("SDAG")) {
        std::vector<uint8_t> b(w.size() * 4);
        if (!b.empty()) std::memcpy(b.data(), w.data(), b.size());
        c.add(id, std::move(b));
      } else {
        c.add(id, original_.get(id));
      }
    }
    return c;
  }
  void expect_rejected(const Container& c, const char* what) {
    try {
      dag_scene_from_container(c);
      ADD_FAILURE() << "accepted a corrupt DAG: " << what;
    } catch (const Error& e) {
      const std::string msg = e.what();
      EXPECT_NE(msg.find("corrupt"), std::string::npos) << what << ": " << msg;
      EXPECT_EQ(msg.find('\n'), std::string::npos) << what << ": " << msg;
    }
  }

  testing::TempDir dir_;
  VoxelSet set_;
  SparseVoxelDag dag_;
  std::string path_;
  Container original_;
};

TEST_F(DagScene, RoundTripsAndDispatches) {
  SceneInfo info;
  const SparseVoxelDag d = load_dag_scene(path_, &info);
  EXPECT_TRUE(d.words == dag_.words);
  EXPECT_TRUE(d.colors == dag_.colors);
  EXPECT_TRUE(d.normals == dag_.normals);
  EXPECT_TRUE(d.voxel_prefix == dag_.voxel_prefix);
  EXPECT_EQ(info.source, "shell");
  EXPECT_EQ(scene_format(original_), "dag");
  const LoadedScene s = load_scene(path_);
  EXPECT_EQ(s.format, "dag");
  EXPECT_EQ(s.structure->name(), "dag");
  EXPECT_FALSE(s.occupied.empty());
  // The ESVO loader refuses it cleanly, and load_scene still reads ESVO files.
  EXPECT_THROW(load_esvo_scene(path_), Error);
  const std::string esvo_path = dir_.file("shell_esvo.vxc");
  save_esvo_scene(esvo_path, esvo::build_octree(set_), SceneInfo{});
  EXPECT_EQ(load_scene(esvo_path).structure->name(), "esvo");
}

TEST_F(DagScene, RejectsCorruptWords) {
  const std::vector<uint32_t>& w0 = dag_.words;
  const int k0 = std::popcount(dag::layout::ChildMask::get(w0[0]));
  ASSERT_GE(k0, 2);
  {
    auto w = w0;
    w[1] = uint32_t(w.size());  // out of range
    expect_rejected(with_words(w), "pointer past the end");
  }
  {
    auto w = w0;
    w[1] = 0xFFFFFFFFu;
    expect_rejected(with_words(w), "huge pointer");
  }
  {
    auto w = w0;
    // A level-1 node pointing back at the root: a cycle.
    const uint32_t child = w[1];
    ASSERT_GT(std::popcount(dag::layout::ChildMask::get(w[child])), 0);
    w[child + 1] = 0;
    expect_rejected(with_words(w), "pointer creating a cycle");
  }
  {
    auto w = w0;
    w[2] = w[1];  // root's children 0 and 1 point at the same node: child 1's node unreachable
    expect_rejected(with_words(w), "unreachable node");
  }
  {
    auto w = w0;
    w[1] = w[1] + 1;  // into the middle of a node
    expect_rejected(with_words(w), "pointer into a node");
  }
  {
    auto w = w0;
    w[0] = 0;  // empty child mask
    expect_rejected(with_words(w), "empty child mask");
  }
  {
    auto w = w0;
    w[0] |= 0x100u;
    expect_rejected(with_words(w), "reserved bits");
  }
  {
    auto w = w0;
    w[w.size() - 2] = 0, w[w.size() - 1] = 0;  // last leaf mask empty
    expect_rejected(with_words(w), "empty leaf mask");
  }
  {
    auto w = w0;
    w.resize(w.size() - 2);
    expect_rejected(with_words(w), "truncated");
  }
  {
    auto w = w0;
    w.push_back(0), w.push_back(1);
    expect_rejected(with_words(w), "trailing words");
  }
  {
    auto w = w0;
    w[w.size() - 1] ^= 0x80000000u;  // one more voxel: META leaf count and DATR mismatch
    expect_rejected(with_words(w), "voxel count changed");
  }
}

TEST_F(DagScene, RejectsBadMetaAttributesAndFiles) {
  // DATR of the wrong size.
  Container c;
  for (uint32_t id : original_.section_ids()) {
    std::vector<uint8_t> b = original_.get(id);
    if (id == fourcc("DATR")) b.resize(b.size() - 8);
    c.add(id, std::move(b));
  }
  expect_rejected(c, "short DATR");
  // Depth in META that does not match the words (which describe 6 levels),
  // or that is inconsistent with the resolution.
  const std::pair<int, int> depths[] = {{5, 32}, {7, 128}, {5, 64}};
  for (auto [levels, res] : depths) {
    std::string meta(original_.get(fourcc("META")).begin(), original_.get(fourcc("META")).end());
    for (auto [key, value] : {std::pair<std::string, int>{"\"levels\": ", levels},
                              std::pair<std::string, int>{"\"resolution\": ", res}}) {
      const size_t at = meta.find(key);
      ASSERT_NE(at, std::string::npos) << meta;
      const size_t end = meta.find_first_not_of("0123456789", at + key.size());
      meta.replace(at + key.size(), end - at - key.size(), std::to_string(value));
    }
    const std::string from = std::to_string(levels) + " levels, " + std::to_string(res);
    Container m;
    for (uint32_t id : original_.section_ids())
      m.add(id, id == fourcc("META") ? std::vector<uint8_t>(meta.begin(), meta.end())
                                     : original_.get(id));
    expect_rejected(m, from.c_str());
  }
  // A truncated file.
  const auto size = std::filesystem::file_size(path_);
  std::filesystem::resize_file(path_, size - 16);
  EXPECT_THROW(load_dag_scene(path_), Error);
}

TEST(DagCli, BuildInfoRender) {
  const std::string mesh = testing::test_mesh("spot.obj").string();
  testing::TempDir dir;
  auto r = testing::run_cli("build " + mesh + " -o " + dir.file("s.vxc") +
                            " --format dag --resolution 128");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  r = testing::run_cli("info " + dir.file("s.vxc"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("DAG nodes"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("bits/voxel"), std::string::npos) << r.output;
  r = testing::run_cli("render " + dir.file("s.vxc") + " -o " + dir.file("s.png") +
                       " --size 64x48");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_TRUE(std::filesystem::exists(dir.file("s.png")));
  r = testing::run_cli("build " + mesh + " -o " + dir.file("x.vxc") + " --format octree");
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("--format"), std::string::npos) << r.output;
}

}  // namespace
}  // namespace voxcast
