// Shadows and ambient occlusion (svdag §4, Laine & Karras 2010b): against
// Embree occlusion rays on the source mesh, ESVO against DAG, and analytic
// scenes (flat plane without acne, an occluder, an open plane, a box corner).
#include <gtest/gtest.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <random>
#include <vector>

#include "support/esvo_testing.hpp"
#include "support/shared_meshes.hpp"
#include "voxcast/dag.hpp"
#include "voxcast/effects.hpp"
#include "voxcast/embree_reference.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/render.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast {
namespace {

const std::filesystem::path kMeshes = std::filesystem::path(VOXCAST_TEST_DATA_DIR) / "meshes";

class EmbreeOccluder final : public Occluder {
 public:
  explicit EmbreeOccluder(const EmbreeScene& s) : s_(s) {}
  bool occluded(const Ray& ray, const LodFootprint&) const override { return s_.occluded(ray); }

 private:
  const EmbreeScene& s_;
};

// ESVO and DAG built from the same voxels.
struct Scene {
  Mesh mesh;
  VoxelSet voxels;
  std::unique_ptr<esvo::EsvoStructure> esvo;
  std::unique_ptr<dag::DagStructure> dag;
};

Scene make_scene(Mesh mesh, uint32_t resolution) {
  Scene s;
  s.mesh = std::move(mesh);
  s.voxels = voxelize(s.mesh, GridTransform::fit(s.mesh.bounds(), resolution), VoxelizeOptions{});
  s.esvo = std::make_unique<esvo::EsvoStructure>(
      std::make_shared<esvo::EsvoOctree>(esvo::build_octree(s.voxels)));
  s.dag = std::make_unique<dag::DagStructure>(
      std::make_shared<dag::SparseVoxelDag>(dag::build_dag(s.voxels)));
  return s;
}

// Triangles of a parallelogram corner + a*e1 + b*e2, a, b in [0, 1].
void add_quad(Mesh* m, Vec3 corner, Vec3 e1, Vec3 e2) {
  const uint32_t base = uint32_t(m->positions.size());
  const Vec3 n = normalize(cross(e1, e2));
  for (Vec3 p : {corner, corner + e1, corner + e1 + e2, corner + e2}) {
    m->positions.push_back(p);
    m->normals.push_back(n);
  }
  for (uint32_t i : {0u, 1u, 2u, 0u, 2u, 3u}) m->indices.push_back(base + i);
}

// ---- Against Embree on the shared meshes ----
//
// For every pixel where both the voxels and the mesh are hit, the shading
// point is Embree's hit (position), with the voxel normal of the same pixel
// and the leaf voxel size as offset scale, so both ray casters answer the very
// same occlusion rays and only the geometry differs.

struct Agreement {
  size_t pixels = 0, hard_agree = 0, dag_equal = 0, beam_equal = 0, shadowed = 0;
  double ao_diff = 0, soft_diff = 0, corners_diff = 0, mean_ao = 0;
};

Agreement compare_with_embree(const Scene& s, int W, int H) {
  const EmbreeScene embree(s.mesh);
  const EmbreeOccluder eocc(embree);
  const StructureOccluder vocc(*s.esvo), docc(*s.dag);
  const Camera camera = Camera::frame(s.mesh.bounds(), W, H);
  const CameraRays cam(camera, W, H);
  const Aabb b = s.mesh.bounds();
  const float diag = length(b.extent());
  const float voxel = float(s.voxels.grid.voxel_size);

  EffectOptions hard;
  hard.shadows = ShadowMode::Hard;
  // Grazing light from the side: much of the visible surface is lit by rays
  // that pass close to other parts of the mesh (a light from behind the
  // camera would leave little in shadow and make agreement trivial).
  const Vec3 light_dir = normalize(Vec3{0.8f, -0.3f, -0.3f});
  EffectOptions soft;
  soft.shadows = ShadowMode::Soft;
  soft.light = LightKind::Area;
  soft.light_position = b.center() + Vec3{-1.2f, 0.8f, 0.5f} * diag;
  soft.area_u = Vec3{0.15f, 0, 0} * diag;
  soft.area_v = Vec3{0, 0, 0.15f} * diag;
  soft.shadow_rays = 16;
  EffectOptions soft_off = soft, soft_corners = soft;
  soft_off.shadow_beam = ShadowBeam::Off;
  soft_corners.shadow_beam = ShadowBeam::Corners;
  EffectOptions ao;
  ao.ao_rays = 64;
  const float radius = 0.1f * diag;

  std::vector<int> used(size_t(W) * H, 0), hard_ok(used.size(), 0), dag_ok(used.size(), 0),
      beam_ok(used.size(), 0), in_shadow(used.size(), 0);
  std::vector<float> ao_e(used.size(), 0);
  std::vector<double> ao_d(used.size(), 0), soft_d(used.size(), 0), corners_d(used.size(), 0);
  tbb::parallel_for(0, H, [&](int y) {
    for (int x = 0; x < W; ++x) {
      const size_t i = size_t(y) * W + x;
      const Ray ray = cam.ray(x, y);
      const float te = embree.intersect(ray);
      SurfaceHit hit;
      if (!std::isfinite(te) || !s.esvo->trace(ray, LodFootprint{}, &hit)) continue;
      Color c;
      Vec3 n;
      s.esvo->attributes(hit, &c, &n);
      if (dot(n, ray.dir) > 0.f) n = -n;
      const ShadingPoint p{ray.origin + ray.dir * te, n, ray.dir, voxel};
      const uint32_t seed = pixel_seed(x, y, 0);
      used[i] = 1;
      const float he = shadow_visibility(eocc, p, hard, light_dir, seed, nullptr);
      const float hv = shadow_visibility(vocc, p, hard, light_dir, seed, nullptr);
      const float hd = shadow_visibility(docc, p, hard, light_dir, seed, nullptr);
      hard_ok[i] = he == hv;
      in_shadow[i] = he == 0.f && dot(light_dir, n) < 0.f;  // blocked by a ray, not by the horizon
      const float se = shadow_visibility(eocc, p, soft, light_dir, seed, nullptr);
      const float sv = shadow_visibility(vocc, p, soft, light_dir, seed, nullptr);
      const float sv_off = shadow_visibility(vocc, p, soft_off, light_dir, seed, nullptr);
      const float sd = shadow_visibility(docc, p, soft, light_dir, seed, nullptr);
      const float sc = shadow_visibility(vocc, p, soft_corners, light_dir, seed, nullptr);
      soft_d[i] = std::fabs(se - sv);
      corners_d[i] = std::fabs(sc - sv);
      beam_ok[i] = sv == sv_off;
      const float ae = ambient_occlusion(eocc, p, ao, radius, seed, nullptr);
      const float av = ambient_occlusion(vocc, p, ao, radius, seed, nullptr);
      const float ad = ambient_occlusion(docc, p, ao, radius, seed, nullptr);
      ao_d[i] = std::fabs(ae - av);
      ao_e[i] = ae;
      dag_ok[i] = hv == hd && sv == sd && av == ad;
    }
  });
  Agreement a;
  for (size_t i = 0; i < used.size(); ++i) {
    if (!used[i]) continue;
    ++a.pixels;
    a.hard_agree += hard_ok[i];
    a.shadowed += in_shadow[i];
    a.mean_ao += ao_e[i];
    a.dag_equal += dag_ok[i];
    a.beam_equal += beam_ok[i];
    a.ao_diff += ao_d[i];
    a.soft_diff += soft_d[i];
    a.corners_diff += corners_d[i];
  }
  if (a.pixels)
    a.mean_ao /= double(a.pixels), a.ao_diff /= double(a.pixels), a.soft_diff /= double(a.pixels),
        a.corners_diff /= double(a.pixels);
  return a;
}

class EffectsOracle : public ::testing::TestWithParam<const char*> {};

TEST_P(EffectsOracle, OcclusionMatchesEmbree) {
  const std::filesystem::path path = kMeshes / GetParam();
  ASSERT_TRUE(std::filesystem::exists(path)) << path;
  const Scene s = make_scene(load_mesh(path), 1024);
  const Agreement a = compare_with_embree(s, 160, 120);
  const double hard = double(a.hard_agree) / double(a.pixels);
  std::printf(
      "%s 1024^3, 160x120, %zu shaded pixels (%.1f%% in cast hard shadow, Embree mean AO %.3f): "
      "hard shadow mask agreement %.3f%%, soft (16 rays) mean |diff| %.4f, AO (64 rays, "
      "R = 10%% diag) mean |diff| %.4f; corner-ray beam vs exact mean |diff| %.4f\n",
      GetParam(), a.pixels, 100.0 * double(a.shadowed) / double(a.pixels), a.mean_ao, 100.0 * hard,
      a.soft_diff, a.ao_diff, a.corners_diff);
  // The automatic camera keeps the whole mesh in view: spot covers ~2600 pixels.
  ASSERT_GT(a.pixels, 2000u);
  // Not a trivial agreement: some pixels are in cast shadow, AO is not all 1
  // (measured: bunny 11.0% / 0.966, spot 1.1% / 0.981).
  EXPECT_GT(a.shadowed, a.pixels / 100);
  EXPECT_LT(a.mean_ao, 0.99);
  // Measured: bunny 99.57% / 0.0053 / 0.0025, spot 99.85% / 0.0012 / 0.0010.
  EXPECT_GE(hard, 0.99);
  EXPECT_LE(a.soft_diff, 0.01);
  EXPECT_LE(a.ao_diff, 0.01);
  // Same voxels -> same answers, ray for ray, whichever structure.
  EXPECT_EQ(a.dag_equal, a.pixels);
  // The conservative beam (svdag §4 via the esvo §6.2 coarse pass) is exact.
  EXPECT_EQ(a.beam_equal, a.pixels);
}

INSTANTIATE_TEST_SUITE_P(SharedMeshes, EffectsOracle,
                         ::testing::Values("stanford-bunny.obj", "spot.obj"),
                         voxcast::testing::mesh_test_name);

// ---- The DAG's any-hit caster (4^3 blocks decided at once, early exit past
// tmax) answers exactly what its closest-hit loop and the ESVO answer ----

// Rays of every kind: random; short and long; from voxel corners, edge
// midpoints and centers along small-integer directions (rays exactly through
// grid edges and corners, where the loop's tie rules decide); axis-aligned;
// from inside occupied space; with and without a LOD cone.
TEST(Effects, DagAnyHitEqualsClosestHit) {
  std::vector<VoxelSet> sets;
  sets.push_back(testing::make_random_voxels(5, 4000, 7));
  sets.push_back(testing::make_random_voxels(7, 60000, 8));
  sets.push_back(testing::make_sphere_shell(6));
  sets.push_back(testing::make_full_grid(3));
  sets.push_back(
      voxelize(load_mesh(kMeshes / "stanford-bunny.obj"),
               GridTransform::fit(load_mesh(kMeshes / "stanford-bunny.obj").bounds(), 128), {}));
  std::mt19937 rng(977);
  std::uniform_real_distribution<float> u01(0.f, 1.f);
  size_t rays = 0, hits = 0, grid_rays = 0, mismatches = 0;
  for (size_t si = 0; si < sets.size(); ++si) {
    const VoxelSet& set = sets[si];
    const esvo::EsvoStructure e(std::make_shared<esvo::EsvoOctree>(esvo::build_octree(set)));
    const dag::DagStructure d(std::make_shared<dag::SparseVoxelDag>(dag::build_dag(set)));
    const GridTransform& g = set.grid;
    const float side = float(g.side()), voxel = side / float(1u << g.levels);
    auto check = [&](const Ray& ray, const LodFootprint& lod) {
      SurfaceHit hit;
      const bool closest = d.trace(ray, lod, &hit);
      const bool any = d.occluded(ray, lod);
      const bool esvo_any = e.occluded(ray, lod);
      ++rays;
      hits += any;
      if (any != closest || any != esvo_any) {
        if (mismatches++ < 5)
          ADD_FAILURE() << "set " << si << " ray " << ray.origin.x << "," << ray.origin.y << ","
                        << ray.origin.z << " dir " << ray.dir.x << "," << ray.dir.y << ","
                        << ray.dir.z << " tmax " << ray.tmax << ": occluded " << any << ", trace "
                        << closest << ", esvo " << esvo_any;
      }
    };
    const int dirs[][3] = {{1, 1, 0}, {1, 1, 1}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {2, 1, 0},
                           {1, 2, 2}, {3, 1, 1}, {1, 1, 2}, {0, 1, 1}, {1, 0, 1}, {2, 2, 1}};
    for (int i = 0; i < 12000; ++i) {
      Ray ray;
      LodFootprint lod;
      if (i % 2 == 0) {  // random origin around the cube, random direction
        ray.origin = g.origin + Vec3{u01(rng), u01(rng), u01(rng)} * (1.4f * side) -
                     Vec3{0.2f, 0.2f, 0.2f} * side;
        ray.dir = normalize(Vec3{u01(rng) - 0.5f, u01(rng) - 0.5f, u01(rng) - 0.5f});
      } else {  // from a grid point (corner / edge midpoint / center) along an integer direction
        ++grid_rays;
        const uint32_t n = 1u << g.levels;
        auto coord = [&]() { return float(rng() % (n + 1)) + 0.5f * float(rng() % 2); };
        ray.origin = g.origin + Vec3{coord(), coord(), coord()} * voxel;
        const int* k = dirs[rng() % (sizeof dirs / sizeof dirs[0])];
        Vec3 dir{float(k[0]), float(k[1]), float(k[2])};
        for (int a = 0; a < 3; ++a)
          if (rng() % 2) dir[a] = -dir[a];
        ray.dir = normalize(dir);
      }
      switch (i % 4) {  // segment length: a few voxels (AO), longer, unbounded (shadow)
        case 0:
          ray.tmax = voxel * (0.5f + 6.f * u01(rng));
          break;
        case 1:
          ray.tmax = side * u01(rng);
          break;
        default:
          ray.tmax = INFINITY;
          break;
      }
      if (i % 7 == 3) lod.size_per_t = 0.05f;  // AO cone: the fast path must stay off
      check(ray, lod);
    }
  }
  std::printf("%zu rays (%zu from grid points along integer directions), %zu hits\n", rays,
              grid_rays, hits);
  EXPECT_EQ(mismatches, 0u);
  EXPECT_GT(hits, rays / 5);
  EXPECT_LT(hits, rays * 4 / 5);
}

// ---- Renders: ESVO == DAG, thread-count independence ----

RenderOptions effect_render_options(const Scene& s) {
  RenderOptions ro;
  ro.width = 96;
  ro.height = 72;
  ro.camera = Camera::frame(s.mesh.bounds(), ro.width, ro.height);
  ro.lod_pixels = 0.f;
  const Aabb b = s.mesh.bounds();
  const float diag = length(b.extent());
  ro.effects.shadows = ShadowMode::Soft;
  ro.effects.light = LightKind::Area;
  ro.effects.light_position = b.center() + Vec3{0.5f, 1.2f, 0.4f} * diag;
  ro.effects.area_u = Vec3{0.2f, 0, 0} * diag;
  ro.effects.area_v = Vec3{0, 0.05f, 0.2f} * diag;
  ro.effects.shadow_rays = 9;
  ro.effects.ao_rays = 16;
  ro.effects.ao_radius = 0.08f * diag;
  return ro;
}

TEST(Effects, EsvoAndDagRenderIdenticalEffectImages) {
  const Scene s = make_scene(load_mesh(kMeshes / "stanford-bunny.obj"), 256);
  const RenderOptions ro = effect_render_options(s);
  const RenderResult a = render(*s.esvo, ro);
  const RenderResult b = render(*s.dag, ro);
  ASSERT_EQ(a.ao.pixels.size(), size_t(ro.width) * ro.height);
  ASSERT_EQ(a.shadow.pixels.size(), size_t(ro.width) * ro.height);
  EXPECT_EQ(a.ao.pixels, b.ao.pixels);
  EXPECT_EQ(a.shadow.pixels, b.shadow.pixels);
  EXPECT_GT(a.effect_counters.ao_rays, 0u);
  EXPECT_EQ(a.effect_counters.ao_rays, b.effect_counters.ao_rays);
  // Something is in shadow, something is lit, something is occluded.
  EXPECT_LT(*std::min_element(a.shadow.pixels.begin(), a.shadow.pixels.end()), 0.5f);
  EXPECT_EQ(*std::max_element(a.shadow.pixels.begin(), a.shadow.pixels.end()), 1.f);
  EXPECT_LT(*std::min_element(a.ao.pixels.begin(), a.ao.pixels.end()), 0.8f);
}

TEST(Effects, DeterministicAcrossThreadCounts) {
  const Scene s = make_scene(load_mesh(kMeshes / "spot.obj"), 256);
  RenderOptions ro = effect_render_options(s);
  ro.tile_size = 8;
  const RenderResult many = render(*s.esvo, ro);
  RenderResult one;
  {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, 1);
    one = render(*s.esvo, ro);
  }
  EXPECT_EQ(many.color.pixels, one.color.pixels);
  EXPECT_EQ(many.ao.pixels, one.ao.pixels);
  EXPECT_EQ(many.shadow.pixels, one.shadow.pixels);
  // And a different image seed gives different (noise) samples.
  ro.effects.seed = 7;
  const RenderResult other = render(*s.esvo, ro);
  EXPECT_NE(other.ao.pixels, many.ao.pixels);
}

