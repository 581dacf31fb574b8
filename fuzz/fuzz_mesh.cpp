// libFuzzer target: arbitrary bytes as a mesh file through Assimp and
// voxcast's own checks (the OFF, PLY and OBJ prechecks, the glTF/GLB header,
// buffer and image checks, texture decoding of embedded images), then a small
// voxelization of whatever loads. The first byte picks the file extension
// (the importer Assimp tries first, and which precheck runs). Textures are
// decoded within a 64 MiB budget, as `build --memory-budget 64M` would: an
// image header claiming 2^28 texels is refused instead of decoded.
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <string>

#include "voxcast/error.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/voxelize.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace voxcast;
  if (size < 1) return 0;
  static const char* const kExt[] = {".obj", ".ply", ".stl", ".off", ".gltf", ".glb", ".dae"};
  const std::string path = "/tmp/voxcast-fuzz-" + std::to_string(getpid()) + kExt[data[0] % 7];
  if (FILE* f = std::fopen(path.c_str(), "wb")) {
    std::fwrite(data + 1, 1, size - 1, f);
    std::fclose(f);
  } else {
    return 0;
  }
  try {
    const Mesh mesh = load_mesh(path, nullptr, uint64_t(64) << 20);
    const VoxelSet v = voxelize(mesh, GridTransform::fit(mesh.bounds(), 16), {});
    (void)v;
  } catch (const Error&) {
  }
  std::remove(path.c_str());
  return 0;
}
