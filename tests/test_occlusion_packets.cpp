// Any-hit packets, their deep start and the AO cull
// (voxcast/occlusion_packets.hpp) against the scalar caster they must
// reproduce: occluded_anyhit == occluded() on every ray, for the ESVO (raw
// and compressed attributes, far pointers, contours) and the DAG built from
// a shipped mesh, on random rays (inside and outside the root, along grid
// planes, tiny components, non-finite input), on clusters of independent
// rays whose origins lie close together (packets that start deep and whose
// rays leave the start cube), on groups of rays sharing an origin (random
// points, origins on grid planes, normals some rays violate), and on the
// shadow and AO rays the effects generate for real shading points, for every
// kernel ISA this CPU runs, deep start with and without the cull and every
// ray from the root, and on runs of parallel rays through the shared walks
// (AnyHitOptions::parallel); and renders with effects through the packets are
// byte-identical to one ray at a time.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "support/octree_rays.hpp"
#include "support/octree_scenes.hpp"
#include "support/packet_testing.hpp"
#include "support/test_data.hpp"
#include "voxcast/camera.hpp"
#include "voxcast/dag.hpp"
#include "voxcast/effects.hpp"
#include "voxcast/esvo.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/occlusion_packets.hpp"
#include "voxcast/packet_caster.hpp"
#include "voxcast/render.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast {
namespace {

using Scenes = testing::OctreeScenes;
const Scenes& scenes() {
  return testing::spot_octree_scenes();
}

// Independent rays around the grid's cube, world space.
std::vector<Ray> random_rays(const GridTransform& grid, size_t n, uint64_t seed) {
  testing::OctreeRayRng rng(seed, 8);
  const float side = float(grid.side());
  std::vector<Ray> rays;
  for (size_t i = 0; i < n; ++i) {
    Vec3 o{rng.uni(-0.5f, 1.5f), rng.uni(-0.5f, 1.5f), rng.uni(-0.5f, 1.5f)};
    Vec3 d = rng.sphere();
    switch (rng.pick(5)) {
      case 0:  // aimed at a point inside
        d = normalize(Vec3{rng.uni(0.2f, 0.8f), rng.uni(0.2f, 0.8f), rng.uni(0.2f, 0.8f)} - o);
        break;
      case 1: {  // along an axis, on grid planes
        const int a = rng.pick(3);
        d = {0, 0, 0};
        d[a] = rng.pick(2) ? 1.f : -1.f;
        o[(a + 1) % 3] = rng.grid_line() - 1.f, o[(a + 2) % 3] = rng.grid_line() - 1.f;
        break;
      }
      case 2:  // a tiny component
        d[rng.pick(3)] = rng.uni(-1e-9f, 1e-9f);
        d = normalize(d);
        break;
      default:
        break;
    }
    Ray r{grid.origin + o * side, d, INFINITY};
    if (rng.pick(3) == 0) r.tmax = rng.uni(0.f, 0.5f) * side;
    if (i % 997 == 5) r.origin.x = NAN;
    if (i % 991 == 7) r.dir.y = INFINITY;
    rays.push_back(r);
  }
  return rays;
}

// Groups of `g` rays sharing an origin (AO-like: short, in a hemisphere),
// with one normal per group. Origins: random inside the cube, some on grid
// planes (ties of the deep start's descent), some near the cube's faces; a
// few groups have a ray below their normal's horizon (the half-space cull
// must notice and not use it), a few have long or infinite rays.
struct Groups {
  std::vector<Ray> rays;
  std::vector<Vec3> normals;
};
Groups random_groups(const GridTransform& grid, size_t count, int g, uint64_t seed) {
  testing::OctreeRayRng rng(seed, 8);
  const float side = float(grid.side());
  Groups out;
  for (size_t k = 0; k < count; ++k) {
    Vec3 o{rng.uni(0.05f, 0.95f), rng.uni(0.05f, 0.95f), rng.uni(0.05f, 0.95f)};
    if (rng.pick(3) == 0) o[rng.pick(3)] = rng.grid_line() - 1.f;
    if (rng.pick(4) == 0) o[rng.pick(3)] = rng.uni(0.f, 0.02f);
    const Vec3 n = rng.sphere();
    const float radius = rng.uni(0.002f, 0.15f) * side;
    const bool rogue = rng.pick(8) == 0;
    for (int i = 0; i < g; ++i) {
      Vec3 d = rng.sphere();
      if (dot(d, n) < 0.f && !(rogue && i == g / 2)) d = -d;
      float len = radius * std::sqrt(rng.uni(0.f, 1.f));
      if (rng.pick(50) == 0) len = rng.pick(2) ? INFINITY : 2.f * side;
      out.rays.push_back({grid.origin + o * side, d, len});
    }
    out.normals.push_back(n);
  }
  return out;
}

// Clusters of 16 independent rays (one packet each) whose origins lie in a
// small box inside the cube (some on grid planes, some in the same voxel),
// random directions, most of them long: the packets start deep and most of
// their rays leave the start cube.
std::vector<Ray> random_clusters(const GridTransform& grid, size_t count, uint64_t seed) {
  testing::OctreeRayRng rng(seed, 8);
  const float side = float(grid.side());
  std::vector<Ray> rays;
  for (size_t k = 0; k < count; ++k) {
    const Vec3 c{rng.uni(0.1f, 0.9f), rng.uni(0.1f, 0.9f), rng.uni(0.1f, 0.9f)};
    const float extent = rng.uni(0.f, 1.f) < 0.3f ? 0.f : rng.uni(0.001f, 0.05f);
    for (int i = 0; i < 16; ++i) {
      Vec3 o = c + Vec3{rng.uni(0.f, extent), rng.uni(0.f, extent), rng.uni(0.f, extent)};
      if (rng.pick(6) == 0) o[rng.pick(3)] = rng.grid_line() - 1.f;
      Vec3 d = rng.sphere();
      if (rng.pick(8) == 0) {  // along an axis
        d = {0, 0, 0};
        d[rng.pick(3)] = rng.pick(2) ? 1.f : -1.f;
      }
      Ray r{grid.origin + o * side, d, INFINITY};
      if (rng.pick(4) == 0) r.tmax = rng.uni(0.f, 0.3f) * side;
      rays.push_back(r);
    }
  }
  return rays;
}

template <class S>
std::vector<uint8_t> scalar_answers(const S& s, const std::vector<Ray>& rays,
                                    const LodFootprint& lod) {
  std::vector<uint8_t> want(rays.size());
  TraceContext ctx;
  for (size_t i = 0; i < rays.size(); ++i) want[i] = s.occluded(rays[i], lod, ctx);
  return want;
}

// occluded_anyhit == occluded() on every ray, each ISA: the per-ray deep
// start with the cull and alone, the packets' shared paths, every ray from
// the root. Returns the stats of the per-ray deep start with the cull on
// AVX2 (8-ray packets), with path_levels from the packet paths there;
// *occluded_count (may be null): the rays the scalar caster finds occluded.
template <class S>
AnyHitStats expect_same(const S& s, const std::vector<Ray>& rays, const LodFootprint& lod,
                        int group, const Vec3* normals, const std::string& what,
                        size_t* occluded_count = nullptr) {
  const std::vector<uint8_t> want = scalar_answers(s, rays, lod);
  size_t occluded = 0;
  for (uint8_t w : want) occluded += w;
  if (occluded_count != nullptr) *occluded_count = occluded;
  // Both answers must occur, or the comparison says little.
  EXPECT_GT(occluded, 0u) << what;
  EXPECT_LT(occluded, rays.size()) << what;
  AnyHitStats stats;
  for (const Isa isa : testing::packet_isas()) {
    for (const int variant : {0, 1, 2, 3, 4}) {
      static const char* const names[] = {" per-ray deep+cull", " per-ray deep", " packet paths",
                                          " root", " parallel walks + root"};
      static const DeepStart starts[] = {DeepStart::PerRay, DeepStart::PerRay, DeepStart::Packet,
                                         DeepStart::Off, DeepStart::Off};
      AnyHitOptions o;
      o.group = group, o.normals = normals, o.deep_start = starts[variant], o.isa = isa;
      o.cull_budget = variant == 0 ? 24 : 0;
      o.parallel = variant == 4;  // the lane kernel alone in the others
      std::vector<uint8_t> got(rays.size(), 7);
      AnyHitStats st;
      occluded_anyhit(s, rays.data(), rays.size(), lod, got.data(), o, &st);
      if (variant == 0 && isa == Isa::Avx2) stats = st;
      if (variant == 2 && isa == Isa::Avx2) stats.path_levels = st.path_levels;
      if (variant == 4 && isa == Isa::Avx2) stats.parallel_rays = st.parallel_rays;
      if (variant >= 2) {
        EXPECT_EQ(st.deep_rays, 0u) << what;
      }
      if (variant < 4 || group != 0) {
        EXPECT_EQ(st.parallel_rays, 0u) << what;
      }
      size_t bad = 0;
      for (size_t i = 0; i < rays.size(); ++i)
        if (got[i] != want[i] && ++bad <= 5)
          ADD_FAILURE() << what << " " << isa_name(isa) << names[variant] << " ray " << i << ": "
                        << int(got[i]) << " want " << int(want[i]);
      EXPECT_EQ(bad, 0u) << what << " " << isa_name(isa) << names[variant];
    }
  }
  return stats;
}

void print_stats(const std::string& what, const AnyHitStats& st) {
  const double mean = st.rays ? double(st.depth_sum) / double(st.rays) : 0.0;
  std::printf(
      "%s: culled %llu of %llu groups; %llu of %llu rays started deep, %.2f levels; "
      "packet paths %llu levels\n",
      what.c_str(), (unsigned long long)st.culled, (unsigned long long)st.points,
      (unsigned long long)st.deep_rays, (unsigned long long)st.rays, mean,
      (unsigned long long)st.path_levels);
}

template <class S>
void check_random(const S& s, const char* name) {
  const Scenes& sc = scenes();
  const std::vector<Ray> rnd = random_rays(sc.grid, 20000, 5);
  expect_same(s, rnd, LodFootprint{}, 0, nullptr, std::string(name) + " random");
  LodFootprint lod;
  lod.size_at_origin = float(sc.grid.voxel_size) * 3.f;
  lod.size_per_t = 0.01f;
  expect_same(s, rnd, lod, 0, nullptr, std::string(name) + " random lod");
  // Clusters: packets that start deep, rays that leave the start cube (a
  // ray started deep that misses has left it: its start cube lies strictly
  // inside the root, and only a hit ends a ray before the root's exit).
  const std::vector<Ray> cl = random_clusters(sc.grid, 1200, 21);
  size_t occluded = 0;
  const AnyHitStats cs =
      expect_same(s, cl, LodFootprint{}, 0, nullptr, std::string(name) + " clusters", &occluded);
  EXPECT_GT(cs.deep_rays, cs.rays / 3) << name;
  EXPECT_GT(cs.deep_rays, occluded + cs.rays / 10) << name;
  EXPECT_GT(cs.depth_sum, cs.deep_rays) << name;  // more than a level on average
  EXPECT_GT(cs.path_levels, cs.rays / 16) << name;
  print_stats(std::string(name) + " clusters", cs);
  expect_same(s, cl, lod, 0, nullptr, std::string(name) + " clusters lod");
  const Groups g = random_groups(sc.grid, 1500, 16, 9);
  const AnyHitStats st =
      expect_same(s, g.rays, LodFootprint{}, 16, g.normals.data(), std::string(name) + " groups");
  // The deep start and the cull must actually have run on these groups.
  EXPECT_GT(st.deep_rays, st.rays / 4) << name;
  EXPECT_GT(st.culled, 0u) << name;
  print_stats(std::string(name) + " groups", st);
  expect_same(s, g.rays, lod, 16, g.normals.data(), std::string(name) + " groups lod");
  // Groups of 5 (not a divisor of the queue) without normals.
  const Groups g5 = random_groups(sc.grid, 600, 5, 13);
  expect_same(s, g5.rays, LodFootprint{}, 5, nullptr, std::string(name) + " groups of 5");
}

// Runs of parallel rays (AnyHitOptions::parallel): each run one direction
// (random, along an axis with a signed zero, tiny components) and origins
// spread over the cube, in a small patch (shadow rays of a surface patch),
// on grid planes, outside the cube, some with short, zero or infinite tmax
// and a few non-finite; runs of 1 to 600 rays, so that both the walks (at
// least kParallelRun rays) and the lane kernel between them answer.
std::vector<Ray> parallel_runs(const GridTransform& grid, size_t count, uint64_t seed) {
  testing::OctreeRayRng rng(seed, 8);
  const float side = float(grid.side());
  std::vector<Ray> rays;
  for (size_t k = 0; k < count; ++k) {
    Vec3 d = rng.sphere();
    const int kind = rng.pick(6);
    if (kind == 0) {  // along an axis, the other components signed zeros
      const int a = rng.pick(3);
      d = {rng.signed_zero(), rng.signed_zero(), rng.signed_zero()};
      d[a] = rng.pick(2) ? 1.f : -1.f;
    } else if (kind == 1) {  // a tiny component
      d[rng.pick(3)] = rng.uni(-1e-9f, 1e-9f);
      d = normalize(d);
    }
    const int n = rng.pick(5) == 0 ? 1 + rng.pick(20) : 16 + rng.pick(600);
    const Vec3 c{rng.uni(0.1f, 0.9f), rng.uni(0.1f, 0.9f), rng.uni(0.1f, 0.9f)};
    const float extent = rng.pick(2) ? rng.uni(0.002f, 0.1f) : 1.f;
    for (int i = 0; i < n; ++i) {
      Vec3 o = extent < 1.f
                   ? c + Vec3{rng.uni(0.f, extent), rng.uni(0.f, extent), rng.uni(0.f, extent)}
                   : Vec3{rng.uni(-0.3f, 1.3f), rng.uni(-0.3f, 1.3f), rng.uni(-0.3f, 1.3f)};
      if (rng.pick(5) == 0) o[rng.pick(3)] = rng.grid_line() - 1.f;
      Ray r{grid.origin + o * side, d, INFINITY};
      if (rng.pick(4) == 0) r.tmax = rng.uni(0.f, 0.3f) * side;
      if (rng.pick(200) == 0) r.tmax = 0.f;
      if (rng.pick(500) == 0) r.origin.z = rng.pick(2) ? NAN : INFINITY;
      rays.push_back(r);
    }
  }
  return rays;
}

template <class S>
void check_parallel(const S& s, const char* name) {
  const Scenes& sc = scenes();
  const std::vector<Ray> rays = parallel_runs(sc.grid, 160, 33);
  const AnyHitStats st =
      expect_same(s, rays, LodFootprint{}, 0, nullptr, std::string(name) + " parallel");
  // Most rays are in runs the walks take.
  EXPECT_GT(st.parallel_rays, rays.size() * 3 / 4) << name;
  EXPECT_LT(st.parallel_rays, rays.size()) << name;
  LodFootprint lod;
  lod.size_at_origin = float(sc.grid.voxel_size) * 2.f;
  lod.size_per_t = 0.02f;
  expect_same(s, rays, lod, 0, nullptr, std::string(name) + " parallel lod");
}

TEST(OcclusionPackets, ParallelWalksEqualScalarOccluded) {
  check_parallel(*scenes().esvo, "esvo");
  check_parallel(*scenes().esvo_far, "esvo far");
  check_parallel(*scenes().esvo_contours, "esvo contours");
  check_parallel(*scenes().dag, "dag");
}

TEST(OcclusionPackets, EsvoEqualsScalarOccluded) {
  check_random(*scenes().esvo, "esvo");
}
TEST(OcclusionPackets, EsvoCompressedEqualsScalarOccluded) {
  check_random(*scenes().esvo_compressed, "esvo compressed");
}
TEST(OcclusionPackets, EsvoFarPointersEqualScalarOccluded) {
  ASSERT_GT(scenes().esvo_far->octree().memory_stats().far_pointer_bytes, 0u);
  check_random(*scenes().esvo_far, "esvo far");
}
TEST(OcclusionPackets, EsvoContoursEqualScalarOccluded) {
  check_random(*scenes().esvo_contours, "esvo contours");
}
TEST(OcclusionPackets, DagEqualsScalarOccluded) {
  check_random(*scenes().dag, "dag");
}

// Records the rays the effects trace (in batches, as with packets on).
class Recorder final : public Occluder {
 public:
  float transmittance(const Ray& ray, const LodFootprint&, TraceContext&,
                      const BeamStart*) const override {
    rays.push_back(ray);
    return 1.f;
  }
  void transmittance_batch(const Ray* r, size_t n, const LodFootprint&, TraceContext&, float* out,
                           int group, const Vec3* normals) const override {
    for (size_t i = 0; i < n; ++i) rays.push_back(r[i]), out[i] = 1.f;
    if (group > 0 && normals != nullptr) this->normals.push_back(*normals);
  }
  mutable std::vector<Ray> rays;
  mutable std::vector<Vec3> normals;
};

// The shadow (directional) and AO rays of the shading points of a camera
// view, as shadow_visibility_batch / ambient_occlusion generate them.
template <class S>
void check_effect_rays(const S& s, const char* name) {
  const int W = 64, H = 48;
  const CameraRays cam(Camera::orbit(s.bounds(), W, H, 30.f, 20.f), W, H);
  std::vector<ShadingPoint> pts;
  std::vector<uint32_t> seeds;
  TraceContext ctx;
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      const Ray r = cam.ray(x, y);
      SurfaceHit hit;
      if (!s.trace(r, LodFootprint{}, ctx, &hit)) continue;
      Color c;
      Vec3 n;
      s.attributes(hit, ctx, &c, &n);
      if (dot(n, r.dir) > 0.f) n = -n;
      pts.push_back({hit.position, n, r.dir, hit.voxel_size});
      seeds.push_back(pixel_seed(x, y, 0));
    }
  ASSERT_GT(pts.size(), 200u) << name;
  EffectOptions fx;
  fx.shadows = ShadowMode::Hard;
  fx.ao_rays = 16;
  const float radius = 0.05f * length(s.bounds().extent());
  Recorder shadow, ao;
  std::vector<float> vis(pts.size());
  const Vec3 light_dir = normalize(Vec3{-0.4f, -1.f, -0.3f});
  shadow_visibility_batch(shadow, ctx, pts.data(), int(pts.size()), fx, light_dir, seeds.data(),
                          nullptr, vis.data());
  for (size_t i = 0; i < pts.size(); ++i)
    ambient_occlusion(ao, ctx, pts[i], fx, radius, seeds[i], nullptr);
  ASSERT_EQ(ao.rays.size(), pts.size() * 16);
  ASSERT_EQ(ao.normals.size(), pts.size());
  size_t occluded = 0;
  const AnyHitStats sh = expect_same(s, shadow.rays, LodFootprint{}, 0, nullptr,
                                     std::string(name) + " shadow", &occluded);
  // The shadow packets start deep, and their unoccluded rays leave the
  // start cube; with parallel walks on, the walks take every shadow ray (one
  // direction, one run).
  EXPECT_GT(sh.deep_rays, sh.rays / 2) << name;
  EXPECT_GT(sh.deep_rays, occluded) << name;
  EXPECT_GT(sh.path_levels, 0u) << name;
  EXPECT_EQ(sh.parallel_rays, shadow.rays.size()) << name;
  print_stats(std::string(name) + " shadow", sh);
  // What the effects trace them with (Structure::transmittance_batch):
  // occluded_packets, the any-hit packets.
  for (const std::vector<Ray>* rays : {&shadow.rays, &ao.rays}) {
    const std::vector<uint8_t> want = scalar_answers(s, *rays, LodFootprint{});
    for (const Isa isa : testing::packet_isas()) {
      std::vector<uint8_t> got(rays->size(), 7);
      occluded_packets(s, rays->data(), rays->size(), LodFootprint{}, got.data(), isa);
      EXPECT_EQ(got, want) << name << " occluded_packets " << isa_name(isa);
    }
  }
  const AnyHitStats st =
      expect_same(s, ao.rays, LodFootprint{}, 16, ao.normals.data(), std::string(name) + " ao");
  EXPECT_GT(st.deep_rays, st.rays / 2) << name;
  print_stats(std::string(name) + " AO", st);
}

