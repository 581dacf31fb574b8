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
#include <ostream>
#include <random>
#include <string>
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
// Shading points: every pixel where both the voxels (ESVO) and the mesh are
// hit, at Embree's hit position, with the voxel normal of the same pixel and
// the leaf voxel size as offset scale. Every occluder (Embree on the source
// triangles, the ESVO, the DAG, the negative controls) answers the very same
// shadow and AO rays from these points, so only the geometry differs.

// What README ("Tests", shadows and AO) states for the voxel occluders against
// Embree at 1024^3, for a directional and for a point light: hard shadow masks
// agree on >= 99 % of the shading points and every disagreement lies within
// two voxels of a shadow boundary (near_shadow_boundary below); the mean
// |AO difference| is <= 0.01 and <= 30 % of Embree's mean occlusion (1 - AO).
// Measured 99.28-99.97 % with 0 unexplained disagreements, AO 0.0006-0.0067
// (<= 22 % of the occlusion). Both differences come from the voxel layer's
// thickness (about a voxel either side of the surface) and shrink with the
// voxel size (bunny AO 0.0041 / 0.0025 / 0.0015 at 512 / 1024 / 2048^3), so
// a fixed figure only holds at the resolution it was measured at. (README
// used to claim 99.5 % and 0.003, true of the bunny alone.)
constexpr double kMinMaskAgreement = 0.99;
constexpr double kMaxMeanAoDiff = 0.01;
constexpr double kMaxAoShareOfOcclusion = 0.3;
// Embree must find >= 5 % of the points in cast shadow (a ray blocked, light
// above the horizon) under each light, so that an occluder that never
// occludes misses the mask threshold by >= 4 points instead of passing.
constexpr double kMinShadowed = 0.05;

// The lights, AO and soft-shadow settings, from the framed mesh's bounds.
struct OcclusionSetup {
  Vec3 light_dir;  // directional light (RenderOptions::light_dir convention)
  EffectOptions dir, point, soft, soft_off, soft_corners, ao;
  float ao_radius = 0;
};

OcclusionSetup occlusion_setup(const Aabb& b) {
  const float diag = length(b.extent());
  OcclusionSetup o;
  // Grazing light from the side: much of the visible surface is lit by rays
  // that pass close to other parts of the mesh (a light from behind the
  // camera would leave little in shadow and make agreement trivial).
  o.light_dir = normalize(Vec3{0.8f, -0.3f, -0.3f});
  o.dir.shadows = ShadowMode::Hard;
  // A point light up and to the left, near enough that its rays diverge
  // visibly over the mesh, at the area light's center.
  o.point.shadows = ShadowMode::Hard;
  o.point.light = LightKind::Point;
  o.point.light_position = b.center() + Vec3{-1.2f, 0.8f, 0.5f} * diag;
  o.soft.shadows = ShadowMode::Soft;
  o.soft.light = LightKind::Area;
  o.soft.light_position = o.point.light_position;
  o.soft.area_u = Vec3{0.15f, 0, 0} * diag;
  o.soft.area_v = Vec3{0, 0, 0.15f} * diag;
  o.soft.shadow_rays = 16;
  o.soft_off = o.soft_corners = o.soft;
  o.soft_off.shadow_beam = ShadowBeam::Off;
  o.soft_corners.shadow_beam = ShadowBeam::Corners;
  o.ao.ao_rays = 64;
  o.ao_radius = 0.1f * diag;
  return o;
}

// A rectangular ground plane (normal +y, the framing camera's up) under `m`,
// `gap` below its lowest point, reaching `reach` beyond its bounds in x and
// z: a receiver for the mesh's shadows (and its contact-free AO). Padded to
// keep the mesh's optional per-vertex / per-triangle arrays consistent.
Mesh with_ground_plane(Mesh m, float gap, float reach) {
  const Aabb b = m.bounds();
  const size_t nv = m.positions.size(), nt = m.triangle_count();
  const float y = b.lo.y - gap;
  add_quad(&m, {b.lo.x - reach, y, b.lo.z - reach}, {0, 0, b.hi.z - b.lo.z + 2 * reach},
           {b.hi.x - b.lo.x + 2 * reach, 0, 0});
  if (!m.colors.empty()) m.colors.resize(m.positions.size(), Color{0.8f, 0.8f, 0.8f, 1.f});
  if (!m.uvs.empty()) m.uvs.resize(m.positions.size(), Vec2{0, 0});
  if (!m.triangle_material.empty()) m.triangle_material.resize(m.triangle_count(), 0);
  EXPECT_EQ(m.positions.size(), nv + 4);
  EXPECT_EQ(m.triangle_count(), nt + 2);
  validate_mesh(m);
  return m;
}

