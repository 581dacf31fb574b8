// GigaVoxels over OpenVDB grids (issue 12 item 5, gigavoxels.hpp VdbVolume)
// and OpenVDB's own volume ray marcher as the peer (VdbPeer):
//  * producer bricks equal direct sampling of the grid: the finest level
//    the grid's voxels read here with an OpenVDB accessor, coarser levels
//    means of the 2^k-voxel blocks summed here in double;
//  * a level set becomes the coverage clamp(0.5 - phi / voxel, 0, 1),
//    interior tiles included;
//  * damaged files (truncated, bad magic, no float grid) are refused with one
//    line, through the library and the CLI;
//  * the GigaVoxels image of a fog volume agrees with OpenVDB's marcher at
//    the same step and light (an error figure against a finer-step peer).
#include <gtest/gtest.h>
#include <openvdb/openvdb.h>
#include <openvdb/tools/LevelSetSphere.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <vector>

#include "support/cli_runner.hpp"
#include "voxcast/error.hpp"
#include "voxcast/gigavoxels.hpp"
#include "voxcast/integrator.hpp"
#include "voxcast/volume_integrator.hpp"

using namespace voxcast;
using namespace voxcast::giga;
using voxcast::testing::TempDir;

namespace {

constexpr int kLo[3] = {-5, 3, 100}, kDim[3] = {37, 21, 29};

/// A smooth fog blob over kDim voxels from kLo, with a constant 16^3 tile
/// inside (a tile, not voxels) and inactive zeros around.
openvdb::FloatGrid::Ptr fog_grid() {
  openvdb::initialize();
  auto g = openvdb::FloatGrid::create(0.f);
  g->setName("density");
  g->setGridClass(openvdb::GRID_FOG_VOLUME);
  auto xf = openvdb::math::Transform::createLinearTransform(0.1);
  xf->postTranslate(openvdb::Vec3d(0.3, -0.2, 0.05));
  g->setTransform(xf);
  auto acc = g->getAccessor();
  for (int z = 0; z < kDim[2]; ++z)
    for (int y = 0; y < kDim[1]; ++y)
      for (int x = 0; x < kDim[0]; ++x) {
        const float v =
            0.02f +
            0.05f * float(std::sin(0.31 * x) * std::cos(0.23 * y) * std::sin(0.17 * z + 0.4)) +
            0.05f;
        acc.setValue(openvdb::Coord(kLo[0] + x, kLo[1] + y, kLo[2] + z), std::max(v, 0.001f));
      }
  // An 8^3 block inside: one tile of value 0.08 instead of its leaf.
  g->tree().addTile(1, openvdb::Coord(24, 16, 112), 0.08f, true);
  return g;
}

void write_grid(const std::string& path, openvdb::GridBase::Ptr g) {
  openvdb::io::File f(path);
  f.write({g});
  f.close();
}

/// The producer's voxel (x, y, z) of `level`, from the grid alone: the mean
/// of the (2^k)^3 grid values (k = max_level - level) from the cube's corner
/// `offset`, times the cube's voxels per side (extinction per unit cube).
double oracle(const openvdb::FloatGrid& grid, openvdb::Coord offset, int max_level, int level,
              int64_t x, int64_t y, int64_t z) {
  const int64_t n = int64_t(kBrickSide) << level;
  if (x < 0 || y < 0 || z < 0 || x >= n || y >= n || z >= n) return 0;
  const int f = 1 << (max_level - level);
  auto acc = grid.getConstAccessor();
  double sum = 0;
  for (int k = 0; k < f; ++k)
    for (int j = 0; j < f; ++j)
      for (int i = 0; i < f; ++i)
        sum +=
            acc.getValue(offset + openvdb::Coord(int(x) * f + i, int(y) * f + j, int(z) * f + k));
  return sum / (double(f) * f * f) * double(kBrickSide << max_level);
}

FrameView view_of(const VdbVolume& v, int w, int h, uint32_t frame = 0) {
  FrameView view;
  view.width = w, view.height = h, view.frame = frame;
  const Aabb box{v.origin, v.origin + Vec3{v.size, v.size, v.size}};
  view.camera = Camera::orbit(box, w, h, 30.f, 20.f);
  return view;
}

GigaOptions placed(const VdbVolume& v) {
  GigaOptions o;
  o.tiles = 1 << 14, o.bricks = 1 << 12;
  o.check_after_pass = true;
  o.origin = v.origin, o.size = v.size;
  return o;
}

Film render(GigaVoxels& g, const FrameView& view, VolumeIntegratorOptions io = {}) {
  VolumeIntegrator integrator(io);
  FrameOptions fo;
  fo.max_passes = 1000;
  fo.tile_size = 8;
  Film film;
  render_frame(g, integrator, view, fo, &film);
  return film;
}

}  // namespace

