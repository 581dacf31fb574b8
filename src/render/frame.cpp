// The frame loop of integrator.hpp: passes over tiles with one trace context
// per worker thread, requests merged between passes and served by the
// structure.
#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/partitioner.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <memory>

#include "voxcast/error.hpp"
#include "voxcast/integrator.hpp"
#include "voxcast/progress.hpp"

namespace voxcast {
namespace {

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

/// Sorts by (kind, key) and keeps one request per pair with the largest
/// priority, so end_pass sees the same list whatever the thread count.
void merge_requests(std::vector<Request>* all) {
  std::sort(all->begin(), all->end(), [](const Request& a, const Request& b) {
    if (a.kind != b.kind) return a.kind < b.kind;
    if (a.key != b.key) return a.key < b.key;
    return a.priority > b.priority;  // the first of a run is the most urgent
  });
  auto same = [](const Request& a, const Request& b) { return a.kind == b.kind && a.key == b.key; };
  all->erase(std::unique(all->begin(), all->end(), same), all->end());
}

}  // namespace

FrameStats render_frame(Structure& structure, Integrator& integrator, const FrameView& view,
                        const FrameOptions& options, Film* film) {
  if (view.width <= 0 || view.height <= 0 || view.width > 65536 || view.height > 65536)
    throw Error("render: image size must be in 1..65536");
  if (!(view.lod_pixels >= 0.f) || !std::isfinite(view.lod_pixels))
    throw Error("render: lod_pixels must be a finite number >= 0");
  if (options.tile_size <= 0) throw Error("render: tile_size must be positive");
  if (options.max_passes < 1) throw Error("render: max_passes must be at least 1");
  view.camera.validate();

  *film = Film(view.width, view.height, integrator.aovs(), integrator.wants_filter_radius());
  structure.begin_frame(view);
  integrator.begin_frame(structure, view, *film);

  const int ts = options.tile_size;
  const int tiles_x = (view.width + ts - 1) / ts, tiles_y = (view.height + ts - 1) / ts;
  const int tile_count = tiles_x * tiles_y;
  std::vector<int> todo(static_cast<size_t>(tile_count));
  for (int i = 0; i < tile_count; ++i) todo[size_t(i)] = i;
  // Per tile: did its rays push a request in the current pass?
  std::vector<uint8_t> asked(size_t(tile_count), 0);
  // Counting: each tile's counters from the last pass that rendered it, so
  // that the frame's total counts every final pixel once (a re-rendered
  // tile replaces its earlier counts) while each pass keeps its own.
  std::vector<RayCounters> tile_counters(options.counting ? size_t(tile_count) : 0);

  tbb::enumerable_thread_specific<std::unique_ptr<TraceContext>> contexts([&] {
    auto ctx = std::make_unique<TraceContext>();
    ctx->requests.reserve(options.requests_per_thread);
    return ctx;
  });

  FrameStats stats;
  std::vector<Request> merged;
  for (int pass = 0; pass < options.max_passes && !todo.empty(); ++pass) {
    for (auto& ctx : contexts) {
      ctx->requests.clear();
      ctx->cache.reset();
    }
    PassStats ps;
    ps.tiles = int(todo.size());
    if (options.progress) options.progress->add_units(todo.size());
    const auto t0 = std::chrono::steady_clock::now();
    tbb::parallel_for(
        tbb::blocked_range<size_t>(0, todo.size(), 1),
        [&](const tbb::blocked_range<size_t>& r) {
          TraceContext& ctx = *contexts.local();
          ctx.counting = options.counting;
          ctx.frame = view.frame;
          ctx.pass = uint32_t(pass);
          for (size_t i = r.begin(); i != r.end(); ++i) {
            const int t = todo[i], tx = t % tiles_x, ty = t / tiles_x;
            const TileRect rect{tx * ts, ty * ts, std::min(view.width, (tx + 1) * ts),
                                std::min(view.height, (ty + 1) * ts)};
            const size_t before = ctx.requests.size();
            const uint64_t dropped_before = ctx.requests.dropped();
            RayCounters outer;
            if (options.counting) outer = ctx.counters, ctx.counters = RayCounters{};
            integrator.render_tile(structure, view, rect, ctx, *film);
            if (options.counting) {
              tile_counters[size_t(t)] = ctx.counters;
              ctx.counters = outer;
              ctx.counters += tile_counters[size_t(t)];
            }
            asked[size_t(t)] =
                ctx.requests.size() != before || ctx.requests.dropped() != dropped_before;
            if (options.progress) options.progress->advance();
          }
        },
        tbb::simple_partitioner());
    ps.seconds = seconds_since(t0);
    stats.seconds += ps.seconds;
    if (options.counting)
      for (int t : todo) ps.counters += tile_counters[size_t(t)];

    merged.clear();
    for (auto& ctx : contexts) {
      merged.insert(merged.end(), ctx->requests.items().begin(), ctx->requests.items().end());
      ps.dropped += ctx->requests.dropped();
    }
    merge_requests(&merged);
    ps.requests = merged.size();
    stats.requests += merged.size();
    const auto s0 = std::chrono::steady_clock::now();
    // A static structure never asks; skip the call only when nothing was lost either.
    if (!merged.empty() || ps.dropped != 0) ps.outcome = structure.end_pass(merged);
    ps.serve_seconds = seconds_since(s0);
    stats.passes.push_back(ps);

    std::vector<int> next;
    if (ps.outcome.changed)
      for (int t : todo)
        if (asked[size_t(t)]) next.push_back(t);
    todo.swap(next);
  }
  for (const RayCounters& c : tile_counters) stats.counters += c;
  integrator.end_frame(structure, view, *film);
  structure.end_frame();
  return stats;
}

}  // namespace voxcast
