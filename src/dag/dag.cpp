// SparseVoxelDag validation, derived voxel index (Hitchhiker's guide,
// "Dynamic voxel indexing" with the prefix sums in the parent), statistics
// (svdag Table 2) and decoding. Layout in dag.hpp.
#include "voxcast/dag.hpp"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <string>

#include "core/prefetch.hpp"
#include "dag/attribute_sum.hpp"
#include "esvo/compress.hpp"
#include "voxcast/error.hpp"
#include "voxcast/system.hpp"

namespace voxcast::dag {
namespace {

[[noreturn]] void corrupt(const std::string& what) {
  throw Error("corrupt DAG: " + what);
}

inline uint64_t leaf_mask(const uint32_t* w) {
  return uint64_t(w[0]) | uint64_t(w[1]) << 32;
}

// Fixed-point sums of linear r, g, b, a and normal x, y, z of voxels
// [first, first + count): the per-voxel rounding is the only error, the sums
// are exact (|value| <= 2^24, so up to 2^39 voxels fit in 63 bits). Raw
// attributes: the runtime-dispatched kernel in attribute_sum_*.cpp.
using detail::AttributeSum;
using detail::to_fixed;

// The same sums over compressed attributes (dag.hpp): of the decoded values,
// so a LOD mean averages what the leaves show. Per block, the slots in range
// are counted per palette entry (4 colors, 16 normals) and each entry used is
// decoded once and added count times: the same integers as decoding slot by
// slot (esvo.hpp: entries decode to exactly the slots' values), with at most
// 4 + 16 decodes per block instead of 2 x 16.
AttributeSum compressed_sum(const uint32_t* blocks, size_t first, size_t count) {
  constexpr size_t S = SparseVoxelDag::kCompressedSlots, W = SparseVoxelDag::kCompressedBlockWords;
  AttributeSum sum{};
  for (size_t i = first, end = first + count; i < end;) {
    const uint32_t* block = blocks + i / S * W;
    const size_t stop = std::min(end, (i / S + 1) * S);
    int64_t colors[4] = {}, normals[16] = {};
    for (; i < stop; ++i) {
      ++colors[esvo::compressed_color_index(block, int(i % S))];
      ++normals[esvo::compressed_normal_index(block, int(i % S))];
    }
    for (int k = 0; k < 4; ++k) {
      if (colors[k] == 0) continue;
      const Color c = esvo::decode_compressed_color(block, k);
      sum[0] += colors[k] * to_fixed(c.r), sum[1] += colors[k] * to_fixed(c.g);
      sum[2] += colors[k] * to_fixed(c.b), sum[3] += colors[k] * to_fixed(c.a);
    }
    uint32_t used = 0;
    for (int k = 0; k < 16; ++k) used |= uint32_t(normals[k] != 0) << k;
    Vec3 n[16];
    esvo::decode_compressed_normals(block, used, n);
    for (uint32_t u = used; u; u &= u - 1) {
      const int k = std::countr_zero(u);
      sum[4] += normals[k] * to_fixed(n[k].x), sum[5] += normals[k] * to_fixed(n[k].y);
      sum[6] += normals[k] * to_fixed(n[k].z);
    }
  }
  return sum;
}

AttributeSum range_sum(const SparseVoxelDag& d, size_t first, size_t count) {
  return d.compressed_attributes()
             ? compressed_sum(d.attribute_blocks.data(), first, count)
             : detail::attribute_sum_kernel()(d.colors.data(), d.normals.data(), first, count);
}

// Blocked prefix sums of the attributes for LOD means (dag.hpp): each
// block summed on its own (in parallel), then one sequential scan; integer
// sums, so the table is the same for every thread count.
void derive_attribute_prefix(SparseVoxelDag& d) {
  constexpr size_t B = SparseVoxelDag::kAttributeBlock;
  d.attribute_prefix.clear();
  if (!d.has_attributes()) return;
  const size_t blocks = size_t(d.leaf_voxels) / B;
  assign_huge(d.attribute_prefix, blocks + 1);
  tbb::parallel_for(size_t(0), blocks,
                    [&](size_t b) { d.attribute_prefix[b + 1] = range_sum(d, b * B, B); });
  for (size_t b = 1; b <= blocks; ++b)
    for (int k = 0; k < 7; ++k)
      d.attribute_prefix[b][size_t(k)] += d.attribute_prefix[b - 1][size_t(k)];
}

// The mean of voxels `range` from their fixed-point sum: mean_attributes'
// result, and the LOD mean table's entries (derive_cube_means), the same
// floats from the same integers.
void mean_of_sum(const SparseVoxelDag& d, const AttributeSum& sum, VoxelRange range, Color* color,
                 Vec3* normal) {
  const double scale = 1.0 / (SparseVoxelDag::kAttributeSumOne * double(range.count));
  *color = {float(double(sum[0]) * scale), float(double(sum[1]) * scale),
            float(double(sum[2]) * scale), float(double(sum[3]) * scale)};
  const Vec3 n{float(double(sum[4]) * scale), float(double(sum[5]) * scale),
               float(double(sum[6]) * scale)};
  const float len = length(n);
  // Opposed normals can cancel; then the first voxel's normal stands in.
  if (len > 1e-6f) {
    *normal = n * (1.0f / len);
  } else {
    Color first;
    d.voxel_attributes(range.first, &first, normal);
  }
}

// The LOD mean tables (dag.hpp `cube_means`, `fine_means`): the cubes of
// more than kCubeMeanMin voxels at levels <= L - 4 and every cube at L - 3,
// found by a depth-first walk by position (a node's subtree count is its
// header's prefix entry). Each L - 3 cube's voxels are summed directly, every
// coarser cube's fixed-point sum is the sum of its children's (exact
// integers), so every voxel is decoded once. The mean is mean_of_sum of that
// sum, as in mean_attributes. The walk is in Morton order, so each level's
// entries arrive in ascending first voxel.
void derive_cube_means(SparseVoxelDag& d) {
  d.cube_means.clear();
  d.fine_starts.clear();
  d.fine_before.clear();
  d.fine_means.clear();
  if (!d.has_attributes()) return;
  const int L = d.grid.levels;
  if (L < 3) return;
  const int fine_level = L - 3;
  // The L - 3 cubes and each coarser level's entries, counted first so that
  // the tables are allocated once, advised as huge pages before they are
  // written (rays read them at random).
  std::vector<SparseVoxelDag::CubeMeanLevel> levels(static_cast<size_t>(fine_level));
  std::vector<size_t> entries(levels.size(), 0);
  auto count_fine = [&](auto&& self, uint32_t w, int level) -> uint64_t {
    if (level == fine_level) return 1;
    entries[size_t(level)] += d.prefix_entry(w) > SparseVoxelDag::kCubeMeanMin;
    const int k = std::popcount(layout::ChildMask::get(d.words[w]));
    if (level == fine_level - 1) return uint64_t(k);
    uint64_t n = 0;
    for (int j = 0; j < k; ++j) n += self(self, d.words[w + 1 + uint32_t(j)], level + 1);
    return n;
  };
  std::vector<SparseVoxelDag::FineMean> fine;
  reserve_huge(fine, size_t(count_fine(count_fine, 0, 0)));
  for (size_t l = 0; l < levels.size(); ++l) reserve_huge(levels[l].entries, entries[l]);
  std::vector<SparseVoxelDag::FineStarts> starts;
  assign_huge(starts, size_t((d.leaf_voxels + 511) / 512));
  // Returns the cube's sum; appends it to its level if it belongs in a table.
  auto visit = [&](auto&& self, uint32_t w, int level, uint64_t first) -> AttributeSum {
    const uint64_t count = d.prefix_entry(w);  // level <= L - 3: an interior node
    if (level == fine_level) {
      const AttributeSum sum = range_sum(d, size_t(first), size_t(count));
      SparseVoxelDag::FineMean f;
      mean_of_sum(d, sum, {first, count}, &f.color, &f.normal);
      fine.push_back(f);
      starts[size_t(first >> 9)].bits[(first >> 6) & 7] |= 1ull << (first & 63);
      return sum;
    }
    AttributeSum sum{};
    const int k = std::popcount(layout::ChildMask::get(d.words[w]));
    for (int j = 0; j < k; ++j) {
      const uint32_t p = w + 1 + uint32_t(j);
      const AttributeSum c =
          self(self, d.words[p], level + 1, first + (j == 0 ? 0 : d.prefix_entry(p)));
      for (int i = 0; i < 7; ++i) sum[size_t(i)] += c[size_t(i)];
    }
    if (count > SparseVoxelDag::kCubeMeanMin) {
      SparseVoxelDag::CubeMean e;
      e.first = first, e.level = level;
      mean_of_sum(d, sum, {first, count}, &e.color, &e.normal);
      // The children went to deeper levels: still ascending here.
      levels[size_t(level)].entries.push_back(e);
    }
    return sum;
  };
  visit(visit, 0, 0, 0);
  size_t total = 0;
  for (SparseVoxelDag::CubeMeanLevel& t : levels) {
    const size_t n = t.entries.size();
    total += n;
    if (n > 0xFFFFFFFFull) corrupt("more than 2^32 LOD mean entries on one level");
    // About one bucket per entry: 2^shift ranks per bucket, shift the floor
    // of log2(voxels / entries).
    const uint64_t per = d.leaf_voxels / std::max<uint64_t>(n, 1);
    t.shift = per > 1 ? int(std::bit_width(per)) - 1 : 0;
    const size_t buckets = size_t(d.leaf_voxels >> t.shift) + 2;
    assign_huge(t.bucket, buckets, 0u);
    size_t i = 0;
    for (size_t b = 0; b < buckets; ++b) {
      while (i < n && (t.entries[i].first >> t.shift) < b) ++i;
      t.bucket[b] = uint32_t(i);
    }
  }
  if (total > 0) d.cube_means = std::move(levels);
  if (fine.size() > 0xFFFFFFFFull) corrupt("more than 2^32 cubes on level L - 3");
  std::vector<uint32_t> before;
  assign_huge(before, starts.size(), 0u);
  uint32_t n = 0;
  for (size_t i = 0; i < starts.size(); ++i) {
    before[i] = n;
    for (const uint64_t w : starts[i].bits) n += uint32_t(std::popcount(w));
  }
  d.fine_starts = std::move(starts);
  d.fine_before = std::move(before);
  d.fine_means = std::move(fine);
}

}  // namespace

void SparseVoxelDag::finalize() {
  const int L = grid.levels;
  if (L < 2 || L > kMaxGridLevels)
    corrupt("depth " + std::to_string(L) + " is outside 2.." + std::to_string(kMaxGridLevels));
  if (grid.resolution != (1u << L)) corrupt("resolution is not 2^levels");
  if (!grid.placement_is_valid())
    corrupt("bad grid placement (the world cube is not a box of float coordinates within 1e18)");
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
      const size_t size = leaf ? 2 : 1 + size_t(std::popcount(layout::ChildMask::get(words[s])));
      if (s + size > n) corrupt("node at word " + std::to_string(s) + " is truncated");
      for (size_t j = 1; j < size; ++j)
        if (mark[s + j] != 0)
          corrupt("a pointer points into the middle of the node at word " + std::to_string(s));
      if (leaf) {
        if (leaf_mask(&words[s]) == 0) corrupt("empty leaf mask at word " + std::to_string(s));
      } else {
        const uint32_t h = words[s];
        if (layout::ChildMask::get(h) == 0)
          corrupt("empty child mask at word " + std::to_string(s));
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
  // Levels whose nodes all count < 2^32 keep 32-bit entries; the first level
  // (from the bottom) with a larger node and every level above it go to the
  // 64-bit table (dag.hpp "64-bit voxel indices"). Counts only grow upward,
  // so those levels are a prefix 0..T-1 and the words a prefix [0, wide_words).
  assign_huge(voxel_prefix, n, 0u);
  voxel_prefix_wide.clear();
  wide_words = 0;
  auto count_of = [&](uint32_t p, bool is_leaf) -> uint64_t {
    return is_leaf ? uint64_t(std::popcount(leaf_mask(&words[p]))) : prefix_entry(p);
  };
  for (int l = L - 3; l >= 0; --l) {
    const bool children_are_leaves = l + 1 == L - 2;
    const size_t begin = level_start[size_t(l)], end = level_start[size_t(l + 1)];
    if (wide_words == 0) {
      // Does level l need 64-bit entries? Its children's counts are known.
      bool wide = false;
      for (size_t w = begin; w < end && !wide;) {
        const int k = std::popcount(layout::ChildMask::get(words[w]));
        uint64_t sum = 0;
        for (int j = 0; j < k; ++j) sum += count_of(words[w + 1 + size_t(j)], children_are_leaves);
        wide = sum > 0xFFFFFFFFull;
        w += 1 + size_t(k);
      }
      if (wide) {
        wide_words = uint32_t(end);
        assign_huge(voxel_prefix_wide, end, uint64_t(0));
      }
    }
    for (size_t w = begin; w < end;) {
      const int k = std::popcount(layout::ChildMask::get(words[w]));
      uint64_t sum = 0;
      auto store = [&](size_t at, uint64_t v) {
        if (at < wide_words)
          voxel_prefix_wide[at] = v;
        else
          voxel_prefix[at] = uint32_t(v);
      };
      for (int j = 0; j < k; ++j) {
        store(w + 1 + size_t(j), sum);
        sum += count_of(words[w + 1 + size_t(j)], children_are_leaves);
      }
      store(w, sum);
      w += 1 + size_t(k);
    }
  }
  leaf_voxels = L == 2 ? uint64_t(std::popcount(leaf_mask(&words[0]))) : prefix_entry(0);

  if (colors.size() != normals.size()) corrupt("color and normal arrays differ in size");
  if (!colors.empty() && colors.size() != leaf_voxels)
    corrupt("attribute arrays hold " + std::to_string(colors.size()) + " voxels, the DAG " +
            std::to_string(leaf_voxels));

  if (!attribute_blocks.empty()) {
    if (!colors.empty()) corrupt("both raw and compressed attribute arrays");
    const uint64_t blocks = (leaf_voxels + kCompressedSlots - 1) / kCompressedSlots;
    if (attribute_blocks.size() != blocks * kCompressedBlockWords)
      corrupt("compressed attributes hold " + std::to_string(attribute_blocks.size()) +
              " words, expected " + std::to_string(blocks * kCompressedBlockWords) + " for " +
              std::to_string(leaf_voxels) + " voxels");
  }
  derive_attribute_prefix(*this);
  derive_cube_means(*this);
}

void SparseVoxelDag::encode_compressed_blocks(const uint32_t* colors, const uint32_t* normals,
                                              size_t count, uint32_t* out) {
  // esvo §5.5 on runs of 16 Morton-consecutive voxels; the shared ESVO
  // encoder (compress.hpp) fits each block from the raw 8-byte values.
  const size_t blocks = (count + kCompressedSlots - 1) / kCompressedSlots;
  tbb::parallel_for(size_t(0), blocks, [&](size_t k) {
    uint64_t values[kCompressedSlots];
    const size_t first = k * kCompressedSlots;
    const size_t n = std::min<size_t>(kCompressedSlots, count - first);
    for (size_t j = 0; j < n; ++j)
      values[j] = uint64_t(colors[first + j]) | uint64_t(normals[first + j]) << 32;
    esvo::detail::encode_block_from_raw(values, uint32_t((1ull << n) - 1),
                                        &out[k * kCompressedBlockWords]);
  });
}

void SparseVoxelDag::compress_attributes() {
  if (colors.empty()) return;
  const size_t V = colors.size(), blocks = (V + kCompressedSlots - 1) / kCompressedSlots;
  std::vector<uint32_t> out;
  assign_huge(out, blocks * kCompressedBlockWords, 0u);
  encode_compressed_blocks(colors.data(), normals.data(), V, out.data());
  attribute_blocks = std::move(out);
  colors = {};
  normals = {};
  derive_attribute_prefix(*this);
  derive_cube_means(*this);
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
        for (int c = 0; c < 8; ++c) blocks += layout::LeafMaskBytes::get(m, unsigned(c)) != 0;
        st.levels[size_t(L - 1)].svo_nodes += mult[w] * uint64_t(blocks);
        st.levels[size_t(L)].svo_nodes += mult[w] * uint64_t(std::popcount(m));
        w += 2;
      } else {
        const int k = std::popcount(layout::ChildMask::get(words[w]));
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
  st.index_bytes = uint64_t(voxel_prefix.size()) * 4 + uint64_t(voxel_prefix_wide.size()) * 8 +
                   uint64_t(attribute_prefix.size()) * sizeof(attribute_prefix[0]) +
                   cube_mean_bytes();
  st.lod_mean_bytes = cube_mean_bytes();
  st.attribute_bytes = uint64_t(colors.size() + normals.size() + attribute_blocks.size()) * 4;
  st.compressed_attributes = compressed_attributes();
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
        out.push_back(layout::LeafBlockCode::put(code) | uint64_t(std::countr_zero(m)));
        m &= m - 1;
      }
      return;
    }
    const uint32_t mask = layout::ChildMask::get(words[w]);
    int j = 0;
    for (int c = 0; c < 8; ++c)
      if (mask & (1u << c))
        self(self, words[w + 1 + size_t(j++)], level + 1, code << 3 | uint64_t(c));
  };
  visit(visit, 0, 0, 0);
  return out;
}

