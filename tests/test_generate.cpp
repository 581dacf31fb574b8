// Procedural stress meshes (generate.hpp): deterministic bytes per seed,
// Menger sponge face count against an independent construction and the
// closed-form surface, hairball tubes closed and consistently oriented,
// terrain a height field, the CLI's error handling.
#include <gtest/gtest.h>

#include <array>
#include <filesystem>
#include <map>
#include <random>
#include <set>
#include <string>
#include <tuple>
#include <vector>

#include "support/cli_runner.hpp"
#include "voxcast/error.hpp"
#include "voxcast/generate.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast {
namespace {

std::string file_bytes(const std::string& path) {
  return testing::read_text(path);
}

TEST(Generate, SameSeedSameBytesOtherSeedOtherBytes) {
  testing::TempDir dir;
  generate::HairballOptions h;
  h.tubes = 20;
  h.segments = 30;
  for (const char* ext : {".obj", ".ply"}) {
    h.seed = 5;
    generate::write_mesh(dir.file(std::string("a") + ext), generate::hairball(h));
    generate::write_mesh(dir.file(std::string("b") + ext), generate::hairball(h));
    h.seed = 6;
    generate::write_mesh(dir.file(std::string("c") + ext), generate::hairball(h));
    EXPECT_EQ(file_bytes(dir.file(std::string("a") + ext)),
              file_bytes(dir.file(std::string("b") + ext)));
    EXPECT_NE(file_bytes(dir.file(std::string("a") + ext)),
              file_bytes(dir.file(std::string("c") + ext)));
  }
  generate::TerrainOptions t;
  t.size = 40;
  t.seed = 3;
  generate::write_mesh(dir.file("t1.ply"), generate::terrain(t));
  generate::write_mesh(dir.file("t2.ply"), generate::terrain(t));
  t.seed = 4;
  generate::write_mesh(dir.file("t3.ply"), generate::terrain(t));
  EXPECT_EQ(file_bytes(dir.file("t1.ply")), file_bytes(dir.file("t2.ply")));
  EXPECT_NE(file_bytes(dir.file("t1.ply")), file_bytes(dir.file("t3.ply")));
}

// Independent Menger construction: subdivide every kept cube into 27 and keep
// the 20 that are not on the central cross, L times; then count the unit faces
// that belong to exactly one kept cube.
size_t menger_faces_by_subdivision(int level) {
  std::vector<std::array<int, 3>> cubes{{0, 0, 0}};
  for (int l = 0; l < level; ++l) {
    std::vector<std::array<int, 3>> next;
    for (const auto& c : cubes)
      for (int z = 0; z < 3; ++z)
        for (int y = 0; y < 3; ++y)
          for (int x = 0; x < 3; ++x)
            if ((x == 1) + (y == 1) + (z == 1) < 2)
              next.push_back({3 * c[0] + x, 3 * c[1] + y, 3 * c[2] + z});
    cubes = std::move(next);
  }
  std::map<std::tuple<int, int, int, int>, int> faces;  // (axis, min corner) -> cubes using it
  for (const auto& c : cubes)
    for (int a = 0; a < 3; ++a)
      for (int s = 0; s < 2; ++s) {
        std::array<int, 3> p = c;
        p[size_t(a)] += s;
        ++faces[{a, p[0], p[1], p[2]}];
      }
  size_t n = 0;
  for (const auto& [k, count] : faces) n += count == 1;
  return n;
}

TEST(Generate, MengerHasExactlyTheExteriorFaces) {
  for (int level : {0, 1, 2, 3}) {
    const Mesh m = generate::menger(level);
    size_t p20 = 1, p8 = 1;
    for (int i = 0; i < level; ++i) p20 *= 20, p8 *= 8;
    const size_t expected = menger_faces_by_subdivision(level);
    EXPECT_EQ(expected, 2 * p20 + 4 * p8);  // surface area 2(20/9)^L + 4(8/9)^L
    EXPECT_EQ(m.triangle_count(), 2 * expected) << "level " << level;
  }
  EXPECT_EQ(generate::menger(2).triangle_count(), 2112u);
  // Closed and consistently oriented: every directed edge exactly once and
  // its reverse exactly once.
  const Mesh m = generate::menger(2);
  std::map<std::pair<uint32_t, uint32_t>, int> directed;
  for (size_t t = 0; t < m.triangle_count(); ++t)
    for (int k = 0; k < 3; ++k) ++directed[{m.indices[3 * t + k], m.indices[3 * t + (k + 1) % 3]}];
  // All faces are unit squares with shared vertices, so no T-junctions.
  for (const auto& [e, c] : directed) {
    ASSERT_EQ(c, 1);
    ASSERT_EQ(directed.count({e.second, e.first}), 1u);
  }
}

TEST(Generate, HairballTubesAreClosedAndVoxelize) {
  generate::HairballOptions h;
  h.tubes = 12;
  h.segments = 50;
  h.sides = 5;
  h.radius = 0.02;
  const Mesh m = generate::hairball(h);
  EXPECT_EQ(m.triangle_count(), size_t(12 * (2 * 50 + 2) * 5));
  std::map<std::pair<uint32_t, uint32_t>, int> directed;
  for (size_t t = 0; t < m.triangle_count(); ++t)
    for (int k = 0; k < 3; ++k) ++directed[{m.indices[3 * t + k], m.indices[3 * t + (k + 1) % 3]}];
  for (const auto& [e, c] : directed) {
    ASSERT_EQ(c, 1);
    ASSERT_EQ(directed.count({e.second, e.first}), 1u)
        << "open edge " << e.first << "-" << e.second;
  }
  for (const Vec3& p : m.positions) EXPECT_LE(length(p), 1.0f + 1e-5f);
  testing::TempDir dir;
  generate::write_mesh(dir.file("h.ply"), m);
  const Mesh loaded = load_mesh(dir.file("h.ply"));
  EXPECT_EQ(loaded.triangle_count(), m.triangle_count());
  VoxelizeOptions vo;
  vo.attributes = false;
  const VoxelSet vs = voxelize(loaded, GridTransform::fit(loaded.bounds(), 128), vo);
  EXPECT_GT(vs.size(), 1000u);
}

// Moller-Trumbore along +y from below the terrain.
int vertical_hits(const Mesh& m, double x, double z) {
  int hits = 0;
  for (size_t t = 0; t < m.triangle_count(); ++t) {
    const Vec3 a = m.positions[m.indices[3 * t]], b = m.positions[m.indices[3 * t + 1]],
               c = m.positions[m.indices[3 * t + 2]];
    // Point-in-triangle in the xz projection (barycentric, closed on one side
    // by a tie rule so shared edges count once).
    const double d =
        (double(b.z) - c.z) * (double(a.x) - c.x) + (double(c.x) - b.x) * (double(a.z) - c.z);
    const double u = ((double(b.z) - c.z) * (x - c.x) + (double(c.x) - b.x) * (z - c.z)) / d;
    const double v = ((double(c.z) - a.z) * (x - c.x) + (double(a.x) - c.x) * (z - c.z)) / d;
    if (u > 0 && v > 0 && 1 - u - v > 0) ++hits;
  }
  return hits;
}

TEST(Generate, TerrainIsAHeightField) {
  generate::TerrainOptions t;
  t.size = 24;
  t.seed = 11;
  const Mesh m = generate::terrain(t);
  EXPECT_EQ(m.triangle_count(), size_t(2 * 23 * 23));
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> u(0.001, 0.999);
  for (int i = 0; i < 200; ++i) {
    const double x = u(rng), z = u(rng);
    EXPECT_EQ(vertical_hits(m, x, z), 1) << x << "," << z;
  }
  // Faces point up (counter-clockwise seen from +y) and heights vary.
  float lo = 1e9f, hi = -1e9f;
  for (size_t tr = 0; tr < m.triangle_count(); ++tr) {
    const Vec3 a = m.positions[m.indices[3 * tr]], b = m.positions[m.indices[3 * tr + 1]],
               c = m.positions[m.indices[3 * tr + 2]];
    EXPECT_GT(cross(b - a, c - a).y, 0.f);
  }
  for (const Vec3& p : m.positions) lo = std::min(lo, p.y), hi = std::max(hi, p.y);
  EXPECT_GT(hi - lo, 0.01f);
  EXPECT_LE(hi, 0.25f);
  EXPECT_GE(lo, -0.25f);
}

TEST(Generate, CliWritesAndRejectsBadInput) {
  testing::TempDir dir;
  auto r = testing::run_cli("generate menger --level 2 -o " + dir.file("m.obj"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("2112 triangles"), std::string::npos) << r.output;
  EXPECT_EQ(load_mesh(dir.file("m.obj")).triangle_count(), 2112u);
  r = testing::run_cli("generate hairball --tubes 3 --seed 9 -o " + dir.file("a.ply"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  r = testing::run_cli("generate hairball --tubes 3 --seed 9 -o " + dir.file("b.ply"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(file_bytes(dir.file("a.ply")), file_bytes(dir.file("b.ply")));
  struct Bad {
    std::string args, message;
  };
  for (const Bad& b :
       {Bad{"generate donut -o " + dir.file("x.obj"), "not hairball, menger, terrain or sky"},
        Bad{"generate menger --level 9 -o " + dir.file("x.obj"), "level 9 is outside"},
        Bad{"generate terrain --size 1 -o " + dir.file("x.obj"), "size 1 is outside"},
        Bad{"generate hairball --sides 2 -o " + dir.file("x.obj"), "sides 2"},
        Bad{"generate menger -o " + dir.file("x.stl"), "must end in .obj or .ply"}}) {
    r = testing::run_cli(b.args);
    EXPECT_EQ(r.exit_code, 2) << b.args << "\n" << r.output;  // usage errors
    EXPECT_NE(r.output.find("voxcast: error: "), std::string::npos) << r.output;
    EXPECT_NE(r.output.find(b.message), std::string::npos) << r.output;
  }
  EXPECT_FALSE(std::filesystem::exists(dir.file("x.obj")));
  r = testing::run_cli("generate menger");
  EXPECT_EQ(r.exit_code, 2) << r.output;
}

}  // namespace
}  // namespace voxcast
