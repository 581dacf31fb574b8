// libFuzzer target: arbitrary bytes as a .vxc scene file. The container
// parser, the META reader, the structure validators (ESVO and DAG) and, when
// a scene is accepted, everything a subcommand does with it (the info
// statistics, occupied bounds, a small render with beam, shadows and AO:
// testing::check_scene) must never crash, hang or read out of bounds (run
// under ASan/UBSan). Byte-level: most inputs die at a section checksum;
// fuzz_scene_sections.cpp fixes the hashes up to get past them.
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <vector>

#include "support/scene_damage.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  // A clean rejection (voxcast::Error) is the expected outcome for most
  // inputs; an accepted scene that info or render cannot use is a finding.
  const voxcast::testing::Verdict v =
      voxcast::testing::check_scene(std::vector<uint8_t>(data, data + size));
  if (!v.use_error.empty()) {
    std::fprintf(stderr, "accepted, then failed: %s\n", v.use_error.c_str());
    std::abort();
  }
  return 0;
}
