#pragma once
// Progress bars and stage timings: the one progress facility of the library
// and the CLI. A bar is drawn on stderr only when stderr is a TTY, the task
// has run for a second, and the process is not quiet (--quiet). A task may
// have several phases of different cost (the voxelizer's rasterization, sort
// and merge): each phase has a weight, its share of the whole task's time,
// and the bar and the ETA follow the weighted fraction of the whole task, so
// the ETA does not read 0 s at the end of a first phase while the later ones
// are still ahead. Thread-safe: workers call advance(); the phases are
// started by the thread that runs the task, between its parallel sections.
#include <atomic>
#include <cstdint>
#include <functional>
#include <mutex>
#include <string>
#include <vector>

namespace voxcast {

/// Where a Progress draws and what time it is. The default is the process's
/// stderr (when it is a TTY) and the steady clock; tests inject both.
struct ProgressSink {
  bool tty = false;                               // draw at all
  std::function<int64_t()> now_ns;                // monotonic clock, nanoseconds
  std::function<void(const std::string&)> write;  // receives the drawn text
  /// No bar before the task has run this long (short tasks show none).
  int64_t delay_ns = 1'000'000'000;
  /// stderr if it is a TTY (and not quiet), the steady clock; the delay from
  /// VOXCAST_PROGRESS_DELAY_MS when set (tests of the terminal output).
  static ProgressSink terminal();
};

class Progress {
 public:
  struct Phase {
    std::string name;
    double weight = 1;  // share of the task's time, relative to the other phases
  };

  /// One phase of `total` work units. `enabled` = false: never draws.
  Progress(std::string label, uint64_t total, bool enabled = true);
  /// Several phases; start each with start_phase().
  Progress(std::string label, std::vector<Phase> phases, bool enabled = true);
  Progress(std::string label, std::vector<Phase> phases, ProgressSink sink);
  ~Progress();
  Progress(const Progress&) = delete;
  Progress& operator=(const Progress&) = delete;

  /// Replaces the phase plan (before any work: a library routine that knows
  /// its own phases, e.g. voxelize, re-plans the bar its caller passed).
  void set_phases(std::vector<Phase> phases);
  /// Starts phase `index` with `units` of work; every earlier phase counts as
  /// done. Not concurrent with advance().
  void start_phase(size_t index, uint64_t units);
  /// More work in the current phase (e.g. another render pass).
  void add_units(uint64_t units);
  void advance(uint64_t units = 1);
  /// Sets the current phase's done units (for sources that report a
  /// position, not increments, e.g. Assimp's progress handler).
  void set_done(uint64_t units);
  /// Draws the final state (when a bar was drawn) and ends its line.
  void finish();

  /// Weighted fraction of the whole task done, in [0, 1].
  double fraction() const;
  /// Seconds since construction.
  double elapsed_seconds() const;
  /// Estimated seconds left: elapsed * (1 - f) / f for the weighted fraction
  /// f; negative (no estimate) until 1% of the task is done.
  double eta_seconds() const;
  /// The status line as drawn (without the carriage return and padding).
  std::string status_line() const;

  /// Process-wide: no bars at all (the CLI's --quiet).
  static void set_quiet(bool quiet);
  static bool quiet();

 private:
  int64_t now() const;
  void maybe_draw();
  void draw(bool final);
  std::string label_;
  std::vector<Phase> phases_;
  double weight_sum_ = 1;
  std::atomic<size_t> phase_{0};
  std::atomic<uint64_t> total_{1};
  std::atomic<uint64_t> done_{0};
  std::atomic<int64_t> last_draw_ns_{0};
  ProgressSink sink_;
  int64_t start_ns_ = 0;
  std::atomic<bool> drawn_{false};
  std::mutex draw_mutex_;
  size_t drawn_width_ = 0;
  bool finished_ = false;
};

/// Stage timer for `-v`: prints "  stage  123.4 ms" to stderr when enabled
/// (every subcommand's -v uses it, so the timings look the same everywhere).
class StageTimer {
 public:
  explicit StageTimer(bool verbose);
  /// Prints the time since the previous mark (or construction) and returns it in seconds.
  double mark(const char* stage);

 private:
  bool verbose_;
  int64_t t0_ns_;
};

}  // namespace voxcast
