#pragma once
// The GI integrator (integrator.hpp): progressive diffuse path tracing on a
// structure's SurfaceQuery (hitchhiker's guide, "Global illumination"), a
// sibling of the surface and volume integrators.
//
// Per sample of a pixel (box filter: the primary ray through a uniformly
// jittered point of the pixel):
//  * at every hit, the voxel's color is the diffuse albedo a and its normal
//    the shading normal (flipped towards the incoming ray);
//  * next-event estimation to the sun (a directional delta light of
//    irradiance `sun_irradiance` on a surface facing it): a shadow ray via
//    SurfaceQuery::occluded, contribution a / pi * E * cos;
//  * a cosine-weighted bounce (pdf cos / pi, so the Lambertian throughput is
//    multiplied by a) up to `bounces` times; a ray that leaves the scene
//    picks up the environment (environment.hpp), the primary ray included
//    (the background is the environment);
//  * with an environment map (and `env_sampling`), next-event estimation to
//    the environment too: a direction drawn by the map's luminance
//    (Environment::sample), a shadow ray, and multiple importance sampling
//    with the cosine bounce (power heuristic; a bounce ray that escapes is
//    weighted by the other half), at every hit that may still bounce;
//  * Russian roulette from bounce `rr_start` on: survive with
//    q = min(1, max channel of the throughput), divide by q (unbiased);
//  * bounce and shadow rays after the first hit are LOD-terminated: they stop
//    at voxels of side <= 2 tan(bounce_cone / 2) * t (a cone from the ray
//    origin, svdag §4's AO cone): fine near the surface, coarse far away.
//
// Determinism: sample s of pixel (x, y) draws from a generator seeded by
// (x, y, seed, s) alone, and a pixel's samples are summed in the order of s,
// so the image does not depend on the thread count, the tile order or how
// the samples are split into frames (spp 4 + 4 gives the bytes of spp 8).
// Progressive accumulation: every frame adds `spp` samples to the running
// sums (sample indices continue where the last frame stopped) and the film
// shows the mean; reset() starts over (the viewer calls it when the camera
// moves).
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <vector>

#include "voxcast/camera.hpp"
#include "voxcast/environment.hpp"
#include "voxcast/integrator.hpp"

namespace voxcast {

struct GiOptions {
  int spp = 16;      // samples per pixel per frame (1..65536)
  int bounces = 8;   // diffuse bounces at most (0 = primary hits with sun only)
  int rr_start = 3;  // Russian roulette from this bounce on (>= 1)
  /// Environment: constant radiance 1 when null.
  std::shared_ptr<const Environment> environment;
  /// Importance-sample an environment map (MIS with the cosine bounce);
  /// false = cosine bounces alone. No effect on a constant environment.
  bool env_sampling = true;
  bool sun = false;
  Vec3 sun_dir = normalize(Vec3{-0.4f, -1.0f, -0.6f});  // direction the sunlight travels
  Color sun_irradiance{3.f, 3.f, 3.f, 1.f};
  /// Cone angle (degrees, [0, 90)) of the LOD of rays after the first hit;
  /// 0 = finest level.
  float bounce_cone_deg = 1.f;
  uint32_t seed = 0;
  bool want_depth = false, want_normal = false;  // AOVs of sample 0's primary hit
};

/// Throws voxcast::Error (one line) for invalid options.
void validate(const GiOptions& options);

/// What the last frame traced (every sample of every pixel).
struct GiStats {
  uint64_t samples = 0;      // camera samples (paths)
  uint64_t rays = 0;         // rays traced: primary + bounce + shadow
  uint64_t bounce_rays = 0;  // of which bounce rays
  uint64_t shadow_rays = 0;  // of which shadow rays (sun and environment)
  double seconds = 0;        // filled by render_gi()
};

class GiIntegrator final : public Integrator {
 public:
  /// Throws voxcast::Error for invalid options.
  explicit GiIntegrator(const GiOptions& options);

  uint32_t aovs() const override;
  /// Throws voxcast::Error when the structure has no surface query. A frame
  /// of another size, camera or LOD than the accumulated ones starts over.
  void begin_frame(const Structure& structure, const FrameView& view, Film& film) override;
  void render_tile(const Structure& structure, const FrameView& view, const TileRect& tile,
                   TraceContext& ctx, Film& film) override;
  void end_frame(const Structure& structure, const FrameView& view, Film& film) override;

  /// Forget the accumulated samples (the next frame starts at sample 0).
  void reset();
  /// Samples the next frames add (1..65536; the accumulation continues).
  void set_spp(int spp);
  /// Distance of pixel (x, y)'s sample-0 camera ray to its hit (+inf on a
  /// miss), valid once a frame ran since reset().
  float first_hit_t(int x, int y) const { return depth_[size_t(y) * size_t(width_) + size_t(x)]; }
  /// Samples per pixel accumulated so far (after end_frame).
  uint32_t samples() const { return samples_; }
  const GiStats& stats() const { return stats_; }
  const GiOptions& options() const { return options_; }

 private:
  GiOptions options_;
  // Per-pixel RGB sums in double: base_ before this frame, sum_ with it.
  std::vector<double> base_, sum_;
  std::vector<float> depth_, normal_;  // sample 0's primary hit (the AOVs)
  int width_ = 0, height_ = 0;
  Camera camera_;  // the view the sums belong to
  float lod_pixels_ = -1.f;
  uint32_t samples_ = 0;  // before this frame
  // Per frame:
  const SurfaceQuery* query_ = nullptr;
  std::optional<CameraRays> cam_;
  LodFootprint lod_, bounce_lod_;
  std::mutex stats_mutex_;
  GiStats stats_;
};

/// A GI frame as one call: `options.spp` samples on a fresh integrator,
/// through the frame loop of integrator.hpp in one pass that serves no
/// requests (a streaming structure shows what is resident, like the const
/// render() of render.hpp). Returns the film (color = mean radiance).
struct GiResult {
  Film film;
  GiStats stats;
};
GiResult render_gi(const Structure& structure, const Camera& camera, int width, int height,
                   float lod_pixels, const GiOptions& options);

}  // namespace voxcast
