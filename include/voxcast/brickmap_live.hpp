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
//
// Saving (LiveOptions::save_to): after an edit the worker appends the chunks
// it changed to the world file's edit journal as one transaction and fsyncs
// it (commit_edits, brickmap_file.hpp), the same write-ahead journal `voxcast
// edit` saves through; an edit is acknowledged (saved(), on_saved) once that
// fsync returned, so no acknowledged edit is lost by a crash or a kill. Edits
// queued behind the one just applied share its transaction (group commit,
// up to LiveOptions::max_group), so a burst costs one fsync; the journal then
// holds the world after a whole number of edits, never a part of one. An edit
// may become visible before it is acknowledged (frames do not wait for the
// disk). A save that fails (a full disk, say) is reported by save_error();
// its edits stay unacknowledged and are saved with the next edit's
// transaction.
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <filesystem>
#include <functional>
#include <memory>
#include <mutex>
#include <thread>
#include <variant>
#include <vector>

#include "voxcast/brickmap.hpp"

namespace voxcast::brickmap {

struct LiveOptions {
  /// The world file (WORLD.vxc) whose edit journal the worker saves every
  /// edit into; empty: edits are not saved. The world given to LiveWorld must
  /// be that file's state (open_world: the file and its journal).
  std::filesystem::path save_to;
  /// Most edits saved as one transaction (group commit); 1: one fsync per edit.
  uint32_t max_group = 64;
  /// Called on the worker thread after each successful save with the number
  /// of the last edit it holds (every edit up to it is acknowledged). May be
  /// null.
  std::function<void(uint64_t)> on_saved;
};

class LiveWorld final : public BrickmapView {
 public:
  explicit LiveWorld(World world, LiveOptions options = {});
  ~LiveWorld() override;  // finishes (and saves) the queued edits, then stops the worker
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
  /// Blocks until the worker has finished (and, with save_to, saved or failed
  /// to save) every submitted edit (they may still wait for the next frame to
  /// become visible).
  void wait_worker();
  /// Edits acknowledged: 1..saved() are in the journal, fsync'ed (without
  /// save_to: 0).
  uint64_t saved() const;
  /// The message of the last failed save ("" when the last save succeeded).
  std::string save_error() const;
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
    VoxelMask carved;  // World::carved of the cell (a terrain's removals)
  };
  struct Done {
    uint64_t number;
    std::vector<NewBrick> bricks;
  };
  uint64_t enqueue(Job job);
  void run();
  // Saves the unsaved cells of back_ through the journal; `number`: the last
  // edit applied to back_.
  void save(uint64_t number);
  bool publish_ready();

  std::shared_ptr<World> front_;
  World back_;
  LiveOptions options_;
  std::vector<uint64_t> unsaved_;  // cells changed in back_ since the last save (worker only)
  uint32_t group_ = 0;             // edits in unsaved_ (worker only)
  mutable std::mutex mutex_;
  std::condition_variable wake_, idle_;
  std::deque<Job> queue_;
  std::vector<Done> ready_;
  uint64_t submitted_ = 0, finished_ = 0, applied_ = 0, saved_ = 0;
  std::string save_error_;
  bool stop_ = false, busy_ = false;
  Throughput throughput_;
  std::string error_;
  std::thread worker_;
};

}  // namespace voxcast::brickmap