struct ShadePoint {
  ShadingPoint p;
  uint32_t seed;
};

std::vector<ShadePoint> shading_points(const Scene& s, const EmbreeScene& embree,
                                       const Camera& camera, int W, int H) {
  const CameraRays cam(camera, W, H);
  const float voxel = float(s.voxels.grid.voxel_size);
  std::vector<ShadePoint> points;
  TraceContext ctx;
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      const Ray ray = cam.ray(x, y);
      const float te = embree.intersect(ray);
      SurfaceHit hit;
      if (!std::isfinite(te) || !s.esvo->trace(ray, LodFootprint{}, ctx, &hit)) continue;
      Color c;
      Vec3 n;
      s.esvo->attributes(hit, ctx, &c, &n);
      if (dot(n, ray.dir) > 0.f) n = -n;
      points.push_back({{ray.origin + ray.dir * te, n, ray.dir, voxel}, pixel_seed(x, y, 0)});
    }
  return points;
}

// One occluder's answers at every shading point. `cast_*`: a shadow ray was
// traced (the light is above the horizon), so a 0 was decided by the occluder.
struct Answers {
  std::vector<float> dir, point, ao, soft, soft_off, soft_corners;
  std::vector<char> cast_dir, cast_point;
};

Answers answer(const Occluder& occ, const std::vector<ShadePoint>& pts, const OcclusionSetup& o,
               bool with_soft) {
  const size_t n = pts.size();
  Answers a;
  a.dir.resize(n), a.point.resize(n), a.ao.resize(n), a.cast_dir.resize(n), a.cast_point.resize(n);
  if (with_soft) a.soft.resize(n), a.soft_off.resize(n), a.soft_corners.resize(n);
  tbb::parallel_for(size_t(0), n, [&](size_t i) {
    const ShadingPoint& p = pts[i].p;
    const uint32_t seed = pts[i].seed;
    TraceContext ctx;
    EffectCounters cd, cp;
    a.dir[i] = shadow_visibility(occ, ctx, p, o.dir, o.light_dir, seed, &cd);
    a.point[i] = shadow_visibility(occ, ctx, p, o.point, o.light_dir, seed, &cp);
    a.cast_dir[i] = cd.shadow_rays > 0;
    a.cast_point[i] = cp.shadow_rays > 0;
    a.ao[i] = ambient_occlusion(occ, ctx, p, o.ao, o.ao_radius, seed, nullptr);
    if (with_soft) {
      a.soft[i] = shadow_visibility(occ, ctx, p, o.soft, o.light_dir, seed, nullptr);
      a.soft_off[i] = shadow_visibility(occ, ctx, p, o.soft_off, o.light_dir, seed, nullptr);
      a.soft_corners[i] =
          shadow_visibility(occ, ctx, p, o.soft_corners, o.light_dir, seed, nullptr);
    }
  });
  return a;
}

// Share of points in cast shadow: a shadow ray was traced and blocked.
double shadowed_share(const std::vector<float>& vis, const std::vector<char>& cast) {
  size_t k = 0;
  for (size_t i = 0; i < vis.size(); ++i) k += cast[i] && vis[i] == 0.f;
  return vis.empty() ? 0.0 : double(k) / double(vis.size());
}

double mean(const std::vector<float>& v) {
  double s = 0;
  for (float x : v) s += x;
  return v.empty() ? 0.0 : s / double(v.size());
}

double mean_abs_diff(const std::vector<float>& a, const std::vector<float>& b) {
  double s = 0;
  for (size_t i = 0; i < a.size(); ++i) s += std::fabs(double(a[i]) - double(b[i]));
  return a.empty() ? 0.0 : s / double(a.size());
}

