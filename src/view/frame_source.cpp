// The viewer's render call (frame_source.hpp).
#include "view/frame_source.hpp"

#include <utility>

#include "voxcast/gi_integrator.hpp"

namespace voxcast::view {

RenderOptions render_options(const ViewSettings& s, const Camera& camera, int width, int height,
                             const Aabb& occupied, uint32_t seed) {
  RenderOptions opt;
  opt.width = width;
  opt.height = height;
  opt.camera = camera;
  opt.lod_pixels = s.lod_pixels;
  opt.beam = s.beam;
  opt.filter = s.filter;
  opt.collect_stats = s.heatmap;
  if (!s.heatmap && !s.gi) opt.spp = s.spp;  // the heat map needs the per-pixel iteration counts
  EffectOptions& fx = opt.effects;
  fx.shadows = s.hard_shadows ? ShadowMode::Hard : ShadowMode::None;
  fx.ao_rays = s.ao_rays;
  // `voxcast render` measures the default AO radius on the occupied bounds
  // (not the structure's root cube); the viewer must match it.
  if (s.ao_rays > 0)
    fx.ao_radius = s.ao_radius > 0 ? s.ao_radius : 0.05f * length(occupied.extent());
  fx.seed = seed;
  return opt;
}

ViewFrame render_frame(const Structure& structure, const RenderOptions& options,
                       const ViewSettings& settings) {
  if (settings.gi && !settings.heatmap) {
    GiOptions gi;
    gi.spp = kGiSamplesPerPass;
    gi.bounces = settings.gi_bounces;
    gi.sun = settings.gi_sun;
    // Normalized once here and again by the integrator, as render --sun.
    gi.sun_dir =
        normalize(Vec3{settings.gi_sun_dir[0], settings.gi_sun_dir[1], settings.gi_sun_dir[2]});
    const float e = settings.gi_sun_intensity;
    gi.sun_irradiance = {e, e, e, 1.f};
    gi.bounce_cone_deg = settings.gi_bounce_cone;
    if (settings.gi_environment) gi.environment = settings.gi_environment;
    gi.env_sampling = settings.gi_env_sampling;
    // Every pass its own seed (render_options: the accumulator's next seed),
    // so the viewer's running mean is the many-sample image.
    gi.seed = options.effects.seed;
    GiResult g =
        render_gi(structure, options.camera, options.width, options.height, options.lod_pixels, gi);
    ViewFrame f;
    f.color = std::move(g.film.color);
    f.rays = g.stats.samples;
    f.secondary_rays = g.stats.bounce_rays + g.stats.shadow_rays;
    f.seconds = g.stats.seconds;
    return f;
  }
  RenderResult r = render(structure, options);
  ViewFrame f;
  f.color =
      settings.heatmap ? iteration_heatmap(r.iterations, settings.heatmap_max) : std::move(r.color);
  f.rays = r.rays;
  f.secondary_rays = r.effect_counters.shadow_rays + r.effect_counters.ao_rays;
  f.seconds = r.seconds;
  return f;
}

}  // namespace voxcast::view
