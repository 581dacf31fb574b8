// Voxelization throughput (triangles/s) on the bundled Stanford bunny and on
// a synthetic mesh, with and without attributes.
#include <benchmark/benchmark.h>

#include <cmath>
#include <filesystem>
#include <random>

#include "voxcast/mesh.hpp"
#include "voxcast/voxelize.hpp"

namespace {

using namespace voxcast;

const Mesh& bunny() {
  static const Mesh m =
      load_mesh(std::filesystem::path(VOXCAST_SOURCE_DIR) / "scenes" / "bunny.obj");
  return m;
}

// A wavy height field of 2 * 256^2 triangles over the unit square: many
// similar, mostly non-axis-aligned triangles.
const Mesh& synthetic() {
  static const Mesh m = [] {
    Mesh s;
    const int k = 256;
    for (int j = 0; j <= k; ++j)
      for (int i = 0; i <= k; ++i) {
        float x = float(i) / k, y = float(j) / k;
        float z = 0.5f + 0.1f * std::sin(12 * x) * std::cos(9 * y);
        s.positions.push_back({x, y, z});
        Vec3 n{-1.2f * std::cos(12 * x) * std::cos(9 * y),
               0.9f * std::sin(12 * x) * std::sin(9 * y), 1};
        s.normals.push_back(normalize(n));
      }
    for (int j = 0; j < k; ++j)
      for (int i = 0; i < k; ++i) {
        uint32_t a = uint32_t(j * (k + 1) + i), b = a + 1, c = a + k + 1, d = c + 1;
        s.indices.insert(s.indices.end(), {a, b, d, a, d, c});
      }
    return s;
  }();
  return m;
}

void run(benchmark::State& state, const Mesh& mesh, VoxelizationMode mode, bool attributes) {
  GridTransform g = GridTransform::fit(mesh.bounds(), uint32_t(state.range(0)));
  VoxelizeOptions opt;
  opt.mode = mode;
  opt.attributes = attributes;
  size_t voxels = 0;
  for (auto _ : state) {
    VoxelSet vs = voxelize(mesh, g, opt);
    voxels = vs.size();
    benchmark::DoNotOptimize(vs.codes.data());
  }
  state.counters["triangles/s"] = benchmark::Counter(double(mesh.triangle_count()),
                                                     benchmark::Counter::kIsIterationInvariantRate);
  state.counters["voxels"] = double(voxels);
}

void BM_VoxelizeBunny(benchmark::State& s) {
  run(s, bunny(), VoxelizationMode::Conservative, true);
}
void BM_VoxelizeBunnyCodesOnly(benchmark::State& s) {
  run(s, bunny(), VoxelizationMode::Conservative, false);
}
void BM_VoxelizeBunny6Sep(benchmark::State& s) {
  run(s, bunny(), VoxelizationMode::SixSeparating, true);
}
void BM_VoxelizeSynthetic(benchmark::State& s) {
  run(s, synthetic(), VoxelizationMode::Conservative, true);
}

BENCHMARK(BM_VoxelizeBunny)
    ->Arg(256)
    ->Arg(1024)
    ->Arg(2048)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(BM_VoxelizeBunnyCodesOnly)
    ->Arg(1024)
    ->Arg(2048)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(BM_VoxelizeBunny6Sep)->Arg(2048)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_VoxelizeSynthetic)->Arg(256)->Arg(1024)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace
