// Bottom-up sparse voxel DAG construction (svdag §3 "Reducing a Sparse Voxel
// Tree to a DAG"): the two lowest levels become 64-bit 4^3 masks, identical
// masks are merged, then each level above is built from the merged ids of
// its children and merged in turn, up to the root.
//
// Merging is the paper's sort-and-compact: the node keys of a level are
// sorted in parallel (tbb::parallel_sort) with the node's position as the
// tie-break, so the order is total and the result is the same for every
// thread count; identical nodes are then adjacent. Unique nodes are numbered
// in order of their first occurrence in Morton order, which keeps the nodes
// a ray visits together close in memory and makes the output a function of
// the voxel set alone.
//
// The bar (optional): the leaf masks and their merge, the levels above
// (units: the nodes each groups, added as they become known), the layout
// and the attributes.
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>

#include <array>
#include <bit>
#include <cstring>
#include <string>
#include <utility>

#include "voxcast/dag.hpp"
#include "voxcast/error.hpp"
#include "voxcast/progress.hpp"
#include "voxcast/system.hpp"

namespace voxcast::dag {
namespace {

// Interior node key: child mask, then the merged ids of the present
// children in slot order, absent slots 0 (so equal keys = equal nodes).
using NodeKey = std::array<uint32_t, 9>;

// Numbers the distinct values of `keys` in order of first occurrence:
// id[i] = number of distinct values among keys[0..first occurrence of keys[i]).
// Returns the positions of the first occurrences (ascending).
template <class Key>
std::vector<uint32_t> merge_identical(const std::vector<Key>& keys, std::vector<uint32_t>* id) {
  const size_t n = keys.size();
  // (key, position) pairs sorted directly (no indirection through `keys`):
  // the pair order is total, so the sorted array does not depend on threads.
  std::vector<std::pair<Key, uint32_t>> sorted(n);
  tbb::parallel_for(size_t(0), n, [&](size_t i) { sorted[i] = {keys[i], uint32_t(i)}; });
  tbb::parallel_sort(sorted.begin(), sorted.end());
  // rep[i] = first occurrence of keys[i] (the smallest position of its group).
  std::vector<uint32_t> rep(n);
  for (size_t g = 0; g < n;) {
    size_t e = g + 1;
    while (e < n && sorted[e].first == sorted[g].first) ++e;
    for (size_t j = g; j < e; ++j) rep[sorted[j].second] = sorted[g].second;
    g = e;
  }
  sorted = {};
  id->resize(n);
  std::vector<uint32_t> firsts;
  for (size_t i = 0; i < n; ++i) {
    if (rep[i] == i) {
      (*id)[i] = uint32_t(firsts.size());
      firsts.push_back(uint32_t(i));
    } else {
      (*id)[i] = (*id)[rep[i]];
    }
  }
  return firsts;
}

}  // namespace

SparseVoxelDag build_dag(const VoxelSet& voxels, Progress* progress) {
  const int L = voxels.grid.levels;
  if (L < 2 || L > kMaxGridLevels)
    throw Error("DAG build: the grid must have 2.." + std::to_string(kMaxGridLevels) +
                " levels (at least 4^3 voxels), not " + std::to_string(L));
  if (voxels.codes.empty()) throw Error("DAG build: no voxels");
  const bool attrs = !voxels.colors.empty();
  if (attrs && (voxels.colors.size() != voxels.size() || voxels.normals.size() != voxels.size()))
    throw Error("DAG build: attribute arrays do not match the voxel count");

  SparseVoxelDag dag;
  dag.grid = voxels.grid;

  // Weights: the phases' shares of the time (measured once on the bunny at
  // 2048^3: masks 0.34 s, levels 0.14 s, layout 0.02 s, attributes 0.81 s).
  if (progress) {
    progress->set_phases(
        {{"leaf masks", 0.27}, {"levels", 0.1}, {"layout", 0.02}, {"attributes", 0.61}});
    progress->start_phase(0, 2);  // the masks, their merge
  }
  // Level L-2: one 64-bit mask per occupied 4^3 block; bit = code & 63.
  std::vector<uint64_t> keys;  // Morton code of each node's cube at its level
  std::vector<uint64_t> masks;
  {
    for (uint64_t code : voxels.codes) {
      const uint64_t k = layout::LeafBlockCode::get(code);
      if (keys.empty() || keys.back() != k) {
        keys.push_back(k);
        masks.push_back(0);
      }
      masks.back() |= 1ull << layout::LeafMaskBit::get(code);
    }
  }
  if (progress) progress->advance();
  // Node positions and ids are 32-bit (merge_identical); the voxel count
  // itself is not limited (64-bit voxel index, dag.hpp).
  if (keys.size() > 0xFFFFFFFFull) throw Error("DAG build: more than 2^32 - 1 leaf-mask nodes");

  // unique_leaf: merged leaf masks; unique_inner[l]: merged interior nodes.
  std::vector<uint32_t> ids;
  std::vector<uint64_t> unique_leaf;
  {
    const std::vector<uint32_t> firsts = merge_identical(masks, &ids);
    unique_leaf.reserve(firsts.size());
    for (uint32_t f : firsts) unique_leaf.push_back(masks[f]);
    masks = {};
  }
  if (progress) progress->start_phase(1, 0);  // (ends the merge of phase 0)
  std::vector<std::vector<NodeKey>> unique_inner(size_t(L - 2));
  for (int l = L - 3; l >= 0; --l) {
    if (progress) progress->add_units(keys.size());
    // Group the level l+1 nodes (sorted by code) under their parents.
    std::vector<uint64_t> parent_keys;
    std::vector<NodeKey> nodes;
    for (size_t i = 0; i < keys.size(); ++i) {
      const uint64_t pk = keys[i] >> 3;
      if (parent_keys.empty() || parent_keys.back() != pk) {
        parent_keys.push_back(pk);
        nodes.push_back(NodeKey{});
      }
      NodeKey& node = nodes.back();
      const uint32_t slot = uint32_t(keys[i] & 7);
      node[0] |= 1u << slot;
      node[1 + slot] = ids[i];
    }
    // Pack the present children first, in slot order (absent = 0 after them).
    tbb::parallel_for(size_t(0), nodes.size(), [&](size_t i) {
      NodeKey& node = nodes[i];
      NodeKey packed{};
      packed[0] = node[0];
      int k = 1;
      for (int s = 0; s < 8; ++s)
        if (node[0] & (1u << s)) packed[size_t(k++)] = node[size_t(1 + s)];
      node = packed;
    });
    std::vector<uint32_t> parent_ids;
    const std::vector<uint32_t> firsts = merge_identical(nodes, &parent_ids);
    auto& uniq = unique_inner[size_t(l)];
    uniq.reserve(firsts.size());
    for (uint32_t f : firsts) uniq.push_back(nodes[f]);
    if (progress) progress->advance(keys.size());
    keys = std::move(parent_keys);
    ids = std::move(parent_ids);
  }

  if (progress) progress->start_phase(2, 1);  // one unit: the layout loops
  // Layout: level 0 (the root) first, each level after the one above, so
  // every child pointer points forward.
  std::vector<std::vector<uint64_t>> node_offset(
      size_t(L - 1));  // word offset of node id in its level
  uint64_t total = 0;
  dag.level_start.assign(size_t(L), 0);
  for (int l = 0; l <= L - 2; ++l) {
    dag.level_start[size_t(l)] = uint32_t(std::min<uint64_t>(total, 0xFFFFFFFFull));
    if (l == L - 2) {
      total += 2 * uint64_t(unique_leaf.size());
    } else {
      auto& offs = node_offset[size_t(l)];
      offs.resize(unique_inner[size_t(l)].size());
      for (size_t i = 0; i < offs.size(); ++i) {
        offs[i] = total;
        total += 1 + uint64_t(std::popcount(unique_inner[size_t(l)][i][0]));
      }
    }
    if (total > 0xFFFFFFFFull) throw Error("DAG build: the DAG exceeds 2^32 words");
  }
  dag.level_start[size_t(L - 1)] = uint32_t(total);
  assign_huge(dag.words, size_t(total), 0u, HugePages::kHot);  // every ray walks them
  for (int l = 0; l < L - 2; ++l) {
    const auto& uniq = unique_inner[size_t(l)];
    const bool children_are_leaves = l + 1 == L - 2;
    const uint32_t child_base = dag.level_start[size_t(l + 1)];
    tbb::parallel_for(size_t(0), uniq.size(), [&](size_t i) {
      uint32_t* w = dag.words.data() + node_offset[size_t(l)][i];
      const NodeKey& node = uniq[i];
      w[0] = node[0];
      const int k = std::popcount(node[0]);
      for (int j = 0; j < k; ++j) {
        const uint32_t child = node[size_t(1 + j)];
        w[1 + j] = children_are_leaves ? child_base + 2 * child
                                       : uint32_t(node_offset[size_t(l + 1)][child]);
      }
    });
  }
  {
    uint32_t* w = dag.words.data() + dag.level_start[size_t(L - 2)];
    tbb::parallel_for(size_t(0), unique_leaf.size(), [&](size_t i) {
      w[2 * i] = uint32_t(unique_leaf[i]);
      w[2 * i + 1] = uint32_t(unique_leaf[i] >> 32);
    });
  }

  if (progress) progress->start_phase(3, 1);  // (ends the layout)
  if (attrs) {
    assign_huge(dag.colors, voxels.size(), 0u);
    assign_huge(dag.normals, voxels.size(), 0u);
    tbb::parallel_for(size_t(0), voxels.size(), [&](size_t i) {
      dag.colors[i] = esvo::encode_color_abgr(voxels.colors[i]);
      dag.normals[i] = esvo::encode_normal_cube(voxels.normals[i]);
    });
  }
  // Validates what was just built and derives the voxel index (cheap, linear).
  dag.finalize();
  if (progress) {
    progress->advance();
    progress->finish();
  }
  return dag;
}

}  // namespace voxcast::dag
