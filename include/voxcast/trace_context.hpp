#pragma once
// The per-thread state every query takes (docs/ARCHITECTURE.md, "Trace
// context"). Structures stay const and thread-safe: whatever a query needs to
// remember or report lives here, owned by the thread that traces.
//
//  * counters: the profiling counters of esvo §8.5 (Table 6), summed over the
//    calls made with this context while `counting` is set;
//  * requests: what a streaming structure could not answer yet (a brick that
//    is not resident, a node to subdivide, a slice to load; gigavoxels §3.6.3,
//    esvo §7.4, brickmaps §3.4). The query answers with what it has (a coarser
//    level, an LOD color) and pushes a request; the frame loop (integrator.hpp)
//    collects every thread's requests after a pass and hands them to the
//    structure, which serves them before the next pass. No locks, no atomics:
//    each context has its own fixed-capacity buffer (gigavoxels §3.6.3 fills a
//    per-pixel request buffer the same way);
//  * frame / pass: the stamp a structure writes into its usage timestamps
//    (gigavoxels §3.6.2 LRU) when a ray touches an element;
//  * cache: scratch space for a structure's accessor cache (the last node or
//    brick visited, NanoVDB's ValueAccessor), tagged with its owner so that two
//    structures traced with one context never read each other's cache.
//
// Lifetime rule ("pinning"): a structure changes what is resident only between
// passes (Structure::end_pass), never while a pass traces. A SurfaceHit or
// VolumeSpan is therefore valid until the end of the pass it was produced in,
// and attributes() of a hit may dereference what the hit points at.
#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <new>
#include <type_traits>
#include <vector>

namespace voxcast {

/// Pixel-cone footprint: a voxel is small enough to stop at when its side is
/// <= size_at_origin + size_per_t * t (world units; esvo §6.1 ray_size_coef/bias).
struct LodFootprint {
  float size_at_origin = 0.f;
  float size_per_t = 0.f;
};

/// Profiling counters of a caster (esvo §8.5, Table 6), summed over rays.
/// Filled only while TraceContext::counting is set; the plain path never
/// touches them.
struct RayCounters {
  uint64_t iterations = 0;          // main-loop iterations
  uint64_t intersects = 0;          // voxels processed by INTERSECT (Figure 15)
  uint64_t pushes = 0;              // PUSH executed (descend into a child)
  uint64_t stores = 0;              // actual stack writes by PUSH
  uint64_t advances = 0;            // ADVANCE executed
  uint64_t pops = 0;                // POP executed (incl. the one that leaves the root)
  uint64_t descriptor_fetches = 0;  // child descriptors read (8 bytes each)
  uint64_t far_reads = 0;           // far pointers read (4 bytes each)
  uint64_t attribute_bytes = 0;     // bytes read to fetch the hit's attributes
  /// "glob bytes" of Table 6: descriptor fetches x 8 + far pointers x 4 + attributes.
  uint64_t bytes() const { return descriptor_fetches * 8 + far_reads * 4 + attribute_bytes; }
  RayCounters& operator+=(const RayCounters& o) {
    iterations += o.iterations, intersects += o.intersects, pushes += o.pushes;
    stores += o.stores, advances += o.advances, pops += o.pops;
    descriptor_fetches += o.descriptor_fetches, far_reads += o.far_reads;
    attribute_bytes += o.attribute_bytes;
    return *this;
  }
};

/// One thing a structure could not answer yet. The meaning of `kind` and
/// `key` belongs to the structure that pushed it (e.g. GigaVoxels: kind 0 =
/// subdivide node `key`, kind 1 = load the brick of node `key`; a brickmap:
/// load brick cell `key`). `priority`: larger is more urgent (a screen-space
/// score, esvo §7.4); duplicates keep the largest.
struct Request {
  uint64_t key = 0;
  uint32_t kind = 0;
  float priority = 0.f;
};

/// A fixed-capacity, per-thread request buffer. push() never allocates: the
/// frame loop reserves the capacity before a pass; a full buffer counts what
/// it dropped (the rays that lost their request ask again next pass).
class RequestSink {
 public:
  explicit RequestSink(size_t capacity = 0) { reserve(capacity); }
  void reserve(size_t capacity) {
    items_.reserve(capacity);
    capacity_ = capacity;
  }
  void push(const Request& r) {
    if (items_.size() < capacity_)
      items_.push_back(r);
    else
      ++dropped_;
  }
  void push(uint32_t kind, uint64_t key, float priority = 0.f) {
    push(Request{key, kind, priority});
  }
  /// Ors `bits` into the keys of the requests from index `first` on (a
  /// structure made of structures tells its parts' requests apart: it notes
  /// size() before a part's query and tags what the part pushed).
  void tag_keys(size_t first, uint64_t bits) {
    for (size_t i = first; i < items_.size(); ++i) items_[i].key |= bits;
  }
  size_t size() const { return items_.size(); }
  bool empty() const { return items_.empty(); }
  uint64_t dropped() const { return dropped_; }
  const std::vector<Request>& items() const { return items_; }
  void clear() { items_.clear(), dropped_ = 0; }

 private:
  std::vector<Request> items_;
  size_t capacity_ = 0;
  uint64_t dropped_ = 0;
};

/// Scratch space for the accessor caches of a few structures traced with
/// one context (a VolumeScene's objects take turns along every ray: one slot
/// each, so that they do not wipe each other's cache at every switch).
/// get<T>(owner) returns a T that lives inside the context: the owner's
/// previous contents, or value-initialized in a new slot (the slots are
/// reused round robin when more owners ask than there are slots).
class AccessorCache {
 public:
  static constexpr size_t kBytes = 256;
  static constexpr int kSlots = 4;
  template <class T>
  T& get(const void* owner) {
    static_assert(sizeof(T) <= kBytes && alignof(T) <= 64, "accessor cache too large");
    static_assert(std::is_trivially_copyable_v<T> && std::is_trivially_destructible_v<T>,
                  "accessor caches are plain data");
    for (int s = 0; s < kSlots; ++s)
      if (owner_[s] == owner) return *reinterpret_cast<T*>(storage_[s]);
    const int s = next_;
    next_ = (next_ + 1) % kSlots;
    T* p = reinterpret_cast<T*>(storage_[s]);
    new (p) T{};
    owner_[s] = owner;
    return *p;
  }
  /// Forget the cached contents (a structure calls this after changing what
  /// is resident; the frame loop calls it before every pass).
  void reset() {
    for (const void*& o : owner_) o = nullptr;
    next_ = 0;
  }

 private:
  alignas(64) unsigned char storage_[kSlots][kBytes];
  const void* owner_[kSlots] = {};
  int next_ = 0;
};

/// Everything a query may use besides the structure and the ray; one per
/// thread (the frame loop keeps one per worker, a caller of the queries makes
/// its own). Not thread-safe by design: never share one between threads.
struct TraceContext {
  bool counting = false;  // accumulate `counters` (the slower counting path)
  RayCounters counters;
  RequestSink requests;
  uint32_t frame = 0;  // frame number stamped into usage timestamps (LRU)
  uint32_t pass = 0;   // pass within the frame (0 = first)
  AccessorCache cache;
};

}  // namespace voxcast
