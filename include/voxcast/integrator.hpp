#pragma once
// Integrators and the frame loop (docs/ARCHITECTURE.md, "Frames and passes").
//
// An integrator turns the rays of a tile into film pixels using a
// structure's queries: the surface integrator (surface_integrator.hpp: shading,
// shadows, AO, post-filter, heat maps) and the volume integrator
// (volume_integrator.hpp: front-to-back emission-absorption) are siblings, as in pbrt-v4. Camera,
// tiles, film and the per-thread trace contexts are the frame loop's, written once:
//
//   structure.begin_frame(view); integrator.begin_frame(...)
//   pass 0: every tile -> integrator.render_tile(..., ctx of this thread, film)
//           merge the contexts' requests (sorted by (kind, key), deduplicated)
//           outcome = structure.end_pass(requests)        <- serves them
//   pass k: while outcome.changed and k < max_passes: the tiles that pushed
//           requests in pass k-1 are rendered again
//   integrator.end_frame(...); structure.end_frame()
//
// max_passes = 1 is the one-pass mode (coarser data shows until the next
// frame; requests are still served after the pass); a larger max_passes is the
// stop-and-go exact mode of gigavoxels §3.6.8. A static structure never
// pushes a request, so every frame is one pass.
//
// Determinism: a pixel depends only on the structure's state in the pass
// that rendered it, and requests reach end_pass sorted, so the image and the
// structure's state do not depend on the thread count or tile order.
#include <cstdint>
#include <vector>

#include "voxcast/camera.hpp"
#include "voxcast/film.hpp"
#include "voxcast/structure.hpp"
#include "voxcast/trace_context.hpp"

namespace voxcast {

class Progress;

/// What a frame looks at, shared by every pass and tile.
struct FrameView {
  Camera camera;
  int width = 0, height = 0;
  /// LOD: stop at voxels whose projection is <= this many pixels (0 = finest).
  float lod_pixels = 1.f;
  uint32_t frame = 0;  // frame number (usage timestamps of streaming structures)
  /// Where in its pixel each camera ray passes (CameraRays::sample; (0.5,
  /// 0.5) = the center). The antialiasing of render.hpp moves it per frame.
  Vec2 sample{0.5f, 0.5f};

  CameraRays rays() const { return CameraRays(camera, width, height, sample); }
  /// The pixel cone of esvo §6.1 for lod_pixels (perspective: grows with t;
  /// orthographic: constant).
  LodFootprint lod() const {
    const CameraRays r = rays();
    return LodFootprint{lod_pixels * r.pixel_size(), lod_pixels * r.pixel_angle()};
  }
};

/// Pixel range [x0, x1) x [y0, y1).
struct TileRect {
  int x0 = 0, y0 = 0, x1 = 0, y1 = 0;
};

class Integrator {
 public:
  virtual ~Integrator() = default;
  /// The AOVs this integrator writes with its current options.
  virtual uint32_t aovs() const = 0;
  /// Whether it fills Film::filter_radius (the esvo §6.3 post-filter).
  virtual bool wants_filter_radius() const { return false; }
  /// Throws voxcast::Error when the structure lacks a query it needs.
  virtual void begin_frame(const Structure& structure, const FrameView& view, Film& film) {
    (void)structure, (void)view, (void)film;
  }
  /// Renders one tile (called concurrently for different tiles; writes only
  /// the tile's pixels; per-frame statistics must be accumulated thread-safely).
  virtual void render_tile(const Structure& structure, const FrameView& view, const TileRect& tile,
                           TraceContext& ctx, Film& film) = 0;
  /// After the last pass (post-processing such as the esvo §6.3 filter).
  virtual void end_frame(const Structure& structure, const FrameView& view, Film& film) {
    (void)structure, (void)view, (void)film;
  }
};

struct FrameOptions {
  int tile_size = 16;
  /// 1 = one-pass mode; > 1 = render again the tiles that asked for data
  /// until a pass changes nothing or this many passes ran.
  int max_passes = 1;
  /// Requests one thread may push per pass before it drops further ones.
  size_t requests_per_thread = size_t(1) << 16;
  /// Counting path: every context has TraceContext::counting set.
  bool counting = false;
  /// Advanced once per rendered tile; each pass adds its tiles to the work
  /// (progress.hpp). Optional.
  Progress* progress = nullptr;
};

struct PassStats {
  int tiles = 0;             // tiles rendered in this pass
  uint64_t requests = 0;     // distinct requests handed to end_pass
  uint64_t dropped = 0;      // requests lost to full buffers
  double seconds = 0;        // wall time of the tiles
  double serve_seconds = 0;  // wall time of end_pass
  PassOutcome outcome;
  RayCounters counters;  // of this pass's tiles (counting only)
};

struct FrameStats {
  std::vector<PassStats> passes;
  double seconds = 0;     // wall time of all passes' tiles (without serving)
  /// Counting only: every tile as the last pass that rendered it counted it,
  /// i.e. each final pixel's rays once. The passes' counters sum to more
  /// when tiles were rendered again (tests/test_frame_loop.cpp).
  RayCounters counters;
  uint64_t requests = 0;  // summed over the passes
};

/// Runs the frame loop above; `film` is (re)allocated for integrator.aovs().
/// Throws voxcast::Error for an invalid view or options.
FrameStats render_frame(Structure& structure, Integrator& integrator, const FrameView& view,
                        const FrameOptions& options, Film* film);

}  // namespace voxcast
