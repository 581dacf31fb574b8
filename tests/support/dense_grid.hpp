#pragma once
// A minimal dense-grid VolumeQuery over the oracle's DenseVolume
// (volume_oracle.hpp), for the volume integrator's and the volume scene's
// tests.
#include <algorithm>
#include <cstdint>
#include <random>
#include <span>
#include <vector>

#include "support/volume_oracle.hpp"
#include "voxcast/structure.hpp"
#include "voxcast/volume_query.hpp"

namespace voxcast::testing {

/// Grid space = world space: cell (x, y, z) is [x, x+1] x [y, y+1] x [z, z+1].
/// As constant spans, each non-empty cell the ray crosses is one span; as one
/// brick span, the ray's chord through the grid box is one span whose
/// samples are the containing cell's values (nearest, piecewise constant).
/// With sampled_cells, the per-cell spans are marked for sampling instead of
/// constant (sample_span reads the cell at each point: exact, as a piece of
/// one cell is constant).
class DenseGridQuery final : public Structure, public VolumeQuery {
 public:
  DenseGridQuery(const DenseVolume& v, bool as_brick, float brick_voxel = 1.f,
                 bool sampled_cells = false)
      : v_(v), brick_(as_brick), voxel_(brick_voxel), sampled_cells_(sampled_cells) {}
  std::string name() const override { return "dense-grid"; }
  Aabb bounds() const override {
    return {{0, 0, 0}, {float(v_.nx()), float(v_.ny()), float(v_.nz())}};
  }
  const VolumeQuery* volume() const override { return this; }

  int march(const Ray& ray, float t_begin, const LodFootprint&, TraceContext&,
            std::span<VolumeSpan> out) const override {
    float t0 = std::max(0.f, t_begin), t1 = ray.tmax;
    const Aabb b = bounds();
    for (int a = 0; a < 3; ++a) {
      if (ray.dir[a] == 0.f) {
        if (!(ray.origin[a] >= b.lo[a] && ray.origin[a] <= b.hi[a])) return 0;
        continue;
      }
      float ta = (b.lo[a] - ray.origin[a]) / ray.dir[a],
            tb = (b.hi[a] - ray.origin[a]) / ray.dir[a];
      if (ta > tb) std::swap(ta, tb);
      t0 = std::max(t0, ta), t1 = std::min(t1, tb);
    }
    if (!(t1 > t0)) return 0;
    int n = 0;
    if (brick_) {
      VolumeSpan s;
      s.t0 = t0, s.t1 = t1, s.voxel_size = voxel_;
      out[0] = s;
      return 1;
    }
    // Cell boundaries crossed in (t0, t1), in order.
    std::vector<float> cuts = {t0, t1};
    for (int a = 0; a < 3; ++a)
      if (ray.dir[a] != 0.f)
        for (int k = int(std::floor(b.lo[a])); k <= int(b.hi[a]); ++k) {
          const float t = (float(k) - ray.origin[a]) / ray.dir[a];
          if (t > t0 && t < t1) cuts.push_back(t);
        }
    std::sort(cuts.begin(), cuts.end());
    for (size_t i = 0; i + 1 < cuts.size() && n < int(out.size()); ++i) {
      if (!(cuts[i + 1] > cuts[i])) continue;
      const voxcast::VolumeSample c = cell(ray.origin + ray.dir * (0.5f * (cuts[i] + cuts[i + 1])));
      if (c.density == 0.f) continue;
      VolumeSpan s;
      s.t0 = cuts[i], s.t1 = cuts[i + 1], s.voxel_size = 1.f;
      s.constant = !sampled_cells_, s.value = sampled_cells_ ? voxcast::VolumeSample{} : c;
      out[size_t(n++)] = s;
    }
    return n;
  }
  voxcast::VolumeSample sample(Vec3 p, float, TraceContext&, const VolumeSpan*) const override {
    return cell(p);
  }

 private:
  voxcast::VolumeSample cell(Vec3 p) const {
    const VolumeCell* c = v_.cell_at({p.x, p.y, p.z});
    if (c == nullptr) return {};
    return {float(c->sigma),
            Color{float(c->color[0]), float(c->color[1]), float(c->color[2]), 1.f}};
  }
  const DenseVolume& v_;
  bool brick_;
  float voxel_;
  bool sampled_cells_;
};

/// A random n^3 grid: each cell non-empty with probability `fill`, its
/// extinction uniform in [0, max_sigma], its color uniform.
inline DenseVolume random_volume(uint64_t seed, int n = 8, double fill = 0.6,
                                 double max_sigma = 1.5) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> U(0, 1);
  DenseVolume v(n, n, n);
  for (int z = 0; z < n; ++z)
    for (int y = 0; y < n; ++y)
      for (int x = 0; x < n; ++x)
        if (U(rng) < fill) v.at(x, y, z) = {max_sigma * U(rng), {U(rng), U(rng), U(rng)}};
  return v;
}

}  // namespace voxcast::testing
