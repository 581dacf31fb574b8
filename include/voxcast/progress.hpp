#pragma once
// A progress bar on stderr, drawn only when stderr is a TTY and the task
// takes longer than a second. Thread-safe: workers call advance().
#include <atomic>
#include <chrono>
#include <cstdint>
#include <string>

namespace voxcast {

class Progress {
 public:
  /// `label` is shown before the bar; `total` is the number of work units.
  Progress(std::string label, uint64_t total, bool enabled = true);
  ~Progress();
  void advance(uint64_t units = 1);
  void finish();

 private:
  void draw(uint64_t done);
  std::string label_;
  uint64_t total_;
  std::atomic<uint64_t> done_{0};
  std::atomic<int64_t> last_draw_ns_{0};
  std::chrono::steady_clock::time_point start_;
  bool tty_;
  std::atomic<bool> drawn_{false};
  bool finished_ = false;
};

/// Stage timer for `-v`: prints "  stage: 123.4 ms" to stderr when enabled.
class StageTimer {
 public:
  explicit StageTimer(bool verbose) : verbose_(verbose), t0_(std::chrono::steady_clock::now()) {}
  /// Prints the time since the previous mark (or construction) and returns it in seconds.
  double mark(const char* stage);

 private:
  bool verbose_;
  std::chrono::steady_clock::time_point t0_;
};

}  // namespace voxcast
