#pragma once
// Surface queries (docs/ARCHITECTURE.md): what a structure that stores an
// opaque surface answers. The split follows pbrt-v4's Shape/Medium: a
// structure offers a SurfaceQuery, a VolumeQuery (volume_query.hpp), or both,
// through Structure::surface() / volume() (structure.hpp). Every call takes
// the caller's per-thread TraceContext (trace_context.hpp): counters, the
// request sink of streaming structures, accessor caches.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "voxcast/isa.hpp"
#include "voxcast/math.hpp"
#include "voxcast/trace_context.hpp"

namespace voxcast {

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

/// One cube of a frustum pass's list (SurfaceQuery::frustum_start), in
/// structure space (the octree family: [1,2]^3, side 2^(scale - 23)).
struct FrustumNode {
  float lo[3];      // min corner
  float side;       // edge length
  uint32_t parent;  // the structure's node whose child the cube is
  uint32_t node;    // the cube's own node (unless leaf)
  int8_t scale;     // the cube's scale (the root's children: 22)
  uint8_t slot;     // the cube's child slot in `parent` (x | y << 1 | z << 2)
  bool leaf;        // a leaf voxel (no node below)
};

/// Result of the coarse pass for one beam (esvo §6.2). The region is
/// structure-specific (ESVO: a box in octree space) and only meaningful to the
/// structure that produced it, for rays of the beam it was computed for.
struct BeamStart {
  bool valid = false;  // false: no information, rays are traced from their start
  bool empty = false;  // no ray of the beam can hit anything
  Aabb region;         // structure space; every voxel a ray of the beam can hit lies inside
  /// The tile frustum pass (frustum_start): octant >= 0 when `nodes` holds
  /// disjoint cubes containing every voxel a ray of the beam can hit, in
  /// front-to-back order for the rays of mirroring octant `octant`
  /// (ray_octant()); `region` is then their bounding box. -1: no list.
  int octant = -1;
  std::vector<FrustumNode> nodes;
};

/// The mirroring octant of the octree family's caster for world direction
/// `dir` (esvo §6.1 "Alternate coordinate system"): bit a clear where the
/// caster mirrors axis a, i.e. where the component's sign bit is clear (a
/// +0 component becomes +2^-23 there, avoid_tiny_components).
inline int ray_octant(Vec3 dir) {
  return 7 ^ (std::signbit(dir.x) ? 0 : 1) ^ (std::signbit(dir.y) ? 0 : 2) ^
         (std::signbit(dir.z) ? 0 : 4);
}

/// A first hit. Valid until the end of the pass it was traced in (the
/// pinning rule of trace_context.hpp), so attributes() may dereference it.
struct SurfaceHit {
  float t = INFINITY;      // world distance along the ray's unit direction
  Vec3 position;           // world hit position, clamped into the voxel
  float voxel_size = 0.f;  // world side length of the voxel that was hit
  uint64_t voxel_ref = 0;  // structure-specific handle for attributes()
  uint32_t child = 0;      // structure-specific
  int level = 0;           // octree level of the hit voxel (root = 0)
};

/// Which caster traces a frame's primary rays (SurfaceOptions::caster,
/// `voxcast render/bench --caster`).
/// Tile: all rays of a tile by one walk of the structure (trace_tile) where
/// it has a tile caster, else as Packet.
enum class Caster { Scalar, Packet, Tile };
/// "scalar", "packet" or "tile".
const char* caster_name(Caster c);

/// The packet capability of a surface query (SurfaceQuery::packets()): many
/// rays per call, traced by lane-parallel kernels (voxcast/packet_caster.hpp).
/// Every answer is that of the scalar trace() / occluded() for the same ray,
/// bit for bit, so a caller may use either for any ray. Neither call counts
/// (ctx.counters): a counting caller uses the scalar methods.
struct CameraRays;  // voxcast/camera.hpp

class SurfacePackets {
 public:
  virtual ~SurfacePackets() = default;
  /// found[k] = trace(cam.ray(x, y), lod, ctx, &hits[k]) for the pixels
  /// [x0, x1) x [y0, y1) of `cam`, k = (y - y0) (x1 - x0) + x - x0, hits
  /// bit-identical, by one walk of the structure per 16 x 16 pixels (the
  /// octree structures: core/octree_tile_caster.hpp). Returns false, and
  /// writes nothing, where the structure has no tile caster (then trace the
  /// rays as packets).
  virtual bool trace_tile(const CameraRays& /*cam*/, int /*x0*/, int /*y0*/, int /*x1*/, int /*y1*/,
                          const LodFootprint& /*lod*/, TraceContext& /*ctx*/, SurfaceHit* /*hits*/,
                          uint8_t* /*found*/, Isa /*isa*/) const {
    return false;
  }
  /// found[i] = trace(rays[i], lod, ctx, &hits[i], beams[i]) for i < n;
  /// hits[i] written where found[i]. beams (may be null, entries may be null):
  /// as trace()'s beam argument per ray. Coherent rays in order (camera rays
  /// as 4x4 pixel blocks, block_order()) make fast packets. `isa`: the kernel
  /// variant (throws voxcast::Error if the CPU lacks it).
  virtual void trace_packets(const Ray* rays, size_t n, const LodFootprint& lod, TraceContext& ctx,
                             SurfaceHit* hits, uint8_t* found, Isa isa,
                             const BeamStart* const* beams = nullptr) const = 0;
  /// occluded[i] = occluded(rays[i], lod, ctx) for i < n (shadow, AO rays).
  virtual void occluded_packets(const Ray* rays, size_t n, const LodFootprint& lod,
                                TraceContext& ctx, uint8_t* occluded, Isa isa) const = 0;
};

class SurfaceQuery {
 public:
  virtual ~SurfaceQuery() = default;