TEST(GigaVdb, ProducerBricksEqualDirectSamplingOfTheGrid) {
  TempDir dir;
  const auto grid = fog_grid();
  write_grid(dir.file("fog.vdb"), grid);
  const VdbVolume v = read_vdb_volume(dir.file("fog.vdb"));
  EXPECT_EQ(v.grid_name, "density");
  EXPECT_FALSE(v.level_set);
  ASSERT_EQ(grid->tree().probeConstLeaf(openvdb::Coord(24, 16, 112)), nullptr);  // a tile
  EXPECT_EQ(v.extent[0], 37);
  EXPECT_EQ(v.extent[1], 21);
  EXPECT_EQ(v.extent[2], 29);
  const int max_level = v.producer->max_level();
  ASSERT_EQ(max_level, std::countr_zero(64u / kBrickSide));  // 37 voxels -> a cube of 64
  // Centered: the cube's corner in grid coordinates, and its world place.
  const openvdb::Coord offset(-5 - (64 - 37) / 2, 3 - (64 - 21) / 2, 100 - (64 - 29) / 2);
  const openvdb::Vec3d corner = grid->transform().indexToWorld(
      openvdb::Vec3d(offset.x() - 0.5, offset.y() - 0.5, offset.z() - 0.5));
  EXPECT_NEAR(v.origin.x, corner.x(), 1e-5);
  EXPECT_NEAR(v.origin.y, corner.y(), 1e-5);
  EXPECT_NEAR(v.origin.z, corner.z(), 1e-5);
  EXPECT_NEAR(v.size, 6.4f, 1e-5);

  GigaVoxels g(v.producer, placed(v));
  // Near and far views: bricks of every level become resident.
  for (uint32_t f = 0; f < 3; ++f) {
    FrameView view = view_of(v, 40, 30, f);
    view.lod_pixels = f == 0 ? 8.f : f == 1 ? 1.f : 0.05f;
    render(g, view);
  }
  const auto bricks = g.resident_bricks();
  int levels_seen[kMaxLevel + 1] = {};
  for (const auto& rb : bricks) {
    const NodeRegion& r = rb.region;
    ++levels_seen[r.level];
    for (int k = 0; k < kBrickStored; ++k)
      for (int j = 0; j < kBrickStored; ++j)
        for (int i = 0; i < kBrickStored; ++i) {
          const double want =
              oracle(*grid, offset, max_level, r.level, int64_t(r.x) * kBrickSide - 1 + i,
                     int64_t(r.y) * kBrickSide - 1 + j, int64_t(r.z) * kBrickSide - 1 + k);
          const BrickVoxel& b = rb.voxels[size_t(i + kBrickStored * (j + kBrickStored * k))];
          // The pool's halves (PoolVoxel) round by at most 2^-11 relative.
          ASSERT_NEAR(b.density, want, 1e-5 * 64 + std::ldexp(std::fabs(want), -11))
              << "level " << r.level << " at " << i << "," << j << "," << k;
          ASSERT_EQ(b.r, b.density);  // white
        }
  }
  for (int l = 0; l <= max_level; ++l) EXPECT_GT(levels_seen[l], 0) << "level " << l;
}

TEST(GigaVdb, LevelSetBecomesCoverage) {
  TempDir dir;
  openvdb::initialize();
  // Radius 40 voxels: the interior holds tiles of the inner value.
  const float h = 0.05f;
  auto ls = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(2.f, {0.5f, 0.f, 0.f}, h, 3.f);
  ls->setName("surface");
  write_grid(dir.file("sphere.vdb"), ls);
  const VdbVolume v = read_vdb_volume(dir.file("sphere.vdb"));
  EXPECT_TRUE(v.level_set);
  const int L = v.producer->max_level();
  const int64_t n = int64_t(kBrickSide) << L;
  // Grid coordinate of the producer's voxel from the cube's world corner.
  auto acc = ls->getConstAccessor();
  int inside = 0, ramp = 0;
  for (int64_t z = 0; z < n; z += 3)
    for (int64_t y = 0; y < n; y += 5)
      for (int64_t x = 0; x < n; x += 2) {
        const openvdb::Vec3d c = ls->transform().worldToIndex(
            openvdb::Vec3d(v.origin.x + (double(x) + 0.5) * h, v.origin.y + (double(y) + 0.5) * h,
                           v.origin.z + (double(z) + 0.5) * h));
        const openvdb::Coord ijk(int(std::lround(c.x())), int(std::lround(c.y())),
                                 int(std::lround(c.z())));
        const double want = std::clamp(0.5 - double(acc.getValue(ijk)) / h, 0.0, 1.0);
        const VolumeSample s = v.producer->voxel(L, x, y, z);
        ASSERT_NEAR(s.density, want * double(n), 1e-4 * double(n)) << x << "," << y << "," << z;
        inside += want == 1.0, ramp += want > 0 && want < 1;
      }
  EXPECT_GT(inside, 1000);  // deep inside: the inactive interior tiles count
  EXPECT_GT(ramp, 100);
  // The root's central voxels (a box filter of the interior) are solid.
  EXPECT_NEAR(v.producer->voxel(0, kBrickSide / 2, kBrickSide / 2, kBrickSide / 2).density,
              double(n), 1e-3 * double(n));
}