double equal_share(const std::vector<float>& a, const std::vector<float>& b) {
  size_t k = 0;
  for (size_t i = 0; i < a.size(); ++i) k += a[i] == b[i];
  return a.empty() ? 0.0 : double(k) / double(a.size());
}

// A hard-shadow disagreement the voxel representation explains: a
// conservative voxel layer stands up to sqrt(3) voxels off the surface, so a
// shadow ray that passes that close to the mesh may be blocked by voxels and
// not by triangles (and the two-voxel ray offset moves where it starts).
// Explained = some copy of the ray shifted by at most two voxels (26
// directions, radii 0.5 .. 2 voxels) gets the other answer from Embree, i.e.
// the ray runs within two voxels of a shadow boundary. A disagreement deep in
// a shadow or deep in the light is not explained.
bool near_shadow_boundary(const EmbreeScene& embree, const Ray& ray, float voxel) {
  const bool answer = embree.occluded(ray);
  for (float r : {0.5f, 1.f, 1.5f, 2.f})
    for (int dx = -1; dx <= 1; ++dx)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dz = -1; dz <= 1; ++dz) {
          if (dx == 0 && dy == 0 && dz == 0) continue;
          const Vec3 shift = normalize(Vec3{float(dx), float(dy), float(dz)}) * (r * voxel);
          if (embree.occluded(Ray{ray.origin + shift, ray.dir, ray.tmax}) != answer) return true;
        }
  return false;
}

// The hard shadow ray of `p` (what shadow_visibility traces).
Ray hard_shadow_ray(const ShadingPoint& p, const EffectOptions& o, Vec3 light_dir) {
  const Vec3 origin = offset_origin(p);
  float dist;
  const Vec3 d = direction_to_light(o, light_dir, origin, &dist);
  return Ray{origin, d, dist};
}

// The comparison with Embree that README's statement is about.
struct MaskAgreement {
  double share = 0;        // points with the same hard-shadow answer
  size_t unexplained = 0;  // disagreements not near a shadow boundary
  bool ok() const { return share >= kMinMaskAgreement && unexplained == 0; }
};

struct OcclusionAgreement {
  MaskAgreement dir, point;
  double ao_diff = 0;   // mean |AO difference|
  double ao_bound = 0;  // what it may be: kMaxMeanAoDiff, and a share of Embree's mean occlusion
  bool ao_ok() const { return ao_diff <= ao_bound; }
  bool passes() const { return dir.ok() && point.ok() && ao_ok(); }
};

MaskAgreement compare_mask(const EmbreeScene& embree, const std::vector<ShadePoint>& pts,
                           const EffectOptions& o, Vec3 light_dir, const std::vector<float>& ref,
                           const std::vector<float>& a) {
  MaskAgreement m;
  m.share = equal_share(ref, a);
  for (size_t i = 0; i < pts.size(); ++i)
    if (ref[i] != a[i] &&
        !near_shadow_boundary(embree, hard_shadow_ray(pts[i].p, o, light_dir), pts[i].p.voxel_size))
      ++m.unexplained;
  return m;
}

OcclusionAgreement compare_occlusion(const EmbreeScene& embree, const std::vector<ShadePoint>& pts,
                                     const OcclusionSetup& o, const Answers& reference,
                                     const Answers& a) {
  OcclusionAgreement r;
  r.dir = compare_mask(embree, pts, o.dir, o.light_dir, reference.dir, a.dir);
  r.point = compare_mask(embree, pts, o.point, o.light_dir, reference.point, a.point);
  r.ao_diff = mean_abs_diff(reference.ao, a.ao);
  r.ao_bound = std::min(kMaxMeanAoDiff, kMaxAoShareOfOcclusion * (1.0 - mean(reference.ao)));
  return r;
}

// Negative controls: an occluder whose any-hit answer is fixed (never
// occludes / always occludes). Both must fail the comparison.
class FixedAnswerOccluder final : public Occluder {
 public:
  explicit FixedAnswerOccluder(bool answer) : answer_(answer) {}
  float transmittance(const Ray&, const LodFootprint&, TraceContext&,
                      const BeamStart*) const override {
    return answer_ ? 0.f : 1.f;
  }

