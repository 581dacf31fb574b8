#pragma once
// Brute-force ray oracle for the voxel casters: a dense N^3 occupancy grid
// walked with the Amanatides & Woo (1987) 3-D DDA in double precision.
// Deliberately independent of the ESVO code: no octree, no mirroring, no
// float bit tricks. Grid space: voxel (x,y,z) is [x,x+1]x[y,y+1]x[z,z+1];
// callers map their rays into it (t is left unchanged by that mapping).
#include <cstdint>
#include <random>
#include <vector>

#include "voxcast/math.hpp"
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

// ---- Comparing a voxel caster with the oracle (any caster: ESVO, DAG) ----
//
// A float caster and the exact DDA may disagree only where float rounding of
// the ray decides: a ray through a shared voxel edge or corner (exact ties),
// or one passing within `delta` (grid units) of a voxel's box (near ties).
// Every other difference is a bug.

/// Float-rounding slack of a caster working in octree space ([1,2]^3), in
/// octree units (~16 ulps in [1,2]); delta = kDeltaOct * N in grid units.
inline constexpr double kDeltaOct = 0x1p-19;

/// [t0, t1] of the ray in the closed box [lo, hi] (t0 clipped to 0).
bool box_span(DVec3 o, DVec3 d, const double lo[3], const double hi[3], double* t0, double* t1);
/// box_span of voxel (x, y, z) grown by `grow` on every side (shrunk if < 0).
bool grown_span(DVec3 o, DVec3 d, int x, int y, int z, double grow, double* t0, double* t1);
/// First occupied voxel whose box shrunk by `shrink` the ray crosses: a hit
/// no float rounding of the ray can remove (t_enter = entry of the shrunk box).
DdaHit robust_first_hit(const DenseGrid& g, DVec3 o, DVec3 d, double shrink);

struct DdaTally {
  uint64_t rays = 0, hits = 0, exact_ties = 0, near_ties = 0;
};

/// What a caster reported for one ray: the hit voxel (grid coordinates) and t.
struct CasterHit {
  bool hit = false;
  int x = -1, y = -1, z = -1;
  double t = 0;
};

/// First hit of the grid-space ray (go, gd), t in [0, inf), against `r`:
/// the same voxel as the DDA, or a tie as above; t between the entries of the
/// voxel grown and shrunk by `delta` (up to 1e-6 relative). Failures are
/// gtest (fatal) assertions naming `p`/`d`, the caster's own ray.
void expect_first_hit_matches(const DenseGrid& grid, DVec3 go, DVec3 gd, const CasterHit& r,
                              double delta, DdaTally* tally, Vec3 p, Vec3 d);

/// Any hit within [0, tmax] of the grid-space ray (go, gd) against the
/// caster's answer `occluded`. Where they differ: a caster "no" is a near
/// tie if no voxel shrunk by `delta` is entered before tmax (up to 1e-6
/// relative); a caster "yes" is one if `witness` (the caster's closest hit of
/// the same ray, unbounded) is an occupied voxel whose box grown by `delta`
/// the ray enters before tmax (up to 1e-6 relative) -- the oracle checks the
/// witness, so it cannot excuse a hit on empty space.
void expect_any_hit_matches(const DenseGrid& grid, DVec3 go, DVec3 gd, double tmax, bool occluded,
                            const CasterHit& witness, double delta, DdaTally* tally, Vec3 p,
                            Vec3 d);

/// Random rays of several kinds in octree space (root cube [1,2]^3, grid of
/// 2^levels voxels), unit directions: anywhere inside and outside the cube,
/// aimed into it from outside, axis-aligned with zero components of either
/// sign, near-axis (tiny components), in a grid plane (grazing voxel faces),
/// along grid edge lines, and through grid corners or edge points.
class OctreeRayGen {
 public:
  OctreeRayGen(uint64_t seed, int levels) : rng_(seed), n_(1u << levels) {}
  float uni(float a, float b) { return std::uniform_real_distribution<float>(a, b)(rng_); }
  int pick(int k) { return std::uniform_int_distribution<int>(0, k - 1)(rng_); }
  Vec3 sphere();
  float grid_line() { return 1.f + float(pick(int(n_) + 1)) / float(n_); }  // exact in float
  float signed_zero() { return pick(2) ? 0.f : -0.f; }
  void next(Vec3* p, Vec3* d);

 private:
  std::mt19937_64 rng_;
  uint32_t n_;
};

}  // namespace voxcast::testing
