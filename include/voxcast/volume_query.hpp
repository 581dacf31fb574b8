#pragma once
// Volume queries (docs/ARCHITECTURE.md): what a structure that stores a
// participating medium answers (GigaVoxels, gigavoxels §3.5; a dense grid in
// tests). The pair to surface_query.hpp, as pbrt-v4's Medium is to Shape.
//
// A ray through a volume is walked as spans, front to back, in the spirit of
// NanoVDB's TreeMarcher: each span is an interval of t over which one node of
// the structure answers, at one level of detail. Empty space yields no span;
// a constant node yields a span whose value is exact over the whole interval
// (integrated analytically by the integrator); a brick node yields a span the
// integrator samples with sample().
#include <cstdint>
#include <span>

#include "voxcast/math.hpp"
#include "voxcast/trace_context.hpp"

namespace voxcast {

/// What the medium holds at a point: extinction coefficient (per world unit)
/// and color (the emitted / scattered radiance per unit extinction, linear).
struct VolumeSample {
  float density = 0.f;
  Color color{0.f, 0.f, 0.f, 1.f};
};

/// One front-to-back interval of a ray (t in world units along the unit
/// direction). Valid until the end of the pass (trace_context.hpp pinning).
struct VolumeSpan {
  float t0 = 0.f, t1 = 0.f;
  uint64_t node = 0;       // structure-specific handle (node / brick)
  int level = 0;           // level of detail of the node (root = 0)
  float voxel_size = 0.f;  // world side of one sample cell at that level
  /// The length along the ray of one sample cell over voxel_size: 1 in a
  /// structure's own space; a scene object stretched (> 1) or squashed (< 1)
  /// along the ray by a non-uniform map (gigavoxels_scene.hpp) scales the
  /// integrator's steps by it, voxel_size staying the size across the ray
  /// that the level of detail compares with the pixel footprint.
  float stretch = 1.f;
  bool constant = false;  // true: `value` holds over [t0, t1]; no sampling needed
  VolumeSample value;     // constant spans only
};

class VolumeQuery {
 public:
  virtual ~VolumeQuery() = default;

  /// Writes up to out.size() spans of `ray` starting at t >= t_begin, front to
  /// back, non-overlapping and ascending, within [0, ray.tmax]; returns how
  /// many. A return value < out.size() means the ray is done; otherwise call
  /// again with t_begin = the last span's t1. The LOD footprint picks the
  /// level (stop descending when a node's voxel is smaller than the pixel
  /// cone, gigavoxels §3.5). A streaming structure answers with a coarser
  /// resident node and pushes a request into ctx.requests.
  virtual int march(const Ray& ray, float t_begin, const LodFootprint& lod, TraceContext& ctx,
                    std::span<VolumeSpan> out) const = 0;

  /// The medium at world point `p`, filtered at a (fractional) level: level
  /// L + f blends levels L and L + 1 by f (quadrilinear, gigavoxels §3.5).
  /// `span` (may be null): the span `p` lies in, as a lookup hint.
  virtual VolumeSample sample(Vec3 p, float level, TraceContext& ctx,
                              const VolumeSpan* span = nullptr) const = 0;

  /// The samples of a brick span in one call: out[k] = sample(ray.origin +
  /// ray.dir * t[k], level[k], ctx, &span) for k < n, every t[k] inside
  /// [span.t0, span.t1]. A structure resolves the span's node (and its
  /// parent, for the blend) once instead of at every sample; the default
  /// calls sample() per point. Never allocates.
  virtual void sample_span(const Ray& ray, const VolumeSpan& span, const float* t,
                           const float* level, int n, TraceContext& ctx, VolumeSample* out) const {
    for (int k = 0; k < n; ++k) out[k] = sample(ray.origin + ray.dir * t[k], level[k], ctx, &span);
  }
};

}  // namespace voxcast
