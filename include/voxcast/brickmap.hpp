#pragma once
// Brickmap worlds (van Wingerden 2015, "Real-time Ray tracing and Editing of
// Large Voxel Scenes", §3.1, §3.3, §4.1, §4.3): a hierarchy of uniform grids
// whose lowest layer keeps voxels raw, so that an edit is a write.
//
//   occupancy layer   one bit per 4x4x4 brickgrid cells (§3.4, §4.1: "one
//                     cell in the higher layer contains (4, 4, 4) brickgrid
//                     cells"), i.e. per 32^3 voxels;
//   brickgrid         one 32-bit cell per 8^3 voxels (§3.1.2, Figure 11);
//   brickmaps         8^3 voxels as a 512-bit solid mask + a color pointer +
//                     an LOD color (§3.1.1, Figure 10).
//
// Coordinates: the world's voxel grid is the GridTransform of the VoxelSet it
// was built from (the same frame ESVO and the DAG are in, so a camera sees the
// same voxels in all of them). Voxel (x, y, z) lies in brickgrid cell
// (x >> 3, y >> 3, z >> 3) at brick-local (x & 7, y & 7, z & 7); brickgrid
// cell (i, j, k) has index i + dims.x * (j + dims.y * k), the occupancy cell
// (i >> 2, j >> 2, k >> 2) likewise with the occupancy dims.
//
// ---- Brickgrid cell (32 bits, Figure 11) ---------------------------------
//   bits 31..30  state: 0 empty, 1 resident, 2 not resident (3 is invalid)
//   bits 29..24  flags: bit 24 = edited (changed since the world was built or
//                loaded; the bricks a save must rewrite), bits 25..29 zero
//   bits 23..0   payload: resident -> brick index in the brick pool;
//                not resident -> the brick's LOD color, R in bits 0..7,
//                G 8..15, B 16..23, 8-bit sRGB (the "first three bytes of the
//                pointer", §3.1.2)
//   An empty cell is the word 0 (validators refuse any other empty word).
//   A resident cell's brick is in RAM and traced voxel by voxel; a
//   not-resident cell answers with its LOD color and asks for its brick
//   through the trace context's request sink (§3.2.1, §4.1).
//
// ---- Brickmap (72 bytes, Figure 10; offsets in bytes) ---------------------
//   +0   u64[8] mask   solid bits: brick-local voxel (x, y, z) is bit
//                      x + 8 y of word z (so one word is one z slice)
//   +64  u32    color  index of the brick's first entry in the color pool;
//                      its popcount(mask) entries follow, voxel v's at
//                      color + popcount(mask bits below v) (§4.1, Figure 13)
//   +68  u32    lod    LOD color: ABGR8 sRGB (esvo::encode_color_abgr) of the
//                      mean linear color of the brick's voxels, A = 255
//   The paper packs 71 bytes (24-bit LOD color); the fourth byte keeps the
//   record 4-byte aligned.
//
// ---- Color pool (§3.1.3, §4.3) --------------------------------------------
//   Per solid voxel one u32 ABGR8 sRGB color and, when the world stores
//   normals, one u32 cube-face normal (esvo::encode_normal_cube) at the same
//   index of a parallel array. Colors stay raw in the world (§3.1.3: "colors
//   can be stored in raw format in RAM which makes editing ... easier").
//   Runs are allocated by size class (ColorAllocator below).
//
// ---- DXT1 colors (§3.1.3; a render-side world, World::use_dxt1) -----------
//   Instead of the u32 colors, one 64-bit DXT1 (BC1) block per 16 voxels of
//   a brick's run: block b of the brick holds the colors of its voxels with
//   rank 16 b .. 16 b + 15 and sits at color_blocks()[Brick::color / 16 + b]
//   (runs start at multiples of 16, their size class). Block bits 0..15 and
//   16..31: endpoint colors c0, c1 as RGB565 of the 8-bit sRGB values (R in
//   the high bits); bits 32 + 2 i .. 33 + 2 i: the palette index of the
//   block's voxel i. c0 > c1: palette c0, c1, (2 c0 + c1) / 3, (c0 + 2 c1) / 3;
//   else c0, c1, (c0 + c1) / 2, black (the encoder never uses black). 0.5 B
//   per voxel instead of 4; normals stay raw.
#include <array>
#include <cstddef>
#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "voxcast/bitfield.hpp"
#include "voxcast/container.hpp"
#include "voxcast/math.hpp"
#include "voxcast/scene_file.hpp"
#include "voxcast/structure.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast {
class FormatRegistry;
}

