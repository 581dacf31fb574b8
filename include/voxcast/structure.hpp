#pragma once
// The one small interface the renderer uses for every voxel structure (the
// ESVO octree and the sparse voxel DAG today, both through the one octree
// caster of octree_structure.hpp; brickmap, GigaVoxels later): trace a ray to
// a hit or a miss with a level-of-detail footprint, then fetch attributes at
// the hit.
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

/// Profiling counters of the ray caster (esvo §8.5, Table 6), summed over one
/// or more rays. Only filled by the counting path (VoxelStructure::trace_hinted
/// with TraceHints::counters set); the plain trace() never touches them.
struct RayCounters {
  uint64_t iterations = 0;          // main-loop iterations
  uint64_t intersects = 0;          // voxels processed by INTERSECT (Figure 15)
  uint64_t pushes = 0;              // PUSH executed (descend into a child)
  uint64_t stores = 0;              // actual stack writes by PUSH
  uint64_t advances = 0;            // ADVANCE executed
  uint64_t pops = 0;                // POP executed (incl. the one that leaves the root)
  uint64_t descriptor_fetches = 0;  // child descriptors read (8 bytes each)
  uint64_t far_reads = 0;           // far pointers read (4 bytes each)
  uint64_t attribute_bytes = 0;     // bytes read to fetch the hit's attributes
  /// "glob bytes" of Table 6: descriptor fetches x 8 + far pointers x 4 + attributes.
  uint64_t bytes() const { return descriptor_fetches * 8 + far_reads * 4 + attribute_bytes; }
  RayCounters& operator+=(const RayCounters& o) {
    iterations += o.iterations, intersects += o.intersects, pushes += o.pushes;
    stores += o.stores, advances += o.advances, pops += o.pops;
    descriptor_fetches += o.descriptor_fetches, far_reads += o.far_reads;
    attribute_bytes += o.attribute_bytes;
    return *this;
  }
};

/// A beam of rays for the beam optimization (esvo §6.2), of one of two kinds:
///  * pinhole (every edge_origin zero): every ray it stands for starts at
///    `eye` and has a unit direction inside the convex cone spanned by the
///    four edge directions (consecutive entries adjacent);
///  * parallel (all four edges the same direction, orthographic cameras):
///    every ray has that direction and starts inside the convex quadrilateral
///    eye + edge_origin[0..3] (consecutive corners adjacent).
/// Any other combination carries no information (the structures ignore it).
struct BeamFrustum {
  Vec3 eye;
  Vec3 edge[4];
  float angular_width = 0.f;  // >= the angle between any two directions of the cone (radians)
  LodFootprint lod;           // the footprint the beam's rays are traced with
  Vec3 edge_origin[4] = {};   // parallel beams: the corners of the origin quadrilateral - eye
  float width = 0.f;          // >= the distance between any two ray origins (world units)
};

/// Result of the coarse pass for one beam (esvo §6.2). The region is
/// structure-specific (ESVO: a box in octree space) and only meaningful to the
/// structure that produced it, for rays of the beam it was computed for.
struct BeamStart {
  bool valid = false;  // false: no information, rays are traced from their start
  bool empty = false;  // no ray of the beam can hit anything
  Aabb region;         // structure space; every voxel a ray of the beam can hit lies inside
};

/// Optional inputs/outputs of VoxelStructure::trace_hinted.
struct TraceHints {
  const BeamStart* beam = nullptr;  // from beam_start() for a beam containing the ray
  RayCounters* counters = nullptr;  // accumulates the ray's counters when set
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
  /// Any hit within [0, ray.tmax] (shadow and AO rays, svdag §4). Default:
  /// trace(), whose nearest-first traversal stops at the first leaf anyway;
  /// structures with a cheaper any-hit caster override it (DAG).
  virtual bool occluded(const Ray& ray, const LodFootprint& lod) const {
    SurfaceHit hit;
    return trace(ray, lod, &hit);
  }
  virtual std::string name() const = 0;

  // ---- Beam optimization and profiling (esvo §6.2, §8.5). The defaults make
  // every structure usable with them: no beam information, no counters. ----

  /// trace() with hints. Must return exactly what trace() returns for the
  /// same ray (the beam only skips work); counters, if set, are incremented.
  virtual bool trace_hinted(const Ray& ray, const LodFootprint& lod, const TraceHints& hints,
                            SurfaceHit* hit) const {
    (void)hints;
    return trace(ray, lod, hit);
  }
  /// Coarse pass of the beam optimization for one beam: fills `start`
  /// (start->valid = false if unsupported). `counters`, if set, receives the
  /// coarse pass's own work (iterations = nodes visited).
  virtual void beam_start(const BeamFrustum& beam, BeamStart* start, RayCounters* counters) const {
    (void)beam, (void)counters;
    *start = BeamStart{};
  }
  /// attributes() that also adds the bytes it reads to `counters` (if set).
  virtual void attributes_counted(const SurfaceHit& hit, Color* color, Vec3* normal,
                                  RayCounters* counters) const {
    (void)counters;
    attributes(hit, color, normal);
  }
};

}  // namespace voxcast
