#pragma once
// Tiled multi-threaded renderer over any VoxelStructure.
#include <cstdint>
#include <span>
#include <vector>

#include "voxcast/camera.hpp"
#include "voxcast/effects.hpp"
#include "voxcast/image.hpp"
#include "voxcast/structure.hpp"

namespace voxcast {

struct RenderOptions {
  int width = 1024, height = 768;
  Camera camera;
  /// LOD: stop at voxels whose projection is <= this many pixels (0 = finest level).
  float lod_pixels = 1.f;
  Vec3 light_dir = normalize(Vec3{-0.4f, -1.0f, -0.6f});  // direction the light travels
  Color background{0.08f, 0.09f, 0.11f, 1.f};
  bool want_depth = false;   // fill RenderResult::depth (world distance, +inf on miss)
  bool want_normal = false;  // fill RenderResult::normal (n*0.5+0.5)
  int tile_size = 16;
  /// Beam optimization (esvo §6.2): block size K of the coarse pass (K x K
  /// pixel blocks, 2..64; 0 = off). The hits are identical either way.
  int beam = 0;
  /// Profiling counters (esvo §8.5, Table 6): fill RenderResult::counters,
  /// coarse_counters and iterations. Slower than a plain render.
  bool collect_stats = false;
  /// Adaptive post-process blur of the color image (esvo §6.3); see post_filter().
  bool filter = false;
  /// Shadows and ambient occlusion per hit pixel (svdag §4, effects.hpp).
  /// The light of Directional is light_dir above.
  EffectOptions effects;
};

struct RenderResult {
  Image color;   // linear RGB
  Image depth;   // 1 channel
  Image normal;  // 3 channels
  uint64_t rays = 0, hits = 0;
  double seconds = 0;  // wall time of the ray-cast loop (with the beam's coarse pass)
  // ---- options.collect_stats (esvo §8.5, Table 6) ----
  RayCounters counters;         // full-resolution rays, summed (incl. attribute fetches)
  RayCounters coarse_counters;  // beam coarse pass, summed (iterations = nodes visited)
  uint64_t beams = 0;           // coarse-pass beams (blocks)
  Image iterations;             // 1 channel: main-loop iterations per pixel
  /// Per-ray average of a frame total (Table 6 divides by the full-resolution rays).
  double per_ray(uint64_t total) const { return rays ? double(total) / double(rays) : 0.0; }
  double filter_seconds = 0;  // wall time of post_filter (0 unless options.filter)
  // ---- options.effects (inside `seconds`) ----
  Image ao;      // 1 channel, AO in [0,1] (1 on misses); when ao_rays > 0
  Image shadow;  // 1 channel, light visibility in [0,1] (1 on misses); with shadows
  EffectCounters effect_counters;  // secondary rays traced
};

RenderResult render(const VoxelStructure& structure, const RenderOptions& options);

/// Iteration-count heat map (esvo Figure 16/32): 0 .. max_iterations mapped
/// onto the perceptual "inferno" ramp (black -> purple -> orange -> pale
/// yellow), values above max clamped. Returns a linear RGB image (write_image
/// sRGB-encodes it). Throws voxcast::Error if max_iterations <= 0.
Image iteration_heatmap(const Image& iterations, float max_iterations);

// ---- Adaptive post-process filter (esvo §6.3, Figures 17-19) ----

/// One entry of the filter kernel: a pixel offset, its distance from the
/// center and the area of the disc it represents (its weight).
struct PostFilterSample {
  int dx = 0, dy = 0;
  float dist = 0.f;
  float weight = 0.f;
};
inline constexpr int kPostFilterSamples = 96;  // §6.3: 96 samples ...
inline constexpr int kPostFilterRadius = 24;   // ... in a disc of radius 24 pixels
/// The fixed kernel, ascending by distance (built once, deterministically;
/// the construction is documented in src/render/postfilter.cpp).
std::span<const PostFilterSample> post_filter_kernel();

/// Filter radius in pixels -> one byte, log2 in 3.5 fixed point:
/// round(log2(r) * 32), 0 for r <= 1 (no blur) or NaN, 255 for huge or +inf.
uint8_t encode_filter_radius(float pixels);
/// 2^(code / 32): 1 (no blur) .. ~250 pixels; the kernel ends at 24.
float decode_filter_radius(uint8_t code);

/// Blurs every pixel of `color` whose radius code decodes to r > 1 with the
/// kernel, clamping r to each visited neighbor's radius and tapering weights
/// to 0 between r-1 and r (Figure 19). `radius_code` has width*height entries
/// (row-major); misses should carry 0 so the blur stops at silhouettes.
/// Samples outside the image are skipped. threads = 0: the current TBB
/// limit. The result does not depend on the thread count.
Image post_filter(const Image& color, const std::vector<uint8_t>& radius_code, int threads = 0);

}  // namespace voxcast
