#pragma once
// Embree 3 ray casts of the source mesh: the independent oracle for tests and
// the peer that `voxcast bench` measures against.
#include <cmath>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "voxcast/camera.hpp"
#include "voxcast/effects.hpp"
#include "voxcast/image.hpp"
#include "voxcast/math.hpp"
#include "voxcast/mesh.hpp"

namespace voxcast {

/// The voxel renderer's surface shading (render.cpp, shade_batch) without
/// effects: ambient 0.18 + diffuse 0.82 times the color, plus Blinn-Phong
/// specular ^32 at 0.12. `n` is flipped to face the viewer. The fair
/// benchmark shades Embree's hits with it so both sides do the same work.
inline Color surface_phong(Color c, Vec3 n, Vec3 dir, Vec3 to_light) {
  if (dot(n, dir) > 0.f) n = -n;
  const float diffuse = std::fmax(0.f, dot(n, to_light));
  const Vec3 half_vec = normalize(to_light - dir);
  float spec = std::fmax(0.f, dot(n, half_vec));
  spec *= spec, spec *= spec, spec *= spec, spec *= spec, spec *= spec;
  const float k = 0.18f + 0.82f * diffuse;
  return {c.r * k + 0.12f * spec, c.g * k + 0.12f * spec, c.b * k + 0.12f * spec, 1.f};
}

/// The mesh as an Occluder (effects.hpp), so that shadows and AO can be
/// computed against the source mesh with the very code the voxel renderer
/// runs (the oracle tests compare the two).
class EmbreeScene final : public Occluder {
 public:
  /// Builds an Embree BVH (high quality) over the mesh; throws voxcast::Error.
  explicit EmbreeScene(const Mesh& mesh);
  ~EmbreeScene();
  EmbreeScene(const EmbreeScene&) = delete;
  EmbreeScene& operator=(const EmbreeScene&) = delete;

  /// rtcIntersect1: distance along the unit direction, +inf on a miss.
  float intersect(const Ray& ray) const;
  struct Hit {
    float t = INFINITY;  // distance along the unit direction, +inf on a miss
    Vec3 ng;             // Embree's geometric normal (RTCHit Ng): unnormalized, winding-oriented
    uint32_t triangle = UINT32_MAX;  // primitive index into the mesh's triangles
    float u = 0.f, v = 0.f;          // barycentrics of the hit (Mesh::surface_color's u, v)
  };
  /// rtcIntersect1 with the hit triangle and its geometric normal.
  Hit intersect_hit(const Ray& ray) const;
  /// rtcOccluded1.
  bool occluded(const Ray& ray) const;
  /// Occluder: 1 - occluded(ray). A mesh has one level of detail and no
  /// beam pass (beam_start gives no information), so `lod`, `ctx` and `beam`
  /// change nothing.
  float transmittance(const Ray& ray, const LodFootprint& lod, TraceContext& ctx,
                      const BeamStart* beam) const override;

  /// Primary-ray modes (issue 10: Embree at its best). Packets are pixel
  /// blocks (2x2, 4x2, 4x4) with invalid lanes masked at tile borders; every
  /// mode but Single passes RTC_INTERSECT_CONTEXT_FLAG_COHERENT. Stream is
  /// rtcIntersect1M over all rays of a tile at once.
  enum class Mode { Single, Packet4, Packet8, Packet16, Stream };
  static constexpr Mode kModes[] = {Mode::Single, Mode::Packet4, Mode::Packet8, Mode::Packet16,
                                    Mode::Stream};
  /// Short name ("x1", "x4", "x8", "x16", "1M") and the Embree call behind it.
  static const char* mode_name(Mode mode);
  static const char* mode_call(Mode mode);
  struct DepthRender {
    Image depth;  // 1 channel, world distance, +inf on a miss
    Image color;  // 3 channels (linear RGB) when shaded, else empty
    uint64_t rays = 0, hits = 0;
    double seconds = 0;  // wall time of the ray loop (all threads)
  };
  /// Casts every primary ray of `camera` (same tiles and threads as the voxel renderer).
  DepthRender render_depth(const Camera& camera, int width, int height, Mode mode) const;
  /// render_depth() plus, per hit, the mesh's interpolated vertex normal and
  /// surface color shaded with surface_phong() (the voxel renderer's shading)
  /// for a directional light travelling along `light_dir`.
  DepthRender render_shaded(const Camera& camera, int width, int height, Mode mode,
                            Vec3 light_dir) const;

  /// Occlusion modes: Single = rtcOccluded1, Packet8/16 = rtcOccluded8/16 on
  /// consecutive rays of the array, Stream = rtcOccluded1M on chunks.
  static constexpr Mode kOcclusionModes[] = {Mode::Single, Mode::Packet8, Mode::Packet16,
                                             Mode::Stream};
  /// occluded[i] = 1 if rays[i] hits anything in [0, tmax]; the rays are
  /// split into chunks of kOcclusionChunk handed out by TBB. Returns the wall time.
  double occluded_all(const std::vector<Ray>& rays, Mode mode,
                      std::vector<uint8_t>* occluded) const;
  static constexpr size_t kOcclusionChunk = 256;

  /// Single-threaded rtcIntersect1 pass with timestamp-counter reads around
  /// each stage (instrumented; never used for throughput).
  struct StageTicks {
    uint64_t ray_generation = 0, traversal = 0, attributes = 0, shading = 0;
    uint64_t rays = 0;
    uint64_t total() const { return ray_generation + traversal + attributes + shading; }
  };
  StageTicks profile_single(const Camera& camera, int width, int height, Vec3 light_dir) const;

  double build_seconds() const { return build_seconds_; }
  /// Bytes Embree reports allocating for the scene (device memory monitor).
  uint64_t memory_bytes() const;
  /// What Embree selected on this CPU: the ISA lines of a separate probe
  /// device created with "verbose=1" (its stdout captured), e.g. "AVX512".
  static std::string probe_isa();

 private:
  DepthRender render_impl(const Camera& camera, int width, int height, Mode mode, bool shade,
                          Vec3 light_dir) const;
  struct Impl;
  std::unique_ptr<Impl> impl_;
  double build_seconds_ = 0;
};

}  // namespace voxcast
