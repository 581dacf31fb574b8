// Per-hit attribute lookup of the sparse voxel DAG (dag.hpp "Attributes"):
// raw 8 B/voxel arrays vs esvo §5.5 blocks of 16 Morton-order voxels
// ("Compressed attributes"). Indices are random, like the hits of a frame
// over a large scene (every lookup a likely cache miss for large DAGs).
// VOXCAST_BENCH_DAG=scene.vxc (a DAG scene with raw attributes) benchmarks
// that scene; otherwise a sphere shell of 2^9 voxels per axis.
#include <benchmark/benchmark.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <map>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "dag/attribute_sum.hpp"
#include "voxcast/dag.hpp"
#include "voxcast/dag_format.hpp"
#include "voxcast/esvo.hpp"
#include "voxcast/isa.hpp"
#include "voxcast/morton.hpp"
#include "voxcast/scene_file.hpp"

namespace {

using voxcast::dag::SparseVoxelDag;

const SparseVoxelDag& bench_dag(bool compressed) {
  static std::map<bool, std::unique_ptr<SparseVoxelDag>> cache;
  auto it = cache.find(compressed);
  if (it != cache.end()) return *it->second;
  auto d = std::make_unique<SparseVoxelDag>();
  if (const char* path = std::getenv("VOXCAST_BENCH_DAG")) {
    *d = voxcast::load_dag_scene(path);
  } else {
    voxcast::VoxelSet set;
    const int L = 9;
    set.grid.levels = L;
    set.grid.resolution = 1u << L;
    set.grid.voxel_size = 1.0 / set.grid.resolution;
    const double n = set.grid.resolution, c = n * 0.5, r = n * 0.4;
    for (uint32_t z = 0; z < set.grid.resolution; ++z)
      for (uint32_t y = 0; y < set.grid.resolution; ++y)
        for (uint32_t x = 0; x < set.grid.resolution; ++x) {
          const double dx = x + 0.5 - c, dy = y + 0.5 - c, dz = z + 0.5 - c;
          const double dist = std::sqrt(dx * dx + dy * dy + dz * dz);
          if (std::fabs(dist - r) <= 0.5) set.codes.push_back(voxcast::morton_encode(x, y, z));
        }
    std::sort(set.codes.begin(), set.codes.end());
    for (uint64_t code : set.codes) {
      const voxcast::MortonCoord p = voxcast::morton_decode(code);
      set.normals.push_back(voxcast::normalize(
          voxcast::Vec3{float(p.x + 0.5 - c), float(p.y + 0.5 - c), float(p.z + 0.5 - c)}));
      set.colors.push_back({float(p.x / n), float(p.y / n), float(p.z / n), 1.f});
      set.weights.push_back(1.f);
    }
    *d = voxcast::dag::build_dag(set);
  }
  if (compressed) d->compress_attributes();
  return *cache.emplace(compressed, std::move(d)).first->second;
}

std::vector<uint64_t> random_indices(uint64_t count, size_t n) {
  std::mt19937_64 rng(7);
  std::vector<uint64_t> out(n);
  for (uint64_t& i : out) i = rng() % count;
  return out;
}

/// ns per voxel_attributes call (one leaf hit's shading lookup).
void BM_DagVoxelAttributes(benchmark::State& state) {
  const SparseVoxelDag& d = bench_dag(state.range(0) != 0);
  const std::vector<uint64_t> idx = random_indices(d.leaf_voxels, 1 << 16);
  size_t k = 0;
  for (auto _ : state) {
    voxcast::Color c;
    voxcast::Vec3 n;
    d.voxel_attributes(idx[k], &c, &n);
    benchmark::DoNotOptimize(c);
    benchmark::DoNotOptimize(n);
    k = (k + 1) & (idx.size() - 1);
  }
  state.SetLabel(state.range(0) ? "compressed" : "raw");
  state.counters["attr_B_per_voxel"] = double(d.stats().attribute_bytes) / double(d.leaf_voxels);
}
BENCHMARK(BM_DagVoxelAttributes)->Arg(0)->Arg(1);

/// ns per mean_attributes call for a LOD hit 3 levels above the leaves
/// (cubes of 8^3 voxels, a surface holds ~100 of them).
void BM_DagMeanAttributesLod3(benchmark::State& state) {
  const SparseVoxelDag& d = bench_dag(state.range(0) != 0);
  const std::vector<uint64_t> idx = random_indices(d.leaf_voxels, 1 << 12);
  std::vector<voxcast::dag::VoxelRange> ranges;
  for (uint64_t i : idx) ranges.push_back(d.cube_range(i, d.levels() - 3));
  size_t k = 0;
  for (auto _ : state) {
    voxcast::Color c;
    voxcast::Vec3 n;
    d.mean_attributes(ranges[k], &c, &n);
    benchmark::DoNotOptimize(c);
    benchmark::DoNotOptimize(n);
    k = (k + 1) & (ranges.size() - 1);
  }
  state.SetLabel(state.range(0) ? "compressed" : "raw");
}
BENCHMARK(BM_DagMeanAttributesLod3)->Arg(0)->Arg(1);

/// ns per coarse (LOD) hit's attributes, `range(0)` levels above the leaves:
/// range(1) = 0 the path without the mean table (cube_range's descent, then
/// mean_attributes), 1 DagStructure::attributes (the table's lookup for cubes
/// of more than kCubeMeanMin voxels at levels <= L-4, dag.hpp `cube_means`,
/// and for every cube at L-3, `fine_means`).
void BM_DagLodHitAttributes(benchmark::State& state) {
  const SparseVoxelDag& d = bench_dag(false);
  const int level = d.levels() - int(state.range(0));
  const bool table = state.range(1) != 0;
  static std::map<const SparseVoxelDag*, std::unique_ptr<voxcast::dag::DagStructure>> structures;
  auto& st = structures[&d];
  if (!st)
    st = std::make_unique<voxcast::dag::DagStructure>(std::shared_ptr<const SparseVoxelDag>(
        std::shared_ptr<const SparseVoxelDag>{}, &d));  // not owned: bench_dag keeps it
  std::vector<voxcast::SurfaceHit> hits;
  for (uint64_t i : random_indices(d.leaf_voxels, 1 << 12)) {
    voxcast::SurfaceHit h{};
    h.voxel_ref = d.cube_range(i, level).first;
    h.level = level;
    hits.push_back(h);
  }
  voxcast::TraceContext ctx;
  size_t k = 0;
  for (auto _ : state) {
    voxcast::Color c;
    voxcast::Vec3 n;
    const voxcast::SurfaceHit& h = hits[k];
    if (table)
      st->attributes(h, ctx, &c, &n);
    else
      d.mean_attributes(d.cube_range(h.voxel_ref, h.level), &c, &n);
    benchmark::DoNotOptimize(c);
    benchmark::DoNotOptimize(n);
    k = (k + 1) & (hits.size() - 1);
  }
  state.SetLabel(table ? "mean table" : "cube_range + mean_attributes");
}
BENCHMARK(BM_DagLodHitAttributes)->ArgsProduct({{1, 2, 3, 4, 5}, {0, 1}});

/// Not a timing: the compression error of the §5.5 blocks over every leaf
/// voxel, compressed vs raw, as counters (docs/BENCHMARKS.md "DAG
/// attributes"): colors as the largest 8-bit sRGB channel difference, normals
/// as the angle in degrees; max, mean, p99 and p99.9 of each.
void BM_DagCompressionErrors(benchmark::State& state) {
  const SparseVoxelDag& raw = bench_dag(false);
  const SparseVoxelDag& cmp = bench_dag(true);
  std::vector<float> color, normal;
  for (auto _ : state) {
    color.assign(raw.leaf_voxels, 0.f);
    normal.assign(raw.leaf_voxels, 0.f);
    for (uint64_t i = 0; i < raw.leaf_voxels; ++i) {
      voxcast::Color cr, cc;
      voxcast::Vec3 nr, nc;
      raw.voxel_attributes(i, &cr, &nr);
      cmp.voxel_attributes(i, &cc, &nc);
      const uint32_t a = voxcast::esvo::encode_color_abgr(cr);
      const uint32_t b = voxcast::esvo::encode_color_abgr(cc);
      int worst = 0;
      for (int shift : {0, 8, 16})
        worst = std::max(worst, std::abs(int(a >> shift & 0xFF) - int(b >> shift & 0xFF)));
      color[i] = float(worst);
      // Chord formula: accurate for the small angles that matter here.
      const double chord = voxcast::length(voxcast::normalize(nr) - voxcast::normalize(nc));
      normal[i] = float(2.0 * std::asin(std::min(1.0, chord / 2.0)) * 180.0 / M_PI);
    }
  }
  const auto report = [&](const char* name, std::vector<float>& v) {
    if (v.empty()) return;
    double sum = 0;
    for (float e : v) sum += e;
    const auto quantile = [&](double q) {
      auto it = v.begin() + std::ptrdiff_t(q * double(v.size() - 1));
      std::nth_element(v.begin(), it, v.end());
      return double(*it);
    };
    state.counters[std::string(name) + "_mean"] = sum / double(v.size());
    state.counters[std::string(name) + "_p99"] = quantile(0.99);
    state.counters[std::string(name) + "_p99.9"] = quantile(0.999);
    state.counters[std::string(name) + "_max"] = double(*std::max_element(v.begin(), v.end()));
  };
  report("color", color);
  report("normal_deg", normal);
  state.counters["voxels"] = double(raw.leaf_voxels);
}
BENCHMARK(BM_DagCompressionErrors)->Iterations(1)->Unit(benchmark::kMillisecond);
// The runtime-dispatched attribute_sum kernel (voxcast/isa.hpp), each ISA
// variant (arg 2 = AVX2, 512 = AVX-512) on 2^16 random voxels (512 KiB).
void BM_AttributeSumKernel(benchmark::State& state) {
  using namespace voxcast;
  const bool avx512 = state.range(0) == 512;
  if (avx512 && !cpu_supports(Isa::Avx512)) {
    state.SkipWithError("no AVX-512");
    return;
  }
  std::mt19937 rng(1);
  std::uniform_real_distribution<float> u(-1, 1);
  std::vector<uint32_t> colors(size_t(1) << 16), normals(colors.size());
  for (size_t i = 0; i < colors.size(); ++i) {
    colors[i] = uint32_t(rng());
    normals[i] = esvo::encode_normal_cube({u(rng), u(rng), u(rng)});
  }
  const auto kernel =
      avx512 ? &dag::detail::avx512::attribute_sum : &dag::detail::avx2::attribute_sum;
  for (auto _ : state)
    benchmark::DoNotOptimize(kernel(colors.data(), normals.data(), 0, colors.size()));
  state.SetItemsProcessed(int64_t(state.iterations()) * int64_t(colors.size()));
}
BENCHMARK(BM_AttributeSumKernel)->Arg(2)->Arg(512)->Unit(benchmark::kMicrosecond);

}  // namespace
