#pragma once
// Helpers that build VoxelSets in code (no mesh, no voxelizer) for the ESVO
// builder, ray caster and scene-file tests. All generators are deterministic
// for a given seed and return codes sorted ascending and unique, with
// attribute arrays filled (colors, unit normals, positive weights) unless
// stated otherwise. Grid placement: origin (0,0,0), voxel_size 1/N, so the
// root cube is the unit cube [0,1]^3 in world space.
#include <cstddef>
#include <cstdint>
#include <functional>
#include <vector>

#include "voxcast/esvo.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast::testing {

/// Unit-cube grid of 2^levels voxels per axis (origin 0, voxel_size 2^-levels).
GridTransform unit_grid(int levels);

/// Fills colors/normals/weights for the codes of `set` from a hash of each code
/// (deterministic, seed-dependent): colors in [0,1], unit normals, weights in [0.1, 2].
void fill_random_attributes(VoxelSet& set, uint64_t seed);

/// `count` distinct random voxels (capped at 8^levels) of a 2^levels grid.
VoxelSet make_random_voxels(int levels, size_t count, uint64_t seed);

/// Voxels whose centers are within half a voxel of the sphere centered in the
/// grid with radius 0.4 * N (a closed one-voxel-thick shell, like a voxelized
/// surface). Normals point outward (radial); colors vary with position.
VoxelSet make_sphere_shell(int levels);

/// Every voxel of the 2^levels grid for which `occupied(x, y, z)` is true
/// (iterates the whole N^3 grid, keep levels small).
VoxelSet make_dense_grid(int levels,
                         const std::function<bool(uint32_t, uint32_t, uint32_t)>& occupied);

/// The full 2^levels grid (all N^3 voxels).
VoxelSet make_full_grid(int levels);

/// A caster oracle case: `count` random voxels (seed `seed`), or the sphere
/// shell (count 0), or the full grid (count SIZE_MAX), moved to world
/// placement `placement` % 3 -- the unit cube, origin (-3, 1, 2) side 2, or
/// origin (1000.5, -20.25, 7) side 0.375 -- so that a caster test checks the
/// world <-> grid mapping too.
VoxelSet make_placed_case(int levels, size_t count, uint64_t seed, int placement);

/// Top-down point query through the descriptors, written independently of the
/// builder (follows child pointers / far pointers as in esvo.hpp): true if the
/// leaf voxel (x,y,z) of the finest level exists. If `parent_slot`/`child` are
/// given, they receive the descriptor slot and child index of the leaf.
bool query_leaf(const esvo::EsvoOctree& octree, uint32_t x, uint32_t y, uint32_t z,
                uint32_t* parent_slot = nullptr, int* child = nullptr);

/// Word 0 of a child descriptor (esvo.hpp, Figure 2) for hand-built octrees.
uint32_t desc(uint32_t child_ptr, bool far, uint32_t valid, uint32_t leaf);

/// A single-block octree laid out by hand as esvo.hpp describes: slot 0 page
/// header, `descriptors` (word 0 each, word 1 zero) from slot 1, then the info
/// section with no attachments (the caster never reads attributes).
esvo::EsvoOctree hand_octree(int levels, const std::vector<uint32_t>& descriptors);

}  // namespace voxcast::testing