  /// First hit along `ray` (unit direction) within [0, ray.tmax], stopping at
  /// the LOD footprint. `beam` (may be null): the result of beam_start() for
  /// a beam that contains the ray; it only skips work, the hit is bit-identical.
  /// A streaming structure that lacks data answers from what is resident
  /// (coarser) and pushes a request into ctx.requests.
  virtual bool trace(const Ray& ray, const LodFootprint& lod, TraceContext& ctx, SurfaceHit* hit,
                     const BeamStart* beam = nullptr) const = 0;

  /// Fraction of light passing along the ray within [0, ray.tmax] (shadow and
  /// AO rays, svdag §4): 0 or 1 for an opaque surface. The default runs
  /// trace(); structures with a cheaper any-hit loop override it.
  virtual float transmittance(const Ray& ray, const LodFootprint& lod, TraceContext& ctx,
                              const BeamStart* beam = nullptr) const {
    SurfaceHit hit;
    return trace(ray, lod, ctx, &hit, beam) ? 0.f : 1.f;
  }
  bool occluded(const Ray& ray, const LodFootprint& lod, TraceContext& ctx,
                const BeamStart* beam = nullptr) const {
    return transmittance(ray, lod, ctx, beam) < 1.f;
  }
  /// out[i] = transmittance(rays[i], lod, ctx) for i < n, the same values.
  /// group > 0: rays [k group, (k + 1) group) share their origin (the AO rays
  /// of one point), and `normals` (may be null) holds one normal per group
  /// with dot(dir, normal) >= 0 for its rays; structures may use both to skip
  /// work (voxcast/occlusion_packets.hpp can start such groups deep; the
  /// octree family answers batches with its packet caster,
  /// voxcast/packet_caster.hpp). Default: one transmittance() per ray.
  virtual void transmittance_batch(const Ray* rays, size_t n, const LodFootprint& lod,
                                   TraceContext& ctx, float* out, int group = 0,
                                   const Vec3* normals = nullptr) const {
    (void)group, (void)normals;
    for (size_t i = 0; i < n; ++i) out[i] = transmittance(rays[i], lod, ctx);
  }

  /// Linear color and unit normal of the hit voxel; adds the bytes read to
  /// ctx.counters.attribute_bytes while counting.
  virtual void attributes(const SurfaceHit& hit, TraceContext& ctx, Color* color,
                          Vec3* normal) const = 0;
  /// Starts loading what attributes(hit) will read (a hint: no result, no
  /// counters), so that a group of hits' attribute reads are in flight
  /// together before the group is shaded. Default: nothing.
  virtual void prefetch_attributes(const SurfaceHit& hit) const { (void)hit; }
  /// The first step of prefetch_attributes for a structure whose lookup is
  /// a chain (an index read, then the values it points to): starts the
  /// index's read, so that prefetch_attributes(hit), called some hits later,
  /// finds it and starts the values'. Default: nothing.
  virtual void prefetch_attribute_index(const SurfaceHit& hit) const { (void)hit; }
  /// attributes(*hits[i], ctx, &colors[i], &normals[i]) for i < n: the same
  /// answers and counts in one call, so that a structure can have a group's
  /// reads in flight together and decode them in vector lanes (the
  /// integrator shades hits in groups). Default: one attributes() per hit,
  /// each hit's prefetch_attributes() 16 hits ahead of its read.
  virtual void attributes_batch(const SurfaceHit* const* hits, int n, TraceContext& ctx,
                                Color* colors, Vec3* normals) const {
    constexpr int kAhead = 16;
    for (int i = 0; i < n && i < kAhead; ++i) prefetch_attributes(*hits[i]);
    for (int i = 0; i < n; ++i) {
      if (i + kAhead < n) prefetch_attributes(*hits[i + kAhead]);
      attributes(*hits[i], ctx, &colors[i], &normals[i]);
    }
  }

  /// Coarse pass of the beam optimization for one beam (esvo §6.2). Default:
  /// no information. While counting, ctx.counters receives the pass's own work
  /// (iterations = nodes visited).
  virtual void beam_start(const BeamFrustum& beam, TraceContext& ctx, BeamStart* start) const {
    (void)beam, (void)ctx;
    *start = BeamStart{};
  }

  /// The tile frustum pass (issue 10 item 4): like beam_start, and where the
  /// structure can, also the list of cubes the beam's rays can touch, front
  /// to back for rays of mirroring octant `octant` (BeamStart::nodes), cut
  /// where a cube is about as wide as the beam, is a leaf or could be a LOD
  /// stop; `within` (may be null): a list for a beam that contains this one
  /// (a tile's, for its pixel blocks), whose cubes the pass starts from when
  /// it is for the same octant. An empty start (no cube) means no ray of the
  /// beam hits anything. The packet caster starts each ray deep at the
  /// first cube it enters (hits bit-identical); trace() uses the region.
  /// Default: beam_start.
  virtual void frustum_start(const BeamFrustum& beam, int octant, TraceContext& ctx,
                             BeamStart* start, const BeamStart* within = nullptr) const {
    (void)octant, (void)within;
    beam_start(beam, ctx, start);
  }

  /// The packet capability, or null (the default) when the structure has
  /// only the scalar trace(): a streaming structure that serves requests per
  /// ray, say. Valid as long as the query.
  virtual const SurfacePackets* packets() const { return nullptr; }
};

}  // namespace voxcast