// ---- Analytic scenes ----

// A tilted square plane (not axis-aligned, so its voxel layer is a staircase).
const Vec3 kPlaneNormal = normalize(Vec3{0.3f, 1.f, 0.2f});
Mesh tilted_plane() {
  Vec3 e1 = normalize(cross(kPlaneNormal, Vec3{0, 0, 1}));
  Vec3 e2 = cross(e1, kPlaneNormal);
  Mesh m;
  add_quad(&m, e1 * -1.f + e2 * -1.f, e1 * 2.f, e2 * 2.f);
  if (dot(normalize(cross(e1, e2)), kPlaneNormal) < 0) std::swap(m.indices[1], m.indices[2]);
  return m;
}

TEST(Effects, FlatLitPlaneHasNoShadowAcne) {
  const Scene s = make_scene(tilted_plane(), 256);
  const StructureOccluder occ(*s.esvo);
  RenderOptions ro;
  ro.width = ro.height = 64;
  ro.camera.eye = kPlaneNormal * 2.f + Vec3{0.4f, 0, 0.3f};
  ro.camera.target = {0, 0, 0};
  ro.camera.fovy_degrees = 40.f;
  ro.lod_pixels = 0.f;
  ro.effects.shadows = ShadowMode::Hard;
  ro.effects.ao_rays = 16;
  ro.effects.ao_radius = 0.3f;
  for (Vec3 light : {-kPlaneNormal, normalize(-kPlaneNormal + Vec3{0.6f, 0, 0}),
                     normalize(-kPlaneNormal + Vec3{0, 0, -1.2f})}) {
    ro.light_dir = light;
    const RenderResult r = render(*s.esvo, ro);
    ASSERT_GT(r.hits, r.rays / 2);
    size_t lit = 0, open = 0;
    for (float v : r.shadow.pixels) lit += v == 1.f;
    for (float v : r.ao.pixels) open += v == 1.f;
    EXPECT_EQ(lit, r.rays) << "shadow acne with light " << light.x << "," << light.y << ","
                           << light.z;
    // An open plane: AO exactly 1 everywhere (every ray leaves into empty space).
    EXPECT_EQ(open, r.rays);
  }
  // The offset is what prevents the acne: starting the shadow rays at the hit
  // itself, a large part of the plane shadows itself.
  const CameraRays cam(ro.camera, ro.width, ro.height);
  size_t naive_blocked = 0, hits = 0;
  for (int y = 0; y < ro.height; ++y)
    for (int x = 0; x < ro.width; ++x) {
      SurfaceHit h;
      if (!s.esvo->trace(cam.ray(x, y), LodFootprint{}, &h)) continue;
      ++hits;
      naive_blocked += occ.occluded(Ray{h.position, kPlaneNormal, INFINITY}, LodFootprint{});
    }
  EXPECT_GT(naive_blocked, hits / 10);
}

