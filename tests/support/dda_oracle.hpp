#pragma once
// Brute-force ray oracle for the voxel casters: a dense N^3 occupancy grid
// walked with the Amanatides & Woo (1987) 3-D DDA in double precision.
// Deliberately independent of the ESVO code: no octree, no mirroring, no
// float bit tricks. Grid space: voxel (x,y,z) is [x,x+1]x[y,y+1]x[z,z+1];
// callers map their rays into it (t is left unchanged by that mapping).
#include <cstdint>
#include <vector>

#include "voxcast/voxelize.hpp"

namespace voxcast::testing {

struct DVec3 {
  double x = 0, y = 0, z = 0;
  double operator[](int i) const { return i == 0 ? x : (i == 1 ? y : z); }
};

struct DdaHit {
  bool hit = false;
  int x = -1, y = -1, z = -1;  // first occupied voxel along the ray
  double t_enter = 0;          // where the ray enters it (clipped to t >= 0)
  double t_exit = 0;           // where it leaves it
};

class DenseGrid {
 public:
  explicit DenseGrid(int levels);
  /// Occupancy from a VoxelSet's Morton codes at the set's finest level, or
  /// (level >= 0) coarsened to `level`: a cube there is occupied if any leaf
  /// below it is.
  static DenseGrid from_voxels(const VoxelSet& set, int level = -1);

  int levels() const { return levels_; }
  uint32_t resolution() const { return n_; }
  void set(uint32_t x, uint32_t y, uint32_t z);
  bool occupied(int x, int y, int z) const;

  /// First occupied voxel whose closed box the ray o + t d, t in [0, tmax],
  /// enters. On a zero direction component the ray lies in a grid plane
  /// possibly; the component's sign bit (+0 / -0) picks the side, like an
  /// infinitesimal step that way (the convention of the ESVO caster).
  DdaHit cast(DVec3 o, DVec3 d, double tmax) const;

  /// Exact slab test of one voxel: [t_enter, t_exit] of the ray in its closed
  /// box (t_enter clipped to 0); returns false if they do not overlap.
  static bool voxel_span(DVec3 o, DVec3 d, int x, int y, int z, double* t_enter, double* t_exit);

 private:
  int levels_;
  uint32_t n_;
  std::vector<uint64_t> bits_;
};

}  // namespace voxcast::testing