namespace voxcast::brickmap {

inline constexpr int kBrickLog2 = 3;  // 8^3 voxels per brick (§3.1.1)
inline constexpr int kBrickSide = 1 << kBrickLog2;
inline constexpr int kBrickVoxels = kBrickSide * kBrickSide * kBrickSide;
inline constexpr int kOccupancyLog2 = 2;  // 4^3 brickgrid cells per occupancy bit (§4.1)
/// Cap of World::clearance (in brickgrid cells): the walk jumps at most a
/// cube of radius kMaxClearance - 1 cells, which covers the 8^3 cells of a
/// pyramid node it walks (traverse.cpp, kPyramidStep).
inline constexpr int kMaxClearance = 8;
inline constexpr int kChunkLog2 = 4;  // 16^3 brickmaps per file chunk (§4.5)
/// Largest brickgrid (cells): 1 GiB of cells, e.g. a 5120^3-voxel cube.
inline constexpr uint64_t kMaxGridCells = uint64_t(1) << 28;
/// Largest resident brick index + 1 (the 24-bit payload).
inline constexpr uint32_t kMaxBricks = uint32_t(1) << 24;

// ---- Brickgrid cell fields (layout above) ----
using CellPayload = BitField<0, 24>;
using CellFlags = BitField<24, 6>;
using CellState = BitField<30, 2>;
static_assert(fields_tile<CellPayload, CellFlags, CellState>());
static_assert(CellState::mask == 0xC0000000u && CellFlags::mask == 0x3F000000u &&
              CellPayload::mask == 0x00FFFFFFu);
inline constexpr uint32_t kStateEmpty = 0, kStateResident = 1, kStateNotResident = 2;
inline constexpr uint32_t kFlagEdited = 1;  // bit 0 of CellFlags (word bit 24)

constexpr uint32_t resident_cell(uint32_t brick, uint32_t flags = 0) {
  return CellState::put(kStateResident) | CellFlags::put(flags) | CellPayload::put(brick);
}
/// `abgr`: the LOD color as ABGR8; its low three bytes become the payload.
constexpr uint32_t not_resident_cell(uint32_t abgr, uint32_t flags = 0) {
  return CellState::put(kStateNotResident) | CellFlags::put(flags) | CellPayload::put(abgr);
}
constexpr uint32_t cell_state(uint32_t cell) {
  return CellState::get(cell);
}
constexpr uint32_t cell_brick(uint32_t cell) {
  return CellPayload::get(cell);
}
/// The LOD color of a not-resident cell as ABGR8 with A = 255.
constexpr uint32_t cell_lod_abgr(uint32_t cell) {
  return CellPayload::get(cell) | 0xFF000000u;
}

/// One brickmap (layout above).
struct Brick {
  uint64_t mask[8] = {};
  uint32_t color = 0;
  uint32_t lod = 0;
};
static_assert(sizeof(Brick) == 72 && alignof(Brick) == 8);
static_assert(offsetof(Brick, mask) == 0 && offsetof(Brick, color) == 64 &&
              offsetof(Brick, lod) == 68);

/// Bit index of brick-local voxel (x, y, z) in the 512-bit mask.
constexpr uint32_t voxel_bit(uint32_t x, uint32_t y, uint32_t z) {
  return x | y << 3 | z << 6;
}
constexpr bool test_voxel(const Brick& b, uint32_t bit) {
  return (b.mask[bit >> 6] >> (bit & 63)) & 1;
}
/// Solid voxels of the brick.
int brick_popcount(const Brick& b);

/// The DXT1 block (layout above) of `count` (1..16) ABGR8 colors: endpoints
/// the extreme colors along the colors' principal axis, each voxel the
/// nearest palette entry. Deterministic (integer arithmetic but the axis).
uint64_t dxt1_encode(const uint32_t* abgr, int count);
/// Voxel i's color (ABGR8, A = 255) of a DXT1 block.
uint32_t dxt1_decode(uint64_t block, int i);
/// Solid voxels of the brick whose bit index is below `bit` (§4.1): the
/// voxel's offset in the brick's color run.
int rank_below(const Brick& b, uint32_t bit);

/// O(1) object pool of bricks (§3.1.4): a free list of indices.
class BrickPool {
 public:
  uint32_t allocate();           // throws voxcast::Error past kMaxBricks
  void release(uint32_t index);  // index must be allocated
  Brick& operator[](uint32_t i) { return bricks_[i]; }
  const Brick& operator[](uint32_t i) const { return bricks_[i]; }
  /// Slots ever allocated (the pool's extent); live() of them are in use.
  uint32_t extent() const { return uint32_t(bricks_.size()); }
  uint32_t live() const { return uint32_t(bricks_.size() - free_.size()); }
  const Brick* data() const { return bricks_.data(); }

