// Brickmap world storage (layout: include/voxcast/brickmap.hpp): the brick
// pool, the size-class color allocator (§3.1.4, §4.3) and the brickgrid with
// its occupancy layer.
#include <algorithm>
#include <array>
#include <bit>
#include <cstdlib>
#include <cstring>
#include <string>

#include "brickmap/codec.hpp"
#include "voxcast/brickmap.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo.hpp"
#include "voxcast/morton.hpp"

namespace voxcast::brickmap {

int brick_popcount(const Brick& b) {
  int n = 0;
  for (uint64_t w : b.mask) n += std::popcount(w);
  return n;
}

int rank_below(const Brick& b, uint32_t bit) {
  const uint32_t word = bit >> 6;
  int n = std::popcount(b.mask[word] & ((uint64_t(1) << (bit & 63)) - 1));
  for (uint32_t w = 0; w < word; ++w) n += std::popcount(b.mask[w]);
  return n;
}

// ---- BrickPool ----

uint32_t BrickPool::allocate() {
  if (!free_.empty()) {
    const uint32_t i = free_.back();
    free_.pop_back();
    bricks_[i] = Brick{};
    return i;
  }
  if (bricks_.size() >= kMaxBricks)
    throw Error("brickmap: more than " + std::to_string(kMaxBricks) +
                " resident bricks (the 24-bit brick index of a brickgrid cell)");
  bricks_.emplace_back();
  return uint32_t(bricks_.size() - 1);
}

void BrickPool::release(uint32_t index) {
  free_.push_back(index);
}

// ---- ColorAllocator ----

int ColorAllocator::class_of(uint32_t count) {
  const int log2 = count <= 1 ? 0 : int(std::bit_width(count - 1));  // ceil(log2(count))
  return std::max(0, log2 - kMinLog2);
}

uint32_t ColorAllocator::class_size(uint32_t count) {
  return uint32_t(1) << (class_of(count) + kMinLog2);
}

uint32_t ColorAllocator::allocate(uint32_t count) {
  const int c = class_of(count);
  int k = c;
  while (k < kClasses && free_[size_t(k)].empty()) ++k;
  if (k == kClasses) {
    // Before the pool grows: merge every class, smallest first (what the
    // threshold would do eventually), and look again.
    // A class is merged again only once its free list has more than doubled
    // since its last merge (what is left after a merge cannot merge by
    // itself), so the sorting stays amortized O(n log n) overall instead of
    // one sort per growth.
    for (int m = 0; m + 1 < kClasses; ++m)
      if (free_[size_t(m)].size() > 2 * merged_size_[size_t(m)]) merge(m, false);
    for (k = c; k < kClasses && free_[size_t(k)].empty(); ++k) {
    }
  }
  uint32_t node;
  if (k == kClasses) {
    // No free node large enough: the pool grows by one top-class node.
    node = extent_;
    extent_ += uint32_t(1) << kMaxLog2;
    k = kClasses - 1;
  } else {
    node = free_[size_t(k)].back();
    free_[size_t(k)].pop_back();
  }
  // Split down to the requested class, keeping the lower half each time.
  for (; k > c; --k) free_[size_t(k - 1)].push_back(node + (uint32_t(1) << (k - 1 + kMinLog2)));
  return node;
}

void ColorAllocator::release(uint32_t first, uint32_t count) {
  const int c = class_of(count);
  free_[size_t(c)].push_back(first);
  if (free_[size_t(c)].size() > merge_threshold(c) && c + 1 < kClasses) merge(c, true);
}

size_t ColorAllocator::merge_threshold(int c) const {
  // Past kMergeThreshold, and past twice what the last merge left (the nodes
  // that did not merge then would be sorted again for nothing at every
  // release: quadratic in a long edit).
  return std::max(kMergeThreshold, 2 * merged_size_[size_t(c)]);
}

void ColorAllocator::merge(int c, bool cascade) {
  // Sort the class's free nodes; a node aligned to the next class's size
  // whose upper neighbour is free too becomes one node of the next class.
  std::vector<uint32_t>& f = free_[size_t(c)];
  std::sort(f.begin(), f.end());
  const uint32_t size = uint32_t(1) << (c + kMinLog2);
  std::vector<uint32_t> keep;
  for (size_t i = 0; i < f.size(); ++i) {
    if (i + 1 < f.size() && f[i] % (2 * size) == 0 && f[i + 1] == f[i] + size) {
      free_[size_t(c + 1)].push_back(f[i]);
      ++i;
    } else {
      keep.push_back(f[i]);
    }
  }
  f = std::move(keep);
  merged_size_[size_t(c)] = f.size();
  if (cascade && free_[size_t(c + 1)].size() > merge_threshold(c + 1) && c + 2 < kClasses)
    merge(c + 1, true);
}

uint64_t ColorAllocator::free_entries() const {
  uint64_t n = 0;
  for (int c = 0; c < kClasses; ++c) n += uint64_t(free_[size_t(c)].size()) << (c + kMinLog2);
  return n;
}

// ---- Clearance (World::clearance): capped Chebyshev distances to the
// nearest filled cell of a grid of dims (index x + dx (y + dy z)) ----

namespace {

// Cells within Chebyshev distance kMaxClearance - 1 of the newly filled
// cell c are at most that far from a filled cell.
void add_clearance_source(std::vector<uint8_t>& clear, const std::array<uint32_t, 3>& dims,
                          const std::array<uint32_t, 3>& cell) {
  constexpr int r = kMaxClearance - 1;
  const int c[3] = {int(cell[0]), int(cell[1]), int(cell[2])};
  int lo[3], hi[3];
  for (int a = 0; a < 3; ++a)
    lo[a] = std::max(0, c[a] - r), hi[a] = std::min(int(dims[size_t(a)]) - 1, c[a] + r);
  for (int z = lo[2]; z <= hi[2]; ++z)
    for (int y = lo[1]; y <= hi[1]; ++y)
      for (int x = lo[0]; x <= hi[0]; ++x) {
        const int d = std::max({std::abs(x - c[0]), std::abs(y - c[1]), std::abs(z - c[2])});
        uint8_t& v = clear[size_t(
            uint64_t(x) + uint64_t(dims[0]) * (uint64_t(y) + uint64_t(dims[1]) * uint64_t(z)))];
        v = std::min(v, uint8_t(d));
      }
}

// Every cell within kMaxClearance - 1 of the box [box_lo, box_hi] from
// filled(x, y, z): the capped Chebyshev distance transform is separable (the
// distance along x, then the min over dy of max(|dy|, .), then the same over
// dz), the last two as whole rows (x contiguous) so that they vectorize.
template <class Filled>
void recompute_clearance(std::vector<uint8_t>& clear, const std::array<uint32_t, 3>& dims,
                         const std::array<uint32_t, 3>& box_lo,
                         const std::array<uint32_t, 3>& box_hi, const Filled& filled) {
  constexpr int K = kMaxClearance, r = K - 1;
  int lo[3], hi[3], elo[3], ehi[3];  // the box R updated; R grown by r (the cells it reads)
  for (int a = 0; a < 3; ++a) {
    const int top = int(dims[size_t(a)]) - 1;
    lo[a] = std::max(0, int(box_lo[size_t(a)]) - r);
    hi[a] = std::min(top, int(box_hi[size_t(a)]) + r);
    elo[a] = std::max(0, lo[a] - r), ehi[a] = std::min(top, hi[a] + r);
  }
  const size_t nx = size_t(hi[0] - lo[0] + 1);
  const int ny = hi[1] - lo[1] + 1, ey = ehi[1] - elo[1] + 1, ez = ehi[2] - elo[2] + 1;
  // f1 over R.x x E.y x E.z: the distance along x (two sweeps per row);
  // f2 over R.x x R.y x E.z.
  std::vector<uint8_t> f1(nx * size_t(ey) * size_t(ez)), f2(nx * size_t(ny) * size_t(ez));
  for (int z = elo[2]; z <= ehi[2]; ++z)
    for (int y = elo[1]; y <= ehi[1]; ++y) {
      uint8_t* row = &f1[(size_t(z - elo[2]) * size_t(ey) + size_t(y - elo[1])) * nx];
      int last = -K;  // the last filled x seen by the sweep
      for (int x = elo[0]; x <= hi[0]; ++x) {
        if (filled(uint32_t(x), uint32_t(y), uint32_t(z))) last = x;
        if (x >= lo[0]) row[x - lo[0]] = uint8_t(std::min(K, x - last));
      }
      last = ehi[0] + K;
      for (int x = ehi[0]; x >= lo[0]; --x) {
        if (filled(uint32_t(x), uint32_t(y), uint32_t(z))) last = x;
        if (x <= hi[0]) row[x - lo[0]] = std::min(row[x - lo[0]], uint8_t(std::min(K, last - x)));
      }
    }
  const auto min_max_row = [nx](uint8_t* out, const uint8_t* in, uint8_t m) {
    for (size_t x = 0; x < nx; ++x) out[x] = std::min(out[x], std::max(m, in[x]));
  };
  for (int z = elo[2]; z <= ehi[2]; ++z)
    for (int y = lo[1]; y <= hi[1]; ++y) {
      uint8_t* out = &f2[(size_t(z - elo[2]) * size_t(ny) + size_t(y - lo[1])) * nx];
      std::fill(out, out + nx, uint8_t(K));
      for (int yy = std::max(elo[1], y - r); yy <= std::min(ehi[1], y + r); ++yy)
        min_max_row(out, &f1[(size_t(z - elo[2]) * size_t(ey) + size_t(yy - elo[1])) * nx],
                    uint8_t(std::abs(yy - y)));
    }
  for (int z = lo[2]; z <= hi[2]; ++z)
    for (int y = lo[1]; y <= hi[1]; ++y) {
      uint8_t* out = &clear[size_t(
          uint64_t(lo[0]) + uint64_t(dims[0]) * (uint64_t(y) + uint64_t(dims[1]) * uint64_t(z)))];
      std::fill(out, out + nx, uint8_t(K));
      for (int zz = std::max(elo[2], z - r); zz <= std::min(ehi[2], z + r); ++zz)
        min_max_row(out, &f2[(size_t(zz - elo[2]) * size_t(ny) + size_t(y - lo[1])) * nx],
                    uint8_t(std::abs(zz - z)));
    }
}

// The clearance after cells `filled_now` turned filled and `emptied` turned
// empty: the cheaper of one add per new filled cell ((2r+1)^3 cells each)
// and one recompute of the box holding all of them (about 3 (2r+1) reads
// per cell of the box grown by 2r), the recompute whenever a cell emptied.
template <class Filled>
void update_clearance(std::vector<uint8_t>& clear, const std::array<uint32_t, 3>& dims,
                      const std::vector<std::array<uint32_t, 3>>& filled_now,
                      const std::vector<std::array<uint32_t, 3>>& emptied, const Filled& filled) {
  if (filled_now.empty() && emptied.empty()) return;
  constexpr double w = 2 * (kMaxClearance - 1) + 1;
  std::array<uint32_t, 3> lo{~0u, ~0u, ~0u}, hi{0, 0, 0};
  for (const auto* list : {&filled_now, &emptied})
    for (const auto& c : *list)
      for (size_t a = 0; a < 3; ++a) lo[a] = std::min(lo[a], c[a]), hi[a] = std::max(hi[a], c[a]);
  double box = 3 * w;
  for (size_t a = 0; a < 3; ++a)
    box *= std::min(double(dims[a]), double(hi[a] - lo[a] + 1) + 2 * (w - 1));
  if (emptied.empty() && double(filled_now.size()) * w * w * w <= box) {
    for (const auto& c : filled_now) add_clearance_source(clear, dims, c);
    return;
  }
  recompute_clearance(clear, dims, lo, hi, filled);
}

}  // namespace

// ---- World ----

World::World(const GridTransform& grid, bool normals, uint32_t height_cells)
    : grid_(grid), normals_(normals) {
  if (grid.levels < 0 || grid.levels > kMaxGridLevels || grid.resolution != (1u << grid.levels) ||
      !grid.placement_is_valid())
    throw Error("brickmap: invalid grid placement");
  const uint32_t n = (grid.resolution + kBrickSide - 1) >> kBrickLog2;
  if (height_cells > n)
    throw Error("brickmap: a brickgrid " + std::to_string(height_cells) +
                " cells high does not fit the " + std::to_string(grid.resolution) + "^3 grid");
  const uint32_t ny = height_cells ? height_cells : n;
  const uint64_t cells = uint64_t(n) * ny * n;
  if (cells > kMaxGridCells)
    throw Error("brickmap: a " + std::to_string(grid.resolution) + "^3 grid needs " +
                std::to_string(cells) + " brickgrid cells, more than the " +
                std::to_string(kMaxGridCells) + " supported");
  dims_ = {n, ny, n};
  const auto occ = [](uint32_t d) { return (d + (1u << kOccupancyLog2) - 1) >> kOccupancyLog2; };
  occ_dims_ = {occ(n), occ(ny), occ(n)};
  cells_.assign(size_t(cells), 0);
  clearance_.assign(size_t(cells), uint8_t(kMaxClearance));
  occupancy_.assign(size_t((uint64_t(occ_dims_[0]) * occ_dims_[1] * occ_dims_[2] + 63) / 64), 0);
  // dims are a power of two (N = 2^L, N / 8 or 1): log2(n) levels above.
  int k = 1;
  for (uint32_t d = n >> 1; d >= 1; d >>= 1, ++k)
    pyramid_.emplace_back(size_t(uint64_t(d) * pyramid_dim_y(k) * d));
  if (pyramid_levels() >= kCellBoxLevel) {
    cell_box_.assign(pyramid_[kCellBoxLevel - 1].size(), 0);
    node_clearance_.assign(pyramid_[kCellBoxLevel - 1].size() * 8, uint8_t(kMaxClearance));
  }
}

void World::set_brick(uint64_t index, const uint64_t mask[8], const uint32_t* colors,
                      const uint32_t* normals, uint32_t flags, const uint32_t* lod,
                      bool update_pyramid) {
  uint32_t& cell = cells_[size_t(index)];
  uint32_t b = 0;
  Brick* brick = nullptr;
  int count = 0;
  for (int w = 0; w < 8; ++w) count += std::popcount(mask[w]);
  // A run whose size class still fits the new count is rewritten in place
  // (§4.3: an edit of a few voxels keeps its node); otherwise it goes back
  // to its class and a new one is taken.
  bool in_place = false;
  if (cell_state(cell) == kStateResident) {
    b = cell_brick(cell);
    brick = &pool_[b];
    const int old = brick_popcount(*brick);
    in_place =
        old > 0 && count > 0 &&
        ColorAllocator::class_size(uint32_t(old)) == ColorAllocator::class_size(uint32_t(count));
    if (old > 0 && !in_place) color_alloc_.release(brick->color, uint32_t(old));
  }
  if (count == 0) {
    if (brick != nullptr) pool_.release(b);
    cell = 0;
    if (update_pyramid) update_occupancy(index);
    return;
  }
  if (brick == nullptr) {
    b = pool_.allocate();
    brick = &pool_[b];
  }
  std::memcpy(brick->mask, mask, sizeof brick->mask);
  if (!in_place) brick->color = color_alloc_.allocate(uint32_t(count));
  if (normals_data_.size() < color_alloc_.extent() || colors_.size() < color_alloc_.extent()) {
    if (!dxt1_) colors_.resize(color_alloc_.extent());
    if (normals_) normals_data_.resize(color_alloc_.extent());
  }
  if (dxt1_) {
    if (blocks_.size() < color_alloc_.extent() / 16) blocks_.resize(color_alloc_.extent() / 16);
    for (int b = 0; b * 16 < count; ++b)
      blocks_[brick->color / 16 + uint32_t(b)] =
          dxt1_encode(colors + 16 * b, std::min(16, count - 16 * b));
  } else {
    std::copy(colors, colors + count, colors_.begin() + brick->color);
  }
  if (normals_) std::copy(normals, normals + count, normals_data_.begin() + brick->color);
  // LOD color: the mean of the voxels' linear colors (what they show at full
  // resolution), re-encoded.
  brick->lod = lod ? *lod : codec::mean_color_abgr(colors, size_t(count));
  cell = resident_cell(b, flags);
  if (update_pyramid) update_occupancy(index);
}

void World::use_dxt1() {
  if (pool_.extent() != 0) throw Error("brickmap: DXT1 colors are chosen before any brick");
  dxt1_ = true;
}

void World::set_not_resident(uint64_t index, uint32_t abgr, uint32_t flags, bool update_pyramid) {
  uint32_t& cell = cells_[size_t(index)];
  if (cell_state(cell) == kStateResident) {
    const uint32_t b = cell_brick(cell);
    const int old = brick_popcount(pool_[b]);
    if (old > 0) color_alloc_.release(pool_[b].color, uint32_t(old));
    pool_.release(b);
  }
  cell = not_resident_cell(abgr, flags);
  if (update_pyramid) update_occupancy(index);
}

void World::update_occupancy(uint64_t index) {
  const uint32_t i = uint32_t(index % dims_[0]);
  const uint32_t j = uint32_t(index / dims_[0] % dims_[1]);
  const uint32_t k = uint32_t(index / dims_[0] / dims_[1]);
  update_occupancy_bit(i >> kOccupancyLog2, j >> kOccupancyLog2, k >> kOccupancyLog2);
  // The clearance changes only where a cell or node turns empty or filled.
  const bool filled = cells_[size_t(index)] != 0, was_filled = clearance_[size_t(index)] == 0;
  if (filled != was_filled) {
    const std::vector<std::array<uint32_t, 3>> c{{i, j, k}}, none;
    update_clearance(clearance_, dims_, filled ? c : none, filled ? none : c, cell_filled());
  }
  for (int q = 1; q <= pyramid_levels(); ++q) update_pyramid_node(q, i >> q, j >> q, k >> q);
  if (pyramid_levels() >= kCellBoxLevel) {
    std::vector<std::array<uint32_t, 3>> filled_now, emptied;
    note_node_change(i >> kCellBoxLevel, j >> kCellBoxLevel, k >> kCellBoxLevel, &filled_now,
                     &emptied);
    update_node_clearance(filled_now, emptied);
  }
}

void World::update_node_clearance(const std::vector<std::array<uint32_t, 3>>& filled_now,
                                  const std::vector<std::array<uint32_t, 3>>& emptied) {
  if (filled_now.empty() && emptied.empty()) return;
  constexpr int K = kMaxClearance;
  const std::array<uint32_t, 3> d = node_dims();
  int lo[3] = {INT32_MAX, INT32_MAX, INT32_MAX}, hi[3] = {0, 0, 0};
  for (const auto* list : {&filled_now, &emptied})
    for (const auto& c : *list)
      for (int a = 0; a < 3; ++a)
        lo[a] = std::min(lo[a], int(c[size_t(a)])), hi[a] = std::max(hi[a], int(c[size_t(a)]));
  const auto filled = node_filled();
  for (int oct = 0; oct < 8; ++oct) {
    // The largest-empty-cube recurrence: an empty node's cube is 1 + the
    // smallest of its 7 neighbours' ahead (in the octant), so the nodes are
    // visited from ahead to behind; only those up to K behind a change can
    // change.
    int from[3], to[3], step[3], s[3];
    for (int a = 0; a < 3; ++a) {
      s[a] = (oct >> a & 1) ? 1 : -1;
      const int top = int(d[size_t(a)]) - 1;
      const int b0 = s[a] > 0 ? std::max(0, lo[a] - K) : lo[a];
      const int b1 = s[a] > 0 ? hi[a] : std::min(top, hi[a] + K);
      from[a] = s[a] > 0 ? b1 : b0, to[a] = s[a] > 0 ? b0 : b1, step[a] = -s[a];
    }
    for (int z = from[2];; z += step[2]) {
      for (int y = from[1];; y += step[1]) {
        for (int x = from[0];; x += step[0]) {
          int v = 0;
          if (!filled(uint32_t(x), uint32_t(y), uint32_t(z))) {
            int m = K;
            for (int e = 1; e < 8; ++e) {
              const int n[3] = {x + (e & 1) * s[0], y + (e >> 1 & 1) * s[1], z + (e >> 2) * s[2]};
              bool inside = true;
              for (int a = 0; a < 3; ++a) inside &= n[a] >= 0 && n[a] < int(d[size_t(a)]);
              if (inside)
                m = std::min(
                    m, int(node_clearance_[size_t(pyramid_index(kCellBoxLevel, uint32_t(n[0]),
                                                                uint32_t(n[1]), uint32_t(n[2])) *
                                                      8 +
                                                  uint64_t(oct))]));
            }
            v = std::min(K, 1 + m);
          }
          node_clearance_[size_t(
              pyramid_index(kCellBoxLevel, uint32_t(x), uint32_t(y), uint32_t(z)) * 8 +
              uint64_t(oct))] = uint8_t(v);
          if (x == to[0]) break;
        }
        if (y == to[1]) break;
      }
      if (z == to[2]) break;
    }
  }
}

void World::note_node_change(uint32_t x, uint32_t y, uint32_t z,
                             std::vector<std::array<uint32_t, 3>>* filled_now,
                             std::vector<std::array<uint32_t, 3>>* emptied) const {
  const uint64_t index = pyramid_index(kCellBoxLevel, x, y, z);
  const bool filled = pyramid_node(kCellBoxLevel, index).bricks != 0;
  if (filled != (node_clearance_[size_t(index * 8)] == 0))
    (filled ? filled_now : emptied)->push_back({x, y, z});
}

void World::update_occupancy(const std::vector<uint64_t>& indices) {
  // The same nodes as update_occupancy(index) for each, every one once:
  // per level, the distinct parents of the level below (§4.4: an edit of
  // many bricks recomputes each pyramid node once, not once per brick).
  std::vector<std::array<uint32_t, 3>> at;
  at.reserve(indices.size());
  for (uint64_t index : indices)
    at.push_back({uint32_t(index % dims_[0]), uint32_t(index / dims_[0] % dims_[1]),
                  uint32_t(index / dims_[0] / dims_[1])});
  auto unique_shifted = [](std::vector<std::array<uint32_t, 3>>& v, int shift) {
    for (auto& c : v)
      for (uint32_t& x : c) x >>= shift;
    std::sort(v.begin(), v.end());
    v.erase(std::unique(v.begin(), v.end()), v.end());
  };
  // Clearance: the cells that turned filled or empty.
  std::vector<std::array<uint32_t, 3>> filled_now, emptied;
  for (size_t n = 0; n < indices.size(); ++n) {
    const bool filled = cells_[size_t(indices[n])] != 0;
    if (filled != (clearance_[size_t(indices[n])] == 0))
      (filled ? filled_now : emptied).push_back(at[n]);
  }
  update_clearance(clearance_, dims_, filled_now, emptied, cell_filled());
  std::vector<std::array<uint32_t, 3>> occ = at;
  unique_shifted(occ, kOccupancyLog2);
  for (const auto& c : occ) update_occupancy_bit(c[0], c[1], c[2]);
  for (int q = 1; q <= pyramid_levels(); ++q) {
    unique_shifted(at, 1);
    for (const auto& c : at) update_pyramid_node(q, c[0], c[1], c[2]);
    if (q != kCellBoxLevel) continue;
    // The node clearances: the nodes that turned filled or empty, at once.
    std::vector<std::array<uint32_t, 3>> nodes_filled, nodes_emptied;
    for (const auto& c : at) note_node_change(c[0], c[1], c[2], &nodes_filled, &nodes_emptied);
    update_node_clearance(nodes_filled, nodes_emptied);
  }
}

void World::update_occupancy_bit(uint32_t oi, uint32_t oj, uint32_t ok) {
  constexpr uint32_t s = 1u << kOccupancyLog2;
  bool any = false;
  for (uint32_t z = ok * s; z < std::min(dims_[2], ok * s + s) && !any; ++z)
    for (uint32_t y = oj * s; y < std::min(dims_[1], oj * s + s) && !any; ++y)
      for (uint32_t x = oi * s; x < std::min(dims_[0], oi * s + s) && !any; ++x)
        any = cells_[size_t(cell_index(x, y, z))] != 0;
  const uint64_t b = oi + uint64_t(occ_dims_[0]) * (oj + uint64_t(occ_dims_[1]) * ok);
  if (any)
    occupancy_[size_t(b >> 6)] |= uint64_t(1) << (b & 63);
  else
    occupancy_[size_t(b >> 6)] &= ~(uint64_t(1) << (b & 63));
}

void World::update_pyramid_node(int q, uint32_t x, uint32_t y, uint32_t z) {
  // The node from its 8 children (a brick counts once, whatever its voxels,
  // so that a brick evicted with its LOD color changes nothing above it).
  double sum[3] = {0, 0, 0};
  uint32_t bricks = 0;
  for (uint32_t c = 0; c < 8; ++c) {
    const uint32_t cx = 2 * x + (c & 1), cy = 2 * y + (c >> 1 & 1), cz = 2 * z + (c >> 2);
    uint32_t nb, abgr;
    if (q == 1) {
      if (cy >= dims_[1]) continue;  // above a cut-off brickgrid
      const uint32_t cell = cells_[size_t(cell_index(cx, cy, cz))];
      if (cell == 0) continue;
      nb = 1;
      abgr = cell_state(cell) == kStateResident ? pool_[cell_brick(cell)].lod : cell_lod_abgr(cell);
    } else {
      if (cy >= pyramid_dim_y(q - 1)) continue;
      const PyramidNode& p = pyramid_[size_t(q - 2)][size_t(pyramid_index(q - 1, cx, cy, cz))];
      if (p.bricks == 0) continue;
      nb = p.bricks, abgr = p.abgr;
    }
    const Color col = esvo::decode_color_abgr(abgr);
    sum[0] += double(nb) * col.r, sum[1] += double(nb) * col.g, sum[2] += double(nb) * col.b;
    bricks += nb;
  }
  PyramidNode& node = pyramid_[size_t(q - 1)][size_t(pyramid_index(q, x, y, z))];
  node.bricks = bricks;
  if (q == kCellBoxLevel) {
    // The box of the node's non-empty cells (cell_box()).
    uint32_t lo[3] = {7, 7, 7}, hi[3] = {0, 0, 0};
    for (uint32_t c = 0; c < 512 && bricks != 0; ++c) {
      const uint32_t l[3] = {c & 7, c >> 3 & 7, c >> 6};
      const uint32_t cy = 8 * y + l[1];
      if (cy >= dims_[1] || cells_[size_t(cell_index(8 * x + l[0], cy, 8 * z + l[2]))] == 0)
        continue;
      for (int a = 0; a < 3; ++a) lo[a] = std::min(lo[a], l[a]), hi[a] = std::max(hi[a], l[a]);
    }
    uint32_t box = 0;
    if (bricks != 0)
      for (int a = 0; a < 3; ++a) box |= lo[a] << (3 * a) | hi[a] << (9 + 3 * a);
    cell_box_[size_t(pyramid_index(q, x, y, z))] = box;
  }
  node.abgr = bricks == 0 ? 0
                          : esvo::encode_color_abgr({float(sum[0] / bricks), float(sum[1] / bricks),
                                                     float(sum[2] / bricks), 1.f});
}

bool World::voxel(uint32_t x, uint32_t y, uint32_t z) const {
  if (x >= grid_.resolution || (y >> kBrickLog2) >= dims_[1] || z >= grid_.resolution) return false;
  const uint32_t c = cells_[size_t(cell_index(x >> 3, y >> 3, z >> 3))];
  if (cell_state(c) != kStateResident) return false;
  return test_voxel(pool_[cell_brick(c)], voxel_bit(x & 7, y & 7, z & 7));
}

void World::set_carved(uint64_t index, const VoxelMask& mask) {
  if (index >= cells_.size()) throw Error("brickmap: carved cell index out of range");
  if (mask == VoxelMask{})
    carved_.erase(index);
  else
    carved_[index] = mask;
}

bool World::carved_voxel(uint32_t x, uint32_t y, uint32_t z) const {
  if (x >= grid_.resolution || (y >> kBrickLog2) >= dims_[1] || z >= grid_.resolution) return false;
  const auto it = carved_.find(cell_index(x >> 3, y >> 3, z >> 3));
  if (it == carved_.end()) return false;
  const uint32_t bit = voxel_bit(x & 7, y & 7, z & 7);
  return (it->second[bit >> 6] >> (bit & 63)) & 1;
}

std::vector<uint64_t> World::decode_voxels() const {
  std::vector<uint64_t> out;
  for (uint32_t k = 0; k < dims_[2]; ++k)
    for (uint32_t j = 0; j < dims_[1]; ++j)
      for (uint32_t i = 0; i < dims_[0]; ++i) {
        const uint32_t c = cells_[size_t(cell_index(i, j, k))];
        if (cell_state(c) != kStateResident) continue;
        const Brick& b = pool_[cell_brick(c)];
        for (uint32_t w = 0; w < 8; ++w)
          for (uint64_t m = b.mask[w]; m != 0; m &= m - 1) {
            const uint32_t bit = uint32_t(std::countr_zero(m));
            out.push_back(morton_encode(i * 8 + (bit & 7), j * 8 + (bit >> 3), k * 8 + w));
          }
      }
  std::sort(out.begin(), out.end());
  return out;
}

WorldStats World::stats() const {
  WorldStats s;
  s.bricks = pool_.live();
  for (uint32_t c : cells_)
    if (cell_state(c) == kStateResident) s.voxels += uint64_t(brick_popcount(pool_[cell_brick(c)]));
  s.grid_bytes = uint64_t(cells_.size()) * 4;
  s.occupancy_bytes = uint64_t(occupancy_.size()) * 8;
  s.clearance_bytes = uint64_t(clearance_.size() + node_clearance_.size());
  for (const std::vector<PyramidNode>& level : pyramid_)
    s.pyramid_bytes += uint64_t(level.size()) * sizeof(PyramidNode);
  s.pyramid_bytes += uint64_t(cell_box_.size()) * sizeof(uint32_t);
  s.brick_bytes = uint64_t(pool_.extent()) * sizeof(Brick);
  s.color_bytes = dxt1_ ? uint64_t(blocks_.size()) * 8 : uint64_t(color_alloc_.extent()) * 4;
  s.normal_bytes = normals_ ? uint64_t(color_alloc_.extent()) * 4 : 0;
  return s;
}

Aabb World::occupied_bounds() const {
  uint32_t lo[3] = {UINT32_MAX, UINT32_MAX, UINT32_MAX}, hi[3] = {0, 0, 0};
  bool any = false;
  for (uint32_t k = 0; k < dims_[2]; ++k)
    for (uint32_t j = 0; j < dims_[1]; ++j)
      for (uint32_t i = 0; i < dims_[0]; ++i) {
        if (cells_[size_t(cell_index(i, j, k))] == 0) continue;
        any = true;
        const uint32_t v[3] = {i, j, k};
        for (int a = 0; a < 3; ++a) lo[a] = std::min(lo[a], v[a]), hi[a] = std::max(hi[a], v[a]);
      }
  Aabb box;
  if (!any) return box;
  const double n = grid_.resolution;
  for (int a = 0; a < 3; ++a) {
    const double l = std::min(n, 8.0 * lo[a]), h = std::min(n, 8.0 * (hi[a] + 1));
    box.lo[a] = float(grid_.origin[a] + l * grid_.voxel_size);
    box.hi[a] = float(grid_.origin[a] + h * grid_.voxel_size);
  }
  return box;
}

}  // namespace voxcast::brickmap
