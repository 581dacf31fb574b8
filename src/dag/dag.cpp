// SparseVoxelDag validation, derived voxel index (Hitchhiker's guide,
// "Dynamic voxel indexing" with the prefix sums in the parent), statistics
// (svdag Table 2) and decoding. Layout in dag.hpp.
#include "voxcast/dag.hpp"

#include <bit>
#include <cmath>
#include <string>

#include "voxcast/error.hpp"

namespace voxcast::dag {
namespace {

[[noreturn]] void corrupt(const std::string& what) {
  throw Error("corrupt DAG: " + what);
}

inline uint64_t leaf_mask(const uint32_t* w) {
  return uint64_t(w[0]) | uint64_t(w[1]) << 32;
}

}  // namespace

void SparseVoxelDag::finalize() {
  const int L = grid.levels;
  if (L < 2 || L > kMaxGridLevels)
    corrupt("depth " + std::to_string(L) + " is outside 2.." + std::to_string(kMaxGridLevels));
  if (grid.resolution != (1u << L)) corrupt("resolution is not 2^levels");
  if (!(grid.voxel_size > 0) || !std::isfinite(grid.voxel_size) || !is_finite(grid.origin))
    corrupt("bad grid placement");
  const size_t n = words.size();
  if (n == 0) corrupt("no nodes");
  if (n > 0xFFFFFFFFull) corrupt("more than 2^32 words");

  // Level by level from the root: the nodes of level l must be exactly the
  // targets of the level l-1 pointers, laid out back to back right after
  // level l-1. mark[w] = l + 1 for a word referenced by a level l-1 pointer.
  std::vector<uint8_t> mark(n, 0);
  mark[0] = 1;
  uint64_t expected = 1;  // distinct nodes referenced for the level being scanned
  level_start.assign(size_t(L), 0);
  size_t s = 0;
  for (int l = 0; l <= L - 2; ++l) {
    level_start[size_t(l)] = uint32_t(s);
    const uint8_t tag = uint8_t(l + 1);
    const bool leaf = l == L - 2;
    uint64_t next_expected = 0;
    for (uint64_t k = 0; k < expected; ++k) {
      if (s >= n) corrupt("level " + std::to_string(l) + " runs past the end (truncated)");
      if (mark[s] != tag)
        corrupt("word " + std::to_string(s) + " of level " + std::to_string(l) +
                " is not the start of a node referenced from the level above "
                "(a gap, or a pointer into a node or to the wrong level)");
      const size_t size = leaf ? 2 : 1 + size_t(std::popcount(words[s] & 0xFFu));
      if (s + size > n) corrupt("node at word " + std::to_string(s) + " is truncated");
      for (size_t j = 1; j < size; ++j)
        if (mark[s + j] != 0)
          corrupt("a pointer points into the middle of the node at word " + std::to_string(s));
      if (leaf) {
        if (leaf_mask(&words[s]) == 0) corrupt("empty leaf mask at word " + std::to_string(s));
      } else {
        const uint32_t h = words[s];
        if ((h & 0xFFu) == 0) corrupt("empty child mask at word " + std::to_string(s));
        if (h & kReservedHeaderBits)
          corrupt("reserved header bits set at word " + std::to_string(s));
        for (size_t j = 1; j < size; ++j) {
          const uint32_t p = words[s + j];
          // Strictly forward, past the node itself: no pointer chain can cycle.
          if (p < s + size)
            corrupt("pointer at word " + std::to_string(s + j) + " points backward to " +
                    std::to_string(p) + " (would allow a cycle)");
          if (p >= n)
            corrupt("pointer at word " + std::to_string(s + j) + " is out of range (" +
                    std::to_string(p) + " >= " + std::to_string(n) + ")");
          if (mark[p] == 0) {
            mark[p] = uint8_t(tag + 1);
            ++next_expected;
          } else if (mark[p] != tag + 1) {
            corrupt("pointer at word " + std::to_string(s + j) +
                    " targets a node of another level");
          }
        }
      }
      s += size;
    }
    expected = next_expected;
  }
  if (s != n) corrupt(std::to_string(n - s) + " trailing words are not reachable from the root");
  level_start[size_t(L - 1)] = uint32_t(n);

  // Leaf voxel counts bottom-up (children live in later levels): header word
  // = the node's count, pointer word j = count of the children before it.
  voxel_prefix.assign(n, 0);
  for (int l = L - 3; l >= 0; --l) {
    const bool children_are_leaves = l + 1 == L - 2;
    for (size_t w = level_start[size_t(l)]; w < level_start[size_t(l + 1)];) {
      const int k = std::popcount(words[w] & 0xFFu);
      uint64_t sum = 0;
      for (int j = 0; j < k; ++j) {
        const uint32_t p = words[w + 1 + size_t(j)];
        voxel_prefix[w + 1 + size_t(j)] = uint32_t(sum);
        sum +=
            children_are_leaves ? uint64_t(std::popcount(leaf_mask(&words[p]))) : voxel_prefix[p];
      }
      if (sum > 0xFFFFFFFFull) corrupt("more than 2^32 - 1 leaf voxels");
      voxel_prefix[w] = uint32_t(sum);
      w += 1 + size_t(k);
    }
  }
  leaf_voxels = L == 2 ? uint64_t(std::popcount(leaf_mask(&words[0]))) : voxel_prefix[0];

  if (colors.size() != normals.size()) corrupt("color and normal arrays differ in size");
  if (!colors.empty() && colors.size() != leaf_voxels)
    corrupt("attribute arrays hold " + std::to_string(colors.size()) + " voxels, the DAG " +
            std::to_string(leaf_voxels));
}

DagStats SparseVoxelDag::stats() const {
  const int L = grid.levels;
  DagStats st;
  st.levels.resize(size_t(L) + 1);
  // How many times each node occurs in the un-merged octree: propagate
  // multiplicities down, level by level (children come later).
  std::vector<uint64_t> mult(words.size(), 0);
  mult[0] = 1;
  for (int l = 0; l <= L - 2; ++l) {
    LevelStats& ls = st.levels[size_t(l)];
    ls.dag_bytes = uint64_t(level_start[size_t(l + 1)] - level_start[size_t(l)]) * 4;
    const bool leaf = l == L - 2;
    for (size_t w = level_start[size_t(l)]; w < level_start[size_t(l + 1)];) {
      ++ls.dag_nodes;
      ls.svo_nodes += mult[w];
      if (leaf) {
        const uint64_t m = leaf_mask(&words[w]);
        int blocks = 0;
        for (int c = 0; c < 8; ++c) blocks += ((m >> (8 * c)) & 0xFF) != 0;
        st.levels[size_t(L - 1)].svo_nodes += mult[w] * uint64_t(blocks);
        st.levels[size_t(L)].svo_nodes += mult[w] * uint64_t(std::popcount(m));
        w += 2;
      } else {
        const int k = std::popcount(words[w] & 0xFFu);
        for (int j = 0; j < k; ++j) mult[words[w + 1 + size_t(j)]] += mult[w];
        w += 1 + size_t(k);
      }
    }
  }
  st.leaf_voxels = st.levels[size_t(L)].svo_nodes;
  st.dag_bytes = uint64_t(words.size()) * 4;
  for (int l = 0; l < L; ++l) st.svo_nodes += st.levels[size_t(l)].svo_nodes;
  for (const LevelStats& ls : st.levels) st.dag_nodes += ls.dag_nodes;
  st.svo_bytes = st.svo_nodes;
  st.esvo_bytes = st.svo_nodes * 8;
  st.index_bytes = uint64_t(voxel_prefix.size()) * 4;
  st.attribute_bytes = uint64_t(colors.size() + normals.size()) * 4;
  st.bits_per_voxel = st.leaf_voxels ? double(st.dag_bytes) * 8.0 / double(st.leaf_voxels) : 0.0;
  return st;
}

std::vector<uint64_t> SparseVoxelDag::decode_leaves() const {
  std::vector<uint64_t> out;
  out.reserve(size_t(leaf_voxels));
  const int L = grid.levels;
  // Depth-first in child-slot order = ascending Morton order.
  auto visit = [&](auto&& self, uint32_t w, int level, uint64_t code) -> void {
    if (level == L - 2) {
      uint64_t m = leaf_mask(&words[w]);
      while (m) {
        out.push_back(code << 6 | uint64_t(std::countr_zero(m)));
        m &= m - 1;
      }
      return;
    }
    const uint32_t mask = words[w] & 0xFFu;
    int j = 0;
    for (int c = 0; c < 8; ++c)
      if (mask & (1u << c))
        self(self, words[w + 1 + size_t(j++)], level + 1, code << 3 | uint64_t(c));
  };
  visit(visit, 0, 0, 0);
  return out;
}

void SparseVoxelDag::voxel_attributes(uint64_t index, Color* color, Vec3* normal) const {
  if (colors.empty() || index >= colors.size()) {
    *color = {0.5f, 0.5f, 0.5f, 1.f};
    *normal = {0, 0, 1};
    return;
  }
  *color = esvo::decode_color_abgr(colors[size_t(index)]);
  *normal = esvo::decode_normal_cube(normals[size_t(index)]);
}

Aabb occupied_bounds(const SparseVoxelDag& dag, int max_level) {
  const int L = dag.levels();
  const int stop = std::max(0, std::min(max_level, L - 2));
  uint32_t lo[3] = {~0u, ~0u, ~0u}, hi[3] = {0, 0, 0};
  auto visit = [&](auto&& self, uint32_t w, int level, uint32_t x, uint32_t y, uint32_t z) -> void {
    if (level == stop) {
      const uint32_t c[3] = {x, y, z};
      for (int a = 0; a < 3; ++a) lo[a] = std::min(lo[a], c[a]), hi[a] = std::max(hi[a], c[a] + 1);
      return;
    }
    const uint32_t mask = dag.words[w] & 0xFFu;
    int j = 0;
    for (int c = 0; c < 8; ++c)
      if (mask & (1u << c))
        self(self, dag.words[w + 1 + size_t(j++)], level + 1, 2 * x + (c & 1),
             2 * y + ((c >> 1) & 1), 2 * z + ((c >> 2) & 1));
  };
  visit(visit, 0, 0, 0, 0, 0);
  const double cell = dag.grid.side() / double(1u << stop);
  Aabb box;
  box.lo = {float(dag.grid.origin.x + lo[0] * cell), float(dag.grid.origin.y + lo[1] * cell),
            float(dag.grid.origin.z + lo[2] * cell)};
  box.hi = {float(dag.grid.origin.x + hi[0] * cell), float(dag.grid.origin.y + hi[1] * cell),
            float(dag.grid.origin.z + hi[2] * cell)};
  return box;
}

}  // namespace voxcast::dag
