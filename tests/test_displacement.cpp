// Displacement mapping (esvo §7.4, include/voxcast/displacement.hpp),
// against an independent oracle: the same displaced surface densely
// tessellated (here, in the test) and voxelized by the ordinary triangle
// voxelizer. No holes: every voxel of the oracle is within one voxel of the
// displaced build and vice versa; nearly all oracle voxels are in the build
// itself. A build without the displacement fails the same check (negative
// control), the min/max mip-map bounds hold for every rectangle, and the
// result does not depend on the thread count.
#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <nlohmann/json.hpp>
#include <set>

#include "support/cli_runner.hpp"
#include "support/file_bytes.hpp"
#include "voxcast/displacement.hpp"
#include "voxcast/error.hpp"
#include "voxcast/image.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/mesh_height.hpp"
#include "voxcast/morton.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast {
namespace {

// A bumpy procedural height map (not a power of two on purpose).
Image height_image(int w, int h) {
  Image im(w, h, 1);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const double u = (x + 0.5) / w, v = (y + 0.5) / h;
      const double s = 0.5 + 0.3 * std::sin(6.283 * 3 * u) * std::cos(6.283 * 2 * v) +
                       0.2 * std::sin(6.283 * 7 * (u + v));
      im.at(x, y)[0] = float(std::clamp(s, 0.0, 1.0));
    }
  return im;
}

// A unit square (two triangles) with uv = (x, y), rotated by `tilt` about x.
Mesh plate(float tilt) {
  Mesh m;
  const float c = std::cos(tilt), s = std::sin(tilt);
  auto rot = [&](Vec3 p) { return Vec3{p.x, c * p.y - s * p.z, s * p.y + c * p.z}; };
  for (const Vec2 uv : {Vec2{0, 0}, Vec2{1, 0}, Vec2{1, 1}, Vec2{0, 1}}) {
    m.positions.push_back(rot({uv.x, uv.y, 0.f}));
    m.normals.push_back(rot({0, 0, 1}));
    m.uvs.push_back(uv);
  }
  m.indices = {0, 1, 2, 0, 2, 3};
  return m;
}

// The oracle: every triangle cut into n^2 pieces whose corners are displaced
// exactly (D = P + N * scale * h(T), the header's definition).
Mesh tessellate(const Mesh& mesh, const DisplacementMap& map, float scale, int n) {
  Mesh out;
  for (size_t t = 0; t < mesh.triangle_count(); ++t) {
    const uint32_t* idx = &mesh.indices[3 * t];
    auto vertex = [&](int i, int j) {  // barycentric (i/n, j/n) at vertices 1 and 2
      const float u = float(i) / float(n), v = float(j) / float(n), w = 1 - u - v;
      const Vec3 p =
          mesh.positions[idx[0]] * w + mesh.positions[idx[1]] * u + mesh.positions[idx[2]] * v;
      const Vec3 nn =
          mesh.normals[idx[0]] * w + mesh.normals[idx[1]] * u + mesh.normals[idx[2]] * v;
      const Vec2 uv{mesh.uvs[idx[0]].x * w + mesh.uvs[idx[1]].x * u + mesh.uvs[idx[2]].x * v,
                    mesh.uvs[idx[0]].y * w + mesh.uvs[idx[1]].y * u + mesh.uvs[idx[2]].y * v};
      out.positions.push_back(p + nn * (scale * map.sample(uv)));
      out.normals.push_back(normalize(nn));
      return uint32_t(out.positions.size() - 1);
    };
    for (int i = 0; i < n; ++i)
      for (int j = 0; i + j < n; ++j) {
        const uint32_t a = vertex(i, j), b = vertex(i + 1, j), c = vertex(i, j + 1);
        out.indices.insert(out.indices.end(), {a, b, c});
        if (i + j + 2 <= n) {
          const uint32_t d = vertex(i + 1, j + 1);
          out.indices.insert(out.indices.end(), {b, d, c});
        }
      }
  }
  return out;
}

struct Compare {
  size_t far_a = 0, far_b = 0;  // voxels of a (b) more than one voxel from b (a)
  size_t b_in_a = 0;            // voxels of b that are in a
};

Compare compare(const VoxelSet& a, const VoxelSet& b) {
  const std::set<uint64_t> sa(a.codes.begin(), a.codes.end()), sb(b.codes.begin(), b.codes.end());
  auto near = [](const std::set<uint64_t>& s, uint64_t code) {
    const MortonCoord c = morton_decode(code);
    for (int dz = -1; dz <= 1; ++dz)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          const int64_t x = int64_t(c.x) + dx, y = int64_t(c.y) + dy, z = int64_t(c.z) + dz;
          if (x < 0 || y < 0 || z < 0) continue;
          if (s.count(morton_encode(uint32_t(x), uint32_t(y), uint32_t(z)))) return true;
        }
    return false;
  };
  Compare r;
  for (uint64_t c : a.codes) r.far_a += !near(sb, c);
  for (uint64_t c : b.codes) r.far_b += !near(sa, c), r.b_in_a += sa.count(c);
  return r;
}

