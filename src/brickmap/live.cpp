// Edits on a worker thread while frames render (brickmap_live.hpp).
#include <algorithm>
#include <bit>
#include <chrono>

#include "voxcast/brickmap_file.hpp"
#include "voxcast/brickmap_live.hpp"
#include "voxcast/error.hpp"

namespace voxcast::brickmap {

LiveWorld::LiveWorld(World world, LiveOptions options)
    : front_(std::make_shared<World>(world)),
      back_(std::move(world)),
      options_(std::move(options)) {
  if (options_.max_group == 0) throw Error("LiveWorld: max_group must be at least 1");
  query_ = std::make_unique<BrickmapStructure>(front_);
  worker_ = std::thread([this] { run(); });
}

LiveWorld::~LiveWorld() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_ = true;
  }
  wake_.notify_all();
  worker_.join();
}

uint64_t LiveWorld::enqueue(Job job) {
  std::lock_guard<std::mutex> lock(mutex_);
  job.number = ++submitted_;
  queue_.push_back(std::move(job));
  wake_.notify_one();
  return submitted_;
}

uint64_t LiveWorld::submit(const Brush& brush, EditOp op, const Color& color) {
  return enqueue(Job{0, brush, op, color});
}

uint64_t LiveWorld::submit(VoxelSet stamp, EditOp op, const Color& color) {
  return enqueue(Job{0, std::move(stamp), op, color});
}

uint64_t LiveWorld::submit_snow(uint32_t step, const SnowOptions& options) {
  return enqueue(Job{0, SnowJob{step, options}, EditOp::Add, options.color});
}

void LiveWorld::run() {
  for (;;) {
    Job job;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      wake_.wait(lock, [&] { return stop_ || !queue_.empty(); });
      if (queue_.empty()) return;  // stopping, every edit done
      job = std::move(queue_.front());
      queue_.pop_front();
      busy_ = true;
    }
    // On the worker's copy: the expensive part, off the render thread.
    const auto t0 = std::chrono::steady_clock::now();
    Done done{job.number, {}};
    std::string error;
    EditResult r;
    try {
      if (const SnowJob* snow = std::get_if<SnowJob>(&job.brush))
        r = snow_step(back_, snow->step, snow->options);
      else if (const Brush* brush = std::get_if<Brush>(&job.brush))
        r = edit(back_, *brush, job.op, job.color);
      else
        r = stamp(back_, std::get<VoxelSet>(job.brush), job.op, job.color);
    } catch (const Error& e) {
      error = e.what();
    }
    for (uint64_t cell : r.cells) {
      NewBrick b{cell, {}, {}, {}, {}};
      if (const auto it = back_.carved().find(cell); it != back_.carved().end())
        b.carved = it->second;
      const uint32_t c = back_.cell(cell);
      if (c != 0) {
        const Brick& src = back_.brick(cell_brick(c));
        std::copy(src.mask, src.mask + 8, b.mask);
        const size_t n = size_t(brick_popcount(src));
        b.colors.assign(back_.colors().begin() + src.color, back_.colors().begin() + src.color + n);
        if (back_.has_normals())
          b.normals.assign(back_.normals().begin() + src.color,
                           back_.normals().begin() + src.color + n);
        else
          b.normals.assign(n, 0);
      }
      done.bricks.push_back(std::move(b));
    }
    const double seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    bool more = false;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      // Visible from the next frame on, before it is on disk: frames do not
      // wait for an fsync.
      ready_.push_back(std::move(done));
      throughput_.voxels += r.voxels;
      throughput_.bricks += r.cells.size();
      throughput_.seconds += seconds;
      if (!error.empty()) error_ = error;
      more = !queue_.empty();
    }
    if (!options_.save_to.empty()) {
      unsaved_.insert(unsaved_.end(), r.cells.begin(), r.cells.end());
      // Group commit: an edit queued behind this one joins its transaction
      // (one fsync for a burst); the group is saved when the queue runs dry.
      if (!more || ++group_ >= options_.max_group) save(job.number);
    }
    {
      std::lock_guard<std::mutex> lock(mutex_);
      ++finished_;
      busy_ = false;
    }
    idle_.notify_all();
  }
}

void LiveWorld::save(uint64_t number) {
  std::string failure;
  try {
    // Nothing changed since the last save (refused edits): acknowledged as
    // they are, without a transaction.
    if (!unsaved_.empty()) {
      std::sort(unsaved_.begin(), unsaved_.end());
      unsaved_.erase(std::unique(unsaved_.begin(), unsaved_.end()), unsaved_.end());
      // back_ holds the world after edits 1..number: whole chunk images of
      // that state (brickmap_file.hpp), fsync'ed before commit_edits returns.
      commit_edits(options_.save_to, back_, unsaved_);
    }
    unsaved_.clear();
    group_ = 0;
  } catch (const std::exception& e) {
    // Kept unsaved: the next save writes these cells again, with the state
    // of the edits after them.
    failure = e.what();
  }
  {
    std::lock_guard<std::mutex> lock(mutex_);
    save_error_ = failure;
    if (failure.empty()) saved_ = number;
  }
  if (failure.empty() && options_.on_saved) options_.on_saved(number);
}

uint64_t LiveWorld::saved() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return saved_;
}

std::string LiveWorld::save_error() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return save_error_;
}

void LiveWorld::wait_worker() {
  std::unique_lock<std::mutex> lock(mutex_);
  idle_.wait(lock, [&] { return finished_ == submitted_; });
}

bool LiveWorld::publish_ready() {
  std::vector<Done> ready;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    ready.swap(ready_);
  }
  for (const Done& d : ready) {
    // The occupancy, pyramid and clearances once per edit, not per brick.
    std::vector<uint64_t> cells;
    try {
      for (const NewBrick& b : d.bricks) {
        front_->set_brick(b.cell, b.mask, b.colors.data(), b.normals.data(), kFlagEdited, nullptr,
                          false);
        front_->set_carved(b.cell, b.carved);
        cells.push_back(b.cell);
      }
    } catch (...) {
      front_->update_occupancy(cells);  // the bricks stored so far stay consistent
      throw;
    }
    front_->update_occupancy(cells);
    applied_ = d.number;
  }
  return !ready.empty();
}

void LiveWorld::publish() {
  publish_ready();
}

void LiveWorld::begin_frame(const FrameView&) {
  publish_ready();
}

PassOutcome LiveWorld::end_pass(std::span<const Request>) {
  PassOutcome out;
  out.changed = publish_ready();
  return out;
}

LiveWorld::Throughput LiveWorld::throughput() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return throughput_;
}

std::string LiveWorld::last_error() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return error_;
}

}  // namespace voxcast::brickmap