 private:
  std::vector<Brick> bricks_;
  std::vector<uint32_t> free_;
};

/// Size-class allocator for color runs (§4.3): free nodes kept per class of
/// 16, 32, ..., 512 entries (one brick holds at most 512 voxels). A request
/// takes a node of the smallest class that fits, splitting a node of the
/// next non-empty larger class in halves (the pool grows by one 512-entry
/// node when none is free); a class that collects more than kMergeThreshold
/// free nodes is sorted and its aligned adjacent pairs are merged one class
/// up (O(F log F), F = free nodes of that class). Before the pool would
/// grow, every class is merged that way and the request looks again.
class ColorAllocator {
 public:
  static constexpr int kMinLog2 = 4, kMaxLog2 = 9, kClasses = kMaxLog2 - kMinLog2 + 1;
  static constexpr size_t kMergeThreshold = 64;
  /// Entries of the node serving a run of `count` (1..512) entries.
  static uint32_t class_size(uint32_t count);
  uint32_t allocate(uint32_t count);  // count in [1, 512]; returns the run's first entry
  void release(uint32_t first, uint32_t count);
  /// Entries the pool spans (the color arrays are at least this long).
  uint32_t extent() const { return extent_; }
  uint64_t free_entries() const;

 private:
  static int class_of(uint32_t count);
  void merge(int c, bool cascade);
  size_t merge_threshold(int c) const;
  std::array<std::vector<uint32_t>, kClasses> free_;
  std::array<size_t, kClasses> merged_size_{};  // free nodes left by each class's last merge
  uint32_t extent_ = 0;
};

/// A node of the occupancy pyramid above the brickgrid (World::pyramid_node).
struct PyramidNode {
  uint32_t bricks = 0;  // non-empty brickgrid cells below it (0: the node is empty)
  uint32_t abgr = 0;    // LOD color: mean of those bricks' LOD colors (linear), ABGR8 sRGB
};
static_assert(sizeof(PyramidNode) == 8);

/// Memory per component (§5.1, Table 2), in bytes.
struct WorldStats {
  uint64_t bricks = 0;      // resident bricks
  uint64_t voxels = 0;      // solid voxels
  uint64_t grid_bytes = 0;  // brickgrid cells (4 B each)
  uint64_t occupancy_bytes = 0;
  uint64_t pyramid_bytes = 0;    // the coarse levels above the brickgrid (8 B per node)
  uint64_t clearance_bytes = 0;  // empty-space distances of the cells and level-3 nodes (1 B each)
  uint64_t brick_bytes = 0;      // brick pool extent x 72 B
  uint64_t color_bytes = 0;      // color pool extent x 4 B (size-class slack included;
                                 // DXT1: 8 B per 16 entries)
  uint64_t normal_bytes = 0;     // the same for normals (0 without stored normals)
  uint64_t total_bytes() const {
    return grid_bytes + occupancy_bytes + pyramid_bytes + clearance_bytes + brick_bytes +
           color_bytes + normal_bytes;
  }
  double bits_per_voxel() const {
    return voxels ? 8.0 * double(total_bytes()) / double(voxels) : 0;
  }
};

/// The procedural terrain a world was generated from (brickmap_terrain.hpp,
/// META "terrain"): its density function says which voxels the generator
/// left out as hidden (§3.2.3, §4.2), so that an edit exposing them can
/// bring them back.
struct TerrainSource {
  std::array<uint32_t, 3> size{};  // voxels in x, y, z
  uint64_t seed = 0;
  bool operator==(const TerrainSource&) const = default;
};
/// One brick's 512 voxels as bits (the layout of Brick::mask).
using VoxelMask = std::array<uint64_t, 8>;

class World {
 public:
  /// An empty world over `grid` (brickgrid of ceil(N / 8)^3 cells). Throws
  /// voxcast::Error for an invalid placement or past kMaxGridCells.
  /// `height_cells` (1 .. ceil(N / 8); 0 = all): a brickgrid cut off above
  /// that many cells in y, the up axis of cameras (a terrain far wider than
  /// high): the grid stays the N^3 cube, the voxels above the cut are empty
  /// and take no memory.
  explicit World(const GridTransform& grid, bool normals = true, uint32_t height_cells = 0);

  const GridTransform& grid() const { return grid_; }
  /// Brickgrid cells per axis (y may be cut off, World()); occupancy cells per axis.
  const std::array<uint32_t, 3>& dims() const { return dims_; }
  const std::array<uint32_t, 3>& occupancy_dims() const { return occ_dims_; }
  bool has_normals() const { return normals_; }

