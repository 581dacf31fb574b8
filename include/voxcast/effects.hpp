#pragma once
// Secondary-ray effects on top of the primary hits: hard shadows, soft shadows
// from a rectangular area light with the per-pixel shadow beam, and ambient
// occlusion with falloff-in-sampling (Kämpe, Sintorn & Assarsson 2013, svdag
// §4; Laine & Karras 2010b). Works on anything that answers transmittance
// queries through an Occluder: a structure's SurfaceQuery (StructureOccluder)
// and the Embree reference of the source mesh (embree_reference.hpp; the
// oracle tests and `voxcast bench`). Occlusion is a transmittance in [0, 1]:
// 0 or 1 for an opaque surface, fractional through a volume; shadow
// visibility and AO are averages of transmittances.
//
// Determinism: every random number of a pixel comes from a hash of (x, y,
// seed), so an image does not depend on the thread count or the tile order.
#include <cstddef>
#include <cstdint>

#include "voxcast/math.hpp"
#include "voxcast/surface_query.hpp"
#include "voxcast/trace_context.hpp"

namespace voxcast {

enum class LightKind { Directional, Point, Area };
enum class ShadowMode { None, Hard, Soft };

/// How soft shadows use the 4-ray beam of svdag §4 (one beam per pixel from
/// the shading point to the light's corners):
///   Conservative: the beam is traced conservatively with the structure's
///     beam_start() (the esvo §6.2 coarse pass, a cone over the whole light):
///     an empty beam means the pixel is fully lit (no shadow rays); otherwise
///     every shadow ray is clipped to the box the coarse pass proved to hold
///     every voxel any ray of the beam can hit (both ends: "from the view
///     sample" and "from the light", svdag §4). Exact: the answers equal those
///     without the beam. The ESVO octree and the DAG share the coarse pass
///     (octree_structure.hpp); structures without beam_start trace all rays.
///   Corners: the literal four corner rays; all four unoccluded -> the pixel
///     counts as fully lit. NOT conservative (an occluder that fits between the
///     corner rays is missed), and four point rays give no provable interval,
///     so the other rays are not shortened. Faster on DAGs; see test_effects
///     for its measured error.
///   Off: N rays per pixel.
enum class ShadowBeam { Off, Conservative, Corners };

struct EffectOptions {
  // ---- light (the directional direction is RenderOptions::light_dir) ----
  LightKind light = LightKind::Directional;
  Vec3 light_position;  // Point: position; Area: rectangle center
  Vec3 area_u, area_v;  // Area: half-edge vectors (corners center +-u +-v)
  // ---- shadows ----
  ShadowMode shadows = ShadowMode::None;
  int shadow_rays = 16;  // Soft: samples per pixel (stratified over the rectangle)
  ShadowBeam shadow_beam = ShadowBeam::Conservative;
  // ---- ambient occlusion (Laine & Karras 2010b falloff-in-sampling) ----
  int ao_rays = 0;                // 0 = off; svdag §4 uses 64
  float ao_radius = 0.f;          // world units; <= 0: 5% of the structure's bounds diagonal
  float ao_cone_angle_deg = 0.f;  // > 0: AO rays stop at nodes subtending this angle (svdag §4)
  uint32_t seed = 0;              // per-image seed of the per-pixel sample hashes
  // ---- how the rays are traced (the images are the same either way) ----
  // true: AO rays of a point and the hard shadow rays of a batch of pixels go
  // to the occluder together (Occluder::transmittance_batch: packets of 16
  // rays on the octree family); false: one ray at a time.
  bool packets = true;

