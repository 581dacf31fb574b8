#pragma once
// 64-bit 3-D Morton codes: bit 3i is x_i, 3i+1 is y_i, 3i+2 is z_i, so the
// lowest three bits of a code are the ESVO child slot index (x | y<<1 | z<<2)
// of the voxel inside its parent and `code >> 3` is the parent's code.
// 21 bits per axis are representable; voxcast uses at most 20 (2^20 grids).
#include <immintrin.h>

#include <cstdint>

namespace voxcast {

inline constexpr uint64_t kMortonMaskX = 0x1249249249249249ull;
inline constexpr uint64_t kMortonMaskY = kMortonMaskX << 1;
inline constexpr uint64_t kMortonMaskZ = kMortonMaskX << 2;

inline uint64_t morton_encode(uint32_t x, uint32_t y, uint32_t z) {
  return _pdep_u64(x, kMortonMaskX) | _pdep_u64(y, kMortonMaskY) | _pdep_u64(z, kMortonMaskZ);
}

struct MortonCoord {
  uint32_t x, y, z;
};

inline MortonCoord morton_decode(uint64_t code) {
  return {static_cast<uint32_t>(_pext_u64(code, kMortonMaskX)),
          static_cast<uint32_t>(_pext_u64(code, kMortonMaskY)),
          static_cast<uint32_t>(_pext_u64(code, kMortonMaskZ))};
}

}  // namespace voxcast