  uint64_t cell_index(uint32_t i, uint32_t j, uint32_t k) const {
    return i + uint64_t(dims_[0]) * (j + uint64_t(dims_[1]) * k);
  }
  uint32_t cell(uint64_t index) const { return cells_[index]; }
  const std::vector<uint32_t>& cells() const { return cells_; }
  bool occupied(uint32_t oi, uint32_t oj, uint32_t ok) const {
    const uint64_t b = oi + uint64_t(occ_dims_[0]) * (oj + uint64_t(occ_dims_[1]) * ok);
    return (occupancy_[b >> 6] >> (b & 63)) & 1;
  }
  const std::vector<uint64_t>& occupancy_words() const { return occupancy_; }

  /// The occupancy pyramid: the coarse levels an LOD footprint can stop at
  /// above the bricks and the empty space the walk skips. Level k (1 ..
  /// pyramid_levels()) has pyramid_dim(k)^2 pyramid_dim_y(k) nodes, node (i,
  /// j, l) covering brickgrid cells [i 2^k, (i+1) 2^k) x ... (pyramid_index:
  /// i + d (j + e l), d = pyramid_dim(k), e = pyramid_dim_y(k) = d unless the
  /// brickgrid is cut off in y; nodes above the cut are empty and not
  /// stored); level 0 is the brickgrid itself
  /// and the top level is one node. Kept up to date by set_brick /
  /// set_not_resident.
  int pyramid_levels() const { return int(pyramid_.size()); }
  uint32_t pyramid_dim(int k) const { return dims_[0] >> k; }
  uint32_t pyramid_dim_y(int k) const { return (dims_[1] + (1u << k) - 1) >> k; }
  uint64_t pyramid_index(int k, uint32_t i, uint32_t j, uint32_t l) const {
    return i + uint64_t(pyramid_dim(k)) * (j + uint64_t(pyramid_dim_y(k)) * l);
  }
  const PyramidNode& pyramid_node(int k, uint64_t index) const {
    return pyramid_[size_t(k - 1)][size_t(index)];
  }

  /// The box of the non-empty brickgrid cells of node `index` of pyramid
  /// level kCellBoxLevel (8^3 cells): bits 3a..3a+2 the lowest cell along
  /// axis a (0..7, relative to the node), bits 9+3a.. the highest; 0 for an
  /// empty node (which the walk never enters). The ray walk tests it before
  /// it walks the node's cells (traverse.cpp, visit_cells). Kept up to date
  /// with the pyramid (update_pyramid_node).
  static constexpr int kCellBoxLevel = 3;
  uint32_t cell_box(uint64_t index) const { return cell_box_[size_t(index)]; }
  const std::vector<uint32_t>& cell_boxes() const { return cell_box_; }

  /// Empty-space distance of brickgrid cell `index` (the ray walk's skip,
  /// traverse.cpp): 0 for a non-empty cell, else the Chebyshev distance in
  /// cells to the nearest non-empty cell, capped at kMaxClearance (cells
  /// outside the grid or above a cut-off count as empty), so that the cube
  /// of radius clearance - 1 around the cell holds no non-empty cell. Kept
  /// up to date with the pyramid (update_occupancy).
  uint8_t clearance(uint64_t index) const { return clearance_[size_t(index)]; }
  const std::vector<uint8_t>& clearances() const { return clearance_; }

  /// Empty space ahead of the pyramid node `index` of level kCellBoxLevel
  /// (8^3 cells) for a ray of octant `octant` (bit a set: the ray moves
  /// up along axis a): the side, in nodes, of the largest cube with its
  /// corner at the node that reaches into that octant and holds no
  /// non-empty node, capped at kMaxClearance (0 for a non-empty node;
  /// nodes outside the grid or above a cut-off count as empty). A ray never
  /// returns behind the node it is in, so the lane walk
  /// (packet_walk_kernel.hpp) jumps across that cube as the cell walk does
  /// across a cell's clearance cube; a one-sided cube is larger than the
  /// centred one next to a surface the ray moves away from. 8 B per node
  /// (node_clearances()[8 index + octant]); empty without such a level
  /// (grids below 2^6 voxels). Kept up to date with the pyramid
  /// (update_occupancy).
  uint8_t node_clearance(uint64_t index, int octant) const {
    return node_clearance_[size_t(index * 8 + uint64_t(octant))];
  }
  const std::vector<uint8_t>& node_clearances() const { return node_clearance_; }

