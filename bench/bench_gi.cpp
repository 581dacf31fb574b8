// GI throughput (docs/BENCHMARKS.md "Progressive diffuse GI"): camera
// samples per second of the GI integrator on the ESVO and the DAG of the
// bunny at 512^3 and of the Embree path tracer on the bunny mesh, in the
// same run, with the same sampling math (path_tracer.hpp): 160x120 pixels,
// 4 samples per pixel, the procedural sky and a sun, up to 8 bounces.
// BM_Gi*/cone:N runs the voxel integrator with bounce_cone_deg = N.
#include <benchmark/benchmark.h>

#include <memory>

#include "voxcast/dag.hpp"
#include "voxcast/embree_path.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/gi_integrator.hpp"
#include "voxcast/voxelize.hpp"

namespace {

using namespace voxcast;

constexpr int kW = 160, kH = 120, kSpp = 4;

struct Scene {
  Mesh mesh;
  std::unique_ptr<esvo::EsvoStructure> esvo;
  std::unique_ptr<dag::DagStructure> dag;
  std::unique_ptr<EmbreeScene> embree;
  Camera camera;
  GiOptions options;
};

const Scene& scene() {
  static const Scene s = [] {
    Scene out;
    out.mesh = load_mesh(std::string(VOXCAST_SOURCE_DIR) + "/scenes/bunny.obj");
    const GridTransform grid = GridTransform::fit(out.mesh.bounds(), 512);
    const VoxelSet voxels = voxelize(out.mesh, grid, VoxelizeOptions{});
    out.esvo = std::make_unique<esvo::EsvoStructure>(
        std::make_shared<const esvo::EsvoOctree>(esvo::build_octree(voxels)));
    out.dag = std::make_unique<dag::DagStructure>(
        std::make_shared<const dag::SparseVoxelDag>(dag::build_dag(voxels)));
    out.embree = std::make_unique<EmbreeScene>(out.mesh);
    out.camera = Camera::frame(out.mesh.bounds(), kW, kH);
    out.options.spp = kSpp;
    out.options.environment = std::make_shared<const Environment>(
        procedural_sky(256, 128, normalize(Vec3{-0.4f, -1.f, -0.6f})));
    out.options.sun = true;
    return out;
  }();
  return s;
}

void report(benchmark::State& state, uint64_t samples, uint64_t rays) {
  state.counters["samples/s"] = benchmark::Counter(double(samples), benchmark::Counter::kIsRate);
  state.counters["rays/s"] = benchmark::Counter(double(rays), benchmark::Counter::kIsRate);
}

template <bool Dag>
void BM_GiVoxels(benchmark::State& state) {
  const Scene& s = scene();
  GiOptions o = s.options;
  o.bounce_cone_deg = float(state.range(0));
  const Structure& structure = Dag ? static_cast<const Structure&>(*s.dag) : *s.esvo;
  uint64_t samples = 0, rays = 0;
  for (auto _ : state) {
    const GiResult r = render_gi(structure, s.camera, kW, kH, 1.f, o);
    samples += r.stats.samples, rays += r.stats.rays;
  }
  report(state, samples, rays);
}
// The bounce cones compared: finest level, the default, a coarse one.
void cones(benchmark::internal::Benchmark* b) {
  b->ArgName("cone")->Arg(0)->Arg(1)->Arg(4)->Unit(benchmark::kMillisecond)->UseRealTime();
}
BENCHMARK_TEMPLATE(BM_GiVoxels, false)->Name("BM_GiEsvo")->Apply(cones);
BENCHMARK_TEMPLATE(BM_GiVoxels, true)->Name("BM_GiDag")->Apply(cones);

void BM_GiEmbree(benchmark::State& state) {
  const Scene& s = scene();
  uint64_t samples = 0, rays = 0;
  for (auto _ : state) {
    const EmbreePathResult r = embree_path_trace(*s.embree, s.mesh, s.camera, kW, kH, s.options);
    samples += r.stats.samples, rays += r.stats.rays;
  }
  report(state, samples, rays);
}
BENCHMARK(BM_GiEmbree)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace
