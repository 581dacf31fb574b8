#pragma once
// Procedural terrain written straight into a brickmap world (van Wingerden
// 2015 §5.2: a noise height field with overhangs and caves; README "Brickmap
// worlds"). The terrain is a density function of the voxel coordinates,
// evaluated in integer fixed point (so every thread count and ISA gives the
// same bits):
//
//   height(x, z)  fBm value noise (octaves of period 2^p voxels, p from
//                 min(10, log2(min(X, Z)) - 1) down to 3, amplitude halving)
//                 plus a squared low-frequency mountain term, in 1/256 voxel
//   density       height(x, z) - (y + 1/2) + overhang noise (3-D value noise
//                 of period 32, amplitude 5 % of Y): voxel (x, y, z) is solid
//                 when it is > 0 and the voxel is not in a cave
//   caves         where two 3-D noises (period 64, y squashed by 2) are both
//                 near zero: tunnels, from y = 4 up through the surface
//   outside       y < 0 is solid (the ground goes on), everything else
//                 outside [0, X) x [0, Y) x [0, Z) is empty
//
// Y is up (the cameras' up axis). The world stores the exposed voxels only:
// solid voxels with at least one of their six neighbours empty (hidden-voxel
// removal at generation, so that a terrain of 8192 x 8192 voxels stays within
// the 2^24 resident bricks), colored by material (sand, grass, rock, snow on
// the tops by height; dirt, rock and cave stone on the sides and below) with
// a small per-voxel brightness jitter, the normal the mean direction of the
// empty voxels among the 26 neighbours.
#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>

#include "voxcast/math.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast {
class Progress;
}

namespace voxcast::brickmap {

struct TerrainOptions {
  uint32_t size[3] = {1024, 256, 1024};  // voxels in x, y (up), z; each 16 .. 65536
  uint64_t seed = 1;
  int threads = 0;               // worker threads generating chunks (0: hardware concurrency)
  Progress* progress = nullptr;  // advanced once per chunk column done (may be null)
};

/// The grid of the terrain world: the smallest power-of-two cube holding
/// X x Y x Z voxels, the terrain centered in x and z, its base at y = 0,
/// voxel size 1 / max(X, Z). Throws voxcast::Error for sizes outside
/// 16 .. 65536 or a brickgrid past kMaxGridCells.
GridTransform terrain_grid(const TerrainOptions& options);

/// The density at voxel (x, y, z) (the definition above, evaluated in full,
/// without the generator's shortcuts): > 0 solid. Caves give -1. Coordinates
/// outside the terrain follow the "outside" rule (solid below 0: 1).
int64_t terrain_density(const TerrainOptions& options, int64_t x, int64_t y, int64_t z);
/// The highest y at which column (x, z) can be solid (the height field plus
/// the largest overhang; -1 outside the terrain): above it terrain_solid is
/// false without evaluating the 3-D noises.
int64_t terrain_column_top(const TerrainOptions& options, int64_t x, int64_t z);
/// terrain_density > 0.
bool terrain_solid(const TerrainOptions& options, int64_t x, int64_t y, int64_t z);
/// The ABGR8 sRGB color a stored voxel gets.
uint32_t terrain_color(const TerrainOptions& options, int64_t x, int64_t y, int64_t z);
/// The cube-face encoded normal (esvo::encode_normal_cube) a stored voxel gets.
uint32_t terrain_normal(const TerrainOptions& options, int64_t x, int64_t y, int64_t z);
/// The same normal from which of the voxel's 26 neighbours are empty
/// (empty(dx, dy, dz), each in -1..1): the mean direction of the empty ones,
/// +y when they cancel. What a voxel an edit exposes gets (edit.cpp).
uint32_t neighbourhood_normal(const std::function<bool(int, int, int)>& empty);

struct TerrainStats {
  uint64_t bricks = 0, voxels = 0;
  uint64_t chunks = 0;        // chunks holding bricks
  uint64_t raw_bytes = 0;     // chunk bytes before LZ4
  uint64_t chunk_bytes = 0;   // LZ4 chunk bytes written
  uint64_t header_cells = 0;  // brickgrid cells (the header kept in RAM)
};

/// Writes the terrain as a brickmap scene file (format.cpp's layout, the
/// chunk section first): chunk columns are generated in parallel, a window
/// of at most 2 x threads chunk columns in flight, and written in order, so
/// memory holds the brickgrid header (4 B per cell) and those columns, never
/// the world; the bytes are the same for every thread count. Atomic
/// (ContainerWriter). Throws voxcast::Error past kMaxBricks.
TerrainStats write_terrain(const std::filesystem::path& path, const TerrainOptions& options);

}  // namespace voxcast::brickmap