void SparseVoxelDag::voxel_attributes(uint64_t index, Color* color, Vec3* normal) const {
  if (!attribute_blocks.empty() && index < leaf_voxels) {
    // One slot of one 24-byte block (dag.hpp "Compressed attributes").
    esvo::decode_compressed_slot(
        &attribute_blocks[size_t(index / kCompressedSlots) * kCompressedBlockWords],
        int(index % kCompressedSlots), color, normal);
    return;
  }
  if (colors.empty() || index >= colors.size()) {
    *color = {0.5f, 0.5f, 0.5f, 1.f};
    *normal = {0, 0, 1};
    return;
  }
  *color = esvo::decode_color_abgr(colors[size_t(index)]);
  *normal = esvo::decode_normal_cube(normals[size_t(index)]);
}

std::vector<uint64_t> SparseVoxelDag::decode_cube(int level, uint64_t cube) const {
  const int L = grid.levels;
  if (level < 0 || level > L)
    throw Error("decode_cube: level " + std::to_string(level) + " is outside 0.." +
                std::to_string(L));
  if (level < 21 && (cube >> (3 * level)) != 0)
    throw Error("decode_cube: cube code " + std::to_string(cube) + " is outside level " +
                std::to_string(level));
  std::vector<uint64_t> out;
  // Down the cube's path to the node at min(level, L-2).
  const int node_level = std::min(level, L - 2);
  uint32_t w = 0;
  for (int k = 0; k < node_level; ++k) {
    const uint32_t c = uint32_t(cube >> (3 * (level - 1 - k))) & 7u;
    const uint32_t mask = layout::ChildMask::get(words[w]);
    if (!((mask >> c) & 1u)) return out;
    w = words[w + 1 + size_t(std::popcount(mask & ((1u << c) - 1)))];
  }
  if (level >= L - 2) {
    // Inside one 4^3 mask: the cube's voxels are a run of 8^(L-level) bits.
    const int bits = 3 * (L - level);
    const uint64_t first = cube << bits;
    uint64_t m = leaf_mask(&words[w]) >> layout::LeafMaskBit::get(first);
    if (bits < 6) m &= (1ull << (1 << bits)) - 1;
    while (m) {
      out.push_back(first + uint64_t(std::countr_zero(m)));
      m &= m - 1;
    }
    return out;
  }
  auto visit = [&](auto&& self, uint32_t node, int k, uint64_t code) -> void {
    if (k == L - 2) {
      uint64_t m = leaf_mask(&words[node]);
      while (m) {
        out.push_back(layout::LeafBlockCode::put(code) | uint64_t(std::countr_zero(m)));
        m &= m - 1;
      }
      return;
    }
    const uint32_t mask = layout::ChildMask::get(words[node]);
    int j = 0;
    for (int c = 0; c < 8; ++c)
      if (mask & (1u << c))
        self(self, words[node + 1 + size_t(j++)], k + 1, code << 3 | uint64_t(c));
  };
  visit(visit, w, level, cube);
  return out;
}

