// Amanatides & Woo 3-D DDA over a dense bit grid, in double (see dda_oracle.hpp).
#include "support/dda_oracle.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

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

bool box_span(DVec3 o, DVec3 d, const double lo[3], const double hi[3], double* t0, double* t1) {
  double a0 = 0, a1 = INFINITY;
  for (int a = 0; a < 3; ++a) {
    if (d[a] == 0) {
      if (o[a] < lo[a] || o[a] > hi[a]) return false;
      continue;
    }
    double ta = (lo[a] - o[a]) / d[a], tb = (hi[a] - o[a]) / d[a];
    if (ta > tb) std::swap(ta, tb);
    a0 = std::max(a0, ta);
    a1 = std::min(a1, tb);
  }
  *t0 = a0;
  *t1 = a1;
  return a0 <= a1;
}

bool grown_span(DVec3 o, DVec3 d, int x, int y, int z, double grow, double* t0, double* t1) {
  const double lo[3] = {x - grow, y - grow, z - grow},
               hi[3] = {x + 1 + grow, y + 1 + grow, z + 1 + grow};
  return box_span(o, d, lo, hi, t0, t1);
}

// The exact DDA visits every voxel the ray crosses, so checking the shrunk
// box in visit order finds the first robust hit.
DdaHit robust_first_hit(const DenseGrid& g, DVec3 o, DVec3 d, double shrink) {
  DdaHit h = g.cast(o, d, INFINITY);
  // Walk on past grazed voxels by restarting just after them.
  double t_skip = 0;
  for (int guard = 0; h.hit && guard < 100000; ++guard) {
    double t0, t1;
    if (grown_span(o, d, h.x, h.y, h.z, -shrink, &t0, &t1) && t0 >= t_skip - 1e-12) {
      h.t_enter = t0;
      return h;
    }
    // Re-cast from the exit of this voxel.
    t_skip = h.t_exit;
    const DVec3 o2{o.x + d.x * t_skip, o.y + d.y * t_skip, o.z + d.z * t_skip};
    DdaHit next = g.cast(o2, d, INFINITY);
    if (next.hit && next.x == h.x && next.y == h.y && next.z == h.z) {
      // Still inside (rounding at the exit point): nudge forward a little.
      const double nudge = 1e-9 * (1 + t_skip);
      const DVec3 o3{o.x + d.x * (t_skip + nudge), o.y + d.y * (t_skip + nudge),
                     o.z + d.z * (t_skip + nudge)};
      next = g.cast(o3, d, INFINITY);
      if (next.hit) next.t_enter += t_skip + nudge, next.t_exit += t_skip + nudge;
    } else if (next.hit) {
      next.t_enter += t_skip, next.t_exit += t_skip;
    }
    h = next;
  }
  return {};
}

namespace {

std::string describe(Vec3 p, Vec3 d) {
  return "p=(" + std::to_string(p.x) + "," + std::to_string(p.y) + "," + std::to_string(p.z) +
         ") d=(" + std::to_string(d.x) + "," + std::to_string(d.y) + "," + std::to_string(d.z) +
         ")";
}

}  // namespace

void expect_first_hit_matches(const DenseGrid& grid, DVec3 go, DVec3 gd, const CasterHit& r,
                              double delta, DdaTally* tally, Vec3 p, Vec3 d) {
  const DdaHit ref = grid.cast(go, gd, INFINITY);
  ++tally->rays;
  const int ex = r.x, ey = r.y, ez = r.z;
  if (r.hit) {
    ++tally->hits;
    ASSERT_TRUE(grid.occupied(ex, ey, ez))
        << "hit an empty voxel " << ex << "," << ey << "," << ez << "; " << describe(p, d);
  }
  const bool same = r.hit == ref.hit && (!r.hit || (ex == ref.x && ey == ref.y && ez == ref.z));
  if (!same) {
    const DdaHit robust = robust_first_hit(grid, go, gd, delta);
    if (r.hit) {
      double t0, t1;
      double te = 0;
      if (ref.hit && DenseGrid::voxel_span(go, gd, ex, ey, ez, &t0, &t1) &&
          std::fabs(t0 - ref.t_enter) <= 1e-6 * std::max(1.0, ref.t_enter)) {
        ++tally->exact_ties;  // the ray passes exactly through a shared edge/corner
      } else {
        ASSERT_TRUE(grown_span(go, gd, ex, ey, ez, delta, &te, &t1))
            << "cast hit voxel " << ex << "," << ey << "," << ez << " the ray does not come near; "
            << describe(p, d) << " ref " << ref.hit << " " << ref.x << "," << ref.y << "," << ref.z
            << " t " << ref.t_enter;
        ASSERT_TRUE(!robust.hit || te <= robust.t_enter + 1e-9 * (1 + te))
            << "cast skipped voxel " << robust.x << "," << robust.y << "," << robust.z << " (t "
            << robust.t_enter << ") and hit " << ex << "," << ey << "," << ez << " (t " << te
            << "); " << describe(p, d);
        ++tally->near_ties;
      }
    } else {
      ASSERT_FALSE(robust.hit) << "cast missed voxel " << robust.x << "," << robust.y << ","
                               << robust.z << " at t " << robust.t_enter << "; " << describe(p, d);
      ++tally->near_ties;
    }
  }
  if (r.hit) {
    // t: the entry of the hit voxel, up to the same float slack: between the
    // entry into the voxel grown by delta and the entry into the voxel shrunk
    // by delta (or anywhere in the grown span for a ray that only grazes it).
    // Near edges and corners the entry t is ill-conditioned, hence no fixed
    // relative tolerance.
    double g0, g1, s0, s1;
    ASSERT_TRUE(grown_span(go, gd, ex, ey, ez, delta, &g0, &g1));
    const double hi = grown_span(go, gd, ex, ey, ez, -delta, &s0, &s1) ? s0 : g1;
    const double slack = 1e-6 * (1 + g0);
    EXPECT_GE(r.t, g0 - slack) << describe(p, d);
    EXPECT_LE(r.t, hi + slack) << describe(p, d);
  }
}

