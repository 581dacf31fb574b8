#pragma once
// The one place the viewer calls the renderer: what the panel's settings
// mean as RenderOptions, and the call itself. The renderer's interface is
// being redesigned (integrators, a pass loop); only this file needs to follow.
#include <cstdint>

#include "voxcast/camera.hpp"
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
  uint32_t seed = 0;  // seed of the first pass (pass k uses seed + k)
  /// Progressive diffuse GI (gi_integrator.hpp) instead of the surface
  /// shading: each pass is kGiSamplesPerPass path-traced samples with the
  /// pass's seed under a uniform sky of radiance 1, with the sun along the
  /// surface shading's light direction when gi_sun.
  bool gi = false;
  int gi_bounces = 8;
  bool gi_sun = true;
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

/// Whether passes after the first add anything (stochastic samples: AO or GI).
inline bool refines(const ViewSettings& s) {
  return !s.heatmap && (s.ao_rays > 0 || s.gi);
}

/// Renders one frame (a heat map when settings.heatmap, GI when settings.gi).
ViewFrame render_frame(const Structure& structure, const RenderOptions& options,
                       const ViewSettings& settings);

}  // namespace voxcast::view
