#pragma once
// What the packet-caster tests share (tests/test_packet_caster.cpp,
// tests/test_tile_frustum.cpp): bit-exact comparison of two SurfaceHits and
// the kernel ISAs this CPU runs.
#include <bit>
#include <cstdint>
#include <cstdio>
#include <vector>

#include "voxcast/isa.hpp"
#include "voxcast/structure.hpp"

namespace voxcast::testing {

inline uint32_t float_bits(float f) {
  return std::bit_cast<uint32_t>(f);
}

/// Every SurfaceHit field equal, floats bit for bit.
inline bool same_hit(const SurfaceHit& a, const SurfaceHit& b) {
  return float_bits(a.t) == float_bits(b.t) &&
         float_bits(a.position.x) == float_bits(b.position.x) &&
         float_bits(a.position.y) == float_bits(b.position.y) &&
         float_bits(a.position.z) == float_bits(b.position.z) &&
         float_bits(a.voxel_size) == float_bits(b.voxel_size) && a.voxel_ref == b.voxel_ref &&
         a.child == b.child && a.level == b.level;
}

/// AVX2, and AVX-512 where the CPU has it (said once on stdout otherwise).
inline std::vector<Isa> packet_isas() {
  std::vector<Isa> v{Isa::Avx2};
  if (cpu_supports(Isa::Avx512))
    v.push_back(Isa::Avx512);
  else
    std::printf("CPU without AVX-512: AVX2 kernels only\n");
  return v;
}

}  // namespace voxcast::testing
