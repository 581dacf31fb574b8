#include "bench_brickmap.hpp"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <nlohmann/json.hpp>

#include "voxcast/brickmap.hpp"
#include "voxcast/brickmap_stream.hpp"
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
  // Twice: the copy above holds its brick, color and normal arrays without
  // slack, so the first add grows them (on a 2048^3 world that copy of
  // ~150 MB costs more than the brush); the second round shows the brushes
  // on grown pools, as on a world loaded from a file.
  for (int round = 0; round < 2; ++round) {
    if (round == 1) std::printf("  again (pools grown by the first add):\n");
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
}

void print_brickmap_decode_row(const Structure& st, int rounds, nlohmann::json* json) {
  const auto* bm = dynamic_cast<const brickmap::BrickmapStructure*>(&st);
  if (bm == nullptr) return;
  const brickmap::ChunkDecodeRate d = brickmap::measure_chunk_decode(bm->world(), rounds);
  const bool same = d.decoded_bricks == d.source_bricks && d.decoded_hash == d.source_hash;
  std::printf(
      "brickmap chunk decode (checksum + LZ4 + brick index, 1 thread, best of %d): %llu chunks, "
      "%.1f MB raw from %.1f MB LZ4, %9.3f ms %8.3f GB/s, %llu bricks decoded of %llu (%s)\n",
      std::max(rounds, 1), (unsigned long long)d.chunks, double(d.raw_bytes) * 1e-6,
      double(d.compressed_bytes) * 1e-6, d.seconds * 1e3, d.bytes_per_second() * 1e-9,
      (unsigned long long)d.decoded_bricks, (unsigned long long)d.source_bricks,
      same ? "masks equal the source's" : "MISMATCH");
  *json = {{"chunks", d.chunks},
           {"raw_bytes", d.raw_bytes},
           {"compressed_bytes", d.compressed_bytes},
           {"seconds", d.seconds},
           {"gb_per_s", d.bytes_per_second() * 1e-9},
           {"source_bricks", d.source_bricks},
           {"decoded_bricks", d.decoded_bricks},
           {"bricks_equal", same}};
}

}  // namespace voxcast::cli