 private:
  bool answer_;
};

struct OcclusionCase {
  const char* mesh;
  bool ground;  // add a ground plane (the mesh alone casts too little shadow)
};

// Readable (and stable: no pointer bytes) parameter text in test names.
void PrintTo(const OcclusionCase& c, std::ostream* os) {
  *os << c.mesh << (c.ground ? " + ground plane" : "");
}

class EffectsOracle : public ::testing::TestWithParam<OcclusionCase> {};

TEST_P(EffectsOracle, OcclusionMatchesEmbree) {
  const OcclusionCase& param = GetParam();
  const std::filesystem::path path = kMeshes / param.mesh;
  ASSERT_TRUE(std::filesystem::exists(path)) << path;
  Mesh mesh = load_mesh(path);
  // Camera, lights and AO radius follow the mesh alone, so a ground plane
  // only adds a receiver at the bottom of the frame.
  const Aabb framed = mesh.bounds();
  const float diag = length(framed.extent());
  if (param.ground) mesh = with_ground_plane(std::move(mesh), 0.02f * diag, 0.25f * diag);
  const Scene s = make_scene(std::move(mesh), 1024);
  // 200x150: the automatic camera keeps the whole mesh in view, and the
  // thinnest mesh (armadillo) still gives > 3000 shading points.
  const int W = 200, H = 150;
  // The view frames the central 80 % of the mesh's box: occlusion is what is
  // compared here, and the closer view puts more of the shading points on the
  // mesh and its cast shadow (camel: 4.9 % in cast shadow with the whole box).
  const Vec3 c = framed.center(), half = framed.extent() * 0.4f;
  Aabb view;
  view.extend(c - half);
  view.extend(c + half);
  const Camera camera = Camera::frame(view, W, H);
  const EmbreeScene embree(s.mesh);
  const std::vector<ShadePoint> pts = shading_points(s, embree, camera, W, H);
  const OcclusionSetup o = occlusion_setup(framed);

  const Occluder& eocc = embree;  // the mesh answers through the same interface
  const StructureOccluder vocc(*s.esvo), docc(*s.dag);
  const Answers ref = answer(eocc, pts, o, true);
  const Answers esvo = answer(vocc, pts, o, true);
  const Answers dag = answer(docc, pts, o, true);
  const Answers never = answer(FixedAnswerOccluder(false), pts, o, false);
  const Answers always = answer(FixedAnswerOccluder(true), pts, o, false);
  const OcclusionAgreement ae = compare_occlusion(embree, pts, o, ref, esvo),
                           ad = compare_occlusion(embree, pts, o, ref, dag),
                           an = compare_occlusion(embree, pts, o, ref, never),
                           aa = compare_occlusion(embree, pts, o, ref, always);
  const double shadow_dir = shadowed_share(ref.dir, ref.cast_dir),
               shadow_point = shadowed_share(ref.point, ref.cast_point);
  auto line = [](const char* what, const OcclusionAgreement& a) {
    std::printf(
        "  %-8s masks %.3f%% / %.3f%% (unexplained %zu / %zu), AO mean |diff| %.4f (bound "
        "%.4f)\n",
        what, 100.0 * a.dir.share, 100.0 * a.point.share, a.dir.unexplained, a.point.unexplained,
        a.ao_diff, a.ao_bound);
  };
  std::printf(
      "%s%s 1024^3, %dx%d, %zu shading points; Embree: %.1f%% / %.1f%% in cast shadow "
      "(directional / point), mean AO %.3f (64 rays, R = 10%% diag); ESVO soft (16 rays) mean "
      "|diff| %.4f, corner-ray beam vs exact %.4f\n",
      param.mesh, param.ground ? " + ground plane" : "", W, H, pts.size(), 100.0 * shadow_dir,
      100.0 * shadow_point, mean(ref.ao), mean_abs_diff(ref.soft, esvo.soft),
      mean_abs_diff(esvo.soft_corners, esvo.soft));
  line("ESVO", ae);
  line("DAG", ad);
  line("never", an);
  line("always", aa);
  ASSERT_GT(pts.size(), 3000u);
  // Not a trivial agreement: enough in cast shadow under both lights.
  EXPECT_GE(shadow_dir, kMinShadowed);
  EXPECT_GE(shadow_point, kMinShadowed);
  // README's statement, for both structures.
  EXPECT_TRUE(ae.passes()) << "ESVO vs Embree";
  EXPECT_TRUE(ad.passes()) << "DAG vs Embree";
  // The same comparison rejects both controls, on every criterion.
  EXPECT_FALSE(an.dir.ok() || an.point.ok() || an.ao_ok()) << "never-occluding control passes";
  EXPECT_FALSE(aa.dir.ok() || aa.point.ok() || aa.ao_ok()) << "always-occluding control passes";
  // The voxel layer is thicker than the surface: voxel AO is darker, never
  // brighter on average (a structure that lost voxels would be brighter).
  EXPECT_LE(mean(esvo.ao), mean(ref.ao));
  // Soft shadows (no README figure; the bound the beam modes are judged by).
  EXPECT_LE(mean_abs_diff(ref.soft, esvo.soft), 0.01);
  // Same voxels -> same answers, ray for ray, whichever structure.
  EXPECT_EQ(esvo.dir, dag.dir);
  EXPECT_EQ(esvo.point, dag.point);
  EXPECT_EQ(esvo.ao, dag.ao);
  EXPECT_EQ(esvo.soft, dag.soft);
  // The conservative beam (svdag §4 via the esvo §6.2 coarse pass) is exact.
  EXPECT_EQ(esvo.soft, esvo.soft_off);
  EXPECT_EQ(dag.soft, dag.soft_off);
}

