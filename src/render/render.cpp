// render(): the surface integrator over the frame loop, as one call.
#include "voxcast/render.hpp"

#include <algorithm>
#include <cmath>
#include <utility>

#include "render/const_view.hpp"
#include "voxcast/error.hpp"
#include "voxcast/integrator.hpp"

namespace voxcast {
namespace {

RenderResult render_once(Structure& structure, const RenderOptions& options, int max_passes,
                         Vec2 sample) {
  SurfaceIntegrator integrator(options);
  FrameView view;
  view.sample = sample;
  view.camera = options.camera;
  view.width = options.width, view.height = options.height;
  view.lod_pixels = options.lod_pixels;
  view.frame = options.frame;
  FrameOptions fo;
  fo.tile_size = options.tile_size;
  fo.max_passes = max_passes;
  fo.counting = options.collect_stats;
  fo.progress = options.progress;
  Film film;
  const FrameStats fs = render_frame(structure, integrator, view, fo, &film);

  const SurfaceStats& st = integrator.stats();
  RenderResult result;
  result.color = std::move(film.color);
  result.depth = std::move(film.depth);
  result.normal = std::move(film.normal);
  result.iterations = std::move(film.iterations);
  result.ao = std::move(film.ao);
  result.shadow = std::move(film.shadow);
  result.rays = uint64_t(options.width) * uint64_t(options.height);
  result.hits = st.hits;
  result.seconds = fs.seconds;
  result.counters = st.counters;
  result.coarse_counters = st.coarse_counters;
  result.beams = st.beams;
  result.filter_seconds = st.filter_seconds;
  result.effect_counters = st.effect_counters;
  result.passes = int(fs.passes.size());
  return result;
}

// Every sample of RenderOptions::spp a frame of its own; the sums are in
// sample order, so the image does not depend on threads or tiles either.
RenderResult render_with(Structure& structure, const RenderOptions& options, int max_passes) {
  if (options.spp < 1 || options.spp > 4096)
    throw Error("render: samples per pixel must be in 1..4096");
  RenderResult result = render_once(structure, options, max_passes, antialias_sample(0));
  if (options.spp == 1) return result;
  RenderOptions o = options;
  for (int k = 1; k < options.spp; ++k) {
    o.effects.seed = options.effects.seed + uint32_t(k);
    const RenderResult r = render_once(structure, o, max_passes, antialias_sample(k));
    auto add = [](Image& sum, const Image& im) {
      for (size_t i = 0; i < sum.pixels.size(); ++i) sum.pixels[i] += im.pixels[i];
    };
    add(result.color, r.color);
    add(result.ao, r.ao);
    add(result.shadow, r.shadow);
    result.rays += r.rays, result.hits += r.hits;
    result.seconds += r.seconds, result.filter_seconds += r.filter_seconds;
    result.counters += r.counters, result.coarse_counters += r.coarse_counters;
    result.beams += r.beams;
    result.effect_counters += r.effect_counters;
    result.passes = std::max(result.passes, r.passes);
  }
  const float inv = 1.f / float(options.spp);
  for (Image* im : {&result.color, &result.ao, &result.shadow})
    for (float& v : im->pixels) v *= inv;
  return result;
}

}  // namespace

Vec2 antialias_sample(int k) {
  // R2 (Roberts 2018): the generalized golden ratio's powers; k = 0 is the center.
  const double a1 = 0.7548776662466927, a2 = 0.5698402909980532;
  const double x = 0.5 + a1 * double(k), y = 0.5 + a2 * double(k);
  return {float(x - std::floor(x)), float(y - std::floor(y))};
}

RenderResult render(Structure& structure, const RenderOptions& options) {
  return render_with(structure, options, options.max_passes);
}

RenderResult render(const Structure& structure, const RenderOptions& options) {
  detail::ConstView view(structure);
  return render_with(view, options, 1);
}

}  // namespace voxcast
