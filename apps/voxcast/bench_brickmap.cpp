#include "bench_brickmap.hpp"

#include <chrono>
#include <cstdio>

#include "voxcast/brickmap.hpp"
#include "voxcast/trace_context.hpp"

namespace voxcast::cli {

void print_brickmap_edit_rows(const Structure& st, const Ray& probe) {
  const auto* bm = dynamic_cast<const brickmap::BrickmapStructure*>(&st);
  if (bm == nullptr) return;
  TraceContext ctx;
  SurfaceHit hit;
  if (!bm->trace(probe, {}, ctx, &hit)) {
    std::printf("brickmap edits: the image's center ray misses the world, not measured\n");
    return;
  }
  brickmap::World world = bm->world();  // the brushes change a copy
  const double radius = 32 * world.grid().voxel_size;
  const Vec3d center{hit.position.x, hit.position.y, hit.position.z};
  struct Row {
    const char* name;
    brickmap::EditOp op;
    Color color;
  };
  // Surface voxels first (paint, remove), then a solid ball (add).
  const Row rows[] = {{"paint", brickmap::EditOp::Paint, {0.2f, 0.6f, 0.2f, 1.f}},
                      {"remove", brickmap::EditOp::Remove, {}},
                      {"add", brickmap::EditOp::Add, {0.9f, 0.9f, 1.f, 1.f}}};
  std::printf("brickmap edits (sphere of radius 32 voxels at the center ray's hit, brush time):\n");
  for (const Row& row : rows) {
    const auto t0 = std::chrono::steady_clock::now();
    const brickmap::EditResult e =
        brickmap::edit(world, brickmap::Brush::sphere(center, radius), row.op, row.color);
    const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::printf("  %-6s %10llu voxels %7zu bricks %9.3f ms %10.3g voxels/s %10.3g bricks/s\n",
                row.name, (unsigned long long)e.voxels, e.cells.size(), s * 1e3,
                s > 0 ? double(e.voxels) / s : 0.0, s > 0 ? double(e.cells.size()) / s : 0.0);
  }
}

}  // namespace voxcast::cli