TEST(Displacement, NoHolesAgainstADenselyTessellatedMesh) {
  const DisplacementMap map(height_image(40, 24));
  for (const float tilt : {0.f, 0.6f}) {
    SCOPED_TRACE("tilt " + std::to_string(tilt));
    const Mesh mesh = plate(tilt);
    const float scale = 0.15f;
    const GridTransform grid = GridTransform::fit(displaced_bounds(mesh, map, scale), 64);
    VoxelizeOptions vo;
    DisplacementStats st;
    const VoxelSet got = voxelize_displaced(mesh, map, scale, grid, vo, &st);
    const VoxelSet want = voxelize(tessellate(mesh, map, scale, 400), grid, vo);
    ASSERT_GT(want.size(), 4000u);
    const Compare c = compare(got, want);
    std::printf("tilt %.1f: %zu voxels (oracle %zu), %llu pieces, %.4f of the oracle's in it\n",
                double(tilt), got.size(), want.size(), (unsigned long long)st.pieces,
                double(c.b_in_a) / double(want.size()));
    EXPECT_EQ(c.far_a, 0u);
    EXPECT_EQ(c.far_b, 0u);
    EXPECT_GE(double(c.b_in_a) / double(want.size()), 0.99);
    EXPECT_LT(got.size(), 2 * want.size());  // not a blob
    // Attributes as voxelize() gives them: unit normals, positive weights.
    ASSERT_EQ(got.normals.size(), got.size());
    for (size_t i = 0; i < got.size(); ++i) {
      EXPECT_NEAR(length(got.normals[i]), 1.f, 1e-4f);
      EXPECT_GT(got.weights[i], 0.f);
    }
    // Negative control: the undisplaced plate is not within one voxel.
    const VoxelSet flat = voxelize_displaced(mesh, map, 0.f, grid, vo);
    const Compare n = compare(flat, want);
    EXPECT_GT(n.far_b, 100u);
  }
}

TEST(Displacement, MipMapRangesBoundTheSurface) {
  const DisplacementMap map(height_image(40, 24));
  uint64_t seed = 7;
  auto rnd = [&] {
    seed = seed * 6364136223846793005ull + 1442695040888963407ull;
    return double(seed >> 11) * 0x1p-53;
  };
  for (int k = 0; k < 2000; ++k) {
    const double size = std::pow(2.0, -10 * rnd());
    const double u0 = 3 * rnd() - 1, v0 = 3 * rnd() - 1, u1 = u0 + size * rnd(),
                 v1 = v0 + size * rnd();
    float lo, hi;
    map.range(u0, v0, u1, v1, &lo, &hi);
    for (int s = 0; s < 30; ++s) {
      const float h = map.sample({float(u0 + (u1 - u0) * rnd()), float(v0 + (v1 - v0) * rnd())});
      ASSERT_GE(h, lo) << u0 << "," << v0 << " " << u1 << "," << v1;
      ASSERT_LE(h, hi) << u0 << "," << v0 << " " << u1 << "," << v1;
    }
  }
  Image bad(2, 2, 1);
  bad.at(1, 1)[0] = 1.5f;
  EXPECT_THROW(DisplacementMap{bad}, Error);
  EXPECT_THROW(DisplacementMap{Image()}, Error);
}

TEST(Displacement, ThreadCountInvariance) {
  const DisplacementMap map(height_image(40, 24));
  const Mesh mesh = plate(0.3f);
  const GridTransform grid = GridTransform::fit(displaced_bounds(mesh, map, 0.1f), 64);
  VoxelSet v[2];
  for (int k = 0; k < 2; ++k) {
    tbb::global_control gc(tbb::global_control::max_allowed_parallelism, size_t(k + 1));
    v[k] = voxelize_displaced(mesh, map, 0.1f, grid, {});
  }
  EXPECT_EQ(v[0].codes, v[1].codes);
  ASSERT_EQ(v[0].weights.size(), v[1].weights.size());
  for (size_t i = 0; i < v[0].size(); ++i) {
    EXPECT_EQ(v[0].weights[i], v[1].weights[i]);
    EXPECT_EQ(v[0].normals[i].x, v[1].normals[i].x);
    EXPECT_EQ(v[0].colors[i].r, v[1].colors[i].r);
  }
}

