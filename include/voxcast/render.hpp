#pragma once
// One-call rendering with the surface integrator (surface_integrator.hpp)
// over the frame loop (integrator.hpp), the heat map, and the esvo §6.3
// post-filter.
#include <cstdint>
#include <span>
#include <vector>

#include "voxcast/camera.hpp"
#include "voxcast/effects.hpp"
#include "voxcast/image.hpp"
#include "voxcast/structure.hpp"
#include "voxcast/surface_integrator.hpp"

namespace voxcast {

class Progress;

/// A frame (size, camera, LOD, tiles) and what the surface integrator does
/// with it (SurfaceOptions: light, background, AOVs, beam, statistics,
/// post-filter, effects).
struct RenderOptions : SurfaceOptions {
  int width = 1024, height = 768;
  Camera camera;
  /// LOD: stop at voxels whose projection is <= this many pixels (0 = finest level).
  float lod_pixels = 1.f;
  int tile_size = 16;
  /// Passes of the frame loop (integrator.hpp): 1 = one-pass mode; more lets
  /// a streaming structure serve what the rays asked for and render the
  /// asking tiles again. A static structure always renders one pass.
  int max_passes = 1;
  /// Progress bar of the frame loop, advanced per tile (progress.hpp); optional.
  Progress* progress = nullptr;
  /// Frame number (FrameView::frame): the usage stamp of streaming structures.
  uint32_t frame = 0;
  /// Antialiasing: camera rays per pixel (1..4096). Sample k passes through
  /// the point (frac(0.5 + k a1), frac(0.5 + k a2)) of every pixel (the R2
  /// low-discrepancy sequence, a1 = 0.7548776662, a2 = 0.5698402910; sample
  /// 0 is the center), with effect seed effects.seed + k; the color, AO and
  /// shadow images are the means, depth, normal and iterations are sample
  /// 0's. The offsets depend on k alone: the same on every structure.
  int spp = 1;
};

/// Sub-pixel position of antialiasing sample k (RenderOptions::spp).
Vec2 antialias_sample(int k);

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
  int passes = 1;                  // passes the frame loop ran
};

/// Renders one frame: a SurfaceIntegrator over render_frame, the film
/// converted into a RenderResult. Throws voxcast::Error for invalid options
/// or a structure without a surface query.
///
/// Two overloads, because the frame loop may change a structure between
/// passes (Structure::end_pass serves the rays' requests):
///  * a mutable structure runs the full loop (options.max_passes);
///  * a const one is rendered in exactly one pass through a view that
///    forwards its queries and serves nothing: a static structure loses
///    nothing, a streaming one shows what is resident and its requests are
///    dropped. The CLI, the bench and most tests render in-core structures
///    they hold const, so the const path keeps them simple.
RenderResult render(Structure& structure, const RenderOptions& options);
RenderResult render(const Structure& structure, const RenderOptions& options);

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
