#pragma once
// The height map of a mesh's materials, for displacement mapping (esvo
// §7.4: "height texture from the mesh material"). Apart from mesh.hpp so
// that the mesh type every module includes stays as it is.
#include <cstdint>
#include <filesystem>

#include "voxcast/image.hpp"
#include "voxcast/mesh.hpp"

namespace voxcast {

/// load_mesh, and into `height_map` the height map of the first material
/// that has one (Assimp's DISPLACEMENT texture, else its HEIGHT one: OBJ
/// `disp`, `bump`/`map_bump`): one channel, the texture's first channel as
/// stored / 255 (like a --displacement PNG, without color conversion);
/// width 0 when no material has one (or its file cannot be used: a warning
/// in `stats`, as for color textures).
Mesh load_mesh(const std::filesystem::path& path, Image* height_map, MeshLoadStats* stats = nullptr,
               uint64_t texture_budget = 0);

}  // namespace voxcast