  const BrickPool& bricks() const { return pool_; }
  const Brick& brick(uint32_t index) const { return pool_[index]; }
  const std::vector<uint32_t>& colors() const { return colors_; }
  /// Store colors as DXT1 blocks from now on (layout above; colors() stays
  /// empty): only an empty world, a render-side one (a streamer's); such a
  /// world cannot be saved (edits re-encode its blocks). Throws
  /// voxcast::Error for a world that has bricks.
  void use_dxt1();
  bool dxt1() const { return dxt1_; }
  const std::vector<uint64_t>& color_blocks() const { return blocks_; }
  /// The ABGR8 color of the voxel of rank `rank` in brick `b` (raw or DXT1).
  uint32_t color_of(const Brick& b, uint32_t rank) const {
    return dxt1_ ? dxt1_decode(blocks_[(b.color + rank) >> 4], int((b.color + rank) & 15))
                 : colors_[b.color + rank];
  }
  const std::vector<uint32_t>& normals() const { return normals_data_; }

  /// Stores a brick in cell `index` (replacing what was there, releasing its
  /// pool slot and color run): `mask`, then per solid voxel in bit order its
  /// ABGR8 color and (with normals) cube-face normal. An all-zero mask
  /// empties the cell. The LOD color is computed from the colors, unless
  /// `lod` gives it (a streamed brick keeps the LOD color of all its voxels
  /// when hidden ones were dropped). `flags`: CellFlags of the new cell.
  /// A brick whose color run's size class fits the new voxel count keeps
  /// its run (written in place). `update_pyramid` false: the occupancy bit
  /// and pyramid nodes above the cell and the clearances are left to a later
  /// update_occupancy(cells) of every cell changed that way (an edit's
  /// batch), and are stale until then.
  void set_brick(uint64_t index, const uint64_t mask[8], const uint32_t* colors,
                 const uint32_t* normals, uint32_t flags = 0, const uint32_t* lod = nullptr,
                 bool update_pyramid = true);
  /// Makes cell `index` not resident with LOD color `abgr` (a brick known to
  /// exist but not loaded, §3.2.1), releasing its brick if it had one.
  /// `update_pyramid`: as for set_brick.
  void set_not_resident(uint64_t index, uint32_t abgr, uint32_t flags = 0,
                        bool update_pyramid = true);
  /// Recomputes the occupancy bit of the occupancy cell holding brickgrid
  /// cell `index` and the pyramid nodes above it (set_brick /
  /// set_not_resident keep them up to date).
  void update_occupancy(uint64_t index);
  /// The same for many cells, each occupancy bit and pyramid node
  /// recomputed once.
  void update_occupancy(const std::vector<uint64_t>& indices);

  /// True if voxel (x, y, z) of the grid is solid in a resident brick.
  bool voxel(uint32_t x, uint32_t y, uint32_t z) const;

  /// A generated terrain's world stores its exposed voxels only; the solid
  /// set it stands for is the stored voxels plus the voxels the terrain's
  /// density makes solid and no edit has carved out:
  ///   solid(v) = voxel(v) || (terrain density(v) > 0 && !carved(v)).
  /// Removals carve (edit(), stamp()) and bring back the density's voxels they
  /// expose. Without a terrain the solid set is the stored voxels.
  const std::optional<TerrainSource>& terrain() const { return terrain_; }
  void set_terrain(const std::optional<TerrainSource>& t) { terrain_ = t; }
  /// The carved voxels per brickgrid cell (cells without any are not listed).
  const std::map<uint64_t, VoxelMask>& carved() const { return carved_; }
  /// Replaces the carved voxels of cell `index` (an all-zero mask: none).
  void set_carved(uint64_t index, const VoxelMask& mask);
  bool carved_voxel(uint32_t x, uint32_t y, uint32_t z) const;
  /// The solid voxels of the resident bricks as sorted Morton codes.
  std::vector<uint64_t> decode_voxels() const;
  WorldStats stats() const;
  /// World-space bounds of the non-empty brickgrid cells (clipped to the grid).
  Aabb occupied_bounds() const;

