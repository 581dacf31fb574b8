#pragma once
// ESVO as a VoxelStructure, and the raw ray caster (esvo §6.1, Appendix A).
#include <memory>

#include "voxcast/esvo.hpp"
#include "voxcast/structure.hpp"

namespace voxcast::esvo {

/// Ray in octree space (root cube [1,2]^3) and the result of a cast.
struct CastResult {
  float t;              // hit t (same parameterization as the input ray); +inf on a miss
  Vec3 pos;             // min corner of the hit cube, octree space
  uint32_t parent_slot; // descriptor slot of the hit voxel's parent
  int child;            // child slot index of the hit voxel in its parent
  int scale;            // hit cube side = 2^(scale - kMaxScale)
  bool hit;             // authoritative hit flag (t of a hit can be any value in [0, tmax])
};

/// Appendix A, ported: `origin`/`dir` in octree space, t in [0, tmax].
/// LOD: terminate at a voxel whose side (octree units) <= size_coef * t + size_bias
/// (t = the voxel's exit t, as in the listing); 0, 0 = always the finest level.
/// Non-finite origin/direction: miss. Direction components below 2^-23 are
/// replaced by +-2^-23 (sign kept, also for -0.0), as in the listing.
CastResult cast_ray(const EsvoOctree& octree, Vec3 origin, Vec3 dir, float tmax, float size_coef,
                    float size_bias);

class EsvoStructure final : public VoxelStructure {
 public:
  explicit EsvoStructure(std::shared_ptr<const EsvoOctree> octree);
  Aabb bounds() const override;
  bool trace(const Ray& ray, const LodFootprint& lod, SurfaceHit* hit) const override;
  void attributes(const SurfaceHit& hit, Color* color, Vec3* normal) const override;
  std::string name() const override { return "esvo"; }
  const EsvoOctree& octree() const { return *octree_; }

 private:
  std::shared_ptr<const EsvoOctree> octree_;
};

}  // namespace voxcast::esvo