  bool active() const { return shadows != ShadowMode::None || ao_rays > 0; }
};

/// Throws voxcast::Error (one line) for invalid settings.
void validate(const EffectOptions& options);

/// One primary hit to shade.
struct ShadingPoint {
  Vec3 position;     // world hit position
  Vec3 normal;       // unit shading normal, facing the viewer (dot(normal, view_dir) <= 0)
  Vec3 view_dir;     // unit primary ray direction
  float voxel_size;  // world side of the hit voxel (offset scale)
};

/// Start of every secondary ray of `p`: out of the hit voxel along the
/// shading normal and back along the view ray,
///   origin = position + voxel_size * (2 * normal - view_dir).
/// Why 2 voxels: a conservative voxelization of a plane holds only voxels
/// that touch the plane, i.e. lie within sqrt(3) voxels of it, and the primary
/// hit is at height >= 0 above the plane (the voxel holding the crossing
/// point is itself occupied, so the ray enters a voxel no later than that).
/// The origin is then >= 2 + cos(view angle) > sqrt(3) voxels above the plane:
/// a ray leaving a flat surface into its upper half space cannot hit the
/// surface's own voxels (no shadow acne; tested). The price: contact
/// shadows/occlusion closer than ~2 voxels to the surface are missed.
Vec3 offset_origin(const ShadingPoint& p);

/// Answers the effects' occlusion queries with the caller's per-thread
/// TraceContext (trace_context.hpp).
class Occluder {
 public:
  virtual ~Occluder() = default;
  /// Fraction of light passing along the ray within [0, ray.tmax] (unit
  /// direction): 0 or 1 for an opaque surface. `beam` (may be null): the
  /// result of beam_start() for a beam containing the ray; it only skips
  /// work, the answer is the same.
  virtual float transmittance(const Ray& ray, const LodFootprint& lod, TraceContext& ctx,
                              const BeamStart* beam) const = 0;
  /// out[i] = transmittance(rays[i], lod, ctx, nullptr) for i < n, the same
  /// values; group / normals as SurfaceQuery::transmittance_batch.
  virtual void transmittance_batch(const Ray* rays, size_t n, const LodFootprint& lod,
                                   TraceContext& ctx, float* out, int group,
                                   const Vec3* normals) const {
    (void)group, (void)normals;
    for (size_t i = 0; i < n; ++i) out[i] = transmittance(rays[i], lod, ctx, nullptr);
  }
  /// Conservative beam pass (esvo §6.2 / svdag §4); default: no information.
  virtual void beam_start(const BeamFrustum& beam, TraceContext& ctx, BeamStart* start) const {
    (void)beam, (void)ctx;
    *start = BeamStart{};
  }
};

/// A structure's SurfaceQuery as an Occluder (transmittance(), beam_start()).
class StructureOccluder final : public Occluder {
 public:
  explicit StructureOccluder(const SurfaceQuery& q) : q_(q) {}
  float transmittance(const Ray& ray, const LodFootprint& lod, TraceContext& ctx,
                      const BeamStart* beam) const override {
    return q_.transmittance(ray, lod, ctx, beam);
  }
  void beam_start(const BeamFrustum& beam, TraceContext& ctx, BeamStart* start) const override {
    q_.beam_start(beam, ctx, start);
  }
  void transmittance_batch(const Ray* rays, size_t n, const LodFootprint& lod, TraceContext& ctx,
                           float* out, int group, const Vec3* normals) const override {
    q_.transmittance_batch(rays, n, lod, ctx, out, group, normals);
  }

 private:
  const SurfaceQuery& q_;
};

/// Ray and beam counts of a frame (or of one pixel).
struct EffectCounters {
  uint64_t shadow_rays = 0;  // shadow rays traced (incl. the 4 corner rays in Corners mode)
  uint64_t ao_rays = 0;      // AO rays traced
  uint64_t beams = 0;        // soft-shadow beams (pixels with the light above the horizon)
  uint64_t beams_lit = 0;    // beams that proved / declared the pixel fully lit
  EffectCounters& operator+=(const EffectCounters& o) {
    shadow_rays += o.shadow_rays, ao_rays += o.ao_rays, beams += o.beams, beams_lit += o.beams_lit;
    return *this;
  }
};

/// Per-pixel hash seed (x, y, image seed) -> 32 bits.
uint32_t pixel_seed(int x, int y, uint32_t seed);

/// Unit direction from `p` towards the light (the area light's center), and
/// the light's distance (+inf for a directional light).
Vec3 direction_to_light(const EffectOptions& o, Vec3 light_dir, Vec3 p, float* distance);

/// Fraction of the light visible from `p` in [0, 1]: hard shadows the
/// transmittance of the ray to the light, soft shadows the mean transmittance
/// of o.shadow_rays stratified samples (svdag §4 beam per o.shadow_beam).
/// Light directions below the surface (dot with the normal <= 0) count as
/// occluded without a ray.
float shadow_visibility(const Occluder& occ, TraceContext& ctx, const ShadingPoint& p,
                        const EffectOptions& o, Vec3 light_dir, uint32_t seed,
                        EffectCounters* counters);

/// shadow_visibility() of points[i] with seeds[i] into out[i] for i < n, the
/// same values. Hard shadows (and every non-area light) with o.packets: the
/// rays of all n points go to the occluder as one batch (under a directional
/// light the shadow rays of neighbouring pixels are parallel: one packet).
void shadow_visibility_batch(const Occluder& occ, TraceContext& ctx, const ShadingPoint* points,
                             int n, const EffectOptions& o, Vec3 light_dir, const uint32_t* seeds,
                             EffectCounters* counters, float* out);

/// Ambient occlusion (1 = open, 0 = fully occluded) of `p` with o.ao_rays
/// rays, falloff in sampling (Laine & Karras 2010b): the occlusion sought is
///   1 - AO = integral over the hemisphere of cos(theta)/pi * f(d(w)) dw,
/// d(w) = distance to the first hit, f(d) = 1 - (d/R)^2 on [0, R], 0 beyond.
/// f(d) = P(L > d) for a ray length L with CDF (l/R)^2, i.e. L = R*sqrt(u),
/// so each ray w ~ cos(theta)/pi gets length R*sqrt(u) and AO is the mean
/// transmittance of the rays (the fraction of unoccluded rays for a
/// surface): no hit distances, no weights, any-hit rays only.
/// Samples: rotated Hammersley in (u1, u2) + base-3 radical inverse in u (one
/// sample per stratum of each dimension), per-pixel Cranley-Patterson rotation.
float ambient_occlusion(const Occluder& occ, TraceContext& ctx, const ShadingPoint& p,
                        const EffectOptions& o, float radius, uint32_t seed,
                        EffectCounters* counters);

}  // namespace voxcast
