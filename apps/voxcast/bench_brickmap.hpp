#pragma once
// Brickmap edit throughput rows of `voxcast bench` (issue 11: voxels/s and
// bricks/s next to the ray casting figures of the same world, so one
// command reports both); cmd_bench.cpp itself names no structure.
#include <nlohmann/json_fwd.hpp>

#include "voxcast/math.hpp"
#include "voxcast/structure.hpp"

namespace voxcast::cli {

/// When `st` is a brickmap world: paint, remove and add a sphere of radius
/// 32 voxels centered where `probe` first hits it, on a copy of the world,
/// printing voxels and bricks changed and their rates per brush (brush
/// time only, as `voxcast edit`). Prints nothing for other structures and
/// one line when the probe misses.
void print_brickmap_edit_rows(const Structure& st, const Ray& probe);

/// When `st` is a brickmap world: its chunks LZ4-encoded in memory as the
/// scene writer stores them and decoded by the streamer's decode
/// (brickmap::measure_chunk_decode, best of `rounds`), printed as one row
/// of decoded GB/s with the bricks decoded against the source's; the same
/// figures into `*json` (an object). Nothing for other structures.
void print_brickmap_decode_row(const Structure& st, int rounds, nlohmann::json* json);

}  // namespace voxcast::cli
