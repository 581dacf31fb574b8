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
#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "voxcast/bitfield.hpp"
#include "voxcast/math.hpp"
#include "voxcast/scene_file.hpp"
#include "voxcast/structure.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast::brickmap {

inline constexpr int kBrickLog2 = 3;  // 8^3 voxels per brick (§3.1.1)
inline constexpr int kBrickSide = 1 << kBrickLog2;
inline constexpr int kBrickVoxels = kBrickSide * kBrickSide * kBrickSide;
inline constexpr int kOccupancyLog2 = 2;  // 4^3 brickgrid cells per occupancy bit (§4.1)
inline constexpr int kChunkLog2 = 4;      // 16^3 brickmaps per file chunk (§4.5)
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
  std::array<std::vector<uint32_t>, kClasses> free_;
  uint32_t extent_ = 0;
};

/// Memory per component (§5.1, Table 2), in bytes.
struct WorldStats {
  uint64_t bricks = 0;      // resident bricks
  uint64_t voxels = 0;      // solid voxels
  uint64_t grid_bytes = 0;  // brickgrid cells (4 B each)
  uint64_t occupancy_bytes = 0;
  uint64_t brick_bytes = 0;   // brick pool extent x 72 B
  uint64_t color_bytes = 0;   // color pool extent x 4 B (size-class slack included)
  uint64_t normal_bytes = 0;  // the same for normals (0 without stored normals)
  uint64_t total_bytes() const {
    return grid_bytes + occupancy_bytes + brick_bytes + color_bytes + normal_bytes;
  }
  double bits_per_voxel() const {
    return voxels ? 8.0 * double(total_bytes()) / double(voxels) : 0;
  }
};

class World {
 public:
  /// An empty world over `grid` (brickgrid of ceil(N / 8)^3 cells). Throws
  /// voxcast::Error for an invalid placement or past kMaxGridCells.
  explicit World(const GridTransform& grid, bool normals = true);

  const GridTransform& grid() const { return grid_; }
  /// Brickgrid cells per axis; occupancy cells per axis.
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

  const BrickPool& bricks() const { return pool_; }
  const Brick& brick(uint32_t index) const { return pool_[index]; }
  const std::vector<uint32_t>& colors() const { return colors_; }
  const std::vector<uint32_t>& normals() const { return normals_data_; }

  /// Stores a brick in cell `index` (replacing what was there, releasing its
  /// pool slot and color run): `mask`, then per solid voxel in bit order its
  /// ABGR8 color and (with normals) cube-face normal. An all-zero mask
  /// empties the cell. The LOD color is computed from the colors. `flags`:
  /// CellFlags of the new cell.
  void set_brick(uint64_t index, const uint64_t mask[8], const uint32_t* colors,
                 const uint32_t* normals, uint32_t flags = 0);
  /// Makes cell `index` not resident with LOD color `abgr` (a brick known to
  /// exist but not loaded, §3.2.1), releasing its brick if it had one.
  void set_not_resident(uint64_t index, uint32_t abgr, uint32_t flags = 0);
  /// Recomputes the occupancy bit of the occupancy cell holding brickgrid
  /// cell `index` (set_brick / set_not_resident keep it up to date).
  void update_occupancy(uint64_t index);

  /// True if voxel (x, y, z) of the grid is solid in a resident brick.
  bool voxel(uint32_t x, uint32_t y, uint32_t z) const;
  /// The solid voxels of the resident bricks as sorted Morton codes.
  std::vector<uint64_t> decode_voxels() const;
  WorldStats stats() const;
  /// World-space bounds of the non-empty brickgrid cells (clipped to the grid).
  Aabb occupied_bounds() const;

 private:
  GridTransform grid_;
  bool normals_;
  std::array<uint32_t, 3> dims_{}, occ_dims_{};
  std::vector<uint32_t> cells_;
  std::vector<uint64_t> occupancy_;
  BrickPool pool_;
  ColorAllocator color_alloc_;
  std::vector<uint32_t> colors_, normals_data_;
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
/// trace(): a DDA per level (occupancy -> brickgrid -> brick mask) in grid
/// units, each level stepping exactly across the planes of the level below
/// (the same plane t is computed the same way on every level, so a level is
/// left where its parent says). Hits are voxel cubes: SurfaceHit::t is the
/// voxel's entry t (0 for an origin inside it), level = grid.levels for a
/// voxel, grid.levels - 3 for a brick answered by its LOD color (0 in grids
/// below 8^3, whose one brick is clipped to the grid); a brick
/// answers with its LOD color when its side is <= the footprint at its exit
/// t (the LOD rule of esvo::cast_ray), or when it is not resident (then a
/// Request{kind kRequestBrick, key = cell index} is pushed). voxel_ref:
/// bit 63 set = LOD hit with the ABGR8 color in bits 0..31; else brick index
/// << 9 | voxel bit. child: the entered face (axis * 2 + (outward normal
/// negative ? 1 : 0)), 6 when the ray starts inside the voxel.
/// attributes(): the stored color and normal; the crossed face's normal
/// without stored normals and for LOD hits; a ray starting inside a voxel
/// gets the face the ray looks at (the dominant axis of -direction).
class BrickmapStructure final : public Structure, public SurfaceQuery {
 public:
  static constexpr uint32_t kRequestBrick = 0;
  explicit BrickmapStructure(std::shared_ptr<const World> world);
  std::string name() const override { return "brickmap"; }
  Aabb bounds() const override;
  const SurfaceQuery* surface() const override { return this; }
  bool trace(const Ray& ray, const LodFootprint& lod, TraceContext& ctx, SurfaceHit* hit,
             const BeamStart* beam = nullptr) const override;
  void attributes(const SurfaceHit& hit, TraceContext& ctx, Color* color,
                  Vec3* normal) const override;
  const World& world() const { return *world_; }

 private:
  std::shared_ptr<const World> world_;
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
/// ignored). Every brick that changes is stored anew (set_brick: pool slot
/// and color run released and reallocated, LOD color recomputed) and flagged
/// Edited. Throws voxcast::Error for a non-finite or inverted brush, or when
/// the brush touches a brick that is not resident.
EditResult edit(World& world, const Brush& brush, EditOp op, const Color& color = {});

/// The world as the renderer's VoxelStructure (render() on main still takes
/// one; an adapter until the renderer takes a Structure): each call traces
/// with a TraceContext of its own (no counters, requests dropped).
std::unique_ptr<VoxelStructure> make_voxel_structure(std::shared_ptr<const World> world);
/// The world behind a make_voxel_structure() result (null for any other structure).
const World* adapted_world(const VoxelStructure& structure);

// ---- Scene files (src/brickmap/format.cpp; layout documented there) ----

/// META "format" of a brickmap scene.
inline constexpr const char* kFormatName = "brickmap";
/// The world as a container (META + the BMGH, BMCT, BMCK sections).
Container save_world(const World& world, const SceneInfo& info);
/// save_world() written to `path` (atomically, Container::write).
void save_scene(const std::filesystem::path& path, const World& world, const SceneInfo& info);
/// The world of a container; every size, offset and index is validated
/// before use (throws voxcast::Error with a one-line reason).
World load_world(const Container& in, SceneInfo* info = nullptr);

}  // namespace voxcast::brickmap
