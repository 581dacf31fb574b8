#pragma once
// 64-bit 3-D Morton codes: bit 3i is x_i, 3i+1 is y_i, 3i+2 is z_i, so the
// lowest three bits of a code are the ESVO child slot index (x | y<<1 | z<<2)
// of the voxel inside its parent and `code >> 3` is the parent's code.
// 21 bits per axis are representable; voxcast uses at most 20 (2^20 grids).
// The library is built with BMI2 (pdep/pext); a consumer compiled without it
// (the ISA flag is not propagated) gets the portable bit spreading instead,
// which computes the same codes.
#if defined(__BMI2__)
#include <immintrin.h>
#endif

#include <cstdint>

namespace voxcast {

inline constexpr uint64_t kMortonMaskX = 0x1249249249249249ull;
inline constexpr uint64_t kMortonMaskY = kMortonMaskX << 1;
inline constexpr uint64_t kMortonMaskZ = kMortonMaskX << 2;

namespace detail {
// Bits 0..20 of v to bits 0, 3, ..., 60 (and back): the classic shift-and-mask
// ladder, the portable form of pdep/pext with kMortonMaskX.
constexpr uint64_t morton_spread(uint64_t v) {
  v &= 0x1FFFFFull;
  v = (v | v << 32) & 0x1F00000000FFFFull;
  v = (v | v << 16) & 0x1F0000FF0000FFull;
  v = (v | v << 8) & 0x100F00F00F00F00Full;
  v = (v | v << 4) & 0x10C30C30C30C30C3ull;
  v = (v | v << 2) & kMortonMaskX;
  return v;
}
constexpr uint64_t morton_compact(uint64_t v) {
  v &= kMortonMaskX;
  v = (v | v >> 2) & 0x10C30C30C30C30C3ull;
  v = (v | v >> 4) & 0x100F00F00F00F00Full;
  v = (v | v >> 8) & 0x1F0000FF0000FFull;
  v = (v | v >> 16) & 0x1F00000000FFFFull;
  v = (v | v >> 32) & 0x1FFFFFull;
  return v;
}
static_assert(morton_spread(0x1FFFFF) == kMortonMaskX && morton_compact(kMortonMaskX) == 0x1FFFFF);
static_assert(morton_spread(5) == 0b1000001ull && morton_compact(0b1000001ull) == 5);
}  // namespace detail

inline uint64_t morton_encode(uint32_t x, uint32_t y, uint32_t z) {
#if defined(__BMI2__)
  return _pdep_u64(x, kMortonMaskX) | _pdep_u64(y, kMortonMaskY) | _pdep_u64(z, kMortonMaskZ);
#else
  return detail::morton_spread(x) | detail::morton_spread(y) << 1 | detail::morton_spread(z) << 2;
#endif
}

struct MortonCoord {
  uint32_t x, y, z;
};

inline MortonCoord morton_decode(uint64_t code) {
#if !defined(__BMI2__)
  return {static_cast<uint32_t>(detail::morton_compact(code)),
          static_cast<uint32_t>(detail::morton_compact(code >> 1)),
          static_cast<uint32_t>(detail::morton_compact(code >> 2))};
#else
  return {static_cast<uint32_t>(_pext_u64(code, kMortonMaskX)),
          static_cast<uint32_t>(_pext_u64(code, kMortonMaskY)),
          static_cast<uint32_t>(_pext_u64(code, kMortonMaskZ))};
#endif
}

}  // namespace voxcast
