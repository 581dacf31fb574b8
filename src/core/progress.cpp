#include "voxcast/progress.hpp"

#include <unistd.h>

#include <cstdio>

namespace voxcast {

namespace {
int64_t now_ns(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now() - t0)
      .count();
}
}  // namespace

Progress::Progress(std::string label, uint64_t total, bool enabled)
    : label_(std::move(label)),
      total_(total ? total : 1),
      start_(std::chrono::steady_clock::now()),
      tty_(enabled && isatty(STDERR_FILENO)) {}

Progress::~Progress() {
  finish();
}

void Progress::advance(uint64_t units) {
  uint64_t done = done_.fetch_add(units, std::memory_order_relaxed) + units;
  if (!tty_) return;
  int64_t t = now_ns(start_);
  // Stay silent for the first second; then redraw at most 10 times a second.
  if (t < 1'000'000'000) return;
  int64_t last = last_draw_ns_.load(std::memory_order_relaxed);
  if (t - last < 100'000'000) return;
  if (!last_draw_ns_.compare_exchange_strong(last, t)) return;
  draw(done);
}

void Progress::draw(uint64_t done) {
  double frac = std::min(1.0, double(done) / double(total_));
  double elapsed = now_ns(start_) * 1e-9;
  double eta = frac > 0 ? elapsed * (1 - frac) / frac : 0;
  constexpr int kWidth = 30;
  int filled = int(frac * kWidth);
  char bar[kWidth + 1];
  for (int i = 0; i < kWidth; ++i) bar[i] = i < filled ? '#' : '.';
  bar[kWidth] = 0;
  std::fprintf(stderr, "\r%s [%s] %5.1f%%  %.1fs elapsed, ETA %.1fs ", label_.c_str(), bar,
               frac * 100, elapsed, eta);
  std::fflush(stderr);
  drawn_ = true;
}

void Progress::finish() {
  if (finished_) return;
  finished_ = true;
  if (tty_ && drawn_) {
    draw(total_);
    std::fputc('\n', stderr);
  }
}

double StageTimer::mark(const char* stage) {
  auto t = std::chrono::steady_clock::now();
  double s = std::chrono::duration<double>(t - t0_).count();
  t0_ = t;
  if (verbose_) std::fprintf(stderr, "  %-22s %9.1f ms\n", stage, s * 1e3);
  return s;
}

}  // namespace voxcast