void expect_any_hit_matches(const DenseGrid& grid, DVec3 go, DVec3 gd, double tmax, bool occluded,
                            const CasterHit& witness, double delta, DdaTally* tally, Vec3 p,
                            Vec3 d) {
  const DdaHit ref = grid.cast(go, gd, tmax);
  ++tally->rays;
  tally->hits += occluded;
  // DenseGrid::cast clips at tmax, so a hit starts at or before it.
  if (occluded == ref.hit) return;
  // The caster compares t with tmax in float: one relative rounding of each.
  const double t_slack = std::isfinite(tmax) ? 1e-6 * (1 + tmax) : 0.0;
  if (occluded) {
    ASSERT_TRUE(witness.hit) << "occluded, but the oracle finds nothing before tmax " << tmax
                             << " and the closest-hit cast no witness; " << describe(p, d);
    ASSERT_TRUE(grid.occupied(witness.x, witness.y, witness.z))
        << "occluded; the witness " << witness.x << "," << witness.y << "," << witness.z
        << " is empty; " << describe(p, d);
    double g0, g1;
    ASSERT_TRUE(grown_span(go, gd, witness.x, witness.y, witness.z, delta, &g0, &g1) &&
                g0 <= tmax + t_slack)
        << "occluded, but nothing is within reach before tmax " << tmax << " (witness " << witness.x
        << "," << witness.y << "," << witness.z << "); " << describe(p, d);
  } else {
    const DdaHit robust = robust_first_hit(grid, go, gd, delta);
    ASSERT_TRUE(!robust.hit || robust.t_enter >= tmax - t_slack)
        << "not occluded, but the ray crosses voxel " << robust.x << "," << robust.y << ","
        << robust.z << " at t " << robust.t_enter << " < tmax " << tmax << "; " << describe(p, d);
  }
  ++tally->near_ties;
}

Vec3 OctreeRayGen::sphere() {
  Vec3 v;
  do v = {uni(-1, 1), uni(-1, 1), uni(-1, 1)};
  while (dot(v, v) > 1 || dot(v, v) < 1e-4f);
  return normalize(v);
}

void OctreeRayGen::next(Vec3* p, Vec3* d) {
  const int kind = pick(20);
  if (kind < 7) {  // anywhere, inside and outside the cube
    *p = {uni(0.4f, 2.6f), uni(0.4f, 2.6f), uni(0.4f, 2.6f)};
    *d = sphere();
  } else if (kind < 10) {  // from outside, aimed into the cube
    const Vec3 target{uni(1, 2), uni(1, 2), uni(1, 2)};
    *p = Vec3{1.5f, 1.5f, 1.5f} + sphere() * uni(1.0f, 2.5f);
    *d = normalize(target - *p);
  } else if (kind < 12) {  // axis-aligned, zero components of either sign
    *p = {uni(0.4f, 2.6f), uni(0.4f, 2.6f), uni(0.4f, 2.6f)};
    const int a = pick(3);
    Vec3 v{signed_zero(), signed_zero(), signed_zero()};
    v[a] = pick(2) ? 1.f : -1.f;
    *d = v;
  } else if (kind < 14) {  // near-axis: tiny components around the 2^-23 epsilon
    *p = {uni(0.4f, 2.6f), uni(0.4f, 2.6f), uni(0.4f, 2.6f)};
    static const float tiny[] = {1e-2f, 1e-4f, 1e-6f, 1e-7f, 1e-9f, 0.f};
    Vec3 v;
    for (int a = 0; a < 3; ++a) v[a] = tiny[pick(6)] * (pick(2) ? 1.f : -1.f);
    v[pick(3)] = pick(2) ? 1.f : -1.f;
    *d = normalize(v);
  } else if (kind < 16) {  // in a grid plane: grazes voxel faces
    *p = {uni(0.6f, 2.4f), uni(0.6f, 2.4f), uni(0.6f, 2.4f)};
    const int a = pick(3);
    (*p)[a] = grid_line();
    Vec3 v = sphere();
    v[a] = 0.f;
    v = normalize(v);
    v[a] = signed_zero();
    *d = v;
  } else if (kind < 18) {  // along a grid edge line
    const int a = pick(3);
    *p = {grid_line(), grid_line(), grid_line()};
    (*p)[a] = uni(0.5f, 2.5f);
    Vec3 v{signed_zero(), signed_zero(), signed_zero()};
    v[a] = pick(2) ? 1.f : -1.f;
    *d = v;
  } else {  // through a grid corner or edge point (to float accuracy)
    Vec3 q{grid_line(), grid_line(), grid_line()};
    if (pick(2)) q[pick(3)] = uni(1, 2);
    *d = sphere();
    *p = q - *d * uni(0.f, 2.f);
  }
}

}  // namespace voxcast::testing
