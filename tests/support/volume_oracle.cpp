// Dense-grid emission–absorption oracle (volume_oracle.hpp). Written for
// clarity, not speed: double precision, no shortcuts shared with any caster.
#include "support/volume_oracle.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace voxcast::testing {
namespace {

double length(DVec3 d) {
  return std::sqrt(d.x * d.x + d.y * d.y + d.z * d.z);
}

DVec3 point(DVec3 o, DVec3 d, double t) {
  return {o.x + d.x * t, o.y + d.y * t, o.z + d.z * t};
}

// One piece of constant σ, c over a length `len`: the closed form.
void composite(const VolumeCell* cell, double len, VolumeSample* s) {
  if (cell == nullptr || len <= 0 || cell->sigma <= 0) return;
  const double a = std::exp(-cell->sigma * len);
  for (int k = 0; k < 3; ++k)
    s->color[size_t(k)] += s->transmittance * (1 - a) * cell->color[size_t(k)];
  s->transmittance *= a;
}

}  // namespace

DenseVolume::DenseVolume(int nx, int ny, int nz) : n_{nx, ny, nz} {
  if (nx <= 0 || ny <= 0 || nz <= 0) throw std::invalid_argument("DenseVolume: empty grid");
  cells_.resize(size_t(nx) * size_t(ny) * size_t(nz));
}

VolumeCell& DenseVolume::at(int x, int y, int z) {
  return cells_[(size_t(z) * size_t(n_[1]) + size_t(y)) * size_t(n_[0]) + size_t(x)];
}
const VolumeCell& DenseVolume::at(int x, int y, int z) const {
  return cells_[(size_t(z) * size_t(n_[1]) + size_t(y)) * size_t(n_[0]) + size_t(x)];
}

const VolumeCell* DenseVolume::cell_at(DVec3 p) const {
  const double c[3] = {std::floor(p.x), std::floor(p.y), std::floor(p.z)};
  for (int a = 0; a < 3; ++a)
    if (!(c[a] >= 0 && c[a] < n_[a])) return nullptr;
  return &at(int(c[0]), int(c[1]), int(c[2]));
}

VolumeSample DenseVolume::integrate_exact(DVec3 o, DVec3 d, double t0, double t1) const {
  VolumeSample s;
  const double speed = length(d);
  if (!(t1 > t0) || speed == 0) return s;
  // Every t where the ray crosses an integer plane inside the grid's range,
  // plus the segment ends; between two consecutive ones the ray stays in one
  // cell (or outside), identified at the piece's midpoint.
  std::vector<double> cuts = {t0, t1};
  for (int a = 0; a < 3; ++a) {
    if (d[a] == 0) continue;
    for (int k = 0; k <= n_[a]; ++k) {
      const double t = (double(k) - o[a]) / d[a];
      if (t > t0 && t < t1) cuts.push_back(t);
    }
  }
  std::sort(cuts.begin(), cuts.end());
  for (size_t i = 0; i + 1 < cuts.size(); ++i) {
    const double a = cuts[i], b = cuts[i + 1];
    if (!(b > a)) continue;
    composite(cell_at(point(o, d, 0.5 * (a + b))), (b - a) * speed, &s);
  }
  return s;
}

VolumeSample DenseVolume::integrate_fixed_step(DVec3 o, DVec3 d, double t0, double t1,
                                               double dt) const {
  VolumeSample s;
  const double speed = length(d);
  if (!(t1 > t0) || speed == 0 || !(dt > 0)) return s;
  const double steps = std::ceil((t1 - t0) / dt);
  for (double i = 0; i < steps; ++i) {
    const double a = t0 + i * dt, b = std::min(t1, a + dt);
    composite(cell_at(point(o, d, 0.5 * (a + b))), (b - a) * speed, &s);
  }
  return s;
}

}  // namespace voxcast::testing
