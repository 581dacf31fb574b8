// Tiled, multi-threaded primary-ray renderer over any VoxelStructure.
#include "voxcast/render.hpp"

#include <atomic>
#include <cmath>

#include "render/tiling.hpp"
#include "voxcast/error.hpp"

namespace voxcast {

RenderResult render(const VoxelStructure& structure, const RenderOptions& options) {
  if (options.width <= 0 || options.height <= 0 || options.width > 65536 || options.height > 65536)
    throw Error("render: image size must be in 1..65536");
  if (!(options.lod_pixels >= 0.f) || !std::isfinite(options.lod_pixels))
    throw Error("render: lod_pixels must be a finite number >= 0");
  if (options.tile_size <= 0) throw Error("render: tile_size must be positive");
  const CameraRays cam(options.camera, options.width, options.height);

  RenderResult result;
  const int W = options.width, H = options.height;
  result.color = Image(W, H, 3);
  if (options.want_depth) result.depth = Image(W, H, 1);
  if (options.want_normal) result.normal = Image(W, H, 3);

  // Pixel cone (esvo §6.1 ray_size_coef/bias): a voxel may stand for the
  // surface once it projects to <= lod_pixels pixels; 0 keeps the finest level.
  LodFootprint lod;
  lod.size_at_origin = 0.f;
  lod.size_per_t = options.lod_pixels * cam.pixel_angle();

  Vec3 to_light = normalize(-options.light_dir);
  if (!is_finite(to_light) || length(to_light) == 0.f) to_light = {0, 1, 0};
  const Color bg = options.background;
  const bool want_depth = options.want_depth, want_normal = options.want_normal;

  std::atomic<uint64_t> total_hits{0};
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
    auto shade_batch = [&] {
      for (int b = 0; b < batch_n; ++b) {
        const SurfaceHit& hit = batch_hit[b];
        const int x = batch_x[b], y = batch_y[b];
        float* out = result.color.at(x, y);
        Color c;
        Vec3 n;
        structure.attributes(hit, &c, &n);
        const Vec3 dir = batch_dir[b];
        // Voxel normals are averages over the surface inside the voxel and may
        // face away from the viewer; shade the side we see.
        if (dot(n, dir) > 0.f) n = -n;
        const float diffuse = std::fmax(0.f, dot(n, to_light));
        const Vec3 half_vec = normalize(to_light - dir);  // Blinn: light + view
        float spec = std::fmax(0.f, dot(n, half_vec));  // ^32 by squaring (no powf call)
        spec *= spec, spec *= spec, spec *= spec, spec *= spec, spec *= spec;
        const float k = 0.18f + 0.82f * diffuse;
        out[0] = c.r * k + 0.12f * spec;
        out[1] = c.g * k + 0.12f * spec;
        out[2] = c.b * k + 0.12f * spec;
        if (want_depth) *result.depth.at(x, y) = hit.t;
        if (want_normal) {
          float* o = result.normal.at(x, y);
          o[0] = n.x * 0.5f + 0.5f, o[1] = n.y * 0.5f + 0.5f, o[2] = n.z * 0.5f + 0.5f;
        }
      }
      batch_n = 0;
    };
    for (int y = tile.y0; y < tile.y1; ++y) {
      for (int x = tile.x0; x < tile.x1; ++x) {
        const Ray ray = cam.ray(x, y);
        if (structure.trace(ray, lod, &batch_hit[batch_n])) {
          ++hits;
          batch_dir[batch_n] = ray.dir;
          batch_x[batch_n] = x;
          batch_y[batch_n] = y;
          if (++batch_n == kBatch) shade_batch();
          continue;
        }
        float* out = result.color.at(x, y);
        out[0] = bg.r, out[1] = bg.g, out[2] = bg.b;
        if (want_depth) *result.depth.at(x, y) = INFINITY;
        if (want_normal) {
          float* n = result.normal.at(x, y);
          n[0] = n[1] = n[2] = 0.5f;
        }
      }
    }
    shade_batch();
    total_hits.fetch_add(hits, std::memory_order_relaxed);
  });
  result.rays = uint64_t(W) * uint64_t(H);
  result.hits = total_hits.load();
  return result;
}

}  // namespace voxcast