TEST(OcclusionPackets, EffectRaysEqualScalarOccluded) {
  check_effect_rays(*scenes().esvo, "esvo");
  check_effect_rays(*scenes().esvo_contours, "esvo contours");
  check_effect_rays(*scenes().dag, "dag");
}

// Renders with hard shadows (directional and point light) and AO: the
// packet path (effects packets on, the default) gives the same bytes as one
// ray at a time, and the frame's effect counters agree.
TEST(OcclusionPackets, EffectImagesAreByteIdenticalToTheScalarPath) {
  const Scenes& sc = scenes();
  RenderOptions ro;
  ro.width = 80;
  ro.height = 60;
  ro.camera = Camera::orbit(sc.mesh.bounds(), ro.width, ro.height, 40.f, 25.f);
  ro.lod_pixels = 0.f;
  ro.effects.shadows = ShadowMode::Hard;
  ro.effects.ao_rays = 16;
  const Vec3 c = sc.mesh.bounds().center();
  const float diag = length(sc.mesh.bounds().extent());
  const Structure* structures[] = {sc.esvo.get(), sc.esvo_contours.get(), sc.dag.get()};
  for (const Structure* st : structures) {
    for (const LightKind light : {LightKind::Directional, LightKind::Point}) {
      for (const int beam : {0, 4}) {
        ro.effects.light = light;
        ro.effects.light_position = c + Vec3{0.4f, 1.1f, 0.3f} * diag;
        ro.beam = beam;
        ro.effects.packets = false;
        const RenderResult a = render(*st, ro);
        ro.effects.packets = true;
        const RenderResult b = render(*st, ro);
        const std::string what = st->name() + (light == LightKind::Point ? " point" : " dir") +
                                 " beam " + std::to_string(beam);
        ASSERT_EQ(a.color.pixels.size(), size_t(ro.width) * ro.height * 3) << what;
        EXPECT_EQ(a.color.pixels, b.color.pixels) << what;
        EXPECT_EQ(a.shadow.pixels, b.shadow.pixels) << what;
        EXPECT_EQ(a.ao.pixels, b.ao.pixels) << what;
        EXPECT_EQ(a.effect_counters.shadow_rays, b.effect_counters.shadow_rays) << what;
        EXPECT_EQ(a.effect_counters.ao_rays, b.effect_counters.ao_rays) << what;
        // The images show shadow and occlusion, not only light.
        size_t shadowed = 0, dark = 0;
        for (float v : a.shadow.pixels) shadowed += v == 0.f;
        for (float v : a.ao.pixels) dark += v < 1.f;
        EXPECT_GT(shadowed, 20u) << what;
        EXPECT_GT(dark, 30u) << what;
      }
    }
  }
}

}  // namespace
}  // namespace voxcast
