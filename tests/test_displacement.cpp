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
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <set>

#include "support/cli_runner.hpp"
#include "support/file_bytes.hpp"
#include "voxcast/displacement.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo.hpp"
#include "voxcast/esvo_slices.hpp"
#include "voxcast/image.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/mesh_height.hpp"
#include "voxcast/morton.hpp"
#include "voxcast/voxelize.hpp"
#include "voxelize/displacement_cells.hpp"

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

// The cell restriction the top-down slice builder voxelizes regions with
// (voxelize/displacement_cells.hpp): over every cell, the tasks binned to it
// give exactly the whole build's voxels in the cell, attributes bit for bit,
// for cells from 8^3 to 32^3 of a 64^3 grid and a tilted and a flat plate.
TEST(Displacement, CellRestrictionIsExact) {
  const DisplacementMap map(height_image(40, 24));
  for (const float tilt : {0.f, 0.6f}) {
    const Mesh mesh = plate(tilt);
    const float scale = 0.15f;
    const GridTransform grid = GridTransform::fit(displaced_bounds(mesh, map, scale), 64);
    VoxelizeOptions vo;
    vo.attributes = true;
    const VoxelSet whole = voxelize_displaced(mesh, map, scale, grid, vo);
    const detail::DisplacedVoxelizer dv(mesh, map, scale, grid);
    for (const int bits : {3, 4, 5}) {
      SCOPED_TRACE("tilt " + std::to_string(tilt) + " cells " + std::to_string(1 << bits));
      const std::vector<detail::CellBin> bins = dv.bin(bits);
      VoxelSet joined;
      size_t cells = 0;
      for (size_t a = 0; a < bins.size();) {
        size_t b = a;
        std::vector<uint32_t> tasks;
        for (; b < bins.size() && bins[b].cell == bins[a].cell; ++b) tasks.push_back(bins[b].tri);
        const MortonCoord c = morton_decode(bins[a].cell);
        const uint32_t lo[3] = {uint32_t(c.x) << bits, uint32_t(c.y) << bits,
                                uint32_t(c.z) << bits};
        const VoxelSet v = dv.voxelize(tasks.data(), tasks.size(), lo, 1u << bits, vo);
        for (size_t i = 0; i < v.size(); ++i) {
          const MortonCoord q = morton_decode(v.codes[i]);
          ASSERT_TRUE(q.x >> bits == c.x && q.y >> bits == c.y && q.z >> bits == c.z);
        }
        joined.codes.insert(joined.codes.end(), v.codes.begin(), v.codes.end());
        joined.colors.insert(joined.colors.end(), v.colors.begin(), v.colors.end());
        joined.normals.insert(joined.normals.end(), v.normals.begin(), v.normals.end());
        joined.weights.insert(joined.weights.end(), v.weights.begin(), v.weights.end());
        ++cells;
        a = b;
      }
      EXPECT_GT(cells, 1u);
      ASSERT_EQ(joined.codes, whole.codes);
      ASSERT_EQ(joined.weights.size(), whole.weights.size());
      size_t differ = 0;
      for (size_t i = 0; i < whole.size(); ++i)
        differ += std::memcmp(&joined.colors[i], &whole.colors[i], sizeof(Color)) != 0 ||
                  std::memcmp(&joined.normals[i], &whole.normals[i], sizeof(Vec3)) != 0 ||
                  std::memcmp(&joined.weights[i], &whole.weights[i], sizeof(float)) != 0;
      EXPECT_EQ(differ, 0u);
    }
  }
}

// The top-down slice builder (esvo §7.1) with displacement (§7.4): each
// region voxelized from the displacement primitives overlapping it; the
// file equals slicing the in-core displaced build byte for byte (several
// slice and cell sizes, with and without attributes), and contours with a
// displacement are refused.
TEST(Displacement, TopDownSlicesEqualSlicingTheInCoreBuild) {
  const DisplacementMap map(height_image(40, 24));
  struct Case {
    float tilt;
    uint32_t resolution;
    uint64_t slice_bytes;
    uint32_t cell;  // 0 = the default
    bool attributes;
    bool compressed = false;  // §5.5 blocks per slice
  };
  const Case cases[] = {{0.6f, 64, 1024, 8, true},
                        {0.f, 64, 4096, 0, false},
                        {0.6f, 128, 2048, 16, true},
                        {0.3f, 128, uint64_t(1) << 20, 0, true},
                        {0.6f, 128, 2048, 16, true, true}};
  for (const Case& cs : cases) {
    SCOPED_TRACE("tilt " + std::to_string(cs.tilt) + " at " + std::to_string(cs.resolution) +
                 " slice " + std::to_string(cs.slice_bytes) + " cell " + std::to_string(cs.cell) +
                 (cs.compressed ? " compressed" : ""));
    const Mesh mesh = plate(cs.tilt);
    const float scale = 0.15f;
    const GridTransform grid =
        GridTransform::fit(displaced_bounds(mesh, map, scale), cs.resolution);
    VoxelizeOptions vo;
    vo.attributes = cs.attributes;
    const esvo::EsvoOctree octree =
        esvo::build_octree(voxelize_displaced(mesh, map, scale, grid, vo));
    testing::TempDir dir;
    esvo::SliceOptions so;
    so.slice_bytes = cs.slice_bytes;
    so.compressed = cs.compressed;
    esvo::write_slices(octree, dir.file("in-core.vxs"), so);
    esvo::SliceBuildOptions bo;
    bo.slice_bytes = cs.slice_bytes;
    bo.cell_size = cs.cell;
    bo.compressed = cs.compressed;
    bo.displacement = &map;
    bo.displacement_scale = scale;
    esvo::SliceBuildStats st;
    esvo::build_slices(mesh, grid, vo, dir.file("top-down.vxs"), bo, &st);
    EXPECT_GT(st.cells, 1u);
    if (cs.slice_bytes < 8192) {
      EXPECT_GT(st.slices, 8u);
    }
    EXPECT_TRUE(testing::read_bytes(dir.file("top-down.vxs")) ==
                testing::read_bytes(dir.file("in-core.vxs")));
  }
  const Mesh mesh = plate(0.f);
  const GridTransform grid = GridTransform::fit(displaced_bounds(mesh, map, 0.1f), 32);
  testing::TempDir dir;
  esvo::SliceBuildOptions bo;
  bo.displacement = &map;
  bo.displacement_scale = 0.1f;
  bo.contours = true;
  EXPECT_THROW(esvo::build_slices(mesh, grid, {}, dir.file("x.vxs"), bo), Error);
  bo.contours = false;
  bo.displacement_scale = std::nanf("");
  EXPECT_THROW(esvo::build_slices(mesh, grid, {}, dir.file("x.vxs"), bo), Error);
  EXPECT_FALSE(std::filesystem::exists(dir.file("x.vxs")));
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
                       "' --displacement-scale 0.15 --slices --slice-size 4K --cell-size 16 -o '" +
                       dir.file("d.vxs") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("top-down from"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find(", displaced"), std::string::npos) << r.output;
  // The slice file renders the in-core scene's image.
  for (const char* in : {"d.vxs", "d.vxc"}) {
    r = testing::run_cli("render '" + dir.file(in) + "' --size 48x40 -o '" +
                         dir.file(std::string(in) + ".png") + "'");
    ASSERT_EQ(r.exit_code, 0) << r.output;
  }
  EXPECT_EQ(testing::read_bytes(dir.file("d.vxs.png")), testing::read_bytes(dir.file("d.vxc.png")));
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
