// Recursive node graphs (gigavoxels.hpp RecursiveVolume, §3.7-3.8).
#include <algorithm>
#include <cmath>
#include <limits>

#include "unit_cube.hpp"
#include "voxcast/error.hpp"
#include "voxcast/gigavoxels.hpp"

namespace voxcast::giga {

RecursiveVolume::RecursiveVolume(std::vector<GraphNode> nodes, int max_depth, float density,
                                 Color color, Vec3 origin, float size)
    : nodes_(std::move(nodes)),
      max_depth_(max_depth),
      density_(density),
      color_(color),
      origin_(origin),
      size_(size) {
  if (nodes_.empty()) throw Error("recursive volume: the graph has no node");
  if (max_depth_ < 1 || max_depth_ > kMaxRecursionDepth)
    throw Error("recursive volume: the depth must be in 1.." + std::to_string(kMaxRecursionDepth));
  if (!(density_ >= 0.f) || !std::isfinite(density_) || !(size_ > 0.f) || !std::isfinite(size_) ||
      !is_finite(origin_))
    throw Error("recursive volume: density >= 0, a positive size and a finite origin");
  for (const GraphNode& n : nodes_)
    for (int32_t c : n.child)
      if (c < kGraphSolid || c >= int32_t(nodes_.size()))
        throw Error("recursive volume: a child names no node");
  // Mean density (fraction of solid) of every node cut at each remaining
  // depth: at depth max_depth a node reference counts as solid (the
  // recursion's bound), above it the mean of its 27 children.
  coverage_.assign(size_t(max_depth_ + 1) * nodes_.size(), 0.f);
  for (size_t n = 0; n < nodes_.size(); ++n) coverage_[n] = 1.f;  // 0 levels left: solid
  for (int left = 1; left <= max_depth_; ++left)
    for (size_t n = 0; n < nodes_.size(); ++n) {
      double sum = 0;
      for (int32_t c : nodes_[n].child)
        sum += c == kGraphEmpty   ? 0.0
               : c == kGraphSolid ? 1.0
                                  : double(coverage_[size_t(left - 1) * nodes_.size() + size_t(c)]);
      coverage_[size_t(left) * nodes_.size() + n] = float(sum / 27.0);
    }
}

RecursiveVolume RecursiveVolume::menger(int max_depth, float density, Color color, Vec3 origin,
                                        float size) {
  // One node whose 20 corner and edge cells are the node itself and whose
  // 7 middle cells (center and face centers: two or more middle
  // coordinates) are empty: the sponge as a graph of one node.
  GraphNode n;
  for (int z = 0; z < 3; ++z)
    for (int y = 0; y < 3; ++y)
      for (int x = 0; x < 3; ++x)
        n.child[size_t(x + 3 * (y + 3 * z))] =
            (x == 1) + (y == 1) + (z == 1) >= 2 ? kGraphEmpty : 0;
  return RecursiveVolume({n}, max_depth, density, color, origin, size);
}

Aabb RecursiveVolume::bounds() const {
  return {origin_, origin_ + Vec3{size_, size_, size_}};
}

float RecursiveVolume::coverage(int32_t node, int depth) const {
  return coverage_[size_t(max_depth_ - depth) * nodes_.size() + size_t(node)];
}

int RecursiveVolume::march(const Ray& ray, float t_begin, const LodFootprint& lod,
                           TraceContext& ctx, std::span<VolumeSpan> out) const {
  (void)ctx;
  if (out.empty()) return 0;
  const float inv = 1.f / size_;
  const Vec3 o = (ray.origin - origin_) * inv, d = ray.dir * inv;
  float t0 = std::max(0.f, t_begin), t1 = ray.tmax;
  if (!detail::clip_unit_cube(o, d, &t0, &t1)) return 0;
  const float finest = size_ * std::pow(3.f, -float(max_depth_));
  const float eps =
      std::max(1e-3f * finest, 4.f * std::numeric_limits<float>::epsilon() * std::fabs(t1));
  int n = 0;
  // Descent by point location in the N^3-tree (N = 3): child int(3x).
  // A cell is the child's whole subtree; the walk stops at a leaf (empty,
  // solid), at the depth bound (the recursion counts as solid there), or
  // where the cell is no larger than the pixel cone (the subtree's mean).
  float lo[3], side = 1.f, value = 0.f;
  int depth = 0;
  auto locate = [&](float, const float* x, float foot) {
    int32_t node = 0;
    depth = 0, side = 1.f;
    lo[0] = lo[1] = lo[2] = 0.f;
    for (;;) {
      const float child_side = side / 3.f;
      uint32_t c[3];
      for (int a = 0; a < 3; ++a) {
        const float u = (x[a] - lo[a]) / child_side;
        c[a] = uint32_t(std::clamp(int(u), 0, 2));
        lo[a] += float(c[a]) * child_side;
      }
      side = child_side, ++depth;
      const int32_t child = nodes_[size_t(node)].child[c[0] + 3 * (c[1] + 3 * c[2])];
      if (child == kGraphEmpty || child == kGraphSolid) {
        value = child == kGraphSolid ? 1.f : 0.f;
        break;
      }
      if (depth == max_depth_ || side * size_ <= foot) {
        value = coverage(child, depth);
        break;
      }
      node = child;
    }
    float te = t1;
    for (int a = 0; a < 3; ++a) {
      if (d[a] > 0.f) te = std::min(te, (lo[a] + side - o[a]) / d[a]);
      if (d[a] < 0.f) te = std::min(te, (lo[a] - o[a]) / d[a]);
    }
    return te;
  };
  auto emit = [&](float t, float te) {
    if (value > 0.f) {
      VolumeSpan s;
      s.t0 = t, s.t1 = te, s.level = depth, s.voxel_size = side * size_, s.constant = true;
      s.value = {density_ * value, color_};
      out[size_t(n++)] = s;
    }
    return n < int(out.size());
  };
  detail::walk_cells(o, d, t0, t1, eps, lod.size_at_origin, lod.size_per_t, locate, emit);
  return n;
}

VolumeSample RecursiveVolume::sample(Vec3 p, float level, TraceContext& ctx,
                                     const VolumeSpan* span) const {
  (void)level, (void)ctx;
  if (span != nullptr && span->constant) return span->value;
  // The finest answer at p (spans are constant: the integrator never asks).
  Vec3 q = (p - origin_) * (1.f / size_);
  for (int a = 0; a < 3; ++a)
    if (!(q[a] >= 0.f && q[a] <= 1.f)) return {};
  int32_t node = 0;
  for (int depth = 1;; ++depth) {
    uint32_t c[3];
    for (int a = 0; a < 3; ++a) {
      c[a] = uint32_t(std::clamp(int(q[a] * 3.f), 0, 2));
      q[a] = q[a] * 3.f - float(c[a]);
    }
    const int32_t child = nodes_[size_t(node)].child[c[0] + 3 * (c[1] + 3 * c[2])];
    if (child == kGraphEmpty) return {};
    if (child == kGraphSolid || depth == max_depth_) return {density_, color_};
    node = child;
  }
}

}  // namespace voxcast::giga
