// Octree build throughput (esvo §7.1 builder): leaf voxels per second for a
// one-voxel-thick sphere shell, the typical shape of a voxelized surface.
#include <benchmark/benchmark.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <vector>

#include "voxcast/esvo.hpp"
#include "voxcast/morton.hpp"

namespace {

/// Sphere shell VoxelSet (radius 0.4 N, voxels whose centers are within half
/// a voxel of the sphere) with radial normals; built once per level.
const voxcast::VoxelSet& shell(int levels) {
  static std::map<int, voxcast::VoxelSet> cache;
  auto it = cache.find(levels);
  if (it != cache.end()) return it->second;
  voxcast::VoxelSet set;
  set.grid.levels = levels;
  set.grid.resolution = 1u << levels;
  set.grid.voxel_size = 1.0 / set.grid.resolution;
  const uint32_t n = set.grid.resolution;
  const double c = n * 0.5, r = n * 0.4;
  for (uint32_t z = 0; z < n; ++z)
    for (uint32_t y = 0; y < n; ++y) {
      const double dy = y + 0.5 - c, dz = z + 0.5 - c, d2 = dy * dy + dz * dz;
      const double outer = (r + 0.5) * (r + 0.5) - d2;
      if (outer < 0) continue;
      const double inner = (r - 0.5) * (r - 0.5) - d2;
      const double lo = inner > 0 ? std::sqrt(inner) : 0, hi = std::sqrt(outer);
      for (uint32_t x = uint32_t(std::max(0.0, std::ceil(c - hi - 0.5))); x < n; ++x) {
        const double dx = std::fabs(x + 0.5 - c);
        if (dx > hi) {
          if (x + 0.5 > c) break;
          continue;
        }
        if (dx >= lo) set.codes.push_back(voxcast::morton_encode(x, y, z));
      }
    }
  std::sort(set.codes.begin(), set.codes.end());
  for (uint64_t code : set.codes) {
    const voxcast::MortonCoord p = voxcast::morton_decode(code);
    set.normals.push_back(voxcast::normalize(
        voxcast::Vec3{float(p.x + 0.5 - c), float(p.y + 0.5 - c), float(p.z + 0.5 - c)}));
    set.colors.push_back({float(p.x) / n, float(p.y) / n, float(p.z) / n, 1.f});
    set.weights.push_back(1.f);
  }
  return cache.emplace(levels, std::move(set)).first->second;
}

void BM_BuildOctreeSphereShell(benchmark::State& state) {
  const voxcast::VoxelSet& set = shell(int(state.range(0)));
  size_t bytes = 0;
  for (auto _ : state) {
    voxcast::esvo::EsvoOctree octree = voxcast::esvo::build_octree(set);
    bytes = octree.words.size() * 4;
    benchmark::DoNotOptimize(octree.words.data());
  }
  state.SetItemsProcessed(int64_t(state.iterations()) * int64_t(set.size()));
  state.counters["voxels"] = double(set.size());
  state.counters["bytes_per_voxel"] = double(bytes) / double(set.size());
}
BENCHMARK(BM_BuildOctreeSphereShell)->Arg(9)->Arg(10)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace
