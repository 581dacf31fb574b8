// render(): the surface integrator over the frame loop, as one call.
#include "voxcast/render.hpp"

#include <utility>

#include "voxcast/integrator.hpp"

namespace voxcast {
namespace {

/// A const structure seen by the frame loop: its queries, and none of its
/// frame-loop hooks (render.hpp: the const overload serves no requests).
class ConstView final : public Structure {
 public:
  explicit ConstView(const Structure& s) : s_(s) {}
  std::string name() const override { return s_.name(); }
  Aabb bounds() const override { return s_.bounds(); }
  const SurfaceQuery* surface() const override { return s_.surface(); }
  const VolumeQuery* volume() const override { return s_.volume(); }

 private:
  const Structure& s_;
};

RenderResult render_with(Structure& structure, const RenderOptions& options, int max_passes) {
  SurfaceIntegrator integrator(options);
  FrameView view;
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

}  // namespace

RenderResult render(Structure& structure, const RenderOptions& options) {
  return render_with(structure, options, options.max_passes);
}

RenderResult render(const Structure& structure, const RenderOptions& options) {
  ConstView view(structure);
  return render_with(view, options, 1);
}

}  // namespace voxcast
