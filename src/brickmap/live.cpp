// Edits on a worker thread while frames render (brickmap_live.hpp).
#include <bit>
#include <chrono>

#include "voxcast/brickmap_live.hpp"
#include "voxcast/error.hpp"

namespace voxcast::brickmap {

LiveWorld::LiveWorld(World world)
    : front_(std::make_shared<World>(world)), back_(std::move(world)) {
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
      NewBrick b{cell, {}, {}, {}};
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
    {
      std::lock_guard<std::mutex> lock(mutex_);
      ready_.push_back(std::move(done));
      ++finished_;
      busy_ = false;
      throughput_.voxels += r.voxels;
      throughput_.bricks += r.cells.size();
      throughput_.seconds += seconds;
      if (!error.empty()) error_ = error;
    }
    idle_.notify_all();
  }
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
