#pragma once
// The brickmap packet walk (BrickmapStructure::trace_packets, traverse.cpp):
// the walk of traverse.cpp's Walker in 16 (AVX-512) or 8 (AVX2) lanes,
// one ray per lane, the per-level DDAs as lane vectors. What the kernels
// read is set up by traverse.cpp; the kernels are compiled per ISA
// (packet_walk_avx2.cpp, packet_walk_avx512.cpp, packet_walk_kernel.hpp).
#include <atomic>
#include <cstddef>
#include <cstdint>

#include "voxcast/math.hpp"

namespace voxcast::brickmap::detail {

inline constexpr int kPacketMaxLevels = 24;

/// The world as the lane walk reads it, and the LOD footprint.
struct PacketWorld {
  const uint32_t* cells = nullptr;          // brickgrid cells (World::cells)
  const uint32_t* bricks = nullptr;         // the brick pool, 18 words per Brick
  const uint32_t* cell_box = nullptr;       // World::cell_box per node of level kCellBoxLevel
  const uint8_t* clearance = nullptr;       // World::clearances, per cell
  int32_t clearance_last = 0;               // the last index a 4-byte read may start at (size - 4)
  const uint8_t* node_clearance = nullptr;  // World::node_clearances, 8 per node of level B - 3
  int32_t node_clearance_last = 0;          // as clearance_last
  uint32_t dims[3] = {};                    // brickgrid cells per axis
  int L = 0, B = 0;                         // voxel level, brickgrid level
  // Per pyramid level p (1 .. B; cube level B - p): its nodes (PyramidNode
  // as two words, `bricks` first) and their index dims.
  const uint32_t* nodes[kPacketMaxLevels + 1] = {};
  uint32_t node_dim[kPacketMaxLevels + 1] = {}, node_dim_y[kPacketMaxLevels + 1] = {};
  // visit_voxels' brick-slice test and slice entry (off: every brick walked
  // voxel by voxel, as detail::brick_skip_mode Off does for the scalar walk).
  bool slice_skip = true;
  // Walker::lod_stop: side_world(level) <= lod_size0 + lod_per_t exit.
  bool lod_on = false;
  float voxel_world = 0.f, lod_size0 = 0.f, lod_per_t = 0.f;
};

/// The rays in grid units (traverse.cpp's GridRay), clipped as walk() clips
/// them, structure of arrays padded to a multiple of 16 entries.
struct PacketRays {
  const float *o[3], *d[3], *inv[3], *slack[3];
  const float *t0, *t1, *start_t;  // start_t: NaN unless the ray starts at a beam's region
  const float* exit;               // the t the ray leaves the grid at (walk()'s exit)
  const int32_t* axis;             // the entered face's axis at t0
  int count;
};

/// A hit as traverse.cpp's Found.
struct PacketFound {
  float t;
  int32_t face;
  int32_t level;  // cube level of the hit (L: a voxel; above: an LOD stop)
  int32_t c[3];
  uint64_t ref;
};

/// The packet walk's ray set-up (trace_packets' per-ray loop: to_grid and
/// clip_ray of traverse.cpp, the same float and double operations) in
/// lanes, AVX-512 only.
struct PacketSetupIn {
  const Ray* rays = nullptr;  // rays[0 .. count)
  int count = 0;
  /// Beam starts (null: none): ray i's entry region_of[i] of `regions`,
  /// entries of 8 floats: the region's lo and hi (grid units, grid_region),
  /// then a kind as uint32 bits (kRegionNone, kRegionClip, kRegionEmpty).
  const int32_t* region_of = nullptr;
  const float* regions = nullptr;
  double origin[3] = {}, inv_vs = 1.0;  // GridTransform::origin, 1 / voxel_size
  float n = 0.f;                        // float(resolution)
  bool lod_on = false;                  // trace_packets' root LOD stop test
  float root_side = 0.f, lod_size0 = 0.f, lod_per_t = 0.f;
};
/// Writes the rays that enter the grid (in order) to f (o, d, inv, slack
/// per axis, t0, t1, start_t, exit: PacketRays' arrays), axis and id (id0 +
/// their index); the rays whose root cube is an LOD stop to scalar (id0 +
/// index, *n_scalar of them). Returns the number written to f.
inline constexpr uint32_t kRegionNone = 0, kRegionClip = 1, kRegionEmpty = 2;
int packet_setup_avx512(const PacketSetupIn& in, uint32_t id0, float* const f[16], int32_t* axis,
                        uint32_t* id, uint32_t* scalar, int* n_scalar);

inline constexpr uint8_t kPacketMiss = 0, kPacketHit = 1, kPacketScalar = 2, kPacketFault = 3;

/// Lanes that ended as kPacketFault since the start (trace_packets counts
/// them; the tests expect none).
extern std::atomic<uint64_t> packet_lane_faults;

/// status[i] for ray i < q.count: kPacketMiss, kPacketHit (out[i] filled),
/// kPacketScalar (a not-resident brick: the scalar walk answers the ray) or
/// kPacketFault (the lane left the grid, which only a bug in the lane walk
/// can do: the scalar walk answers the ray, the fault is counted).
void packet_walk_avx2(const PacketWorld& w, const PacketRays& q, uint8_t* status, PacketFound* out);
void packet_walk_avx512(const PacketWorld& w, const PacketRays& q, uint8_t* status,
                        PacketFound* out);

}  // namespace voxcast::brickmap::detail
