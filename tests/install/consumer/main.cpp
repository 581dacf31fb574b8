// A user program linking the installed voxcast: mesh -> voxels -> octree -> one ray.
#include <cstdio>
#include <memory>
#include <voxcast/esvo_structure.hpp>
#include <voxcast/mesh.hpp>
#include <voxcast/morton.hpp>
#include <voxcast/voxelize.hpp>

int main(int argc, char** argv) {
  if (argc < 2) return 2;
  // Built without voxcast's -march (not propagated): the inline Morton
  // helpers must work with the consumer's own ISA.
  const voxcast::MortonCoord mc = voxcast::morton_decode(voxcast::morton_encode(1000, 2, 77777));
  if (mc.x != 1000 || mc.y != 2 || mc.z != 77777) return 3;
  voxcast::Mesh mesh = voxcast::load_mesh(argv[1]);
  auto grid = voxcast::GridTransform::fit(mesh.bounds(), 64);
  voxcast::VoxelSet voxels = voxcast::voxelize(mesh, grid, {});
  auto octree = std::make_shared<voxcast::esvo::EsvoOctree>(voxcast::esvo::build_octree(voxels));
  voxcast::esvo::EsvoStructure structure(octree);
  voxcast::Aabb b = mesh.bounds();
  voxcast::Vec3 eye = b.center() + voxcast::Vec3{0, 0, 10 * (b.hi.z - b.lo.z)};
  voxcast::SurfaceHit hit;
  voxcast::TraceContext ctx;  // per-thread query state (counters, requests, caches)
  bool found = structure.trace({eye, {0, 0, -1}, INFINITY}, {}, ctx, &hit);
  std::printf("%zu voxels, center ray %s at t=%g\n", voxels.size(), found ? "hit" : "missed",
              hit.t);
  return found ? 0 : 1;
}
