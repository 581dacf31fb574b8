#pragma once
// Edits on a worker thread while frames render (van Wingerden 2015 §3.2.2,
// §4.4; issue 11 item 4): a brickmap world as a Structure whose edits are
// computed off the render thread and made visible between frames.
//
// The worker owns a copy of the world and applies every submitted edit to it
// in order (brush evaluation, brick expansion, the allocators: the costly
// part). Each finished edit leaves the bricks it rewrote, as their new
// masks, colors and normals, in a ready list; begin_frame() and end_pass()
// (the frame loop's points where no ray traces, integrator.hpp) store them
// into the rendered world -- the §4.4 re-upload of edited bricks. An edit
// becomes visible whole: a frame shows the world after edits 1..k for some
// k, never a part of one. The copy doubles the world's memory.
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <thread>
#include <variant>
#include <vector>

#include "voxcast/brickmap.hpp"

namespace voxcast::brickmap {

class LiveWorld final : public BrickmapView {
 public:
  explicit LiveWorld(World world);
  ~LiveWorld() override;  // finishes the queued edits, then stops the worker
  LiveWorld(const LiveWorld&) = delete;
  LiveWorld& operator=(const LiveWorld&) = delete;

  /// Queue an edit (edit() / stamp() semantics); returns its number (1, 2,
  /// ...). An edit that throws (e.g. a bad brush) changes nothing and counts
  /// as applied; its message is kept (last_error()).
  uint64_t submit(const Brush& brush, EditOp op, const Color& color = {});
  uint64_t submit(VoxelSet stamp, EditOp op, const Color& color = {});
  /// Queue one step of snowfall (snow_step on the worker's copy: the
  /// world-scale simulation of §5.5 while frames render).
  uint64_t submit_snow(uint32_t step, const SnowOptions& options = {});
  /// Blocks until the worker has finished every submitted edit (they may
  /// still wait for the next frame to become visible).
  void wait_worker();
  /// Edits visible in the rendered world (all of 1..applied()).
  uint64_t applied() const { return applied_; }
  /// Makes every finished edit visible now; only where no ray traces
  /// (between frames, or without rendering).
  void publish();
  /// Voxels and bricks the worker changed so far, and its seconds of work.
  struct Throughput {
    uint64_t voxels = 0, bricks = 0;
    double seconds = 0;
  };
  Throughput throughput() const;
  std::string last_error() const;

  void begin_frame(const FrameView& view) override;
  PassOutcome end_pass(std::span<const Request> requests) override;
  /// The rendered world.
  const World& world() const { return *front_; }

 private:
  struct SnowJob {
    uint32_t step;
    SnowOptions options;
  };
  struct Job {
    uint64_t number;
    std::variant<Brush, VoxelSet, SnowJob> brush;
    EditOp op;
    Color color;
  };
  struct NewBrick {
    uint64_t cell;
    uint64_t mask[8];
    std::vector<uint32_t> colors, normals;
  };
  struct Done {
    uint64_t number;
    std::vector<NewBrick> bricks;
  };
  uint64_t enqueue(Job job);
  void run();
  bool publish_ready();

  std::shared_ptr<World> front_;
  World back_;
  mutable std::mutex mutex_;
  std::condition_variable wake_, idle_;
  std::deque<Job> queue_;
  std::vector<Done> ready_;
  uint64_t submitted_ = 0, finished_ = 0, applied_ = 0;
  bool stop_ = false, busy_ = false;
  Throughput throughput_;
  std::string error_;
  std::thread worker_;
};

}  // namespace voxcast::brickmap
