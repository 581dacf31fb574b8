// Tiled, multi-threaded primary-ray renderer over any VoxelStructure.
#include "voxcast/render.hpp"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <mutex>
#include <vector>

#include "render/beam.hpp"
#include "render/tiling.hpp"
#include "voxcast/error.hpp"

namespace voxcast {

RenderResult render(const VoxelStructure& structure, const RenderOptions& options) {
  if (options.width <= 0 || options.height <= 0 || options.width > 65536 || options.height > 65536)
    throw Error("render: image size must be in 1..65536");
  if (!(options.lod_pixels >= 0.f) || !std::isfinite(options.lod_pixels))
    throw Error("render: lod_pixels must be a finite number >= 0");
  if (options.tile_size <= 0) throw Error("render: tile_size must be positive");
  if (options.beam != 0 && (options.beam < 2 || options.beam > 64))
    throw Error("render: beam must be 0 (off) or a block size in 2..64");
  const CameraRays cam(options.camera, options.width, options.height);

  RenderResult result;
  const int W = options.width, H = options.height;
  result.color = Image(W, H, 3);
  if (options.want_depth) result.depth = Image(W, H, 1);
  if (options.want_normal) result.normal = Image(W, H, 3);

  // Pixel cone (esvo §6.1 ray_size_coef/bias): a voxel may stand for the
  // surface once it projects to <= lod_pixels pixels; 0 keeps the finest
  // level. Perspective: the footprint grows with t; orthographic: constant.
  LodFootprint lod;
  lod.size_at_origin = options.lod_pixels * cam.pixel_size();
  lod.size_per_t = options.lod_pixels * cam.pixel_angle();

  Vec3 to_light = normalize(-options.light_dir);
  if (!is_finite(to_light) || length(to_light) == 0.f) to_light = {0, 1, 0};
  const Color bg = options.background;
  // Secondary-ray effects (svdag §4, effects.cpp): shadows and AO per hit pixel.
  EffectOptions fx = options.effects;
  validate(fx);
  const bool effects = fx.active();
  if (fx.ao_rays > 0 && !(fx.ao_radius > 0.f))
    fx.ao_radius = 0.05f * length(structure.bounds().extent());
  const StructureOccluder occluder(structure);
  if (fx.ao_rays > 0)
    result.ao = Image(W, H, 1), std::fill(result.ao.pixels.begin(), result.ao.pixels.end(), 1.f);
  if (fx.shadows != ShadowMode::None)
    result.shadow = Image(W, H, 1),
    std::fill(result.shadow.pixels.begin(), result.shadow.pixels.end(), 1.f);
  std::mutex effects_mutex;
  const bool want_depth = options.want_depth, want_normal = options.want_normal;

  // esvo §6.3: per-pixel projected size of the hit voxel, log2 in 3.5 fixed
  // point (the paper's alpha channel); misses keep 0 = radius 1 = no blur.
  std::vector<uint8_t> filter_radius;
  if (options.filter) filter_radius.assign(size_t(W) * size_t(H), 0);
  const float pixel_angle = cam.pixel_angle(), pixel_size = cam.pixel_size();

  std::atomic<uint64_t> total_hits{0};
  // Profiling (esvo §8.5) and beam optimization (§6.2) state.
  const bool collect = options.collect_stats;
  const int beam_k = options.beam;
  if (collect) result.iterations = Image(W, H, 1);
  std::mutex stats_mutex;
  // Pixels go in batches: first every ray of the batch is traced, then the
  // hits are shaded. Attribute fetches are mostly cache misses (the values
  // live far from the descriptors); issued back to back they overlap in the
  // memory system instead of stalling one ray at a time.
  constexpr int kBatch = 32;
  result.seconds = detail::for_each_tile(W, H, options.tile_size, [&](const detail::Tile& tile) {
    uint64_t hits = 0;
    SurfaceHit batch_hit[kBatch];
    Vec3 batch_dir[kBatch];
    int batch_x[kBatch], batch_y[kBatch];
    int batch_n = 0;
    RayCounters tile_counters, tile_coarse;
    uint64_t tile_beams = 0;
    EffectCounters tile_fx;
    auto shade_batch = [&] {
      for (int b = 0; b < batch_n; ++b) {
        const SurfaceHit& hit = batch_hit[b];
        const int x = batch_x[b], y = batch_y[b];
        float* out = result.color.at(x, y);
        Color c;
        Vec3 n;
        if (collect)
          structure.attributes_counted(hit, &c, &n, &tile_counters);
        else
          structure.attributes(hit, &c, &n);
        const Vec3 dir = batch_dir[b];
        // Voxel normals are averages over the surface inside the voxel and may
        // face away from the viewer; shade the side we see.
        if (dot(n, dir) > 0.f) n = -n;
        Vec3 light = to_light;
        float visibility = 1.f, ao = 1.f;
        if (fx.light != LightKind::Directional) {
          float dist;
          light = direction_to_light(fx, options.light_dir, hit.position, &dist);
        }
        if (effects) {
          const ShadingPoint sp{hit.position, n, dir, hit.voxel_size};
          const uint32_t seed = pixel_seed(x, y, fx.seed);
          if (fx.shadows != ShadowMode::None)
            *result.shadow.at(x, y) = visibility =
                shadow_visibility(occluder, sp, fx, options.light_dir, seed, &tile_fx);
          if (fx.ao_rays > 0)
            *result.ao.at(x, y) = ao =
                ambient_occlusion(occluder, sp, fx, fx.ao_radius, seed, &tile_fx);
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
        if (want_depth) *result.depth.at(x, y) = hit.t;
        if (!filter_radius.empty()) {
          // Voxel side over the pixel footprint at distance t; t ~ 0 (eye in
          // the voxel, perspective) gives +inf or a huge size -> the largest code.
          const float footprint = pixel_size + hit.t * pixel_angle;
          filter_radius[size_t(y) * W + x] =
              footprint > 0.f ? encode_filter_radius(hit.voxel_size / footprint) : uint8_t(255);
        }
        if (want_normal) {
          float* o = result.normal.at(x, y);
          o[0] = n.x * 0.5f + 0.5f, o[1] = n.y * 0.5f + 0.5f, o[2] = n.z * 0.5f + 0.5f;
        }
      }
      batch_n = 0;
    };
    // One pixel; `beam` = the coarse-pass result of its block (or null).
    auto trace_pixel = [&](int x, int y, const BeamStart* beam) {
      const Ray ray = cam.ray(x, y);
      bool found;
      if (!collect && beam == nullptr) {
        found = structure.trace(ray, lod, &batch_hit[batch_n]);  // the plain fast path
      } else {
        RayCounters rc;
        found = structure.trace_hinted(ray, lod, TraceHints{beam, collect ? &rc : nullptr},
                                       &batch_hit[batch_n]);
        if (collect) {
          tile_counters += rc;
          *result.iterations.at(x, y) = float(rc.iterations);
        }
      }
      if (found) {
        ++hits;
        batch_dir[batch_n] = ray.dir;
        batch_x[batch_n] = x;
        batch_y[batch_n] = y;
        if (++batch_n == kBatch) shade_batch();
        return;
      }
      float* out = result.color.at(x, y);
      out[0] = bg.r, out[1] = bg.g, out[2] = bg.b;
      if (want_depth) *result.depth.at(x, y) = INFINITY;
      if (want_normal) {
        float* n = result.normal.at(x, y);
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
          structure.beam_start(detail::block_beam(cam, bx, by, bx1, by1, lod), &start,
                               collect ? &tile_coarse : nullptr);
          ++tile_beams;
          for (int y = by; y < by1; ++y)
            for (int x = bx; x < bx1; ++x) trace_pixel(x, y, &start);
        }
      }
    }
    shade_batch();
    total_hits.fetch_add(hits, std::memory_order_relaxed);
    if (effects) {
      std::lock_guard<std::mutex> lock(effects_mutex);
      result.effect_counters += tile_fx;
    }
    if (collect) {
      std::lock_guard<std::mutex> lock(stats_mutex);
      result.counters += tile_counters;
      result.coarse_counters += tile_coarse;
      result.beams += tile_beams;
    }
  });
  result.rays = uint64_t(W) * uint64_t(H);
  result.hits = total_hits.load();
  if (options.filter) {  // esvo §6.3 post-process filter, timed on its own
    const auto f0 = std::chrono::steady_clock::now();
    result.color = post_filter(result.color, filter_radius);
    result.filter_seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - f0).count();
  }
  return result;
}

}  // namespace voxcast
