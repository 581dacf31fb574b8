#pragma once
// What a brickmap world holds, independent of pool slots and color-run
// placement: the tests' comparison of worlds saved, replayed and edited;
// the crash tests' reaping of a killed child.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>

#include <algorithm>
#include <bit>
#include <cstdint>
#include <tuple>
#include <vector>

#include "voxcast/brickmap.hpp"
#include "voxcast/morton.hpp"

namespace voxcast::testing {

/// Every solid voxel (Morton code) with its stored color and normal, sorted.
using BrickmapVoxels = std::vector<std::tuple<uint64_t, uint32_t, uint32_t>>;
inline BrickmapVoxels brickmap_contents(const brickmap::World& w) {
  using namespace brickmap;
  BrickmapVoxels out;
  for (uint64_t ci = 0; ci < w.cells().size(); ++ci) {
    const uint32_t c = w.cell(ci);
    if (c == 0) continue;
    EXPECT_EQ(cell_state(c), kStateResident);
    const Brick& b = w.brick(cell_brick(c));
    const uint32_t i = uint32_t(ci % w.dims()[0]), j = uint32_t(ci / w.dims()[0] % w.dims()[1]),
                   k = uint32_t(ci / w.dims()[0] / w.dims()[1]);
    uint32_t n = b.color;
    for (uint32_t word = 0; word < 8; ++word)
      for (uint64_t m = b.mask[word]; m != 0; m &= m - 1, ++n) {
        const uint32_t bit = uint32_t(std::countr_zero(m));
        out.emplace_back(morton_encode(i * 8 + (bit & 7), j * 8 + (bit >> 3), k * 8 + word),
                         w.colors()[n], w.has_normals() ? w.normals()[n] : 0);
      }
  }
  std::sort(out.begin(), out.end());
  return out;
}

/// Waits for the crash tests' child `pid`: true if SIGKILL ended it, else
/// expects a clean exit.
inline bool reap_child_killed(pid_t pid) {
  int status = 0;
  ::waitpid(pid, &status, 0);
  const bool killed = WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL;
  if (!killed) {
    EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << status;
  }
  return killed;
}

}  // namespace voxcast::testing
