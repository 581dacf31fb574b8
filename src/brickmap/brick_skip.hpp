// The walk's brick test (traverse.cpp, brick_slices), switchable for tests.
#pragma once

#include <atomic>

namespace voxcast::brickmap::detail {

/// How the walk tests a brick before its voxel DDA (skip a brick none of
/// whose slices the ray meets at a solid voxel): the SIMD test (the
/// default; the scalar loop in builds without AVX2), the scalar reference
/// loop, or no test (every brick walked voxel by voxel; the lane walk too,
/// PacketWorld::slice_skip). Hits are the same in all three; tests switch it
/// to compare them. Atomic (read relaxed, once per brick or per
/// trace_packets call), so that a test switching it while another thread
/// walks is no data race; a walk running across the switch may mix the two
/// tests, which gives the same hits.
enum class BrickSkip { Simd, Scalar, Off };
extern std::atomic<BrickSkip> brick_skip_mode;

/// How the walk tests the cubes inside a brick an LOD footprint may stop
/// at: true (the default) from the brick's mask folded once per cube walk
/// (traverse.cpp, visit_blocks), false with the general loop's per-cube
/// occupancy test (the reference). The same hits either way; atomic, as
/// above.
extern std::atomic<bool> brick_block_masks;

}  // namespace voxcast::brickmap::detail