uint64_t SparseVoxelDag::voxel_rank(uint64_t code) const {
  const int L = grid.levels;
  if (L < 21 && (code >> (3 * L)) != 0) return leaf_voxels;  // past the grid
  uint64_t rank = 0;
  uint32_t w = 0;
  for (int k = 0; k < L - 2; ++k) {
    const uint32_t c = uint32_t(code >> (3 * (L - 1 - k))) & 7u;
    const uint32_t mask = layout::ChildMask::get(words[w]);
    const int k_children = std::popcount(mask);
    const int j = std::popcount(mask & ((1u << c) - 1));
    // Voxels in the children before slot c: the prefix entry of the next
    // present child's pointer, or the node's own count if there is none.
    rank += j < k_children ? prefix_entry(w + 1 + uint32_t(j)) : prefix_entry(w);
    if (!((mask >> c) & 1u)) return rank;
    w = words[w + 1 + size_t(j)];
  }
  const uint64_t below = (1ull << layout::LeafMaskBit::get(code)) - 1;
  return rank + uint64_t(std::popcount(leaf_mask(&words[w]) & below));
}

VoxelRange SparseVoxelDag::cube_range(uint64_t voxel, int level) const {
  const int L = grid.levels;
  if (level < 0 || level > L)
    throw Error("cube_range: level " + std::to_string(level) + " is outside 0.." +
                std::to_string(L));
  if (voxel >= leaf_voxels)
    throw Error("cube_range: voxel " + std::to_string(voxel) + " is past the " +
                std::to_string(leaf_voxels) + " leaf voxels");
  if (level == 0) return {0, leaf_voxels};
  // Descend to the child holding rank `voxel`: the last child whose prefix
  // entry (voxels before it) is <= the remaining rank.
  uint64_t first = 0, rem = voxel;
  uint32_t w = 0;
  const int node_level = std::min(level, L - 2);
  for (int k = 0; k < node_level; ++k) {
    int j = std::popcount(layout::ChildMask::get(words[w])) - 1;
    while (j > 0 && prefix_entry(w + 1 + uint32_t(j)) > rem) --j;
    const uint64_t before = prefix_entry(w + 1 + uint32_t(j));
    first += before;
    rem -= before;
    w = words[w + 1 + size_t(j)];
  }
  const uint64_t m = leaf_mask(&words[w]);
  if (level == node_level && level < L - 2) return {first, prefix_entry(w)};
  if (level == L - 2) return {first, uint64_t(std::popcount(m))};
  // Inside the 4^3 mask: bit of the rem-th voxel, then its run of 8^(L-level) bits.
  const uint64_t bit = uint64_t(std::countr_zero(_pdep_u64(1ull << rem, m)));
  const int bits = 3 * (L - level);  // 3 (a 2^3 sub-block) or 0 (one voxel)
  const uint64_t lo = bit >> bits << bits;
  const uint64_t run = ((1ull << (1 << bits)) - 1) << lo;
  return {first + uint64_t(std::popcount(m & ((1ull << lo) - 1))),
          uint64_t(std::popcount(m & run))};
}