TEST(GigaVdb, DamagedFilesAreRefusedWithOneLine) {
  TempDir dir;
  write_grid(dir.file("fog.vdb"), fog_grid());
  std::vector<char> bytes;
  {
    std::ifstream in(dir.file("fog.vdb"), std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(in), {});
  }
  ASSERT_GT(bytes.size(), 1000u);
  auto refused = [&](const std::vector<char>& b, const std::string& what) {
    const std::string p = dir.file("bad.vdb");
    std::ofstream(p, std::ios::binary).write(b.data(), std::streamsize(b.size()));
    try {
      read_vdb_volume(p);
      ADD_FAILURE() << what << ": accepted";
    } catch (const Error& e) {
      const std::string m = e.what();
      EXPECT_EQ(m.find('\n'), std::string::npos) << what << ": " << m;
      EXPECT_NE(m.find("bad.vdb"), std::string::npos) << what << ": " << m;
    }
  };
  for (size_t cut : {size_t(0), size_t(7), size_t(30), size_t(100), bytes.size() / 2,
                     bytes.size() - 40, bytes.size() - 1})
    refused(std::vector<char>(bytes.begin(), bytes.begin() + std::ptrdiff_t(cut)),
            "truncated at " + std::to_string(cut));
  std::vector<char> magic = bytes;
  magic[1] ^= 0x5A;
  refused(magic, "bad magic");
  // A file with a vector grid only.
  {
    auto vec = openvdb::Vec3SGrid::create(openvdb::Vec3s(0.f));
    vec->setName("Cd");
    vec->tree().setValue(openvdb::Coord(1, 2, 3), openvdb::Vec3s(1.f));
    write_grid(dir.file("vec.vdb"), vec);
    std::ifstream in(dir.file("vec.vdb"), std::ios::binary);
    refused(std::vector<char>(std::istreambuf_iterator<char>(in), {}), "no float grid");
  }
  // Through the CLI: exit 1, one error line.
  std::ofstream(dir.file("cut.vdb"), std::ios::binary)
      .write(bytes.data(), std::streamsize(bytes.size() / 2));
  const auto r = voxcast::testing::run_cli_split("volume render " + dir.file("cut.vdb") + " -o " +
                                                 dir.file("x.png") + " --size 16x16");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_EQ(std::count(r.errors.begin(), r.errors.end(), '\n'), 1) << r.errors;
  EXPECT_EQ(r.errors.rfind("voxcast: error: ", 0), 0u) << r.errors;
  EXPECT_FALSE(std::filesystem::exists(dir.file("x.png")));
}

TEST(GigaVdb, CliRendersAndDescribesGrids) {
  TempDir dir;
  write_grid(dir.file("fog.vdb"), fog_grid());
  const auto r = voxcast::testing::run_cli_split("volume render " + dir.file("fog.vdb") + " -o " +
                                                 dir.file("fog.png") + " --size 40x30");
  ASSERT_EQ(r.exit_code, 0) << r.errors;
  EXPECT_NE(r.output.find("vdb:density"), std::string::npos) << r.output;
  EXPECT_TRUE(std::filesystem::exists(dir.file("fog.png")));
  const auto info = voxcast::testing::run_cli_split("volume info " + dir.file("fog.vdb"));
  ASSERT_EQ(info.exit_code, 0) << info.errors;
  EXPECT_NE(info.output.find("grid        density (fog volume)"), std::string::npos) << info.output;
  EXPECT_NE(info.output.find("37 x 21 x 29"), std::string::npos) << info.output;
}