std::string occlusion_case_name(const ::testing::TestParamInfo<OcclusionCase>& info) {
  return voxcast::testing::mesh_test_name({info.param.mesh, info.index});
}

// Every shared mesh. Measured alone (1024^3, this camera and these lights),
// the bunny and the armadillo have >= 7 % of their points in cast shadow
// under both lights; the others 0.3-5.7 % under at least one, so they get a
// ground plane to cast on.
INSTANTIATE_TEST_SUITE_P(
    SharedMeshes, EffectsOracle,
    ::testing::Values(OcclusionCase{"stanford-bunny.obj", false},
                      OcclusionCase{"armadillo.off", false},
                      OcclusionCase{"refined_elephant.off", true}, OcclusionCase{"camel.off", true},
                      OcclusionCase{"fandisk_large.off", true}, OcclusionCase{"spot.obj", true},
                      OcclusionCase{"teapot.obj", true},
                      OcclusionCase{"CesiumMilkTruck/CesiumMilkTruck.gltf", true}),
    occlusion_case_name);

// ---- The DAG's any-hit caster (4^3 blocks decided at once, early exit past
// tmax) answers exactly what its closest-hit loop and the ESVO answer ----

// Rays of every kind: random; short and long; from voxel corners, edge
// midpoints and centers along small-integer directions (rays exactly through
// grid edges and corners, where the loop's tie rules decide); axis-aligned;
// from inside occupied space; with and without a LOD cone.
TEST(Effects, DagAnyHitEqualsClosestHit) {
  TraceContext ctx;
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
      const bool closest = d.trace(ray, lod, ctx, &hit);
      const bool any = d.occluded(ray, lod, ctx);
      const bool esvo_any = e.occluded(ray, lod, ctx);
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
  TraceContext ctx;
  const Scene s = make_scene(tilted_plane(), 256);
  const SurfaceQuery& occ = *s.esvo;
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
      if (!s.esvo->trace(cam.ray(x, y), LodFootprint{}, ctx, &h)) continue;
      ++hits;
      naive_blocked += occ.occluded(Ray{h.position, kPlaneNormal, INFINITY}, LodFootprint{}, ctx);
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
  for (const Structure* st :
       {static_cast<const Structure*>(s.esvo.get()), static_cast<const Structure*>(s.dag.get())}) {
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
    TraceContext ctx;
    return ambient_occlusion(StructureOccluder(*c.esvo), ctx, sp, ao, 0.2f, 1234u, nullptr);
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
