#pragma once
// What every voxel structure is to the rest of the engine
// (docs/ARCHITECTURE.md): a Structure names itself, has bounds, offers its
// queries by capability (surface_query.hpp, volume_query.hpp) and takes part
// in the frame loop of integrator.hpp (begin_frame -> passes -> end_frame),
// serving between passes the requests its queries pushed into the trace
// contexts. A static, in-core structure ignores the loop.
#include <cstdint>
#include <span>
#include <string>

#include "voxcast/math.hpp"
#include "voxcast/surface_query.hpp"
#include "voxcast/trace_context.hpp"
#include "voxcast/volume_query.hpp"

namespace voxcast {

struct FrameView;  // integrator.hpp

/// What serving one pass's requests did.
struct PassOutcome {
  /// Something the pass's rays asked for became available: the tiles that
  /// pushed requests are worth tracing again (the multi-pass exact mode of
  /// gigavoxels §3.6.8 stops when a pass changes nothing).
  bool changed = false;
  uint64_t served = 0;   // requests served
  uint64_t pending = 0;  // requests left for later passes (budget, worker queues)
};

class Structure {
 public:
  virtual ~Structure() = default;
  virtual std::string name() const = 0;
  /// World-space bounds of everything the structure can return.
  virtual Aabb bounds() const = 0;
  /// The structure's queries, or null when it has no such capability.
  virtual const SurfaceQuery* surface() const { return nullptr; }
  virtual const VolumeQuery* volume() const { return nullptr; }

  // ---- The frame loop (integrator.hpp). Never called while a pass traces. ----
  /// Before the first pass of a frame (a streaming structure may prefetch
  /// for the view, esvo §7.4 scores).
  virtual void begin_frame(const FrameView& view) { (void)view; }
  /// After each pass: the pass's requests, merged from every thread, sorted by
  /// (kind, key) and deduplicated (largest priority kept). The only place a
  /// structure may change what is resident (the pinning rule).
  virtual PassOutcome end_pass(std::span<const Request> requests) {
    (void)requests;
    return {};
  }
  virtual void end_frame() {}
};

}  // namespace voxcast
