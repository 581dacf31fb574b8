#pragma once
// The one small interface the renderer uses for every voxel structure
// (ESVO today; DAG, brickmap, GigaVoxels later): trace a ray to a hit or a
// miss with a level-of-detail footprint, then fetch attributes at the hit.
#include <cstdint>
#include <string>

#include "voxcast/math.hpp"

namespace voxcast {

/// Pixel-cone footprint: a voxel is small enough to stop at when its side is
/// <= size_at_origin + size_per_t * t (world units; esvo §6.1 ray_size_coef/bias).
struct LodFootprint {
  float size_at_origin = 0.f;
  float size_per_t = 0.f;
};

struct SurfaceHit {
  float t = INFINITY;      // world distance along the ray's unit direction
  Vec3 position;           // world hit position, clamped into the voxel
  float voxel_size = 0.f;  // world side length of the voxel that was hit
  uint64_t voxel_ref = 0;  // structure-specific handle for attributes()
  uint32_t child = 0;      // structure-specific
  int level = 0;           // octree level of the hit voxel (root = 0)
};

class VoxelStructure {
 public:
  virtual ~VoxelStructure() = default;
  /// World-space bounds of the structure's root cube.
  virtual Aabb bounds() const = 0;
  /// First hit along `ray` (direction must be unit length) within [0, ray.tmax].
  virtual bool trace(const Ray& ray, const LodFootprint& lod, SurfaceHit* hit) const = 0;
  /// Linear color and unit normal of the hit voxel.
  virtual void attributes(const SurfaceHit& hit, Color* color, Vec3* normal) const = 0;
  virtual std::string name() const = 0;
};

}  // namespace voxcast
