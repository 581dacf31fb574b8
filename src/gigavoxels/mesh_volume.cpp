// A mesh through the voxelization pipeline as a scalar volume (gigavoxels.hpp
// solid_volume): density 1 in every solid voxel, 0 elsewhere.
#include <bit>

#include "voxcast/error.hpp"
#include "voxcast/gigavoxels.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/morton.hpp"
#include "voxcast/solid.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast::giga {

ScalarVolume solid_volume(const Mesh& mesh, int resolution) {
  if (resolution < 1 || resolution > 1024 || !std::has_single_bit(unsigned(resolution)))
    throw Error("mesh volume: the resolution must be a power of two in 1..1024");
  // The pipeline's grid (the mesh's bounds with its margin), its
  // conservative surface voxels and the interior filled by fill_solid.
  const GridTransform grid = GridTransform::fit(mesh.bounds(), uint32_t(resolution));
  VoxelizeOptions vo;
  vo.attributes = false;
  const VoxelSet solid = fill_solid(mesh, voxelize(mesh, grid, vo));
  ScalarVolume v;
  v.nx = v.ny = v.nz = resolution;
  v.vx = v.vy = v.vz = float(grid.voxel_size);
  v.values.assign(size_t(resolution) * size_t(resolution) * size_t(resolution), 0.f);
  for (const uint64_t code : solid.codes) {
    const MortonCoord c = morton_decode(code);
    v.values[(size_t(c.z) * size_t(resolution) + c.y) * size_t(resolution) + c.x] = 1.f;
  }
  return v;
}

}  // namespace voxcast::giga
