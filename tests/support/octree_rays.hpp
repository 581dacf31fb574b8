#pragma once
// Random numbers for the octree casters' ray tests (octree space: the root
// cube is [1,2]^3): uniform floats, picks, unit directions, grid planes.
// Each test draws its own mix of ray kinds from these.
#include <cstdint>
#include <random>

#include "voxcast/math.hpp"

namespace voxcast::testing {

class OctreeRayRng {
 public:
  /// `levels`: the grid whose planes grid_line() returns.
  OctreeRayRng(uint64_t seed, int levels) : rng_(seed), n_(1u << levels) {}
  float uni(float a, float b) { return std::uniform_real_distribution<float>(a, b)(rng_); }
  int pick(int k) { return std::uniform_int_distribution<int>(0, k - 1)(rng_); }
  /// Uniform unit direction (rejection sampling in the unit ball).
  Vec3 sphere() {
    Vec3 v;
    do v = {uni(-1, 1), uni(-1, 1), uni(-1, 1)};
    while (dot(v, v) > 1 || dot(v, v) < 1e-4f);
    return normalize(v);
  }
  /// A random grid plane coordinate in [1, 2] (exact in float).
  float grid_line() { return 1.f + float(pick(int(n_) + 1)) / float(n_); }
  float signed_zero() { return pick(2) ? 0.f : -0.f; }

 private:
  std::mt19937_64 rng_;
  uint32_t n_;
};

}  // namespace voxcast::testing