 private:
  void update_occupancy_bit(uint32_t oi, uint32_t oj, uint32_t ok);
  void update_pyramid_node(int level, uint32_t x, uint32_t y, uint32_t z);
  // The clearance of the kCellBoxLevel node holding (x, y, z) of that level
  // after its pyramid update, if it turned filled or empty (also added to
  // *filled_now / *emptied when given, for one batched update).
  void note_node_change(uint32_t x, uint32_t y, uint32_t z,
                        std::vector<std::array<uint32_t, 3>>* filled_now,
                        std::vector<std::array<uint32_t, 3>>* emptied) const;
  // node_clearance() of the nodes a change of the nodes in [lo, hi] (of
  // level kCellBoxLevel) can reach: up to kMaxClearance behind them.
  void update_node_clearance(const std::vector<std::array<uint32_t, 3>>& filled_now,
                             const std::vector<std::array<uint32_t, 3>>& emptied);
  std::array<uint32_t, 3> node_dims() const {
    return {pyramid_dim(kCellBoxLevel), pyramid_dim_y(kCellBoxLevel), pyramid_dim(kCellBoxLevel)};
  }
  auto node_filled() const {
    return [this](uint32_t i, uint32_t j, uint32_t k) {
      return pyramid_node(kCellBoxLevel, pyramid_index(kCellBoxLevel, i, j, k)).bricks != 0;
    };
  }
  auto cell_filled() const {
    return [this](uint32_t i, uint32_t j, uint32_t k) {
      return cells_[size_t(cell_index(i, j, k))] != 0;
    };
  }

  GridTransform grid_;
  bool normals_;
  std::array<uint32_t, 3> dims_{}, occ_dims_{};
  std::vector<uint32_t> cells_;
  std::vector<uint64_t> occupancy_;
  std::vector<std::vector<PyramidNode>> pyramid_;  // levels 1 .. K
  std::vector<uint8_t> clearance_;                 // per brickgrid cell (clearance())
  std::vector<uint32_t> cell_box_;                 // per node of level kCellBoxLevel
  std::vector<uint8_t> node_clearance_;            // per node of level kCellBoxLevel
  BrickPool pool_;
  ColorAllocator color_alloc_;
  std::vector<uint32_t> colors_, normals_data_;
  bool dxt1_ = false;
  std::vector<uint64_t> blocks_;  // DXT1 colors, one block per 16 entries
  std::optional<TerrainSource> terrain_;
  std::map<uint64_t, VoxelMask> carved_;  // ordered: saved in cell order
};

struct BuildOptions {
  /// Keep the voxel set's normals (4 B per voxel); false: shading normals
  /// come from the crossed voxel face (§4.1).
  bool normals = true;
};

/// Builds the world of `voxels` (the voxelizer's output, the input ESVO and
/// the DAG are built from): one brick per non-empty 8^3 block, its colors
/// (and normals) raw in bit order (§4.1), its LOD color the mean of its
/// voxels' linear colors. Voxel sets without attributes get linear gray
/// (0.5, 0.5, 0.5) as in ESVO. Deterministic. Throws voxcast::Error past
/// kMaxGridCells or kMaxBricks.
World build_world(const VoxelSet& voxels, const BuildOptions& options = {});

/// The brickmap world as a Structure with a SurfaceQuery (§3.3, §4.1).
///
/// trace(): a DDA per level in grid units over the cube hierarchy of the
/// grid (cube level l has side 2^(L - l) voxels, L = grid.levels): the
/// pyramid levels above the brickgrid (World::pyramid_node), the brickgrid
/// (level L - 3), the 4^3 and 2^3 blocks inside a brick and the voxels. Each
/// level walks the children of one occupied cube of the level above, stepping
/// exactly across its planes (the same plane t is computed the same way on
/// every level, so a level is left where its parent says). Where no LOD stop
/// is possible in between, the walk skips levels: above the brickgrid it
/// visits the pyramid levels B - 3j only (B = L - 3; a node's 8^3 children
/// per descent), and goes from a brick straight to its voxels (the paper's
/// bottom layers); an empty brickgrid cell's clearance (World::clearance)
/// lets it cross the empty cube around the cell in one exact step. The pyramid, brickgrid and voxel
/// levels have loops of their own (index stepped, the brick's mask held) with the same planes and
/// tie breaks as the general one (src/brickmap/traverse.cpp). Hits are cubes: SurfaceHit::t is the
/// cube's entry t (0 for an origin inside it) and level its level. An occupied cube answers (LOD,
/// the rule of esvo::cast_ray) when its side is <= the footprint at its exit t: above the brickgrid
/// with its pyramid node's color, at or below it with the brick's LOD color. A brick that is not
/// resident answers with its LOD color at the brick level and, unless the footprint stops there
/// anyway, pushes Request{kind kRequestBrick, key = cell index}. voxel_ref: bit 63 set = LOD hit
/// with the ABGR8 color in bits 0..31; else brick index << 9 | voxel bit. child: the entered face
/// (axis * 2 + (outward normal negative ? 1 : 0)), 6 when the ray starts inside the voxel.
/// beam_start(): the coarse pass of the beam optimization (esvo §6.2) over
/// the pyramid and the brickgrid with the octree family's conservative cube
/// test (core/beam_frustum.hpp): a box holding every cell (and LOD cube) a
/// ray of the beam can stop in; trace() then starts just before the box's
/// entry planes, with each level's start cell found by plane comparisons,
/// so the hit is bit-identical to the walk from the grid's entry.
/// frustum_start(): beam_start() that also lists the kept cubes (BeamStart::
/// nodes, octant -1: no front-to-back order, the packet walk uses the box
/// only); given such a `within` (a tile's, for its pixel blocks), the pass
/// starts from its cubes instead of the root: the tile's beam holds the
/// block's, so every cube a block ray can stop in lies in one of them.
/// attributes(): the stored color and normal; the crossed face's normal
/// without stored normals and for LOD hits; a ray starting inside a voxel
/// gets the face the ray looks at (the dominant axis of -direction).
/// trace_packets(): trace()'s hits bit for bit, the walk in 16 (AVX-512) or
/// 8 (AVX2) lanes (src/brickmap/packet_walk_kernel.hpp); counting contexts,
/// worlds with a brick-use record, grids below 2^7 voxels and rays that meet
/// a not-resident brick go through trace(). occluded_packets(): occluded()
/// per ray.
class BrickmapStructure final : public Structure, public SurfaceQuery, public SurfacePackets {
 public:
  static constexpr uint32_t kRequestBrick = 0;
  /// `brick_seen` (may be null): per brick pool slot, the TraceContext::frame
  /// of the last ray that entered the brick (relaxed atomic stores; sized to
  /// the pool's extent by the owner, between passes): the usage a streamer
  /// evicts by.
  explicit BrickmapStructure(std::shared_ptr<const World> world,
                             std::vector<uint32_t>* brick_seen = nullptr);
  std::string name() const override { return "brickmap"; }
  Aabb bounds() const override;
  const SurfaceQuery* surface() const override { return this; }
  bool trace(const Ray& ray, const LodFootprint& lod, TraceContext& ctx, SurfaceHit* hit,
             const BeamStart* beam = nullptr) const override;
  /// The any-hit query of shadow and AO rays: 0 when trace() would find a
  /// hit, else 1, by the same walk without recording the hit (no hit
  /// position, voxel reference or face), the same requests and brick use.
  float transmittance(const Ray& ray, const LodFootprint& lod, TraceContext& ctx,
                      const BeamStart* beam = nullptr) const override;
  void beam_start(const BeamFrustum& beam, TraceContext& ctx, BeamStart* start) const override;
  void frustum_start(const BeamFrustum& beam, int octant, TraceContext& ctx, BeamStart* start,
                     const BeamStart* within = nullptr) const override;
  void attributes(const SurfaceHit& hit, TraceContext& ctx, Color* color,
                  Vec3* normal) const override;
  const SurfacePackets* packets() const override { return this; }
  void trace_packets(const Ray* rays, size_t n, const LodFootprint& lod, TraceContext& ctx,
                     SurfaceHit* hits, uint8_t* found, Isa isa,
                     const BeamStart* const* beams = nullptr) const override;
  void occluded_packets(const Ray* rays, size_t n, const LodFootprint& lod, TraceContext& ctx,
                        uint8_t* occluded, Isa isa) const override;
  const World& world() const { return *world_; }

