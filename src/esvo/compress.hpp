#pragma once
// Compressed color/normal blocks (esvo §5.5, Figures 9-10), private to
// src/esvo. The bit layout is documented in include/voxcast/esvo.hpp and in
// compress.cpp; the public entry points are declared in esvo.hpp.
#include <cstdint>

#include "voxcast/esvo.hpp"

namespace voxcast::esvo::detail {

/// Words of one compression block (Figure 9: 2 color words + 4 normal words).
inline constexpr uint32_t kCompressedBlockWords = 6;

/// Encodes the 16 slots of one block from raw attachment values (the 64-bit
/// value of the raw format: ABGR color word | cube normal word << 32). Slot i
/// is used iff bit i of `used` is set; `values` holds the used slots' values
/// in ascending slot order (popcount(used) entries). Unused slots get index 0.
void encode_block_from_raw(const uint64_t* values, uint32_t used, uint32_t out[6]);

}  // namespace voxcast::esvo::detail
