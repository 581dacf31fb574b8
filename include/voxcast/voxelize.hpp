#pragma once
// Triangle -> surface voxel conversion (Hitchhiker's guide to voxels:
// dominant-axis projection, 2-D edge functions with per-edge constants, depth
// range from the triangle plane), parallel over triangles with TBB.
#include <cstdint>
#include <vector>

#include "voxcast/math.hpp"
#include "voxcast/mesh.hpp"

namespace voxcast {

class Progress;

inline constexpr int kMaxGridLevels = 20;  // grids up to 2^20 voxels per axis

/// Largest world coordinate of a scene's root cube (see placement_is_valid):
/// 1e18, well below sqrt(FLT_MAX) ~ 1.8e19.
inline constexpr double kMaxWorldCoordinate = 1e18;

/// Placement of an N^3 voxel grid in world space. Voxel (i,j,k) covers
/// [origin + i*voxel_size, origin + (i+1)*voxel_size) per axis. The grid is
/// also the octree root cube: side = resolution * voxel_size.
struct GridTransform {
  Vec3 origin;              // world position of the grid's min corner
  double voxel_size = 1.0;  // world units
  uint32_t resolution = 1;  // N = 2^levels
  int levels = 0;

  double side() const { return voxel_size * resolution; }
  /// True if the root cube is a non-degenerate box in float world
  /// coordinates (what cameras and rays work in): positive finite voxel
  /// size, origin + side above the origin on every axis, and every corner
  /// coordinate within +-kMaxWorldCoordinate, so that distances, their
  /// squares and a camera a few extents away stay finite in float. Scene
  /// validators refuse any other placement, so a loaded scene can always be
  /// framed (README "Reliability").
  bool placement_is_valid() const;
  /// Smallest power-of-two grid of `resolution` voxels per axis whose cube
  /// contains `bounds` with a small margin, the mesh centered in it.
  static GridTransform fit(const Aabb& bounds, uint32_t resolution);
  /// Grid whose voxels are at most `voxel_size` wide (resolution rounded up to
  /// a power of two). Throws voxcast::Error past 2^20.
  static GridTransform fit_voxel_size(const Aabb& bounds, double voxel_size);
};

enum class VoxelizationMode {
  Conservative,   // every voxel the closed triangle touches (separating-axis exact)
  SixSeparating,  // thin: no 6-connected path leaks through a closed surface
};

struct VoxelizeOptions {
  VoxelizationMode mode = VoxelizationMode::Conservative;
  bool attributes = true;  // compute per-voxel colors and normals
  Progress* progress = nullptr;
};

/// Sorted, unique surface voxels with box-filtered attributes.
struct VoxelSet {
  GridTransform grid;
  std::vector<uint64_t> codes;  // Morton codes (see morton.hpp), ascending, unique
  // The attribute arrays are empty when VoxelizeOptions::attributes was false.
  std::vector<Color> colors;   // area-weighted mean surface color, linear RGBA
  std::vector<Vec3> normals;   // area-weighted mean shading normal, unit length
  std::vector<float> weights;  // surface area inside the voxel, in voxel units^2
  size_t size() const { return codes.size(); }
};

/// Voxelizes `mesh` into `grid`. Deterministic: the same mesh and options give
/// the same VoxelSet whatever the thread count.
VoxelSet voxelize(const Mesh& mesh, const GridTransform& grid, const VoxelizeOptions& options);

/// The voxels of an N^3 grid covered by one triangle given in grid units
/// (voxel (i,j,k) = [i,i+1]x[j,j+1]x[k,k+1]); Morton codes are appended to
/// `out` unsorted, possibly with duplicates. Exposed for tests and tools.
void triangle_voxels(const double tri[3][3], uint32_t resolution, VoxelizationMode mode,
                     std::vector<uint64_t>& out);

}  // namespace voxcast
