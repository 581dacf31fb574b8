#pragma once
// What every reader does with a slice file (esvo §7), for the fuzz target
// fuzz/fuzz_slices.cpp and the committed regression inputs
// (tests/test_esvo_slices.cpp). No GoogleTest dependency.
#include <cstdint>
#include <span>
#include <string>
#include <vector>

namespace voxcast::testing {

/// Recomputes every in-range slice hash and the directory hash of the
/// slice-file bytes (so that edits reach the validators behind the hashes).
void rehash_slice_file(std::vector<uint8_t>& bytes);

/// Writes `bytes` to a temporary file, opens it as a slice file and, when
/// accepted, streams it with an unlimited budget and then a tiny one over a
/// few 16x16 frames, checking the streamed structure's invariants after every
/// pass. Returns "" when the file was accepted, else the one-line refusal.
/// Aborts (std::abort) when an accepted file breaks an invariant or the
/// stream throws anything but a refusal of a slice.
std::string check_slice_file(std::span<const uint8_t> bytes);

}  // namespace voxcast::testing
