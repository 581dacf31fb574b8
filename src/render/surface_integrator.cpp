// The surface integrator (include/voxcast/surface_integrator.hpp): primary
// hits, Blinn-Phong shading, shadows and AO, the beam coarse pass per block,
// counters, AOVs and the post-filter, one tile at a time.
#include "voxcast/surface_integrator.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <vector>

#include "render/beam.hpp"
#include "render/shade_kernel.hpp"
#include "voxcast/error.hpp"
#include "voxcast/packet_caster.hpp"
#include "voxcast/render.hpp"

namespace voxcast {

SurfaceIntegrator::SurfaceIntegrator(const SurfaceOptions& options) : options_(options) {
  if (options_.beam != 0 && (options_.beam < 2 || options_.beam > 64))
    throw Error("render: beam must be 0 (off) or a block size in 2..64");
  if (options_.frustum != 0 && (options_.frustum < 2 || options_.frustum > 64))
    throw Error("render: frustum must be 0 (off) or a block size in 2..64");
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
  packets_ = options_.caster != Caster::Scalar ? query_->packets() : nullptr;
  isa_ = options_.isa ? *options_.isa : active_isa();
  if (!cpu_supports(isa_))
    throw Error(std::string("render: this CPU does not support ") + isa_name(isa_));
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
  const int frustum_k = options_.frustum;
  const int W = film.width;
  const float pixel_angle = cam.pixel_angle(), pixel_size = cam.pixel_size();
  const StructureOccluder occluder(q);

  TileStats ts;
  // The counters of this tile's primary rays accumulate in ctx.counters from
  // zero; the frame's running total is put back (plus this tile's work) at
  // the end, so the frame loop's sum still covers everything.
  RayCounters outer;
  if (collect) outer = ctx.counters, ctx.counters = RayCounters{};

  // Hits are shaded in groups: first the group's attributes are fetched by
  // one SurfaceQuery::attributes_batch (mostly cache misses: the values live
  // far from the descriptors; read together, they overlap in the memory
  // system instead of stalling one hit at a time), then the group's shadow
  // rays are traced together (effects.hpp: one packet of parallel rays
  // under a directional light), then per hit the AO rays, then the
  // Blinn-Phong runs kShadeLanes hits at a time in vector lanes
  // (render/shade_kernel.hpp), and the AOVs are written.
  //
  // The tile and packet paths hand groups of up to kShadowGroup hits (a
  // tile's, in traced order): the more reads one attributes_batch has in
  // flight, the less each waits (groups of 16 measured 1.05x slower shaded
  // frames, ESVO); the shadow rays, all parallel under a directional light,
  // are one batch that the octree structures trace by shared walks
  // (voxcast/occlusion_packets.hpp AnyHitOptions::parallel). The scalar
  // path shades kShadeLanes hits at a time.
  const detail::ShadeKernel phong = detail::shade_kernel(isa_);
  detail::ShadeBatch sb{};
  constexpr int kShadowGroup = 256;
  thread_local Color group_c[kShadowGroup];
  thread_local Vec3 group_n[kShadowGroup];
  thread_local ShadingPoint group_point[kShadowGroup];
  thread_local uint32_t group_seed[kShadowGroup];
  thread_local float group_vis[kShadowGroup];
  // Shades hits [g, g + m) of the group (m <= kShadeLanes; hits, xs, ys and
  // dirs start at hit g): AO, Blinn-Phong in vector lanes, the AOVs.
  auto shade_lanes = [&](const SurfaceHit* const* hits, const int* xs, const int* ys,
                         const Vec3* dirs, int g, int m) {
    for (int i = 0; i < m; ++i) {
      const SurfaceHit& hit = *hits[i];
      const int x = xs[i], y = ys[i];
      const Vec3 dir = dirs[i];
      const Vec3 n = group_n[g + i];
      Vec3 light = to_light;
      float visibility = 1.f, ao = 1.f;
      if (fx.light != LightKind::Directional) {
        float dist;
        light = direction_to_light(fx, options_.light_dir, hit.position, &dist);
      }
      if (effects) {
        const bool counting = ctx.counting;
        ctx.counting = false;
        if (fx.shadows != ShadowMode::None) *film.shadow.at(x, y) = visibility = group_vis[g + i];
        if (fx.ao_rays > 0)
          *film.ao.at(x, y) = ao = ambient_occlusion(occluder, ctx, group_point[g + i], fx,
                                                     fx.ao_radius, group_seed[g + i], &ts.effects);
        ctx.counting = counting;
      }
      const Color c = group_c[g + i];
      sb.cr[i] = c.r, sb.cg[i] = c.g, sb.cb[i] = c.b;
      sb.nx[i] = n.x, sb.ny[i] = n.y, sb.nz[i] = n.z;
      sb.dx[i] = dir.x, sb.dy[i] = dir.y, sb.dz[i] = dir.z;
      sb.lx[i] = light.x, sb.ly[i] = light.y, sb.lz[i] = light.z;
      sb.visibility[i] = visibility, sb.ao[i] = ao;
    }
    sb.count = m;
    phong(&sb);
    for (int i = 0; i < m; ++i) {
      const SurfaceHit& hit = *hits[i];
      const int x = xs[i], y = ys[i];
      float* out = film.color.at(x, y);
      out[0] = sb.r[i], out[1] = sb.g[i], out[2] = sb.b[i];
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
        o[0] = sb.nx[i] * 0.5f + 0.5f, o[1] = sb.ny[i] * 0.5f + 0.5f, o[2] = sb.nz[i] * 0.5f + 0.5f;
      }
    }
  };
  auto shade_group = [&](const SurfaceHit* const* hits, const int* xs, const int* ys,
                         const Vec3* dirs, int m) {
    // The group's attribute reads together (counts their bytes while collecting).
    q.attributes_batch(hits, m, ctx, group_c, group_n);
    for (int i = 0; i < m; ++i) {
      const SurfaceHit& hit = *hits[i];
      // Voxel normals are averages over the surface inside the voxel and may
      // face away from the viewer; shade the side we see.
      if (dot(group_n[i], dirs[i]) > 0.f) group_n[i] = -group_n[i];
      group_point[i] = ShadingPoint{hit.position, group_n[i], dirs[i], hit.voxel_size};
      if (effects) group_seed[i] = pixel_seed(xs[i], ys[i], fx.seed);  // (shadow and AO rays)
    }
    if (effects && fx.shadows != ShadowMode::None) {
      // The Table 6 counters describe primary rays; secondary rays are
      // counted by EffectCounters.
      const bool counting = ctx.counting;
      ctx.counting = false;
      shadow_visibility_batch(occluder, ctx, group_point, m, fx, options_.light_dir, group_seed,
                              &ts.effects, group_vis);
      ctx.counting = counting;
    }
    for (int g = 0; g < m; g += detail::kShadeLanes) {
      const int lanes = std::min(detail::kShadeLanes, m - g);
      shade_lanes(hits + g, xs + g, ys + g, dirs + g, g, lanes);
    }
  };
  // Scalar path: the hits of kShadeLanes rays in a row.
  constexpr int kBatch = detail::kShadeLanes;
  SurfaceHit batch_hit[kBatch];
  const SurfaceHit* batch_ptr[kBatch];
  for (int b = 0; b < kBatch; ++b) batch_ptr[b] = &batch_hit[b];
  Vec3 batch_dir[kBatch];
  int batch_x[kBatch], batch_y[kBatch];
  int batch_n = 0;
  auto shade_batch = [&] {
    shade_group(batch_ptr, batch_x, batch_y, batch_dir, batch_n);
    batch_n = 0;
  };
  auto miss = [&](int x, int y) {
    float* out = film.color.at(x, y);
    out[0] = bg.r, out[1] = bg.g, out[2] = bg.b;
    if (want_depth) *film.depth.at(x, y) = INFINITY;
    if (want_normal) {
      float* n = film.normal.at(x, y);
      n[0] = n[1] = n[2] = 0.5f;
    }
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
    miss(x, y);
  };
  // The coarse pass (§6.2) of the K x K block at (bx, by), clipped to the
  // tile; it runs inside the timed loop and ignores contours (§6.2: whole
  // cubes contain their contour-clipped shape; core/beam_frustum.hpp).
  auto coarse_pass = [&](int bx, int by, BeamStart* start) {
    const int bx1 = std::min(bx + beam_k, tile.x1), by1 = std::min(by + beam_k, tile.y1);
    const BeamFrustum frustum = detail::block_beam(cam, bx, by, bx1, by1, lod);
    if (collect) {
      // The coarse pass's work is kept apart from the rays' (Table 6).
      const RayCounters rays = ctx.counters;
      ctx.counters = RayCounters{};
      q.beam_start(frustum, ctx, start);
      ts.coarse_counters += ctx.counters;
      ctx.counters = rays;
      ++ts.beams;
    } else {
      q.beam_start(frustum, ctx, start);
    }
  };
  // Packets need a frame that does not count: the kernels have no counters
  // (and the iteration AOV is per ray).
  // The tile's rays in 4x4 pixel blocks (block_order), traced as one call:
  // the packet caster fills its lanes from this queue in order, so a packet
  // starts as a coherent block. Buffers per thread, grown once.
  thread_local detail::PacketTile pt;
  thread_local BeamStart tile_start;
  // The tile caster: the tile's hits row by row, then shaded in groups.
  thread_local std::vector<SurfaceHit> tile_hits;
  thread_local std::vector<uint8_t> tile_found;
  const int tile_w = tile.x1 - tile.x0, tile_n = tile_w * (tile.y1 - tile.y0);
  bool tiled = false;
  if (packets_ != nullptr && !ctx.counting && options_.caster == Caster::Tile) {
    tile_hits.resize(size_t(tile_n)), tile_found.resize(size_t(tile_n));
    tiled = packets_->trace_tile(cam, tile.x0, tile.y0, tile.x1, tile.y1, lod, ctx,
                                 tile_hits.data(), tile_found.data(), isa_);
  }
  if (!tiled && packets_ != nullptr && !ctx.counting && frustum_k != 0) {
    // The tile frustum pass: the tile's cubes, front to back for the
    // mirroring octant of its center ray; none = every pixel a miss.
    const int octant = ray_octant(cam.ray((tile.x0 + tile.x1) / 2, (tile.y0 + tile.y1) / 2).dir);
    q.frustum_start(detail::block_beam(cam, tile.x0, tile.y0, tile.x1, tile.y1, lod), octant, ctx,
                    &tile_start);
    ts.empty_tile = tile_start.valid && tile_start.empty;
  }
  // The hits of a tile or packet call in groups of up to kShadowGroup (a
  // 16 x 16 tile's hits are one group), in the order traced: one
  // attributes_batch per group (the more reads in flight together, the
  // less each waits), one batch of shadow rays (above).
  const int group_size = kShadowGroup;
  thread_local const SurfaceHit* group_hit[kShadowGroup];
  thread_local Vec3 group_dir[kShadowGroup];
  thread_local int group_x[kShadowGroup], group_y[kShadowGroup];
  int group_m = 0;
  auto add_hit = [&](const SurfaceHit* hit, Vec3 dir, int x, int y) {
    ++ts.hits;
    group_hit[group_m] = hit, group_dir[group_m] = dir;
    group_x[group_m] = x, group_y[group_m] = y;
    if (++group_m == group_size)
      shade_group(group_hit, group_x, group_y, group_dir, group_m), group_m = 0;
  };
  auto flush_hits = [&] {
    if (group_m > 0) shade_group(group_hit, group_x, group_y, group_dir, group_m), group_m = 0;
  };
  if (tiled) {
    // The first step of every hit's attribute reads (an index, for a
    // structure whose lookup is a chain) before the group is shaded: by the
    // time shade_group's attributes_batch reads it, it is on its way.
    for (int k = 0; k < tile_n; ++k)
      if (tile_found[size_t(k)]) q.prefetch_attribute_index(tile_hits[size_t(k)]);
    for (int k = 0; k < tile_n; ++k) {
      const int x = tile.x0 + k % tile_w, y = tile.y0 + k / tile_w;
      if (tile_found[size_t(k)])
        add_hit(&tile_hits[size_t(k)], cam.direction(x, y), x, y);
      else
        miss(x, y);
    }
    flush_hits();
  } else if (ts.empty_tile) {
    for (int y = tile.y0; y < tile.y1; ++y)
      for (int x = tile.x0; x < tile.x1; ++x) miss(x, y);
  } else if (packets_ != nullptr && !ctx.counting) {
    pt.generate(cam, tile.x0, tile.y0, tile.x1, tile.y1);
    if (frustum_k != 0) {
      // Per K x K block: the finer cubes within the tile's (packet starts).
      pt.frustum_blocks(q, cam, lod, tile.x0, tile.y0, tile.x1, tile.y1, frustum_k, ctx,
                        tile_start);
    } else if (beam_k != 0) {
      pt.coarse_pass(tile.x0, tile.y0, tile.x1, tile.y1, beam_k, coarse_pass);
    }
    const size_t n = pt.order.size();
    packets_->trace_packets(pt.rays.data(), n, lod, ctx, pt.hits.data(), pt.found.data(), isa_,
                            pt.beam_list());
    for (size_t i = 0; i < n; ++i)  // as in the tile path above
      if (pt.found[i]) q.prefetch_attribute_index(pt.hits[i]);
    for (size_t i = 0; i < n; ++i) {
      if (pt.found[i])
        add_hit(&pt.hits[i], pt.rays[i].dir, pt.x(i), pt.y(i));
      else
        miss(pt.x(i), pt.y(i));
    }
    flush_hits();
  } else if (beam_k == 0) {
    for (int y = tile.y0; y < tile.y1; ++y)
      for (int x = tile.x0; x < tile.x1; ++x) trace_pixel(x, y, nullptr);
  } else {
    // §6.2: per K x K block (clipped to the tile), a coarse pass computes a
    // conservative start region shared by the block's rays.
    for (int by = tile.y0; by < tile.y1; by += beam_k) {
      for (int bx = tile.x0; bx < tile.x1; bx += beam_k) {
        const int bx1 = std::min(bx + beam_k, tile.x1), by1 = std::min(by + beam_k, tile.y1);
        BeamStart start;
        coarse_pass(bx, by, &start);
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
    stats_.empty_tiles += t.empty_tile ? 1 : 0;
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