TEST(GigaVdb, AgreesWithOpenVdbMarcherAtEqualStep) {
  TempDir dir;
  write_grid(dir.file("fog.vdb"), fog_grid());
  const VdbVolume v = read_vdb_volume(dir.file("fog.vdb"));
  const int w = 48, h = 36;
  FrameView view = view_of(v, w, h);
  view.lod_pixels = 0.25f;  // the finest level everywhere, as the peer samples
  VolumeIntegratorOptions io;
  io.shadows = true, io.ambient = 0.f, io.step_scale = 0.5f;
  GigaVoxels g(v.producer, placed(v));
  const Film film = render(g, view, io);
  VdbPeer peer(v);
  VdbPeerOptions po;
  po.light_dir = io.light_dir;
  po.step = 0.5;
  const Image ours = film.color, theirs = peer.render(view.camera, w, h, po);
  po.step = 0.125;
  const Image fine = peer.render(view.camera, w, h, po);
  auto rmse = [&](const Image& a, const Image& b) {
    double s = 0, m = 0;
    for (size_t i = 0; i < a.pixels.size(); ++i)
      s += (double(a.pixels[i]) - b.pixels[i]) * (double(a.pixels[i]) - b.pixels[i]),
          m = std::max(m, double(b.pixels[i]));
    EXPECT_GT(m, 0.2);  // a visible volume
    return std::sqrt(s / double(a.pixels.size()));
  };
  const double e_ours = rmse(ours, fine), e_theirs = rmse(theirs, fine);
  EXPECT_LT(e_ours, 0.03) << "peer at step 0.5: " << e_theirs;
  EXPECT_LT(e_theirs, 0.03);
  // Light cones from the finest level at the sample itself (the peer's
  // shadow rays start there too): closer to the reference than the cones as
  // wide as the pixel's, started one footprint away, and at least as close
  // as the peer at the same step.
  io.shadow_footprint_scale = 0.f;
  GigaVoxels g0(v.producer, placed(v));
  const double e_finest = rmse(render(g0, view, io).color, fine);
  EXPECT_LT(e_finest, 0.5 * e_ours) << e_ours;
  EXPECT_LE(e_finest, e_theirs) << e_ours;
}

TEST(GigaVdb, ExportWritesTheFinestLevelDeterministically) {
  TempDir dir;
  const auto r =
      voxcast::testing::run_cli_split("volume export procedural:menger --resolution 32 -o " +
                                      dir.file("m.vdb") + " --density-scale 2");
  ASSERT_EQ(r.exit_code, 0) << r.errors;
  const auto again =
      voxcast::testing::run_cli_split("volume export procedural:menger --resolution 32 -o " +
                                      dir.file("m2.vdb") + " --density-scale 2");
  ASSERT_EQ(again.exit_code, 0) << again.errors;
  EXPECT_EQ(voxcast::testing::read_text(dir.file("m.vdb")),
            voxcast::testing::read_text(dir.file("m2.vdb")));
  openvdb::initialize();
  openvdb::io::File f(dir.file("m.vdb"));
  f.open();
  auto grid = openvdb::gridPtrCast<openvdb::FloatGrid>(f.readGrid("density"));
  f.close();
  ASSERT_TRUE(grid);
  EXPECT_NEAR(grid->voxelSize()[0], 1.0 / 32, 1e-9);
  const auto menger = make_procedural("menger", 32);
  auto acc = grid->getConstAccessor();
  int solid = 0;
  for (int z = 0; z < 32; ++z)
    for (int y = 0; y < 32; ++y)
      for (int x = 0; x < 32; ++x) {
        const float want = menger->voxel(menger->max_level(), x, y, z).density * 2.f / 32.f;
        ASSERT_FLOAT_EQ(acc.getValue(openvdb::Coord(x, y, z)), want) << x << "," << y << "," << z;
        solid += want > 0.f;
      }
  EXPECT_GT(solid, 1000);
  // Read back: a producer over the same voxels.
  const VdbVolume v = read_vdb_volume(dir.file("m.vdb"));
  EXPECT_EQ(v.producer->max_level(), menger->max_level());
}

TEST(GigaVdb, BenchPrintsBothRenderersAgainstTheReference) {
  TempDir dir;
  write_grid(dir.file("fog.vdb"), fog_grid());
  const auto r = voxcast::testing::run_cli_split("volume bench " + dir.file("fog.vdb") +
                                                 " --size 32x24 --frames 1 --threads 1");
  ASSERT_EQ(r.exit_code, 0) << r.errors;
  EXPECT_NE(r.output.find("  gigavoxels "), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("  openvdb VolumeRender "), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("RMSE"), std::string::npos) << r.output;
  // The peer reads grids only: its options need a .vdb SOURCE.
  const auto p = voxcast::testing::run_cli_split(
      "volume bench procedural:cloud --size 8x8 "
      "--peer-output " +
      dir.file("peer.png"));
  EXPECT_EQ(p.exit_code, 2) << p.output;
  EXPECT_FALSE(std::filesystem::exists(dir.file("peer.png")));
}
