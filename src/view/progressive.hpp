#pragma once
// Progressive refinement of a still view: while the camera moves the viewer
// shows one quick frame per display frame (optionally at a fraction of the
// resolution); once it stops, frames at full resolution with new effect
// seeds are averaged until `max_passes` have been added.
//
// What refines: the stochastic effects (ambient occlusion and soft-shadow
// samples are hashed from the pixel and the seed, effects.hpp), so pass k
// uses seed base + k and the mean converges to the many-sample image. The
// primary hits do not change between passes (no jitter yet).
//
// The post-filter (esvo §6.3) blurs with weights set by the hit voxels'
// projected sizes alone, which are the same in every pass: it is linear in
// the colors, so the mean of the filtered passes is the filtered mean of the
// passes. The viewer therefore filters each pass as it renders it and the
// average shown is the post-filtered accumulation
// (ViewProgressive.FilterCommutesWithTheMean checks the linearity).
#include <cstdint>

#include "voxcast/image.hpp"

namespace voxcast::view {

class Accumulator {
 public:
  static constexpr int kMaxPasses = 256;
  explicit Accumulator(int max_passes = 16) { set_max_passes(max_passes); }
  /// The view changed: start over.
  void reset() { passes_ = 0; }
  int passes() const { return passes_; }
  int max_passes() const { return max_passes_; }
  void set_max_passes(int n) { max_passes_ = n < 1 ? 1 : (n > kMaxPasses ? kMaxPasses : n); }
  bool done() const { return passes_ >= max_passes_; }
  /// Seed of the next pass: base + passes().
  uint32_t next_seed(uint32_t base) const { return base + uint32_t(passes_); }
  /// Adds a pass (same size as the earlier ones since reset(); a different
  /// size starts over with this one).
  void add(const Image& color);
  /// The mean of the passes added since reset() (an empty image before any).
  const Image& mean() const { return mean_; }

 private:
  int max_passes_ = 1;
  int passes_ = 0;
  // Float sums: at most kMaxPasses adds of values ~[0, 1] lose < 2^-15, far
  // below one 8-bit display step.
  Image sum_;
  Image mean_;
};

}  // namespace voxcast::view
