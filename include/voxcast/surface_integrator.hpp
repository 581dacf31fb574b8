#pragma once
// The surface integrator (integrator.hpp): first hits through a structure's
// SurfaceQuery, shaded with Blinn-Phong, optional shadows and ambient
// occlusion (svdag §4, effects.hpp), the beam optimization's coarse pass per
// pixel block (esvo §6.2), the profiling counters and iteration AOV
// (esvo §8.5), depth and normal AOVs, and the adaptive post-filter
// (esvo §6.3). render() (render.hpp) is the one-call way to use it.
#include <cstdint>
#include <map>
#include <mutex>
#include <optional>

#include "voxcast/camera.hpp"
#include "voxcast/effects.hpp"
#include "voxcast/integrator.hpp"

namespace voxcast {

/// What the surface integrator does with a hit (the frame's camera, size,
/// LOD and tiles are the FrameView's and FrameOptions').
struct SurfaceOptions {
  Vec3 light_dir = normalize(Vec3{-0.4f, -1.0f, -0.6f});  // direction the light travels
  Color background{0.08f, 0.09f, 0.11f, 1.f};
  bool want_depth = false;   // the depth AOV (world distance, +inf on miss)
  bool want_normal = false;  // the normal AOV (n*0.5+0.5)
  /// Beam optimization (esvo §6.2): block size K of the coarse pass (K x K
  /// pixel blocks, 2..64; 0 = off). The hits are identical either way.
  int beam = 0;
  /// Tile frustum pass (issue 10 item 4; SurfaceQuery::frustum_start): per
  /// tile the cubes its rays can touch (a tile with none is a miss for every
  /// pixel, with no ray generated), then per K x K pixel block (2..64; 0 =
  /// off) the finer cubes within the tile's, from which the packet caster
  /// starts each ray deep (K at least the tile's sides: the tile's list for
  /// all its rays, no second pass). Packet path only (the scalar path and
  /// --stats use `beam`); takes the place of `beam` there. The hits are
  /// identical either way.
  int frustum = 0;
  /// Profiling counters (esvo §8.5, Table 6) and the iteration AOV. Needs the
  /// frame's counting path (FrameOptions::counting); slower than a plain render.
  bool collect_stats = false;
  /// Adaptive post-process blur of the color image (esvo §6.3); see post_filter().
  bool filter = false;
  /// Primary rays: Packet traces each tile as 4x4 pixel blocks through the
  /// structure's packet caster (SurfaceQuery::packets()) where it has one
  /// and the frame does not count (the packet kernels have no counters);
  /// Scalar, or a structure without packets, traces one ray at a time; Tile
  /// traces each tile by one walk of the structure (SurfacePackets::
  /// trace_tile; beam and frustum do not apply) where it has a tile caster,
  /// else as Packet. The images are byte-identical in every case
  /// (tests/test_surface_integrator.cpp, SurfaceIntegratorPackets.*).
  Caster caster = Caster::Packet;
  /// The ISA of the packet caster's and the batched shading's kernels
  /// (render/shade_kernel.hpp); unset: active_isa(). The image is the same
  /// for every ISA.
  std::optional<Isa> isa;
  /// Shadows and ambient occlusion per hit pixel (svdag §4, effects.hpp).
  /// The light of Directional is light_dir above.
  EffectOptions effects;
};

/// What a frame of the surface integrator counted. Per tile, the pass that
/// rendered it last counts (a tile rendered again in a later pass replaces
/// its earlier numbers), so the totals describe the image.
struct SurfaceStats {
  uint64_t hits = 0;               // primary rays that hit
  RayCounters counters;            // collect_stats: primary rays, incl. attribute fetches
  RayCounters coarse_counters;     // collect_stats: beam coarse pass (iterations = nodes visited)
  uint64_t beams = 0;              // collect_stats: coarse-pass beams (blocks)
  uint64_t empty_tiles = 0;        // frustum: tiles resolved as misses by the tile pass alone
  EffectCounters effect_counters;  // secondary rays traced
  double filter_seconds = 0;       // wall time of post_filter (0 unless filter)
};

class SurfaceIntegrator final : public Integrator {
 public:
  /// Throws voxcast::Error for an invalid beam size or effect options.
  explicit SurfaceIntegrator(const SurfaceOptions& options);

  /// Color, plus depth / normal / iterations / AO / shadow as the options ask.
  uint32_t aovs() const override;
  bool wants_filter_radius() const override { return options_.filter; }
  /// Throws voxcast::Error when the structure has no surface query.
  void begin_frame(const Structure& structure, const FrameView& view, Film& film) override;
  void render_tile(const Structure& structure, const FrameView& view, const TileRect& tile,
                   TraceContext& ctx, Film& film) override;
  /// Runs the post-filter (options.filter) and sums the per-tile statistics.
  void end_frame(const Structure& structure, const FrameView& view, Film& film) override;

  /// The statistics of the last frame (valid after end_frame).
  const SurfaceStats& stats() const { return stats_; }
  /// The effect options of the last frame, with the AO radius resolved
  /// (<= 0 in the options: 5 % of the structure's bounds diagonal).
  const EffectOptions& effects() const { return fx_; }

 private:
  struct TileStats {
    uint64_t hits = 0;
    RayCounters counters, coarse_counters;
    uint64_t beams = 0;
    bool empty_tile = false;
    EffectCounters effects;
  };

  SurfaceOptions options_;
  // Per frame (begin_frame):
  EffectOptions fx_;
  const SurfaceQuery* query_ = nullptr;
  const SurfacePackets* packets_ = nullptr;  // null: scalar primary rays
  Isa isa_ = Isa::Avx2;
  std::optional<CameraRays> cam_;
  LodFootprint lod_;
  Vec3 to_light_;
  std::mutex tiles_mutex_;
  std::map<uint64_t, TileStats> tiles_;  // key: the tile's first pixel
  SurfaceStats stats_;
};

}  // namespace voxcast
