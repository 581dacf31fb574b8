// Primary and shadow rays per CPU second of the scalar octree caster and of
// the packet casters (voxcast/packet_caster.hpp), ESVO and DAG of the bunny
// at 1024^3, one thread, the same rays for every caster. CPU time, not wall
// time: on a shared machine it leaves out the time other processes ran, so
// the casters' ratios stay comparable across runs (voxcast bench measures
// wall time against Embree).
#include <benchmark/benchmark.h>

#include <memory>
#include <string>
#include <vector>

#include "voxcast/camera.hpp"
#include "voxcast/dag.hpp"
#include "voxcast/esvo.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/mesh.hpp"
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

}  // namespace
