#pragma once
// Procedural stress meshes for the voxelizer and the sparse voxel DAG
// (svdag §5 evaluates on scenes of very different sharing behaviour):
// hairball (many thin random tubes: little sharing, the hard case for DAGs),
// Menger sponge (exact self-similarity: maximal sharing), fractal terrain (a
// height field). All generators are deterministic for their parameters: the
// same options give the same mesh bytes on every machine (own PRNG-to-double
// conversion, no <random> distributions).
#include <cstdint>
#include <filesystem>

#include "voxcast/mesh.hpp"

namespace voxcast::generate {

struct HairballOptions {
  uint64_t seed = 1;
  int tubes = 200;        // 1 .. 1000000
  int segments = 64;      // polyline steps per tube, 1 .. 100000
  int sides = 6;          // sides of the swept circle, 3 .. 64
  double radius = 0.004;  // tube radius, ball radius 1
  double step = 0.04;     // random-walk step length
};
/// Random walks in the unit ball (reflected at its surface), each swept by a
/// k-sided circle with a parallel-transported frame and capped at both ends:
/// every tube is a closed 2-manifold (each edge in exactly two triangles).
Mesh hairball(const HairballOptions& options);

/// Menger sponge of `level` (0 .. 5) in [0,1]^3: only the faces of the solid
/// sub-cubes that no other solid sub-cube covers, two triangles each
/// (2 * 20^L + 4 * 8^L faces), vertices shared.
Mesh menger(int level);

struct TerrainOptions {
  uint64_t seed = 1;
  int size = 256;            // vertices per side, 2 .. 8192
  int octaves = 6;           // fBm octaves, 1 .. 16
  double height = 0.25;      // vertical scale; the terrain spans [0,1] in x and z
  double persistence = 0.5;  // amplitude factor per octave
};
/// Height field y = height * fBm(x, z) over an N x N vertex grid of [0,1]^2
/// (value noise, smooth interpolation, frequency doubling per octave).
Mesh terrain(const TerrainOptions& options);

/// Writes positions and triangles as OBJ (text) or binary little-endian PLY,
/// chosen by the extension (.obj / .ply), atomically. Throws voxcast::Error.
void write_mesh(const std::filesystem::path& path, const Mesh& mesh);

}  // namespace voxcast::generate