TEST(Effects, OccluderCastsFullShadowAndBoxCornerIsOccluded) {
  // Receiver y = 0 over [-1,1]^2, occluder y = 0.5 over [-2,2]^2; the camera
  // sits between them looking down; light straight down (hard) or a small
  // area light above the occluder (soft): every visible receiver pixel is in
  // full shadow.
  Mesh m;
  add_quad(&m, {-1, 0, -1}, {0, 0, 2}, {2, 0, 0});
  add_quad(&m, {-2, 0.5f, -2}, {0, 0, 4}, {4, 0, 0});
  const Scene s = make_scene(m, 256);
  RenderOptions ro;
  ro.width = ro.height = 48;
  ro.camera.eye = {0, 0.35f, 0};
  ro.camera.target = {0.01f, 0, 0};
  ro.camera.up = {0, 0, 1};
  ro.camera.fovy_degrees = 60.f;
  ro.lod_pixels = 0.f;
  ro.light_dir = {0, -1, 0};
  ro.effects.shadows = ShadowMode::Hard;
  for (const VoxelStructure* st : {static_cast<const VoxelStructure*>(s.esvo.get()),
                                   static_cast<const VoxelStructure*>(s.dag.get())}) {
    RenderResult r = render(*st, ro);
    ASSERT_EQ(r.hits, r.rays);
    for (float v : r.shadow.pixels) ASSERT_EQ(v, 0.f) << st->name();
    RenderOptions soft = ro;
    soft.effects.shadows = ShadowMode::Soft;
    soft.effects.light = LightKind::Area;
    soft.effects.light_position = {0, 3, 0};
    soft.effects.area_u = {0.3f, 0, 0};
    soft.effects.area_v = {0, 0, 0.3f};
    r = render(*st, soft);
    for (float v : r.shadow.pixels) ASSERT_EQ(v, 0.f) << st->name();
  }

  // Inside corner of a box: floor y = 0 and walls x = 0, z = 0 over [0,1].
  Mesh box;
  add_quad(&box, {0, 0, 0}, {0, 0, 1}, {1, 0, 0});
  add_quad(&box, {0, 0, 0}, {0, 1, 0}, {0, 0, 1});
  add_quad(&box, {0, 0, 0}, {1, 0, 0}, {0, 1, 0});
  const Scene c = make_scene(box, 256);
  EffectOptions ao;
  ao.ao_rays = 64;
  const float voxel = float(c.voxels.grid.voxel_size);
  auto ao_at = [&](Vec3 p) {
    const ShadingPoint sp{p, {0, 1, 0}, normalize(Vec3{-0.3f, -1, -0.2f}), voxel};
    return ambient_occlusion(StructureOccluder(*c.esvo), sp, ao, 0.2f, 1234u, nullptr);
  };
  const float corner = ao_at({0.05f, 0, 0.05f}), open = ao_at({0.7f, 0, 0.7f});
  std::printf("box corner AO %.3f, open floor AO %.3f\n", corner, open);
  EXPECT_LT(corner, 0.8f);
  EXPECT_EQ(open, 1.f);
  // Near one wall only: in between.
  const float wall = ao_at({0.05f, 0, 0.7f});
  EXPECT_GT(wall, corner);
  EXPECT_LT(wall, 1.f);
  // The cone-angle LOD (svdag §4) never makes AO brighter on this scene.
  ao.ao_cone_angle_deg = 20.f;
  EXPECT_LE(ao_at({0.05f, 0, 0.05f}), corner);
}

TEST(Effects, InvalidOptionsAreOneLineErrors) {
  EffectOptions o;
  o.shadows = ShadowMode::Soft;  // no area light
  EXPECT_THROW(validate(o), Error);
  o = {};
  o.light = LightKind::Area;
  o.area_u = {1, 0, 0};
  o.area_v = {2, 0, 0};  // parallel
  EXPECT_THROW(validate(o), Error);
  o = {};
  o.ao_cone_angle_deg = 90.f;
  EXPECT_THROW(validate(o), Error);
  o = {};
  o.shadow_rays = 0;
  EXPECT_THROW(validate(o), Error);
}

}  // namespace
}  // namespace voxcast