void SparseVoxelDag::mean_attributes(VoxelRange range, Color* color, Vec3* normal) const {
  if (!has_attributes() || range.count == 0 || range.first >= leaf_voxels ||
      range.count > leaf_voxels - range.first) {
    voxel_attributes(range.first, color, normal);  // gray / out of range: as one voxel
    return;
  }
  const size_t a = size_t(range.first), e = size_t(range.first + range.count);
  const size_t B = kAttributeBlock, V = size_t(leaf_voxels);
  AttributeSum sum;
  if (e - a <= B) {
    sum = range_sum(*this, a, e - a);
  } else {
    // Sum of voxels [0, x) from the nearer block boundary: at most B/2
    // voxels summed directly per end (32 on average when B = 64 -> 16).
    auto prefix_at = [&](size_t x) {
      const size_t lo = x / B * B, hi = lo + B;
      if (x - lo <= B / 2 || hi > V) {
        AttributeSum p = range_sum(*this, lo, x - lo);
        for (int k = 0; k < 7; ++k) p[size_t(k)] += attribute_prefix[lo / B][size_t(k)];
        return p;
      }
      AttributeSum p = range_sum(*this, x, hi - x);
      for (int k = 0; k < 7; ++k) p[size_t(k)] = attribute_prefix[hi / B][size_t(k)] - p[size_t(k)];
      return p;
    };
    const AttributeSum pa = prefix_at(a), pe = prefix_at(e);
    for (int k = 0; k < 7; ++k) sum[size_t(k)] = pe[size_t(k)] - pa[size_t(k)];
  }
  mean_of_sum(*this, sum, range, color, normal);
}

