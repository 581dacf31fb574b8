#include "voxcast/progress.hpp"

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>

#include "fmt/format.h"

namespace voxcast {

namespace {

std::atomic<bool> g_quiet{false};

int64_t steady_ns() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

constexpr int64_t kSecond = 1'000'000'000;

}  // namespace

ProgressSink ProgressSink::terminal() {
  ProgressSink s;
  s.tty = !Progress::quiet() && isatty(STDERR_FILENO);
  s.now_ns = steady_ns;
  if (const char* ms = std::getenv("VOXCAST_PROGRESS_DELAY_MS"))
    s.delay_ns = std::max<int64_t>(0, std::atoll(ms)) * 1'000'000;
  s.write = [](const std::string& text) {
    std::fputs(text.c_str(), stderr);
    std::fflush(stderr);
  };
  return s;
}

void Progress::set_quiet(bool quiet) {
  g_quiet = quiet;
}

bool Progress::quiet() {
  return g_quiet;
}

Progress::Progress(std::string label, uint64_t total, bool enabled)
    : Progress(std::move(label), std::vector<Phase>{{"", 1}}, enabled) {
  total_ = total;  // 0: work still unknown (add_units)
}

Progress::Progress(std::string label, std::vector<Phase> phases, bool enabled)
    : Progress(std::move(label), std::move(phases), [&] {
        ProgressSink s = ProgressSink::terminal();
        s.tty = s.tty && enabled;
        return s;
      }()) {}

Progress::Progress(std::string label, std::vector<Phase> phases, ProgressSink sink)
    : label_(std::move(label)), sink_(std::move(sink)) {
  if (!sink_.now_ns) sink_.now_ns = steady_ns;
  if (!sink_.write) sink_.tty = false;
  start_ns_ = sink_.now_ns();
  set_phases(std::move(phases));
  total_ = 0;
}

Progress::~Progress() {
  finish();
}

void Progress::set_phases(std::vector<Phase> phases) {
  if (phases.empty()) phases.push_back({"", 1});
  weight_sum_ = 0;
  for (Phase& p : phases) {
    p.weight = std::max(0.0, p.weight);
    weight_sum_ += p.weight;
  }
  if (!(weight_sum_ > 0)) {
    for (Phase& p : phases) p.weight = 1;
    weight_sum_ = double(phases.size());
  }
  phases_ = std::move(phases);
  phase_ = 0;
}

void Progress::start_phase(size_t index, uint64_t units) {
  phase_ = std::min(index, phases_.size() - 1);
  done_ = 0;
  total_ = units;
}

void Progress::add_units(uint64_t units) {
  total_.fetch_add(units, std::memory_order_relaxed);
}

int64_t Progress::now() const {
  return sink_.now_ns() - start_ns_;
}

void Progress::advance(uint64_t units) {
  done_.fetch_add(units, std::memory_order_relaxed);
  maybe_draw();
}

void Progress::set_done(uint64_t units) {
  done_ = units;
  maybe_draw();
}

void Progress::maybe_draw() {
  if (!sink_.tty) return;
  const int64_t t = now();
  // Silent for the first second (short tasks show no bar); then at most 10
  // redraws a second.
  if (t < sink_.delay_ns) return;
  int64_t last = last_draw_ns_.load(std::memory_order_relaxed);
  if (drawn_ && t - last < kSecond / 10) return;
  if (!last_draw_ns_.compare_exchange_strong(last, t)) return;
  draw(false);
}

double Progress::fraction() const {
  const size_t p = std::min(phase_.load(), phases_.size() - 1);
  double before = 0;
  for (size_t i = 0; i < p; ++i) before += phases_[i].weight;
  const uint64_t total = total_, done = done_;
  const double in_phase = total ? std::min(1.0, double(done) / double(total)) : 0.0;
  return std::min(1.0, (before + phases_[p].weight * in_phase) / weight_sum_);
}

double Progress::elapsed_seconds() const {
  return double(now()) * 1e-9;
}

double Progress::eta_seconds() const {
  const double f = fraction();
  if (f < 0.01) return -1;
  return elapsed_seconds() * (1 - f) / f;
}

std::string Progress::status_line() const {
  const double f = finished_ ? 1.0 : fraction();
  constexpr int kWidth = 30;
  const int filled = int(f * kWidth);
  std::string bar(size_t(kWidth), '.');
  std::fill(bar.begin(), bar.begin() + filled, '#');
  std::string name = label_;
  const size_t p = std::min(phase_.load(), phases_.size() - 1);
  if (!finished_ && phases_.size() > 1 && !phases_[p].name.empty())
    name += " (" + phases_[p].name + ")";
  std::string line =
      fmt::format("{} [{}] {:5.1f}%  {:.1f}s elapsed", name, bar, f * 100, elapsed_seconds());
  if (!finished_) {
    const double eta = eta_seconds();
    line += eta < 0 ? ", ETA --" : fmt::format(", ETA {:.1f}s", eta);
  }
  return line;
}

void Progress::draw(bool final) {
  std::lock_guard<std::mutex> lock(draw_mutex_);
  std::string line = status_line();
  // Pad over a longer previous line (a phase name that got shorter).
  const size_t width = line.size();
  if (width < drawn_width_) line.append(drawn_width_ - width, ' ');
  drawn_width_ = width;
  sink_.write("\r" + line + (final ? "\n" : ""));
  drawn_ = true;
}

void Progress::finish() {
  if (finished_) return;
  finished_ = true;
  if (sink_.tty && drawn_) draw(true);
}

StageTimer::StageTimer(bool verbose) : verbose_(verbose), t0_ns_(steady_ns()) {}

double StageTimer::mark(const char* stage) {
  const int64_t t = steady_ns();
  const double s = double(t - t0_ns_) * 1e-9;
  t0_ns_ = t;
  if (verbose_) std::fprintf(stderr, "  %-22s %9.1f ms\n", stage, s * 1e3);
  return s;
}

}  // namespace voxcast
