// Amanatides & Woo 3-D DDA over a dense bit grid, in double (see dda_oracle.hpp).
#include "support/dda_oracle.hpp"

#include <cmath>
#include <limits>
#include <stdexcept>

#include "voxcast/morton.hpp"

namespace voxcast::testing {

DenseGrid::DenseGrid(int levels) : levels_(levels), n_(1u << levels) {
  if (levels < 0 || levels > 10) throw std::invalid_argument("DenseGrid: levels must be 0..10");
  bits_.assign((size_t(n_) * n_ * n_ + 63) / 64, 0);
}

DenseGrid DenseGrid::from_voxels(const VoxelSet& set, int level) {
  if (level < 0) level = set.grid.levels;
  DenseGrid g(level);
  const int shift = set.grid.levels - level;
  for (uint64_t code : set.codes) {
    const MortonCoord c = morton_decode(code >> (3 * shift));
    g.set(c.x, c.y, c.z);
  }
  return g;
}

void DenseGrid::set(uint32_t x, uint32_t y, uint32_t z) {
  const size_t i = (size_t(z) * n_ + y) * n_ + x;
  bits_[i >> 6] |= uint64_t(1) << (i & 63);
}

bool DenseGrid::occupied(int x, int y, int z) const {
  if (x < 0 || y < 0 || z < 0 || x >= int(n_) || y >= int(n_) || z >= int(n_)) return false;
  const size_t i = (size_t(z) * n_ + size_t(y)) * n_ + size_t(x);
  return (bits_[i >> 6] >> (i & 63)) & 1;
}

bool DenseGrid::voxel_span(DVec3 o, DVec3 d, int x, int y, int z, double* t_enter, double* t_exit) {
  double t0 = 0, t1 = std::numeric_limits<double>::infinity();
  const int c[3] = {x, y, z};
  for (int a = 0; a < 3; ++a) {
    const double lo = c[a], hi = c[a] + 1.0;
    if (d[a] == 0) {
      if (o[a] < lo || o[a] > hi) return false;
      continue;
    }
    double ta = (lo - o[a]) / d[a], tb = (hi - o[a]) / d[a];
    if (ta > tb) std::swap(ta, tb);
    t0 = std::max(t0, ta);
    t1 = std::min(t1, tb);
  }
  *t_enter = t0;
  *t_exit = t1;
  return t0 <= t1;
}

DdaHit DenseGrid::cast(DVec3 o, DVec3 d, double tmax) const {
  const double inf = std::numeric_limits<double>::infinity();
  const double n = n_;
  // Clip to the grid cube [0, N]^3.
  double t0 = 0, t1 = tmax;
  for (int a = 0; a < 3; ++a) {
    if (d[a] == 0) {
      if (o[a] < 0 || o[a] > n) return {};
      continue;
    }
    double ta = (0 - o[a]) / d[a], tb = (n - o[a]) / d[a];
    if (ta > tb) std::swap(ta, tb);
    t0 = std::max(t0, ta);
    t1 = std::min(t1, tb);
  }
  if (!(t0 <= t1)) return {};

  // Starting voxel and per-axis stepping state. A coordinate exactly on a
  // voxel boundary belongs to the voxel the ray moves into (direction sign;
  // the sign bit for zero components).
  int cell[3], step[3];
  double t_next[3];
  for (int a = 0; a < 3; ++a) {
    const bool positive = !std::signbit(d[a]);
    step[a] = positive ? 1 : -1;
    // The entry point; on the entry axis it is exactly the face.
    double p = o[a] + t0 * d[a];
    if (d[a] != 0) {
      const double ta = ((positive ? 0.0 : n) - o[a]) / d[a];
      if (ta == t0) p = positive ? 0.0 : n;
    } else {
      p = o[a];
    }
    double f = std::floor(p);
    int c = int(f);
    if (!positive && f == p) c -= 1;  // on a boundary moving down: lower voxel
    c = std::min(std::max(c, 0), int(n_) - 1);
    cell[a] = c;
    if (d[a] == 0) {
      t_next[a] = inf;
    } else {
      const double boundary = positive ? c + 1.0 : double(c);
      t_next[a] = (boundary - o[a]) / d[a];
    }
  }

  double t_enter = t0;
  while (true) {
    const double t_exit = std::min(std::min(t_next[0], t_next[1]), t_next[2]);
    if (occupied(cell[0], cell[1], cell[2])) {
      DdaHit h;
      h.hit = true;
      h.x = cell[0], h.y = cell[1], h.z = cell[2];
      h.t_enter = t_enter;
      h.t_exit = std::min(t_exit, t1);
      return h;
    }
    if (t_exit > t1) return {};
    // Step every axis whose boundary is reached at t_exit (several when the
    // ray passes exactly through an edge or corner).
    for (int a = 0; a < 3; ++a) {
      if (t_next[a] == t_exit) {
        cell[a] += step[a];
        if (cell[a] < 0 || cell[a] >= int(n_)) return {};
        // Recompute from the boundary instead of accumulating t_delta: keeps
        // the oracle's t exact to one rounding.
        const double boundary = step[a] > 0 ? cell[a] + 1.0 : double(cell[a]);
        t_next[a] = (boundary - o[a]) / d[a];
      }
    }
    t_enter = t_exit;
  }
}

}  // namespace voxcast::testing