void SparseVoxelDag::mean_attributes(const VoxelRange* ranges, size_t n, Color* colors,
                                     Vec3* normals) const {
  if (!has_attributes() || compressed_attributes()) {
    for (size_t i = 0; i < n; ++i) mean_attributes(ranges[i], &colors[i], &normals[i]);
    return;
  }
  // Per chunk of 64 ranges: every line they cover prefetched (a LOD hit's
  // voxels are one short run, far from the last hit's), then their normal
  // codes copied out and decoded 8 at a time, then each range's fixed-point
  // sums and mean as mean_attributes computes them (attribute_sum's
  // per-voxel integers: decode_normal_cubes gives decode_normal_cube's
  // floats, and integer sums do not depend on the order).
  constexpr size_t kChunk = 64, kVoxels = kChunk * kBatchMeanVoxels;
  thread_local uint32_t codes[kVoxels];
  thread_local Vec3 decoded[kVoxels];
  const int64_t* ch = detail::fixed_channel_table();
  auto batched = [&](const VoxelRange& r) {
    return r.count > 0 && r.count <= kBatchMeanVoxels && r.first < leaf_voxels &&
           r.count <= leaf_voxels - r.first;
  };
  for (size_t i0 = 0; i0 < n; i0 += kChunk) {
    const size_t m = std::min(kChunk, n - i0);
    const VoxelRange* rs = ranges + i0;
    for (size_t i = 0; i < m; ++i) {
      if (!batched(rs[i])) continue;
      const size_t a = size_t(rs[i].first), e = a + size_t(rs[i].count);
      for (const uint32_t* v : {this->colors.data(), this->normals.data()}) {
        const uintptr_t last = reinterpret_cast<uintptr_t>(v + e - 1) | 63;
        for (uintptr_t p = reinterpret_cast<uintptr_t>(v + a); p <= last; p += 64)
          ::voxcast::detail::prefetch_line(reinterpret_cast<const char*>(p));
      }
    }
    size_t at = 0;
    for (size_t i = 0; i < m; ++i) {
      if (!batched(rs[i])) continue;
      std::copy_n(&this->normals[size_t(rs[i].first)], size_t(rs[i].count), codes + at);
      at += size_t(rs[i].count);
    }
    esvo::decode_normal_cubes(codes, at, decoded);
    at = 0;
    for (size_t i = 0; i < m; ++i) {
      if (!batched(rs[i])) {
        mean_attributes(rs[i], &colors[i0 + i], &normals[i0 + i]);
        continue;
      }
      AttributeSum sum{};
      const size_t a = size_t(rs[i].first), count = size_t(rs[i].count);
      for (size_t j = 0; j < count; ++j, ++at) {
        const uint32_t abgr = this->colors[a + j];
        sum[0] += ch[esvo::layout::ColorR::get(abgr)];
        sum[1] += ch[esvo::layout::ColorG::get(abgr)];
        sum[2] += ch[esvo::layout::ColorB::get(abgr)];
        sum[3] += ch[256 + esvo::layout::ColorA::get(abgr)];
        sum[4] += to_fixed(decoded[at].x);
        sum[5] += to_fixed(decoded[at].y);
        sum[6] += to_fixed(decoded[at].z);
      }
      mean_of_sum(*this, sum, rs[i], &colors[i0 + i], &normals[i0 + i]);
    }
  }
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
    const uint32_t mask = layout::ChildMask::get(dag.words[w]);
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