 private:
  // beam_start() and frustum_start(): the pass from the root, or from
  // `within`'s cubes; `list`: also record the kept cubes in start->nodes.
  void coarse_pass(const BeamFrustum& beam, TraceContext& ctx, BeamStart* start,
                   const BeamStart* within, bool list) const;
  std::shared_ptr<const World> world_;
  std::vector<uint32_t>* seen_;
};

/// The queries of a world that its owner changes between passes (the
/// streamer, brickmap_stream.hpp; the live editor, brickmap_live.hpp):
/// answered by a BrickmapStructure the derived class creates in query_.
class BrickmapView : public Structure, public SurfaceQuery {
 public:
  std::string name() const override { return "brickmap"; }
  Aabb bounds() const override { return query_->bounds(); }
  const SurfaceQuery* surface() const override { return this; }
  bool trace(const Ray& ray, const LodFootprint& lod, TraceContext& ctx, SurfaceHit* hit,
             const BeamStart* beam = nullptr) const override {
    return query_->trace(ray, lod, ctx, hit, beam);
  }
  float transmittance(const Ray& ray, const LodFootprint& lod, TraceContext& ctx,
                      const BeamStart* beam = nullptr) const override {
    return query_->transmittance(ray, lod, ctx, beam);
  }
  void beam_start(const BeamFrustum& beam, TraceContext& ctx, BeamStart* start) const override {
    query_->beam_start(beam, ctx, start);
  }
  void attributes(const SurfaceHit& hit, TraceContext& ctx, Color* color,
                  Vec3* normal) const override {
    query_->attributes(hit, ctx, color, normal);
  }

