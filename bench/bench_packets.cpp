// Primary and shadow rays per CPU second of the scalar octree caster and of
// the packet casters (voxcast/packet_caster.hpp), and occlusion rays of the
// any-hit packets (voxcast/occlusion_packets.hpp), ESVO and DAG of the bunny
// at 1024^3, one thread, the same rays for every caster. CPU time, not wall
// time: on a shared machine it leaves out the time other processes ran, so
// the casters' ratios stay comparable across runs (voxcast bench measures
// wall time against Embree).
#include <benchmark/benchmark.h>

#include <algorithm>
#include <memory>
#include <string>
#include <vector>

#include "voxcast/camera.hpp"
#include "voxcast/dag.hpp"
#include "voxcast/effects.hpp"
#include "voxcast/esvo.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/occlusion_packets.hpp"
#include "voxcast/packet_caster.hpp"
#include "voxcast/voxelize.hpp"

namespace {

struct Scene {
  std::unique_ptr<voxcast::esvo::EsvoStructure> esvo;
  std::unique_ptr<voxcast::dag::DagStructure> dag;
  std::vector<voxcast::Ray> primary, shadow;  // primary in 4x4 block order
  float pixel_angle = 0;
};

const Scene& scene() {
  static const Scene s = [] {
    using namespace voxcast;
    Scene s;
    const Mesh mesh =
        load_mesh(std::string(VOXCAST_SOURCE_DIR) + "/tests/data/meshes/stanford-bunny.obj");
    const VoxelSet v = voxelize(mesh, GridTransform::fit(mesh.bounds(), 1024), {});
    s.esvo = std::make_unique<esvo::EsvoStructure>(
        std::make_shared<const esvo::EsvoOctree>(esvo::build_octree(v)));
    s.dag = std::make_unique<dag::DagStructure>(
        std::make_shared<const dag::SparseVoxelDag>(dag::build_dag(v)));
    // The automatic camera zoomed in so that about 40 % of the pixels hit.
    constexpr int w = 512, h = 384;
    Camera cam = Camera::frame(s.esvo->bounds(), w, h);
    cam.fovy_degrees *= 0.55f;
    const CameraRays cr(cam, w, h);
    s.pixel_angle = cr.pixel_angle();
    std::vector<uint32_t> order;
    block_order(0, 0, w, h, &order);
    const Vec3 to_light = normalize(Vec3{0.3f, 1.f, 0.5f});
    TraceContext ctx;
    for (uint32_t xy : order) {
      const Ray r = cr.ray(int(xy & 0xFFFF), int(xy >> 16));
      s.primary.push_back(r);
      SurfaceHit hit;
      if (s.esvo->trace(r, LodFootprint{}, ctx, &hit))
        s.shadow.push_back({hit.position + to_light * (2.f * hit.voxel_size), to_light, INFINITY});
    }
    return s;
  }();
  return s;
}

// Arg 0: 0 = scalar, 1 = packet AVX2, 2 = packet AVX-512; arg 1: LOD pixels.
template <class S>
void run(benchmark::State& state, const S& s, bool shadow) {
  using namespace voxcast;
  const Scene& sc = scene();
  const std::vector<Ray>& rays = shadow ? sc.shadow : sc.primary;
  const int caster = int(state.range(0));
  if (caster == 2 && !cpu_supports(Isa::Avx512)) {
    state.SkipWithError("no AVX-512");
    return;
  }
  LodFootprint lod;
  lod.size_per_t = float(state.range(1)) * sc.pixel_angle;
  std::vector<SurfaceHit> hits(rays.size());
  std::vector<uint8_t> found(rays.size());
  const Isa isa = caster == 2 ? Isa::Avx512 : Isa::Avx2;
  TraceContext ctx;
  for (auto _ : state) {
    for (size_t b = 0; b < rays.size(); b += 256) {  // a 16x16 tile's worth per call
      const size_t n = std::min<size_t>(256, rays.size() - b);
      if (caster == 0) {
        for (size_t i = b; i < b + n; ++i)
          found[i] = shadow ? s.occluded(rays[i], lod, ctx) : s.trace(rays[i], lod, ctx, &hits[i]);
      } else if (shadow) {
        occluded_packets(s, rays.data() + b, n, lod, found.data() + b, isa);
      } else {
        trace_packets(s, rays.data() + b, n, lod, hits.data() + b, found.data() + b, isa);
      }
    }
    benchmark::DoNotOptimize(found.data());
  }
  state.SetItemsProcessed(int64_t(state.iterations()) * int64_t(rays.size()));
}

void BM_PrimaryEsvo(benchmark::State& st) {
  run(st, *scene().esvo, false);
}
void BM_PrimaryDag(benchmark::State& st) {
  run(st, *scene().dag, false);
}
void BM_ShadowEsvo(benchmark::State& st) {
  run(st, *scene().esvo, true);
}
void BM_ShadowDag(benchmark::State& st) {
  run(st, *scene().dag, true);
}
#define PACKET_ARGS ArgsProduct({{0, 1, 2}, {0, 1}})->Unit(benchmark::kMillisecond)
BENCHMARK(BM_PrimaryEsvo)->PACKET_ARGS;
BENCHMARK(BM_PrimaryDag)->PACKET_ARGS;
BENCHMARK(BM_ShadowEsvo)->ArgsProduct({{0, 1, 2}, {0}})->Unit(benchmark::kMillisecond);
BENCHMARK(BM_ShadowDag)->ArgsProduct({{0, 1, 2}, {0}})->Unit(benchmark::kMillisecond);

/// The shading point of the ESVO's LOD 0 hit of `r` (voxel normal facing
/// the viewer), as the effects see it; false on a miss.
bool shading_point(const Scene& sc, const voxcast::Ray& r, voxcast::TraceContext& ctx,
                   voxcast::ShadingPoint* p) {
  using namespace voxcast;
  SurfaceHit hit;
  if (!sc.esvo->trace(r, LodFootprint{}, ctx, &hit)) return false;
  Color c;
  Vec3 n;
  sc.esvo->attributes(hit, ctx, &c, &n);
  if (dot(n, r.dir) > 0.f) n = -n;
  *p = {hit.position, n, r.dir, hit.voxel_size};
  return true;
}

/// Not a timing: the scalar caster's loop counters (TraceContext::counting)
/// per ray of the primary rays, of shadow rays from the effects' offset
/// origins (offset_origin: 2 voxels along the normal, 1 back along the view;
/// towards the light, above the horizon) and of the same shadow rays with
/// tmax = 0 (the descent to the origin's cube; a hit = an origin inside an
/// occupied voxel), and the lane use of 16-ray groups in block order
/// (sum of the rays' iterations over 16 x the group's longest).
/// docs/BENCHMARKS.md "Shadow rays: why 0.06x". Arg: 0 = ESVO, 1 = DAG.
void BM_RayCounters(benchmark::State& state) {
  using namespace voxcast;
  const Scene& sc = scene();
  const SurfaceQuery& s = state.range(0) == 0 ? static_cast<const SurfaceQuery&>(*sc.esvo)
                                              : static_cast<const SurfaceQuery&>(*sc.dag);
  const Vec3 to_light = normalize(Vec3{0.3f, 1.f, 0.5f});
  std::vector<Ray> shadow;
  TraceContext ctx;
  for (const Ray& r : sc.primary) {
    ShadingPoint p;
    if (shading_point(sc, r, ctx, &p) && dot(to_light, p.normal) > 0.f)
      shadow.push_back({offset_origin(p), to_light, INFINITY});
  }
  std::vector<Ray> descent = shadow;
  for (Ray& r : descent) r.tmax = 0.f;
  auto count = [&](const char* name, const std::vector<Ray>& rays, bool occlusion) {
    TraceContext c;
    c.counting = true;
    RayCounters total;
    uint64_t hits = 0, sum = 0, packed = 0, longest = 0;
    for (size_t i = 0; i < rays.size(); ++i) {
      c.counters = RayCounters{};
      SurfaceHit h;
      hits += occlusion ? s.transmittance(rays[i], LodFootprint{}, c) == 0.f
                        : s.trace(rays[i], LodFootprint{}, c, &h);
      total += c.counters;
      sum += c.counters.iterations;
      longest = std::max<uint64_t>(longest, c.counters.iterations);
      if (i % 16 == 15 || i + 1 == rays.size()) packed += 16 * longest, longest = 0;
    }
    const double n = double(std::max<size_t>(rays.size(), 1));
    const std::string k(name);
    state.counters[k + "_rays"] = double(rays.size());
    state.counters[k + "_hits"] = double(hits);
    state.counters[k + "_iterations"] = double(total.iterations) / n;
    state.counters[k + "_pushes"] = double(total.pushes) / n;
    state.counters[k + "_advances"] = double(total.advances) / n;
    state.counters[k + "_pops"] = double(total.pops) / n;
    state.counters[k + "_fetches"] = double(total.descriptor_fetches) / n;
    state.counters[k + "_lane_use"] = packed ? double(sum) / double(packed) : 0.0;
  };
  for (auto _ : state) {
    count("primary", sc.primary, false);
    count("shadow", shadow, true);
    count("descent", descent, true);
  }
  state.SetLabel(state.range(0) == 0 ? "esvo" : "dag");
}
BENCHMARK(BM_RayCounters)->Arg(0)->Arg(1)->Iterations(1);

// ---- Occlusion packets (voxcast/occlusion_packets.hpp) ----

// The AO rays the effects generate for the ESVO's hits (16 per point,
// radius 5 % of the diagonal), point-major, and one normal per point.
struct AoRays {
  std::vector<voxcast::Ray> rays;
  std::vector<voxcast::Vec3> normals;
};
class AoRecorder final : public voxcast::Occluder {
 public:
  float transmittance(const voxcast::Ray& ray, const voxcast::LodFootprint&, voxcast::TraceContext&,
                      const voxcast::BeamStart*) const override {
    rays->push_back(ray);
    return 1.f;
  }
  std::vector<voxcast::Ray>* rays;
};
const AoRays& ao_rays() {
  static const AoRays a = [] {
    using namespace voxcast;
    const Scene& sc = scene();
    AoRays a;
    EffectOptions fx;
    fx.ao_rays = 16;
    fx.packets = false;  // the recorder sees the rays one by one
    const float radius = 0.05f * length(sc.esvo->bounds().extent());
    AoRecorder rec;
    rec.rays = &a.rays;
    TraceContext ctx;
    for (size_t i = 0; i < sc.primary.size(); ++i) {
      ShadingPoint p;
      if (!shading_point(sc, sc.primary[i], ctx, &p)) continue;
      ambient_occlusion(rec, ctx, p, fx, radius, uint32_t(i), nullptr);
      a.normals.push_back(p.normal);
    }
    return a;
  }();
  return a;
}

// Arg 0: 0 = scalar occluded(), 1 = occluded_packets (the shadow rays by
// parallel walks, AnyHitOptions::parallel), 2 = occluded_anyhit's lane kernel
// from the root (AO: in point groups, AnyHitOptions::group), 3 =
// occluded_anyhit with the per-ray deep start, 4 = the same with a cull of 24 fetches, 5 = the
// packets' shared paths (DeepStart::Packet), 6 = the same with path_share 0.5; arg 1: 0 = AVX2, 1 =
// AVX-512; arg 2: 0 = shadow rays, 1 = AO rays (point-major).
template <class S>
void run_occlusion(benchmark::State& state, const S& s) {
  using namespace voxcast;
  const int caster = int(state.range(0));
  const Isa isa = state.range(1) == 1 ? Isa::Avx512 : Isa::Avx2;
  const bool ao = state.range(2) == 1;
  if (!cpu_supports(isa)) {
    state.SkipWithError("ISA not supported");
    return;
  }
  const std::vector<Ray>& rays = ao ? ao_rays().rays : scene().shadow;
  std::vector<uint8_t> occ(rays.size());
  TraceContext ctx;
  AnyHitOptions o;
  o.isa = isa;
  const size_t chunk = 256;  // 16 points' AO rays, or a 16x16 tile's shadow rays
  AnyHitStats stats;
  for (auto _ : state) {
    for (size_t b = 0; b < rays.size(); b += chunk) {
      const size_t n = std::min(chunk, rays.size() - b);
      if (caster == 0) {
        for (size_t i = b; i < b + n; ++i) occ[i] = s.occluded(rays[i], LodFootprint{}, ctx);
      } else if (caster == 1) {
        occluded_packets(s, rays.data() + b, n, LodFootprint{}, occ.data() + b, isa);
      } else {
        o.group = ao ? 16 : 0;  // point-major: one point's rays per group
        o.normals = o.group > 0 ? ao_rays().normals.data() + b / 16 : nullptr;
        o.deep_start = caster == 5   ? DeepStart::Packet
                       : caster >= 3 ? DeepStart::PerRay
                                     : DeepStart::Off;
        o.cull_budget = caster == 4 ? 24 : 0;
        o.path_share = caster == 6 ? 0.5f : 1.f;
        o.parallel = false;  // the lane kernel (casters 2..6)
        occluded_anyhit(s, rays.data() + b, n, LodFootprint{}, occ.data() + b, o, &stats);
      }
    }
    benchmark::DoNotOptimize(occ.data());
  }
  state.SetItemsProcessed(int64_t(state.iterations()) * int64_t(rays.size()));
  // What the deep starts did, per ray traced (not a timing).
  if (stats.rays > 0) {
    state.counters["per_ray_levels"] = double(stats.depth_sum) / double(stats.rays);
    state.counters["path_levels_per_ray"] =
        double(stats.path_levels) * packet_width(isa) / double(stats.rays);
  }
}

void BM_OcclusionEsvo(benchmark::State& st) {
  run_occlusion(st, *scene().esvo);
}
void BM_OcclusionDag(benchmark::State& st) {
  run_occlusion(st, *scene().dag);
}
BENCHMARK(BM_OcclusionEsvo)
    ->ArgsProduct({{0, 1, 2, 3, 4, 5, 6}, {0, 1}, {0, 1}})
    ->Unit(benchmark::kMillisecond);
BENCHMARK(BM_OcclusionDag)
    ->ArgsProduct({{0, 1, 2, 3, 4, 5, 6}, {0, 1}, {0, 1}})
    ->Unit(benchmark::kMillisecond);

}  // namespace
