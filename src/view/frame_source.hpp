#pragma once
// The one place the viewer calls the renderer: what the panel's settings
// mean as RenderOptions, and the call itself. The renderer's interface is
// being redesigned (integrators, a pass loop); only this file needs to follow.
#include <array>
#include <cstdint>
#include <memory>

#include "voxcast/camera.hpp"
#include "voxcast/environment.hpp"
#include "voxcast/image.hpp"
#include "voxcast/math.hpp"
#include "voxcast/render.hpp"
#include "voxcast/structure.hpp"

namespace voxcast::view {

/// What the panel changes (any change restarts the refinement).
struct ViewSettings {
  float lod_pixels = 1.f;  // RenderOptions::lod_pixels
  int beam = 0;            // esvo §6.2 block size, 0 = off
  bool hard_shadows = false;
  int ao_rays = 0;        // 0 = off
  float ao_radius = 0.f;  // <= 0: 5% of the occupied bounds' diagonal, as `voxcast render`
  bool filter = false;    // esvo §6.3 post-filter
  bool heatmap = false;   // show the iteration heat map instead of the colors
  float heatmap_max = 64.f;
  uint32_t seed = 0;  // seed of the first pass (pass k uses seed + k * seeds_per_pass)
  /// Antialiasing of the surface shading: camera rays per pixel of every
  /// pass (RenderOptions::spp, render --spp; pass k's sample j has effect
  /// seed seed + k * spp + j, so no two samples share one).
  int spp = 1;
  /// Progressive diffuse GI (gi_integrator.hpp) instead of the surface
  /// shading: each pass is kGiSamplesPerPass path-traced samples with the
  /// pass's seed under gi_environment (null: a uniform sky of radiance 1),
  /// with a sun of irradiance gi_sun_intensity along gi_sun_dir when gi_sun.
  bool gi = false;
  int gi_bounces = 8;
  bool gi_sun = true;
  std::array<float, 3> gi_sun_dir{-0.4f, -1.f, -0.6f};  // render --sun's default in the viewer
  float gi_sun_intensity = 3.f;
  float gi_bounce_cone = 1.f;  // degrees (render --bounce-cone)
  std::shared_ptr<const Environment> gi_environment;
  bool gi_env_sampling = true;
  bool operator==(const ViewSettings&) const = default;
};

/// The options `voxcast render` uses for the same view: its defaults for
/// light and background, and the same effect settings as its flags.
RenderOptions render_options(const ViewSettings& settings, const Camera& camera, int width,
                             int height, const Aabb& occupied, uint32_t seed);

struct ViewFrame {
  Image color;  // linear RGB: the shaded frame, or the heat map
  uint64_t rays = 0, secondary_rays = 0;
  double seconds = 0;  // the renderer's ray-cast time
};

inline constexpr int kGiSamplesPerPass = 2;

/// Effect seeds a pass uses (pass k starts at seed + k * this).
inline int seeds_per_pass(const ViewSettings& s) {
  return s.gi || s.heatmap ? 1 : s.spp;
}

/// Whether passes after the first add anything (stochastic samples: AO or GI).
inline bool refines(const ViewSettings& s) {
  return !s.heatmap && (s.ao_rays > 0 || s.gi);
}

/// Renders one frame (a heat map when settings.heatmap, GI when settings.gi).
ViewFrame render_frame(const Structure& structure, const RenderOptions& options,
                       const ViewSettings& settings);

}  // namespace voxcast::view
