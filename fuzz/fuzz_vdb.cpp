// libFuzzer target: arbitrary bytes as an OpenVDB .vdb file through
// read_vdb (libopenvdb's reader, then voxcast's grid checks: geometry grid,
// transform, voxel budget, extent, placement). Whatever is accepted must be a
// valid voxel set that writes as .vdb and reads back with the same voxels;
// anything else must be refused with voxcast::Error. libopenvdb itself is
// not instrumented, so the coverage feedback is voxcast's side only; a crash
// or an oversized allocation inside the library still stops the fuzzer.
// Seeds: fuzz/corpus/vdb (fog volumes with colors, written by `convert`) and
// a level set and a bool grid written by OpenVDB itself:
//   VOXCAST_WRITE_SEEDS=DIR ./fuzz_vdb
#include <openvdb/openvdb.h>
#include <openvdb/tools/LevelSetSphere.h>
#include <unistd.h>

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "voxcast/error.hpp"
#include "voxcast/morton.hpp"
#include "voxcast/voxel_io.hpp"

namespace {

void check(bool ok) {
  if (!ok) std::abort();
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  const char* dir = std::getenv("VOXCAST_WRITE_SEEDS");
  if (!dir) return 0;
  openvdb::initialize();
  const std::string d(dir);
  auto sphere = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(
      3.f, openvdb::Vec3f(1.f, 2.f, 3.f), 0.5f, 2.f);
  sphere->setName("surface");
  openvdb::io::File(d + "/level_set_sphere.vdb").write({sphere});
  auto mask = openvdb::BoolGrid::create(false);
  mask->setName("mask");
  auto acc = mask->getAccessor();
  for (int i = 0; i < 6; ++i) acc.setValue(openvdb::Coord(i, i % 3, -i), true);
  mask->fill(openvdb::CoordBBox(openvdb::Coord(8), openvdb::Coord(9)), true);  // an active tile
  openvdb::io::File(d + "/bool_grid.vdb").write({mask});
  std::exit(0);
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace voxcast;
  // read_vdb reads a path (libopenvdb opens the file itself).
  const std::string path = "/tmp/voxcast-fuzz-" + std::to_string(getpid()) + ".vdb";
  const std::string again = "/tmp/voxcast-fuzz-" + std::to_string(getpid()) + "-2.vdb";
  if (FILE* f = std::fopen(path.c_str(), "wb")) {
    std::fwrite(data, 1, size, f);
    std::fclose(f);
  } else {
    return 0;
  }
  VoxelReadOptions options;
  options.memory_budget = uint64_t(64) << 20;
  VoxelSet a;
  bool accepted = false;
  try {
    a = read_vdb(path, options);
    accepted = true;
  } catch (const Error&) {
  }
  std::remove(path.c_str());
  if (!accepted) return 0;
  check(!a.codes.empty() && std::is_sorted(a.codes.begin(), a.codes.end()));
  check(std::adjacent_find(a.codes.begin(), a.codes.end()) == a.codes.end());
  check(a.colors.size() == a.size());
  for (uint64_t c : a.codes) {
    const MortonCoord m = morton_decode(c);
    check(std::max({m.x, m.y, m.z}) < a.grid.resolution);
  }
  write_vdb(again, a);
  const VoxelSet b = read_vdb(again, options);
  std::remove(again.c_str());
  check(b.codes == a.codes);
  return 0;
}
