// `voxcast render --gi SPP` (gi_cli.hpp).
#include "gi_cli.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <memory>

#include "cli_io.hpp"
#include "commands.hpp"
#include "render/const_view.hpp"
#include "voxcast/environment.hpp"
#include "voxcast/integrator.hpp"
#include "voxcast/progress.hpp"

namespace voxcast::cli {

void add_gi_options(CLI::App* cmd, GiArgs& a) {
  cmd->add_option("--gi", a.spp,
                  "Progressive diffuse global illumination (path tracing) with this many "
                  "samples per pixel (0 = off: the surface shading)")
      ->capture_default_str();
  cmd->add_option("--bounces", a.bounces, "With --gi: diffuse bounces at most")
      ->capture_default_str();
  cmd->add_option("--env", a.env,
                  "With --gi: environment map (.hdr or .exr, latitude-longitude); default a "
                  "uniform sky of radiance 1");
  cmd->add_flag("--no-env-sampling", a.no_env_sampling,
                "With --env: find the map's light by cosine bounces alone (default: also "
                "sample the map by luminance, with multiple importance sampling)");
  cmd->add_option("--env-scale", a.env_scale, "With --gi: multiplies the environment")
      ->capture_default_str();
  cmd->add_option("--sun", a.sun, "With --gi: a sun (directional light) travelling along dx,dy,dz");
  cmd->add_option("--sun-intensity", a.sun_intensity,
                  "With --sun: irradiance on a surface facing the sun")
      ->capture_default_str();
  cmd->add_option("--bounce-cone", a.bounce_cone,
                  "With --gi: rays after the first hit stop at voxels subtending this angle "
                  "in degrees (0 = finest level)")
      ->capture_default_str();
}

GiOptions gi_options(const GiArgs& a, const std::string& surface_only, uint32_t seed) {
  require_range("--gi", a.spp, 1, 65536);
  if (!surface_only.empty())
    throw UsageError(surface_only + " is an option of the surface shading, not of --gi");
  require_range("--bounces", a.bounces, 0, 1024);
  require_range("--env-scale", a.env_scale, 0, 1e30);
  require_range("--sun-intensity", a.sun_intensity, 0, 1e30);
  if (!(a.bounce_cone >= 0 && a.bounce_cone < 90))
    throw UsageError("--bounce-cone must be in [0, 90) degrees");
  GiOptions o;
  o.spp = a.spp;
  o.bounces = a.bounces;
  o.bounce_cone_deg = a.bounce_cone;
  o.seed = seed;
  o.env_sampling = !a.no_env_sampling;
  if (!a.sun.empty()) {
    const Vec3 d = parse_vec3(a.sun, "--sun");
    if (!(length(d) > 0) || !std::isfinite(length(d)))
      throw UsageError("--sun must be a non-zero, finite vector");
    o.sun = true;
    o.sun_dir = normalize(d);
    o.sun_irradiance = {a.sun_intensity, a.sun_intensity, a.sun_intensity, 1.f};
  }
  const float s = a.env_scale;
  o.environment = std::make_shared<const Environment>(Color{s, s, s, 1.f});
  return o;
}

void load_gi_environment(const GiArgs& a, GiOptions* o) {
  if (a.env.empty()) return;
  require_regular_input(a.env, "environment map");
  o->environment = std::make_shared<const Environment>(load_environment(a.env, a.env_scale));
}

RenderResult render_gi_view(const Structure& structure, const RenderOptions& options, GiOptions gi,
                            bool verbose) {
  const int total = gi.spp;
  // About 20 frames for the progress bar, at least 1 sample each.
  const int per_frame = std::max(1, total / 20);
  gi.want_depth = options.want_depth;
  gi.want_normal = options.want_normal;
  gi.spp = per_frame;
  GiIntegrator integrator(gi);
  // One pass per frame that serves nothing, as render_gi() (gi_integrator.hpp).
  detail::ConstView frame_structure(structure);
  FrameView view;
  view.camera = options.camera;
  view.width = options.width, view.height = options.height;
  view.lod_pixels = options.lod_pixels;
  FrameOptions fo;
  fo.tile_size = options.tile_size;
  Film film;
  RenderResult r;
  GiStats sum;
  Progress progress("path tracing", uint64_t(total));
  for (int done = 0; done < total;) {
    const int n = std::min(per_frame, total - done);
    if (n != per_frame) {
      // The last frame takes the remainder: a new integrator would restart
      // at sample 0, so this one continues with fewer samples.
      integrator.set_spp(n);
    }
    const FrameStats fs = render_frame(frame_structure, integrator, view, fo, &film);
    const GiStats& st = integrator.stats();
    sum.samples += st.samples, sum.rays += st.rays;
    sum.bounce_rays += st.bounce_rays, sum.shadow_rays += st.shadow_rays;
    sum.seconds += fs.seconds;
    done += n;
    progress.advance(uint64_t(n));
  }
  progress.finish();
  r.color = std::move(film.color);
  r.depth = std::move(film.depth);
  r.normal = std::move(film.normal);
  // Per pixel (sample 0's camera ray): the CLI's "% of pixels hit"; the
  // rates are the gi line's.
  r.rays = uint64_t(options.width) * uint64_t(options.height);
  r.seconds = sum.seconds;
  for (int y = 0; y < options.height; ++y)
    for (int x = 0; x < options.width; ++x) r.hits += std::isfinite(integrator.first_hit_t(x, y));
  std::printf(
      "gi: %d spp, %d bounces at most, %.3g Msamples/s, %.3g Mrays/s (%llu bounce + %llu "
      "shadow rays)\n",
      total, gi.bounces, double(sum.samples) / sum.seconds * 1e-6,
      double(sum.rays) / sum.seconds * 1e-6, (unsigned long long)sum.bounce_rays,
      (unsigned long long)sum.shadow_rays);
  if (verbose) std::fprintf(stderr, "  %-22s %9.1f ms\n", "  of which paths", sum.seconds * 1e3);
  return r;
}

}  // namespace voxcast::cli
