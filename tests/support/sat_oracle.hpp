#pragma once
// Brute-force triangle / axis-aligned box overlap by the separating axis
// theorem (Akenine-Moeller, "Fast 3D Triangle-Box Overlap Testing", 2001):
// all 13 axes (3 box normals, the triangle normal, 9 edge x box-axis cross
// products), in double, closed sets (touching counts as overlap). Written
// independently of src/voxelize/ to serve as the reference in tests.
#include <cstdint>
#include <vector>

namespace voxcast::testing {

/// True iff the closed triangle `tri` overlaps the closed box [lo, lo + size]^3.
bool sat_triangle_box_overlap(const double tri[3][3], const double lo[3], double size);

/// All voxels (i,j,k) of an n^3 grid (voxel = [i,i+1]x[j,j+1]x[k,k+1]) that the
/// triangle overlaps, by testing every voxel of its bounding box; returned as
/// sorted unique Morton codes.
std::vector<uint64_t> sat_triangle_voxels(const double tri[3][3], uint32_t n);

}  // namespace voxcast::testing
