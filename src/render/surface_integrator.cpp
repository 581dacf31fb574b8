// The surface integrator (include/voxcast/surface_integrator.hpp): primary
// hits, Blinn-Phong shading, shadows and AO, the beam coarse pass per block,
// counters, AOVs and the post-filter, one tile at a time.
#include "voxcast/surface_integrator.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>

#include "render/beam.hpp"
#include "voxcast/error.hpp"
#include "voxcast/render.hpp"

namespace voxcast {

SurfaceIntegrator::SurfaceIntegrator(const SurfaceOptions& options) : options_(options) {
  if (options_.beam != 0 && (options_.beam < 2 || options_.beam > 64))
    throw Error("render: beam must be 0 (off) or a block size in 2..64");
  validate(options_.effects);
}

uint32_t SurfaceIntegrator::aovs() const {
  uint32_t a = kAovColor;
  if (options_.want_depth) a |= kAovDepth;
  if (options_.want_normal) a |= kAovNormal;
  if (options_.collect_stats) a |= kAovIterations;
  if (options_.effects.ao_rays > 0) a |= kAovAo;
  if (options_.effects.shadows != ShadowMode::None) a |= kAovShadow;
  return a;
}

void SurfaceIntegrator::begin_frame(const Structure& structure, const FrameView& view, Film&) {
  query_ = structure.surface();
  if (query_ == nullptr)
    throw Error("render: the " + structure.name() + " structure has no surface query");
  cam_.emplace(view.rays());
  // Pixel cone (esvo §6.1 ray_size_coef/bias): a voxel may stand for the
  // surface once it projects to <= lod_pixels pixels; 0 keeps the finest
  // level. Perspective: the footprint grows with t; orthographic: constant.
  lod_ = view.lod();
  to_light_ = normalize(-options_.light_dir);
  if (!is_finite(to_light_) || length(to_light_) == 0.f) to_light_ = {0, 1, 0};
  fx_ = options_.effects;
  if (fx_.ao_rays > 0 && !(fx_.ao_radius > 0.f))
    fx_.ao_radius = 0.05f * length(structure.bounds().extent());
  tiles_.clear();
  stats_ = SurfaceStats{};
}

void SurfaceIntegrator::render_tile(const Structure&, const FrameView&, const TileRect& tile,
                                    TraceContext& ctx, Film& film) {
  const SurfaceQuery& q = *query_;
  const CameraRays& cam = *cam_;
  const LodFootprint lod = lod_;
  const Vec3 to_light = to_light_;
  const Color bg = options_.background;
  const EffectOptions& fx = fx_;
  const bool effects = fx.active();
  const bool want_depth = options_.want_depth, want_normal = options_.want_normal;
  const bool collect = options_.collect_stats && ctx.counting;
  const int beam_k = options_.beam;
  const int W = film.width;
  const float pixel_angle = cam.pixel_angle(), pixel_size = cam.pixel_size();
  const StructureOccluder occluder(q);

  TileStats ts;
  // The counters of this tile's primary rays accumulate in ctx.counters from
  // zero; the frame's running total is put back (plus this tile's work) at
  // the end, so the frame loop's sum still covers everything.
  RayCounters outer;
  if (collect) outer = ctx.counters, ctx.counters = RayCounters{};

  // Pixels go in batches: first every ray of the batch is traced, then the
  // hits are shaded. Attribute fetches are mostly cache misses (the values
  // live far from the descriptors); issued back to back they overlap in the
  // memory system instead of stalling one ray at a time.
  constexpr int kBatch = 32;
  SurfaceHit batch_hit[kBatch];
  Vec3 batch_dir[kBatch];
  int batch_x[kBatch], batch_y[kBatch];
  int batch_n = 0;
  auto shade_batch = [&] {
    for (int b = 0; b < batch_n; ++b) {
      const SurfaceHit& hit = batch_hit[b];
      const int x = batch_x[b], y = batch_y[b];
      float* out = film.color.at(x, y);
      Color c;
      Vec3 n;
      q.attributes(hit, ctx, &c, &n);  // counts its bytes while collecting
      const Vec3 dir = batch_dir[b];
      // Voxel normals are averages over the surface inside the voxel and may
      // face away from the viewer; shade the side we see.
      if (dot(n, dir) > 0.f) n = -n;
      Vec3 light = to_light;
      float visibility = 1.f, ao = 1.f;
      if (fx.light != LightKind::Directional) {
        float dist;
        light = direction_to_light(fx, options_.light_dir, hit.position, &dist);
      }
      if (effects) {
        // The Table 6 counters describe primary rays; secondary rays are
        // counted by EffectCounters.
        const bool counting = ctx.counting;
        ctx.counting = false;
        const ShadingPoint sp{hit.position, n, dir, hit.voxel_size};
        const uint32_t seed = pixel_seed(x, y, fx.seed);
        if (fx.shadows != ShadowMode::None)
          *film.shadow.at(x, y) = visibility =
              shadow_visibility(occluder, ctx, sp, fx, options_.light_dir, seed, &ts.effects);
        if (fx.ao_rays > 0)
          *film.ao.at(x, y) = ao =
              ambient_occlusion(occluder, ctx, sp, fx, fx.ao_radius, seed, &ts.effects);
        ctx.counting = counting;
      }
      const float diffuse = std::fmax(0.f, dot(n, light)) * visibility;
      const Vec3 half_vec = normalize(light - dir);   // Blinn: light + view
      float spec = std::fmax(0.f, dot(n, half_vec));  // ^32 by squaring (no powf call)
      spec *= spec, spec *= spec, spec *= spec, spec *= spec, spec *= spec;
      spec *= visibility;
      const float k = 0.18f * ao + 0.82f * diffuse;
      out[0] = c.r * k + 0.12f * spec;
      out[1] = c.g * k + 0.12f * spec;
      out[2] = c.b * k + 0.12f * spec;
      if (want_depth) *film.depth.at(x, y) = hit.t;
      if (!film.filter_radius.empty()) {
        // esvo §6.3: the voxel side over the pixel footprint at distance t,
        // log2 in 3.5 fixed point (the paper's alpha channel); t ~ 0 (eye in
        // the voxel, perspective) gives +inf or a huge size -> the largest
        // code. Misses keep 0 = radius 1 = no blur.
        const float footprint = pixel_size + hit.t * pixel_angle;
        film.filter_radius[size_t(y) * W + x] =
            footprint > 0.f ? encode_filter_radius(hit.voxel_size / footprint) : uint8_t(255);
      }
      if (want_normal) {
        float* o = film.normal.at(x, y);
        o[0] = n.x * 0.5f + 0.5f, o[1] = n.y * 0.5f + 0.5f, o[2] = n.z * 0.5f + 0.5f;
      }
    }
    batch_n = 0;
  };
  // One pixel; `beam` = the coarse-pass result of its block (or null).
  auto trace_pixel = [&](int x, int y, const BeamStart* beam) {
    const Ray ray = cam.ray(x, y);
    const uint64_t iterations_before = collect ? ctx.counters.iterations : 0;
    const bool found = q.trace(ray, lod, ctx, &batch_hit[batch_n], beam);
    if (collect) *film.iterations.at(x, y) = float(ctx.counters.iterations - iterations_before);
    if (found) {
      ++ts.hits;
      batch_dir[batch_n] = ray.dir;
      batch_x[batch_n] = x;
      batch_y[batch_n] = y;
      if (++batch_n == kBatch) shade_batch();
      return;
    }
    float* out = film.color.at(x, y);
    out[0] = bg.r, out[1] = bg.g, out[2] = bg.b;
    if (want_depth) *film.depth.at(x, y) = INFINITY;
    if (want_normal) {
      float* n = film.normal.at(x, y);
      n[0] = n[1] = n[2] = 0.5f;
    }
  };
  if (beam_k == 0) {
    for (int y = tile.y0; y < tile.y1; ++y)
      for (int x = tile.x0; x < tile.x1; ++x) trace_pixel(x, y, nullptr);
  } else {
    // §6.2: per K x K block (clipped to the tile), a coarse pass computes a
    // conservative start region shared by the block's rays. It runs inside
    // the timed loop and ignores contours (§6.2: whole cubes contain their
    // contour-clipped shape; core/beam_frustum.hpp).
    for (int by = tile.y0; by < tile.y1; by += beam_k) {
      for (int bx = tile.x0; bx < tile.x1; bx += beam_k) {
        const int bx1 = std::min(bx + beam_k, tile.x1), by1 = std::min(by + beam_k, tile.y1);
        BeamStart start;
        if (collect) {
          // The coarse pass's work is kept apart from the rays' (Table 6).
          const RayCounters rays = ctx.counters;
          ctx.counters = RayCounters{};
          q.beam_start(detail::block_beam(cam, bx, by, bx1, by1, lod), ctx, &start);
          ts.coarse_counters += ctx.counters;
          ctx.counters = rays;
          ++ts.beams;
        } else {
          q.beam_start(detail::block_beam(cam, bx, by, bx1, by1, lod), ctx, &start);
        }
        for (int y = by; y < by1; ++y)
          for (int x = bx; x < bx1; ++x) trace_pixel(x, y, &start);
      }
    }
  }
  shade_batch();
  if (collect) {
    ts.counters = ctx.counters;
    ctx.counters = outer;
    ctx.counters += ts.counters;
    ctx.counters += ts.coarse_counters;
  }
  const uint64_t key = uint64_t(uint32_t(tile.y0)) << 32 | uint32_t(tile.x0);
  std::lock_guard<std::mutex> lock(tiles_mutex_);
  tiles_[key] = ts;
}

void SurfaceIntegrator::end_frame(const Structure&, const FrameView&, Film& film) {
  for (const auto& [key, t] : tiles_) {
    (void)key;
    stats_.hits += t.hits;
    stats_.counters += t.counters;
    stats_.coarse_counters += t.coarse_counters;
    stats_.beams += t.beams;
    stats_.effect_counters += t.effects;
  }
  if (options_.filter) {  // esvo §6.3 post-process filter, timed on its own
    const auto f0 = std::chrono::steady_clock::now();
    film.color = post_filter(film.color, film.filter_radius);
    stats_.filter_seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - f0).count();
  }
}

}  // namespace voxcast