 protected:
  std::unique_ptr<BrickmapStructure> query_;
};

// ---- Editing (§3.2.2, §4.4; src/brickmap/edit.cpp) ----

enum class EditOp {
  Add,     // make the voxels solid with the brush color (normals facing away from its center)
  Remove,  // make them empty
  Paint,   // recolor the solid ones
};

/// A brush in world coordinates. A voxel is inside when its center is (a
/// sphere's closed ball, a box's closed box).
struct Brush {
  enum class Shape { Sphere, Box };
  Shape shape = Shape::Sphere;
  Vec3d a;            // sphere: center; box: min corner
  Vec3d b;            // box: max corner
  double radius = 0;  // sphere
  static Brush sphere(Vec3d center, double radius) { return {Shape::Sphere, center, {}, radius}; }
  static Brush box(Vec3d lo, Vec3d hi) { return {Shape::Box, lo, hi, 0}; }
  bool contains(const Vec3d& p) const;
};

struct EditResult {
  uint64_t voxels = 0;          // voxels whose state or color changed
  std::vector<uint64_t> cells;  // brickgrid cells rewritten (the bricks to re-upload, §4.4)
};

/// Applies one brush to the voxels of the grid (outside voxels are
/// ignored). Every brick that changes is stored anew (set_brick: the color
/// run rewritten in place when its size class fits, else released and
/// reallocated; LOD color recomputed) and flagged Edited; the occupancy and
/// pyramid are recomputed once at the end. The brush is applied to batches
/// of bricks in parallel (TBB) and the bricks are stored in cell order, so
/// the world is the same whatever the threads. Throws voxcast::Error for a
/// non-finite or inverted brush, or (before anything changes) when the
/// brush touches a brick that is not resident.
EditResult edit(World& world, const Brush& brush, EditOp op, const Color& color = {});

/// The mesh-stamp brush: `voxels` (on the world's grid, e.g. a mesh
/// voxelized into world.grid(), with --fill solid for its interior) as the
/// brush. Add stores them with their own colors and normals (`color` and +z
/// when the set has none), Remove empties them, Paint recolors the solid
/// ones with their colors (or `color`). Same bookkeeping and refusals as
/// edit() (parallel batches stored in cell order; a not-resident brick
/// refuses the stamp before anything changes); throws voxcast::Error for a
/// set on another grid.
EditResult stamp(World& world, const VoxelSet& voxels, EditOp op, const Color& color = {});

/// World-scale snowfall (§5.5).
struct SnowOptions {
  uint64_t seed = 1;
  double rate = 0.5;                      // share of the columns a step snows on, [0, 1]
  Color color{0.86f, 0.88f, 0.92f, 1.f};  // linear
};
/// One step of snowfall: in every voxel column (x, z) that has a solid voxel
/// and is chosen this step (a hash of x, z, `step` and the seed below
/// `rate`), one snow voxel (normal +y) on top of the column's highest solid
/// voxel: snow lands only where the sky is open above, on upward-facing
/// surfaces, never under overhangs or in caves, and piles up step by step.
/// Applied through stamp() (the bricks it rewrote in the result). Throws
/// voxcast::Error for a rate outside [0, 1] or a brick that is not resident.
EditResult snow_step(World& world, uint32_t step, const SnowOptions& options = {});

// ---- Scene files (src/brickmap/format.cpp; layout documented there) ----

/// META "format" of a brickmap scene.
inline constexpr const char* kFormatName = "brickmap";
/// The world as a container (META + the BMGH, BMCT, BMCK sections).
Container save_world(const World& world, const SceneInfo& info);
/// save_world() written to `path` (atomically, Container::write).
void save_scene(const std::filesystem::path& path, const World& world, const SceneInfo& info);
/// The same sections streamed into a container writer (the registry's save).
void write_world(ContainerWriter& out, const World& world, const SceneInfo& info);
/// The world of a container; every size, offset and index is validated
/// before use (throws voxcast::Error with a one-line reason).
World load_world(const Container& in, SceneInfo* info = nullptr);
World load_world(const ContainerReader& in, SceneInfo* info = nullptr);

/// Adds the "brickmap" entry to the format registry (format_registry.hpp).
void register_format(FormatRegistry& registry);

}  // namespace voxcast::brickmap
