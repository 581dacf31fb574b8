// The voxel renderer against Embree on the shared meshes: depth images of
// the finest level must match the triangles to within two voxel diagonals.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "support/shared_meshes.hpp"
#include "voxcast/embree_reference.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/render.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast {
namespace {

const std::filesystem::path kMeshes = std::filesystem::path(VOXCAST_TEST_DATA_DIR) / "meshes";

TEST(EmbreeScene, SingleRaysOnATriangle) {
  Mesh m;
  m.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  m.normals = {{0, 0, 1}, {0, 0, 1}, {0, 0, 1}};
  m.indices = {0, 1, 2};
  const EmbreeScene s(m);
  EXPECT_NEAR(s.intersect({{0.2f, 0.2f, 2.f}, {0, 0, -1}, INFINITY}), 2.f, 1e-5f);
  EXPECT_TRUE(std::isinf(s.intersect({{0.8f, 0.8f, 2.f}, {0, 0, -1}, INFINITY})));
  EXPECT_TRUE(std::isinf(s.intersect({{0.2f, 0.2f, 2.f}, {0, 0, -1}, 1.5f})));
  // The hit with its triangle and geometric normal (the triangle's plane).
  const EmbreeScene::Hit h = s.intersect_hit({{0.2f, 0.2f, 2.f}, {0, 0, -1}, INFINITY});
  EXPECT_NEAR(h.t, 2.f, 1e-5f);
  EXPECT_EQ(h.triangle, 0u);
  EXPECT_EQ(h.ng.x, 0.f);
  EXPECT_EQ(h.ng.y, 0.f);
  EXPECT_NE(h.ng.z, 0.f);
  EXPECT_TRUE(std::isinf(s.intersect_hit({{0.8f, 0.8f, 2.f}, {0, 0, -1}, INFINITY}).t));
  EXPECT_TRUE(s.occluded({{0.2f, 0.2f, 2.f}, {0, 0, -1}, INFINITY}));
  EXPECT_FALSE(s.occluded({{0.2f, 0.2f, 2.f}, {0, 0, 1}, INFINITY}));
  EXPECT_GT(s.memory_bytes(), 0u);
  // Single and packet renders agree exactly on the same rays.
  Camera cam = Camera::parse("0.3,0.3,2,0.3,0.3,0,0,1,0,60");
  const auto a = s.render_depth(cam, 37, 21, EmbreeScene::Mode::Single);
  const auto b = s.render_depth(cam, 37, 21, EmbreeScene::Mode::Packet8);
  EXPECT_EQ(a.rays, 37u * 21u);
  EXPECT_GT(a.hits, 0u);
  EXPECT_LT(a.hits, a.rays);
  EXPECT_EQ(a.hits, b.hits);
  for (size_t i = 0; i < a.depth.pixels.size(); ++i) {
    const float x = a.depth.pixels[i], y = b.depth.pixels[i];
    if (std::isinf(x) || std::isinf(y)) {
      EXPECT_EQ(x, y) << i;
    } else {
      EXPECT_NEAR(x, y, 1e-5f * x) << i;
    }
  }
}

// Every primary mode (single, 2x2/4x2/4x4 packets, stream) traces the same
// rays: same hits; an image size that is no multiple of the blocks exercises
// the masked lanes. Shaded: the interpolated vertex normal at the analytic hit
// point, through surface_phong; misses get the renderer's background.
TEST(EmbreeScene, EveryModeTracesTheSameRaysAndShadesInterpolatedNormals) {
  Mesh m;
  m.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  m.normals = {{0, 0, 1}, normalize(Vec3{1, 0, 1}), normalize(Vec3{0, 1, 1})};
  m.indices = {0, 1, 2};
  const EmbreeScene s(m);
  const Camera cam = Camera::parse("0.3,0.3,2,0.3,0.3,0,0,1,0,60");
  const int W = 37, H = 21;
  const Vec3 light_dir = normalize(Vec3{-0.4f, -1.0f, -0.6f});
  const CameraRays rays(cam, W, H);
  const auto ref = s.render_depth(cam, W, H, EmbreeScene::Mode::Single);
  ASSERT_GT(ref.hits, 0u);
  ASSERT_LT(ref.hits, ref.rays);
  for (const EmbreeScene::Mode mode : EmbreeScene::kModes) {
    const auto d = s.render_depth(cam, W, H, mode);
    const auto c = s.render_shaded(cam, W, H, mode, light_dir);
    EXPECT_EQ(d.hits, ref.hits) << EmbreeScene::mode_name(mode);
    EXPECT_EQ(c.hits, ref.hits) << EmbreeScene::mode_name(mode);
    EXPECT_TRUE(d.color.pixels.empty());
    for (int y = 0; y < H; ++y)
      for (int x = 0; x < W; ++x) {
        const Ray r = rays.ray(x, y);
        const float t = -r.origin.z / r.dir.z;
        const float u = r.origin.x + t * r.dir.x, v = r.origin.y + t * r.dir.y;
        if (std::fmin(std::fmin(u, v), 1.f - u - v) < -1e-3f) {
          EXPECT_TRUE(std::isinf(*d.depth.at(x, y)));
          EXPECT_EQ(c.color.at(x, y)[0], RenderOptions{}.background.r);
          continue;
        }
        if (std::fmin(std::fmin(u, v), 1.f - u - v) < 1e-3f) continue;  // on an edge
        EXPECT_NEAR(*d.depth.at(x, y), t, 1e-5f * t) << x << "," << y;
        const Vec3 n =
            normalize(m.normals[0] * (1.f - u - v) + m.normals[1] * u + m.normals[2] * v);
        const Color want = surface_phong(m.surface_color(0, u, v), n, r.dir, -light_dir);
        EXPECT_NEAR(c.color.at(x, y)[0], want.r, 1e-4f) << x << "," << y;
        EXPECT_NEAR(c.color.at(x, y)[2], want.b, 1e-4f) << x << "," << y;
      }
  }
  // Occlusion: every mode answers like rtcOccluded1, ray by ray (37 rays: the
  // packets' last lanes are masked).
  std::vector<Ray> occ_rays;
  for (int i = 0; i < 37; ++i)
    occ_rays.push_back({{0.03f * float(i), 0.3f, 1.f},
                        normalize(Vec3{0.f, 0.1f * float(i % 3), -1.f}),
                        i % 5 == 0 ? 0.5f : INFINITY});
  for (const EmbreeScene::Mode mode : EmbreeScene::kOcclusionModes) {
    std::vector<uint8_t> occ;
    s.occluded_all(occ_rays, mode, &occ);
    ASSERT_EQ(occ.size(), occ_rays.size());
    for (size_t i = 0; i < occ_rays.size(); ++i)
      EXPECT_EQ(bool(occ[i]), s.occluded(occ_rays[i])) << EmbreeScene::mode_name(mode) << " " << i;
  }
}

class MeshOracle : public ::testing::TestWithParam<const char*> {};

TEST_P(MeshOracle, DepthMatchesEmbree) {
  const std::filesystem::path path = kMeshes / GetParam();
  ASSERT_TRUE(std::filesystem::exists(path)) << path;
  const Mesh mesh = load_mesh(path);
  VoxelizeOptions vo;
  vo.mode = VoxelizationMode::Conservative;
  const VoxelSet voxels = voxelize(mesh, GridTransform::fit(mesh.bounds(), 2048), vo);
  auto octree = std::make_shared<esvo::EsvoOctree>(esvo::build_octree(voxels));
  const esvo::EsvoStructure structure(octree);
  const float voxel = float(octree->grid.voxel_size);

  // 512x384: the automatic camera keeps the whole mesh in view, so the mesh
  // covers 8-35 % of the image; this size keeps ~10^4-10^5 common hits.
  RenderOptions ro;
  ro.width = 512;
  ro.height = 384;
  ro.camera = Camera::frame(mesh.bounds(), ro.width, ro.height);
  ro.lod_pixels = 0.f;
  ro.want_depth = true;
  const RenderResult vr = render(structure, ro);
  const EmbreeScene embree(mesh);
  const auto er = embree.render_depth(ro.camera, ro.width, ro.height, EmbreeScene::Mode::Single);

  // Depth agreement. A conservative voxel layer is up to ~sqrt(3) voxels
  // thick on each side of the surface measured along the surface normal, so
  // along a ray at incidence angle theta the first voxel may come up to
  // thickness / |cos theta| before the triangle: near silhouettes the error in
  // t grows without bound. We report the plain two-diagonal agreement and
  // assert 99% with the tolerance divided by |cos theta|, theta from the
  // source mesh: the geometric normal of the triangle Embree hits (the
  // voxels' own normal would let a wrong normal loosen its own check), clamped
  // at cos 75 deg (a 4x wider tolerance) where the surface is seen edge-on.
  // Measured at 2048^3: 99.10 % (teapot) - 99.94 % (fandisk), with 1.0 -
  // 8.6 % of the common hits clamped.
  size_t agree = 0, both = 0, close = 0, close_incidence = 0, clamped = 0, border_hits = 0;
  const size_t n = size_t(ro.width) * ro.height;
  const float tol = 2.f * std::sqrt(3.f) * voxel;
  const CameraRays rays(ro.camera, ro.width, ro.height);
  for (int y = 0; y < ro.height; ++y)
    for (int x = 0; x < ro.width; ++x) {
      const size_t i = size_t(y) * ro.width + x;
      const float dv = vr.depth.pixels[i], de = er.depth.pixels[i];
      const bool hv = std::isfinite(dv), he = std::isfinite(de);
      agree += hv == he;
      if (he && (x == 0 || y == 0 || x == ro.width - 1 || y == ro.height - 1)) ++border_hits;
      if (!(hv && he)) continue;
      ++both;
      const bool ok = std::fabs(dv - de) <= tol;
      close += ok;
      const EmbreeScene::Hit eh = embree.intersect_hit(rays.ray(x, y));
      ASSERT_EQ(eh.t, de) << "the same ray must give the same Embree hit";
      const float cos_mesh = std::fabs(dot(normalize(eh.ng), rays.direction(x, y)));
      clamped += cos_mesh < 0.25f;
      close_incidence += std::fabs(dv - de) <= tol / std::fmax(cos_mesh, 0.25f);
    }
  std::printf(
      "%s: %zu voxels, coverage %.1f%%, hit/miss agreement %.3f%%, depth within 2 voxel diagonals "
      "%.2f%% of common hits (%.3f%% within 2 diagonals / |cos theta| of the mesh; %.2f%% of "
      "common hits beyond 75 deg, clamped), border hits %zu\n",
      GetParam(), voxels.size(), 100.0 * double(er.hits) / double(n),
      100.0 * double(agree) / double(n), 100.0 * double(close) / double(std::max<size_t>(both, 1)),
      100.0 * double(close_incidence) / double(std::max<size_t>(both, 1)),
      100.0 * double(clamped) / double(std::max<size_t>(both, 1)), border_hits);
  EXPECT_EQ(vr.rays, n);
  EXPECT_GT(both, n / 20) << "the framed mesh should cover a good part of the image";
  EXPECT_GE(double(agree), 0.995 * double(n));
  // Plain share: 89.2 % on the truck, whose flat sides the automatic view
  // meets at grazing angles; the incidence-scaled criterion is the real one.
  EXPECT_GE(double(close), 0.88 * double(both));
  // With the automatic framing (whole mesh in view) and theta from the mesh:
  // 98.98 % (armadillo) to 99.9 %; the clamp holds 1.0-10.6 % of the common
  // hits (10.6 %: the truck's flat sides seen at grazing angles).
  EXPECT_GE(double(close_incidence), 0.985 * double(both));
  // The 4x clamp must stay the exception, or it would carry the check.
  EXPECT_LE(double(clamped), 0.12 * double(both));
}

// The same oracle on the octree with contours (esvo §5.2): slabs follow the
// surface inside each voxel, so the grazing-angle depth error of cubes is
// gone and the plain criterion holds: >= 99.5 % hit/miss agreement and >= 99 %
// of common hits within two voxel diagonals of Embree's distance.
class ContourMeshOracle : public ::testing::TestWithParam<const char*> {};

TEST_P(ContourMeshOracle, DepthWithinTwoVoxelDiagonalsOfEmbree) {
  const std::filesystem::path path = kMeshes / GetParam();
  ASSERT_TRUE(std::filesystem::exists(path)) << path;
  const Mesh mesh = load_mesh(path);
  const VoxelSet voxels = voxelize(mesh, GridTransform::fit(mesh.bounds(), 2048), {});
  esvo::BuildOptions bo;
  bo.contours = true;
  auto octree = std::make_shared<esvo::EsvoOctree>(esvo::build_octree(voxels, mesh, bo));
  const esvo::EsvoStructure structure(octree);
  // 512x384: the automatic camera keeps the whole mesh in view, so the mesh
  // covers 8-35 % of the image; this size keeps ~10^4-10^5 common hits.
  RenderOptions ro;
  ro.width = 512;
  ro.height = 384;
  ro.camera = Camera::frame(mesh.bounds(), ro.width, ro.height);
  ro.lod_pixels = 0.f;
  ro.want_depth = true;
  const RenderResult vr = render(structure, ro);
  const EmbreeScene embree(mesh);
  const auto er = embree.render_depth(ro.camera, ro.width, ro.height, EmbreeScene::Mode::Single);
  const float tol = 2.f * std::sqrt(3.f) * float(octree->grid.voxel_size);
  size_t agree = 0, both = 0, close = 0;
  const size_t n = size_t(ro.width) * ro.height;
  for (size_t i = 0; i < n; ++i) {
    const float dv = vr.depth.pixels[i], de = er.depth.pixels[i];
    agree += std::isfinite(dv) == std::isfinite(de);
    if (!(std::isfinite(dv) && std::isfinite(de))) continue;
    ++both;
    close += std::fabs(dv - de) <= tol;
  }
  std::printf(
      "%s with contours: hit/miss agreement %.3f%%, depth within 2 voxel diagonals %.3f%%\n",
      GetParam(), 100.0 * double(agree) / double(n),
      100.0 * double(close) / double(std::max<size_t>(both, 1)));
  EXPECT_GT(both, n / 20);
  EXPECT_GE(double(agree), 0.995 * double(n));
  EXPECT_GE(double(close), 0.99 * double(both));
}

INSTANTIATE_TEST_SUITE_P(SharedMeshes, ContourMeshOracle, voxcast::testing::all_shared_meshes(),
                         voxcast::testing::mesh_test_name);

INSTANTIATE_TEST_SUITE_P(SharedMeshes, MeshOracle, voxcast::testing::all_shared_meshes(),
                         voxcast::testing::mesh_test_name);

}  // namespace
}  // namespace voxcast
