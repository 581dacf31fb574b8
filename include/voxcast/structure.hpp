#pragma once
// What every voxel structure is to the rest of the engine
// (docs/ARCHITECTURE.md): a Structure names itself, has bounds, offers its
// queries by capability (surface_query.hpp, volume_query.hpp) and takes part
// in the frame loop of integrator.hpp (begin_frame -> passes -> end_frame),
// serving between passes the requests its queries pushed into the trace
// contexts. A static, in-core structure ignores the loop.
#include <cstdint>
#include <span>
#include <string>

#include "voxcast/math.hpp"
#include "voxcast/surface_query.hpp"
#include "voxcast/trace_context.hpp"
#include "voxcast/volume_query.hpp"

namespace voxcast {

struct FrameView;  // integrator.hpp

/// What serving one pass's requests did.
struct PassOutcome {
  /// Something the pass's rays asked for became available: the tiles that
  /// pushed requests are worth tracing again (the multi-pass exact mode of
  /// gigavoxels §3.6.8 stops when a pass changes nothing).
  bool changed = false;
  uint64_t served = 0;   // requests served
  uint64_t pending = 0;  // requests left for later passes (budget, worker queues)
};

class Structure {
 public:
  virtual ~Structure() = default;
  virtual std::string name() const = 0;
  /// World-space bounds of everything the structure can return.
  virtual Aabb bounds() const = 0;
  /// The structure's queries, or null when it has no such capability.
  virtual const SurfaceQuery* surface() const { return nullptr; }
  virtual const VolumeQuery* volume() const { return nullptr; }

  // ---- The frame loop (integrator.hpp). Never called while a pass traces. ----
  /// Before the first pass of a frame (a streaming structure may prefetch
  /// for the view, esvo §7.4 scores).
  virtual void begin_frame(const FrameView& view) { (void)view; }
  /// After each pass: the pass's requests, merged from every thread, sorted by
  /// (kind, key) and deduplicated (largest priority kept). The only place a
  /// structure may change what is resident (the pinning rule).
  virtual PassOutcome end_pass(std::span<const Request> requests) {
    (void)requests;
    return {};
  }
  virtual void end_frame() {}
};

// ---- Being replaced by Structure + SurfaceQuery (issue 9 item 1). ----
/// Optional inputs/outputs of VoxelStructure::trace_hinted.
struct TraceHints {
  const BeamStart* beam = nullptr;  // from beam_start() for a beam containing the ray
  RayCounters* counters = nullptr;  // accumulates the ray's counters when set
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