// The CLI: build --displacement MAP --displacement-scale S, the same voxels
// as the library (leaf count), in a .vxc and a .vxs; usage errors.
TEST(DisplacementCli, BuildDisplaced) {
  testing::TempDir dir;
  const std::string obj = dir.file("plate.obj"), png = dir.file("h.png");
  {
    std::ofstream o(obj);
    o << "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 1\nvt 1 1\nvt 1 0\nvt 0 0\n"
         "vn 0 0 1\nf 1/1/1 2/2/1 3/3/1\nf 1/1/1 3/3/1 4/4/1\n";
  }
  write_image(png, height_image(40, 24), /*already_srgb=*/true);  // the heights as stored
  auto leaves = [&](const std::string& scene) {
    const auto r = testing::run_cli("info --json '" + scene + "'");
    EXPECT_EQ(r.exit_code, 0) << r.output;
    return nlohmann::json::parse(r.output.substr(r.output.find('{'))).value("leaf_voxels", 0ull);
  };
  auto r = testing::run_cli("build '" + obj + "' --resolution 64 --displacement '" + png +
                            "' --displacement-scale 0.15 -o '" + dir.file("d.vxc") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  // The library on the same inputs (the mesh as the CLI imports it).
  const Mesh mesh = load_mesh(obj);
  const DisplacementMap map(read_png(png));
  const GridTransform grid = GridTransform::fit(displaced_bounds(mesh, map, 0.15f), 64);
  EXPECT_EQ(leaves(dir.file("d.vxc")), voxelize_displaced(mesh, map, 0.15f, grid, {}).size());
  r = testing::run_cli("build '" + obj + "' --resolution 64 -o '" + dir.file("f.vxc") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_LT(2 * leaves(dir.file("f.vxc")), leaves(dir.file("d.vxc")));
  r = testing::run_cli("build '" + obj + "' --resolution 64 --displacement '" + png +
                       "' --displacement-scale 0.15 --slices -o '" + dir.file("d.vxs") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  for (const char* bad :
       {" --displacement h.png", " --displacement h.png --displacement-scale 0.1 --contours"}) {
    std::string cmd = bad;
    const size_t at = cmd.find("h.png");
    if (at != std::string::npos) cmd.replace(at, 5, "'" + png + "'");
    r = testing::run_cli("build '" + obj + "' --resolution 16" + cmd + " -o '" + dir.file("x.vxc") +
                         "'");
    EXPECT_EQ(r.exit_code, 2) << bad << ": " << r.output;
  }
  r = testing::run_cli("build '" + obj + "' --resolution 16 --displacement '" +
                       dir.file("none.png") + "' --displacement-scale 0.1 -o '" +
                       dir.file("x.vxc") + "'");
  EXPECT_NE(r.exit_code, 0) << r.output;
  EXPECT_FALSE(std::filesystem::exists(dir.file("x.vxc")));
  // --displacement-scale alone takes the material's height map: this plate
  // has no material, a runtime error in one line, no output.
  r = testing::run_cli("build '" + obj + "' --resolution 16 --displacement-scale 0.1 -o '" +
                       dir.file("x.vxc") + "'");
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("no height or displacement texture"), std::string::npos) << r.output;
  EXPECT_FALSE(std::filesystem::exists(dir.file("x.vxc")));
}

// The height map from the mesh material (OBJ `disp`, Assimp's DISPLACEMENT
// texture; tests/data/displaced_plate): --displacement-scale alone builds
// the same scene, byte for byte, as naming the same PNG with --displacement,
// and a different one from the flat plate; the library sees the texture only
// when asked for the height map.
TEST(DisplacementCli, MaterialHeightTextureIsTheDisplacementMap) {
  testing::TempDir dir;
  const std::filesystem::path data =
      std::filesystem::path(VOXCAST_TEST_DATA_DIR) / "displaced_plate";
  const std::string obj = (data / "plate.obj").string(), png = (data / "height.png").string();
  Image height;
  const Mesh mesh = load_mesh(obj, &height);
  ASSERT_EQ(mesh.materials.size(), 1u);
  ASSERT_EQ(height.width, 16);
  ASSERT_EQ(height.height, 12);
  EXPECT_EQ(height.pixels, read_png(png).pixels);  // as the --displacement PNG reads
  const std::string common = " --resolution 64 --displacement-scale 0.15 -o '";
  auto r = testing::run_cli("build '" + obj + "'" + common + dir.file("m.vxc") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  r = testing::run_cli("build '" + obj + "' --displacement '" + png + "'" + common +
                       dir.file("p.vxc") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  r = testing::run_cli("build '" + obj + "' --resolution 64 -o '" + dir.file("f.vxc") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(testing::read_bytes(dir.file("m.vxc")), testing::read_bytes(dir.file("p.vxc")));
  EXPECT_NE(testing::read_bytes(dir.file("m.vxc")), testing::read_bytes(dir.file("f.vxc")));
}

}  // namespace
}  // namespace voxcast
