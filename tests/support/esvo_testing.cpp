// Deterministic VoxelSet generators and an independent top-down ESVO point
// query for tests (see esvo_testing.hpp).
#include "support/esvo_testing.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <random>
#include <unordered_set>

#include "voxcast/error.hpp"
#include "voxcast/morton.hpp"

namespace voxcast::testing {
namespace {

// SplitMix64: a cheap, well-mixed hash so attributes depend only on (code, seed).
uint64_t mix(uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}
float unit_float(uint64_t h) {
  return float(h >> 40) / float(1u << 24);
}  // [0,1)

}  // namespace

GridTransform unit_grid(int levels) {
  GridTransform g;
  g.origin = {0, 0, 0};
  g.levels = levels;
  g.resolution = 1u << levels;
  g.voxel_size = 1.0 / double(g.resolution);
  return g;
}

void fill_random_attributes(VoxelSet& set, uint64_t seed) {
  const size_t n = set.codes.size();
  set.colors.resize(n);
  set.normals.resize(n);
  set.weights.resize(n);
  for (size_t i = 0; i < n; ++i) {
    uint64_t h = mix(set.codes[i] ^ mix(seed));
    set.colors[i] = {unit_float(h), unit_float(mix(h + 1)), unit_float(mix(h + 2)),
                     0.5f + 0.5f * unit_float(mix(h + 3))};
    Vec3 v;
    do {  // rejection-sample a direction so normals are uniform on the sphere
      h = mix(h + 7);
      v = {2 * unit_float(h) - 1, 2 * unit_float(mix(h + 1)) - 1, 2 * unit_float(mix(h + 2)) - 1};
    } while (dot(v, v) > 1.f || dot(v, v) < 1e-4f);
    set.normals[i] = normalize(v);
    set.weights[i] = 0.1f + 1.9f * unit_float(mix(h + 5));
  }
}

VoxelSet make_random_voxels(int levels, size_t count, uint64_t seed) {
  VoxelSet set;
  set.grid = unit_grid(levels);
  const uint64_t total = uint64_t(1) << (3 * levels);
  count = size_t(std::min<uint64_t>(count, total));
  std::mt19937_64 rng(seed);
  if (count * 2 >= total) {  // dense: pick by shuffling all codes
    std::vector<uint64_t> all(total);
    for (uint64_t i = 0; i < total; ++i) all[i] = i;
    std::shuffle(all.begin(), all.end(), rng);
    all.resize(count);
    set.codes = std::move(all);
  } else {
    std::unordered_set<uint64_t> seen;
    while (seen.size() < count) seen.insert(rng() & (total - 1));
    set.codes.assign(seen.begin(), seen.end());
  }
  std::sort(set.codes.begin(), set.codes.end());
  fill_random_attributes(set, seed);
  return set;
}

VoxelSet make_sphere_shell(int levels) {
  VoxelSet set;
  set.grid = unit_grid(levels);
  const double n = double(set.grid.resolution);
  const double c = n * 0.5, r = n * 0.4;
  const uint32_t res = set.grid.resolution;
  // Row by row: for each (y, z) the shell crosses the row in at most two
  // x-intervals |x - c| in [sqrt(max(0,(r-.5)^2 - d^2)), sqrt((r+.5)^2 - d^2)],
  // so the cost is O(N^2 + voxels), not O(N^3).
  for (uint32_t z = 0; z < res; ++z) {
    for (uint32_t y = 0; y < res; ++y) {
      const double dy = y + 0.5 - c, dz = z + 0.5 - c;
      const double d2 = dy * dy + dz * dz;
      const double outer2 = (r + 0.5) * (r + 0.5) - d2;
      if (outer2 < 0) continue;
      const double inner2 = (r - 0.5) * (r - 0.5) - d2;
      const double lo = inner2 > 0 ? std::sqrt(inner2) : 0.0, hi = std::sqrt(outer2);
      const auto emit = [&](double a, double b) {  // x + 0.5 - c in [a, b]
        const int64_t x0 = std::max<int64_t>(0, int64_t(std::ceil(a + c - 0.5)));
        const int64_t x1 = std::min<int64_t>(res - 1, int64_t(std::floor(b + c - 0.5)));
        for (int64_t x = x0; x <= x1; ++x) set.codes.push_back(morton_encode(uint32_t(x), y, z));
      };
      if (lo > 0) {
        emit(-hi, -lo);
        emit(lo, hi);
      } else {
        emit(-hi, hi);  // the row passes through the shell's cap: one interval
      }
    }
  }
  std::sort(set.codes.begin(), set.codes.end());
  set.codes.erase(std::unique(set.codes.begin(), set.codes.end()), set.codes.end());
  const size_t count = set.codes.size();
  set.colors.resize(count);
  set.normals.resize(count);
  set.weights.resize(count);
  for (size_t i = 0; i < count; ++i) {
    const MortonCoord p = morton_decode(set.codes[i]);
    const Vec3 d{float(p.x + 0.5 - c), float(p.y + 0.5 - c), float(p.z + 0.5 - c)};
    set.normals[i] = normalize(d);
    set.colors[i] = {float(p.x) / float(res), float(p.y) / float(res), float(p.z) / float(res),
                     1.f};
    set.weights[i] = 1.f;
  }
  return set;
}

VoxelSet make_dense_grid(int levels,
                         const std::function<bool(uint32_t, uint32_t, uint32_t)>& occupied) {
  VoxelSet set;
  set.grid = unit_grid(levels);
  const uint32_t res = set.grid.resolution;
  for (uint32_t z = 0; z < res; ++z)
    for (uint32_t y = 0; y < res; ++y)
      for (uint32_t x = 0; x < res; ++x)
        if (occupied(x, y, z)) set.codes.push_back(morton_encode(x, y, z));
  std::sort(set.codes.begin(), set.codes.end());
  fill_random_attributes(set, 12345);
  return set;
}

VoxelSet make_full_grid(int levels) {
  return make_dense_grid(levels, [](uint32_t, uint32_t, uint32_t) { return true; });
}

VoxelSet make_placed_case(int levels, size_t count, uint64_t seed, int placement) {
  VoxelSet set = count == SIZE_MAX ? make_full_grid(levels)
                 : count == 0      ? make_sphere_shell(levels)
                                   : make_random_voxels(levels, count, seed);
  const Vec3 origins[] = {{0, 0, 0}, {-3.f, 1.f, 2.f}, {1000.5f, -20.25f, 7.f}};
  const double sides[] = {1.0, 2.0, 0.375};
  set.grid.origin = origins[placement % 3];
  set.grid.voxel_size = sides[placement % 3] / double(set.grid.resolution);
  return set;
}

bool query_leaf(const esvo::EsvoOctree& octree, uint32_t x, uint32_t y, uint32_t z,
                uint32_t* parent_slot, int* child) {
  const int levels = octree.levels();
  uint32_t slot = octree.root_slot();
  for (int depth = 0; depth < levels; ++depth) {
    const int shift = levels - 1 - depth;
    const int i = int((x >> shift) & 1) | int((y >> shift) & 1) << 1 | int((z >> shift) & 1) << 2;
    const uint32_t w0 = octree.slot_ptr(slot)[0];
    const uint32_t valid = esvo::layout::ValidMask::get(w0), leaf = esvo::layout::LeafMask::get(w0);
    if (!(valid & (1u << i))) return false;
    if (leaf & (1u << i)) {
      if (parent_slot) *parent_slot = slot;
      if (child) *child = i;
      return depth == levels - 1;
    }
    // Non-leaf child: its descriptor is the popcount-th of the parent's group.
    uint32_t first = slot + esvo::layout::ChildPointer::get(w0);
    if (esvo::layout::FarBit::test(w0))
      first = uint32_t(int64_t(slot) + int32_t(octree.slot_ptr(first)[0]));
    const uint32_t non_leaf = valid & ~leaf;
    slot = first + uint32_t(std::popcount(non_leaf & ((1u << i) - 1)));
  }
  return false;
}

// Hand-built from the documented layout (an oracle independent of
// esvo::layout), pinned to it:
static_assert((5u << 17 | 1u << 16 | 0xA5u << 8 | 0x21u) ==
              (esvo::layout::ChildPointer::put(5) | esvo::layout::FarBit::put(1) |
               esvo::layout::ValidMask::put(0xA5) | esvo::layout::LeafMask::put(0x21)));
uint32_t desc(uint32_t child_ptr, bool far, uint32_t valid, uint32_t leaf) {
  return child_ptr << 17 | (far ? 1u : 0u) << 16 | valid << 8 | leaf;
}

esvo::EsvoOctree hand_octree(int levels, const std::vector<uint32_t>& descriptors) {
  esvo::EsvoOctree o;
  o.grid = unit_grid(levels);
  o.block_count = 1;
  const uint32_t slots = 1 + uint32_t(descriptors.size());
  o.words.assign(size_t(slots) * 2 + 4, 0);
  o.words[0] = slots * 2;  // page header -> info section (word offset)
  for (size_t i = 0; i < descriptors.size(); ++i) o.words[(i + 1) * 2] = descriptors[i];
  uint32_t* info = &o.words[size_t(slots) * 2];
  info[0] = esvo::kInfoMagic;
  info[1] = uint32_t(-int32_t(slots * 2 - 2));  // info -> first descriptor slot
  info[2] = slots;
  info[3] = 0;
  return o;
}

}  // namespace voxcast::testing
