// Contours (esvo §5.2-5.3) and their construction (§7.2), plus the
// variable-depth refinement decisions of §7.1/§7.3.
//
// Construction is greedy and top-down, as in §7.2. For every voxel V:
//   1. the surface inside V = the mesh triangles that overlap V's cube,
//      clipped to it (Sutherland-Hodgman in double); the triangle index list
//      is filtered from the parent's list, so the recursion carries one list
//      per level of the current path (memory-bounded);
//   2. the polyhedron P = V's cube ∩ the slabs of its nearest kMaxAncestors
//      ancestors that have a contour (using fewer ancestors only makes P
//      larger, which is conservative for both decisions below; the paper
//      also keeps only "the most important ancestor contours", §7.1);
//   3. if every vertex of P is within the contour tolerance of the surface,
//      V gets no contour (§7.2 "omitting unnecessary contours");
//   4. otherwise candidate directions -- the normals of V's triangles,
//      their area-weighted mean, and the in-plane perpendiculars of mesh
//      boundary edges ("normals of the original surface as well as
//      perpendiculars of surface boundaries") -- are quantized to the 6-bit
//      contour normal first, and for each one the overestimation h - h' of
//      Figure 22 is measured with the QUANTIZED slab: h = extent of P along
//      the direction, h' = extent of P ∩ slab. The best one becomes V's
//      contour if it removes at least kMinGain of V's side.
// No holes (§7.2 "as long as we ensure that the original surface is fully
// enclosed by each contour"): the slab encloses every vertex of V's clipped
// surface, hence its convex hull; position and thickness are rounded so that
// the decoded slab strictly contains the measured range plus a margin of
// 2^-21 octree units (a few float ulps of the ray caster) + 1e-6 of V's side.
// The final shape (§5.3) of a voxel is cube ∩ every ancestor slab ∩ its own,
// and every one of them contains the surface inside the voxel.
//
// Variable depth (§7.1): a voxel above max_level is subdivided when
// REFINE-GEOMETRY holds (some vertex of its final shape is farther than
// geometry_error from the surface; checked on the vertices only, as §7.2
// suggests) or REFINE-ATTRIBUTES (§7.3: the attributes the voxel decodes to
// are farther than the tolerance from the original attributes of some
// full-depth voxel below it; attributes_exceed() compares every one of them,
// exactly). Otherwise its subtree is dropped and it becomes a leaf, keeping
// its box-filtered attributes from phase 1. The planner tests the raw 8-bit
// encoding, which is what a raw build decodes to; with compressed attributes
// (§5.5) the decoded value also depends on the block the leaf shares with
// its sibling pair, known only after the layout, so the builder tests the
// decoded leaves afterwards and ContourPlanner::refine() subdivides the ones
// out of tolerance ("attribute quantization and compression is performed
// before the test", §7.3).
#include "esvo/contours.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstring>
#include <numbers>
#include <numeric>
#include <stdexcept>
#include <unordered_map>

#include "esvo/layout_internal.hpp"
#include "voxcast/error.hpp"
#include "voxcast/math.hpp"

namespace voxcast::esvo {

// ---- Figure 4 bit fields (layout and fixed point: esvo.hpp, ContourValue) ----

uint32_t encode_contour(const ContourValue& c) {
  return layout::ContourThickness::put(c.thickness) |
         layout::ContourPosition::put_signed(c.position) | layout::ContourNx::put_signed(c.nx) |
         layout::ContourNy::put_signed(c.ny) | layout::ContourNz::put_signed(c.nz);
}

ContourValue decode_contour(uint32_t value) {
  // get_signed() is the Appendix A decode: shift the field to the top of an
  // int, then an arithmetic shift back down sign-extends it exactly (two's
  // complement, C++20).
  ContourValue c;
  c.thickness = layout::ContourThickness::get(value);
  c.position = layout::ContourPosition::get_signed(value);
  c.nx = layout::ContourNx::get_signed(value);
  c.ny = layout::ContourNy::get_signed(value);
  c.nz = layout::ContourNz::get_signed(value);
  return c;
}

bool EsvoOctree::has_contours() const {
  // Bounds-checked like attribute_format(): block 0's info section table.
  const uint64_t size = words.size();
  if (size < 2) return false;
  const int64_t info = int32_t(words[0]);
  if (info <= 0 || uint64_t(info) + detail::kInfoAttachTable > size) return false;
  const uint64_t count = words[size_t(info) + detail::kInfoAttachCountWord];
  for (uint64_t a = 0; a < count && uint64_t(info) + detail::kInfoAttachTable + 2 * a < size; ++a)
    if (words[size_t(uint64_t(info) + detail::kInfoAttachTable + 2 * a)] == kAttachContours)
      return true;
  return false;
}

namespace detail {

Slab contour_slab(uint32_t value, const double lo[3], double side) {
  const ContourValue c = decode_contour(value);
  Slab s;
  s.n[0] = c.nx, s.n[1] = c.ny, s.n[2] = c.nz;
  const double center =
      s.n[0] * (lo[0] + 0.5 * side) + s.n[1] * (lo[1] + 0.5 * side) + s.n[2] * (lo[2] + 0.5 * side);
  const double mid = center + 0.75 * side * c.position, half = 0.375 * side * c.thickness;
  s.lo = mid - half;
  s.hi = mid + half;
  return s;
}

namespace {

// Grid-unit geometry in double: voxcast::Vec3d (include/voxcast/math.hpp).

constexpr int kMaxAncestors = 6;       // ancestor slabs used for the polyhedron P
constexpr size_t kMaxCandidates = 24;  // triangle normals tried per voxel (§7.2 "a small subset")
constexpr double kMinGain = 0.02;      // a contour must cut >= 2% of the side off P
constexpr double kDefaultContourTolerance = 0.25;  // finest voxels (BuildOptions::geometry_error)

struct GridSlab {  // n . x in [lo, hi], x in grid units
  Vec3d n;
  double lo, hi;
};

/// Squared distance from p to triangle abc (Ericson, Real-Time Collision
/// Detection, 5.1.5: closest point by Voronoi regions).
double dist2_point_triangle(Vec3d p, Vec3d a, Vec3d b, Vec3d c) {
  const Vec3d ab = b - a, ac = c - a, ap = p - a;
  const double d1 = dot(ab, ap), d2 = dot(ac, ap);
  auto d2of = [&](Vec3d q) { return dot(p - q, p - q); };
  if (d1 <= 0 && d2 <= 0) return d2of(a);
  const Vec3d bp = p - b;
  const double d3 = dot(ab, bp), d4 = dot(ac, bp);
  if (d3 >= 0 && d4 <= d3) return d2of(b);
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return d2of(a + ab * (d1 / (d1 - d3)));
  const Vec3d cp = p - c;
  const double d5 = dot(ab, cp), d6 = dot(ac, cp);
  if (d6 >= 0 && d5 <= d6) return d2of(c);
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return d2of(a + ac * (d2 / (d2 - d6)));
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0)
    return d2of(b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6))));
  const double denom = 1.0 / (va + vb + vc);
  return d2of(a + ab * (vb * denom) + ac * (vc * denom));
}

/// Appends to `out` the part of polygon in[0..k) with n . x <= off
/// (Sutherland-Hodgman; points on the plane are kept, so touching geometry
/// survives). A polygon with no vertex beyond the plane is copied as is: that
/// is exactly what the general loop produces (no crossing edges), found
/// without the per-edge work -- most clips in the recursion are such no-ops.
template <class Out>
void clip_append(const Vec3d* in, size_t k, Vec3d n, double off, Out& out) {
  bool any_out = false;
  for (size_t i = 0; i < k; ++i) any_out |= dot(n, in[i]) - off > 0;
  if (!any_out) {
    out.insert(out.end(), in, in + k);
    return;
  }
  for (size_t i = 0; i < k; ++i) {
    const Vec3d a = in[i], b = in[i + 1 == k ? 0 : i + 1];
    const double da = dot(n, a) - off, db = dot(n, b) - off;
    if (da <= 0) out.push_back(a);
    if ((da < 0 && db > 0) || (da > 0 && db < 0)) out.push_back(a + (b - a) * (da / (da - db)));
  }
}

/// Convex polyhedron as a list of convex faces; only its vertices are used.
/// Faces are stored flat (face f = v_[end_[f-1], end_[f])) and the buffers
/// are reused: one Polyhedron per thread is reset for every voxel, so the
/// recursion allocates only while the buffers grow.
class Polyhedron {
 public:
  void reset(Vec3d lo, double s) {
    const Vec3d c[8] = {lo,
                        lo + Vec3d{s, 0, 0},
                        lo + Vec3d{0, s, 0},
                        lo + Vec3d{s, s, 0},
                        lo + Vec3d{0, 0, s},
                        lo + Vec3d{s, 0, s},
                        lo + Vec3d{0, s, s},
                        lo + Vec3d{s, s, s}};
    v_ = {c[0], c[2], c[3], c[1], c[4], c[5], c[7], c[6], c[0], c[1], c[5], c[4],
          c[2], c[6], c[7], c[3], c[0], c[4], c[6], c[2], c[1], c[3], c[7], c[5]};
    end_ = {4, 8, 12, 16, 20, 24};
    center_ = lo + Vec3d{0.5 * s, 0.5 * s, 0.5 * s};
    side_ = s;
  }
  /// Keeps n . x <= off; the cut adds a cap face.
  void clip(Vec3d n, double off) {
    const double tol = 1e-12 * (std::fabs(off) + 1);
    // Plane beyond the whole cube (most ancestor slabs of a small voxel,
    // §7.2, are far thicker than it): every vertex of P lies in the cube
    // (new vertices interpolate two old ones) up to rounding errors far
    // below the 1e-6 margin, so every distance is < -tol and the loop
    // below would take its fast exit; decided without the per-vertex loop.
    // (A bounding box of P, tighter, costs more to maintain than it saves.)
    const double n1 = std::fabs(n.x) + std::fabs(n.y) + std::fabs(n.z);
    if (dot(n, center_) + 0.5 * side_ * n1 - off <
        -(tol + 1e-6 * n1 * (side_ + 1) + 1e-9 * (std::fabs(off) + 1)))
      return;
    // The signed distance of every face vertex, computed once: the loop
    // below is clip_append() per face with these values instead of
    // recomputed ones (the same dot() expression, so the same bits; the
    // build is -ffp-contract=off) -- a vertex is shared by three or more
    // faces.
    d_.resize(v_.size());
    // Fast exit, exact: with no vertex beyond the plane every face is kept
    // as is, and the cap face is only added when >= 3 (face) vertices lie
    // on the plane -- the general path below would produce the same faces.
    bool any_out = false;
    int on = 0;
    for (size_t i = 0; i < v_.size(); ++i) {
      const double d = dot(n, v_[i]) - off;
      d_[i] = d;
      any_out |= d > 0;
      on += std::fabs(d) <= tol;
    }
    if (!any_out && on < 3) return;

    nv_.clear();
    nend_.clear();
    cap_.clear();
    size_t b = 0;
    for (const uint32_t e : end_) {
      // Sutherland-Hodgman as in clip_append(); kept points within tol of
      // the plane also go to the cap, in output order.
      const size_t s = nv_.size(), k = e - b;
      for (size_t i = 0; i < k; ++i) {
        const size_t ia = b + i, ib = b + (i + 1 == k ? 0 : i + 1);
        const double da = d_[ia], db = d_[ib];
        if (da <= 0) {
          nv_.push_back(v_[ia]);
          if (std::fabs(da) <= tol) cap_.push_back(v_[ia]);
        }
        if ((da < 0 && db > 0) || (da > 0 && db < 0)) {
          const Vec3d a = v_[ia], x = a + (v_[ib] - a) * (da / (da - db));
          nv_.push_back(x);
          if (std::fabs(dot(n, x) - off) <= tol) cap_.push_back(x);
        }
      }
      b = e;
      if (nv_.size() - s >= 3)
        nend_.push_back(uint32_t(nv_.size()));
      else
        nv_.resize(s);
    }
    if (cap_.size() >= 3) {
      // Order the cap points by angle around their centroid in the plane.
      Vec3d m{0, 0, 0};
      for (const Vec3d& p : cap_) m = m + p;
      m = m * (1.0 / double(cap_.size()));
      const Vec3d a = std::fabs(n.x) < 0.9 * length(n) ? Vec3d{1, 0, 0} : Vec3d{0, 1, 0};
      const Vec3d u = cross(n, a), v = cross(n, u);
      // The angle is computed once per point instead of twice per
      // comparison; std::sort sees the same comparison results, so the
      // permutation (ties included) is the one of the per-comparison form.
      // A point reached from several faces (a vertex on the plane, or an
      // intersection computed to the same bits from both faces of an edge)
      // reuses the angle of its first copy: same point, same key.
      keyed_.clear();
      for (const Vec3d& p : cap_) {
        double key = 0;
        bool found = false;
        for (const auto& kp : keyed_)
          if (kp.second.x == p.x && kp.second.y == p.y && kp.second.z == p.z) {
            key = kp.first, found = true;
            break;
          }
        if (!found) key = std::atan2(dot(p - m, v), dot(p - m, u));
        keyed_.push_back({key, p});
      }
      std::sort(keyed_.begin(), keyed_.end(),
                [](const std::pair<double, Vec3d>& p, const std::pair<double, Vec3d>& q) {
                  return p.first < q.first;
                });
      for (const auto& kp : keyed_) nv_.push_back(kp.second);
      nend_.push_back(uint32_t(nv_.size()));
    }
    v_.swap(nv_);
    end_.swap(nend_);
  }
  void clip(const GridSlab& s) {
    clip(s.n, s.hi);
    clip(s.n * -1.0, -s.lo);
  }
  /// The distinct vertices (into `v`, reused), in first-occurrence order.
  /// Exact duplicates (shared by adjacent faces) are dropped with a small
  /// open-addressing table on the coordinates: its users (within(), the
  /// range minima/maxima of ranges()) only depend on the set of points, so
  /// this gives the same results as sorting and std::unique did, without
  /// the sort (a quarter of the planning time).
  void vertices(std::vector<Vec3d>& v) const {
    v.clear();
    size_t cap = 64;
    while (cap < 2 * v_.size()) cap *= 2;
    table_.assign(cap, -1);
    for (const Vec3d& p : v_) {
      // +0.0 maps -0 to +0, which == treats as equal.
      const uint64_t hx = std::bit_cast<uint64_t>(p.x + 0.0),
                     hy = std::bit_cast<uint64_t>(p.y + 0.0),
                     hz = std::bit_cast<uint64_t>(p.z + 0.0);
      uint64_t h = (hx * 0x9E3779B97F4A7C15ull) ^ (hy * 0xC2B2AE3D27D4EB4Full) ^
                   (hz * 0x165667B19E3779F9ull);
      h ^= h >> 29;
      for (size_t i = size_t(h) & (cap - 1);; i = (i + 1) & (cap - 1)) {
        const int32_t j = table_[i];
        if (j < 0) {
          table_[i] = int32_t(v.size());
          v.push_back(p);
          break;
        }
        const Vec3d q = v[size_t(j)];
        if (q.x == p.x && q.y == p.y && q.z == p.z) break;
      }
    }
  }

 private:
  std::vector<Vec3d> v_, nv_, cap_;
  std::vector<double> d_;  // clip(): signed distance per entry of v_
  Vec3d center_;           // the cube of reset()
  double side_ = 0;
  std::vector<uint32_t> end_, nend_;
  std::vector<std::pair<double, Vec3d>> keyed_;
  mutable std::vector<int32_t> table_;  // vertices(): hash table of indices into v
};

struct Candidate {
  int n[3];
  int pos;
  unsigned thick;
  double gain;  // h - h' in grid units (Figure 22)
  GridSlab slab;
};

}  // namespace

/// The mesh as the planner reads it, built once per build: the cell-by-cell
/// build runs one planner per cell and must not redo the O(T) parts (the
/// boundary-edge hash map) per cell.
struct PlannerMesh {
  std::vector<std::array<Vec3d, 3>> tri;  // triangles in grid units
  std::vector<Vec3d> normal;              // unit normals (0 for degenerate triangles)
  std::vector<Vec3d> lo, hi;              // bounding boxes (both filters test them per voxel)
  std::vector<uint8_t> boundary;          // bit k: edge k -> k+1 is a mesh boundary edge
};

/// What child() hands down to a refined voxel's subtree (its node() call):
/// the triangles overlapping it and the ancestor slabs including its own.
struct SubtreeSeed {
  int depth = 0;
  uint32_t x = 0, y = 0, z = 0;  // cube at its level
  std::vector<uint32_t> tris;
  std::vector<GridSlab> slabs;
};

namespace {

/// Mesh boundary edges (one adjacent triangle, matched by position so split
/// vertices do not count as boundaries): bit k of boundary[t] = edge k -> k+1.
void find_boundary_edges(const Mesh& mesh, std::vector<uint8_t>& boundary) {
  struct Key {
    float a[6];
    bool operator==(const Key& o) const { return std::memcmp(a, o.a, sizeof a) == 0; }
  };
  struct Hash {
    size_t operator()(const Key& k) const {
      uint64_t h = 1469598103934665603ull;
      for (float f : k.a) h = (h ^ std::bit_cast<uint32_t>(f)) * 1099511628211ull;
      return size_t(h);
    }
  };
  std::unordered_map<Key, uint32_t, Hash> count;
  auto key = [&](size_t t, int k) {
    Vec3 p = mesh.positions[mesh.indices[3 * t + size_t(k)]];
    Vec3 q = mesh.positions[mesh.indices[3 * t + size_t((k + 1) % 3)]];
    if (std::tie(q.x, q.y, q.z) < std::tie(p.x, p.y, p.z)) std::swap(p, q);
    return Key{{p.x + 0.f, p.y + 0.f, p.z + 0.f, q.x + 0.f, q.y + 0.f, q.z + 0.f}};  // +0: -0 -> 0
  };
  const size_t T = mesh.triangle_count();
  count.reserve(3 * T);
  for (size_t t = 0; t < T; ++t)
    for (int k = 0; k < 3; ++k) ++count[key(t, k)];
  for (size_t t = 0; t < T; ++t)
    for (int k = 0; k < 3; ++k)
      if (count[key(t, k)] == 1) boundary[t] |= uint8_t(1u << k);
}

class Planner {
 public:
  /// `stop_depth` (cell-by-cell top plan): refined voxels at that depth are
  /// not descended into; their seeds are kept for the cells' planners.
  /// `attr_flags` [depth][node]: precomputed REFINE-ATTRIBUTES answers (the
  /// full-depth voxels are not in `t`), used instead of attributes_exceed().
  Planner(const TreeView& t, std::shared_ptr<const PlannerMesh> m, const BuildOptions& o,
          int stop_depth = 1 << 30, const std::vector<std::vector<uint8_t>>* attr_flags = nullptr)
      : t_(t),
        o_(o),
        L_(t.levels),
        Lmax_(o.max_level > 0 ? std::min(o.max_level, t.levels) : t.levels),
        mesh_(std::move(m)),
        tri_(mesh_->tri),
        normal_(mesh_->normal),
        tlo_(mesh_->lo),
        thi_(mesh_->hi),
        boundary_(mesh_->boundary),
        stop_depth_(stop_depth),
        attr_flags_(attr_flags) {
    if (stop_depth_ <= L_) seeds_.resize(t.count[size_t(stop_depth_)]);
    contour_tol_ = o.geometry_error > 0 ? o.geometry_error : kDefaultContourTolerance;
    variable_ = o.geometry_error > 0 || o.color_error >= 0 || o.normal_error >= 0;
    plan_.contour.resize(size_t(L_) + 1);
    plan_.leaf.resize(size_t(L_));
    for (int d = 1; d <= L_; ++d) plan_.contour[size_t(d)].assign(t.count[size_t(d)], 0);
    for (int d = 1; d < L_; ++d) plan_.leaf[size_t(d)].assign(t.count[size_t(d)], 0);
    seen_.resize(size_t(L_) + 1);
    for (int d = 1; d <= L_; ++d) seen_[size_t(d)].assign(t.count[size_t(d)], 0);
  }

  /// Plans every voxel not planned yet and re-plans the paths marked by
  /// refine(). A voxel's contour and decision depend only on its ancestors'
  /// (the triangles and slabs handed down) and on the forced set, so
  /// re-planning a path reproduces it and only the subtrees below newly
  /// forced voxels change.
  const ContourPlan& run() {
    if (start_ != nullptr) {
      // A cell's subtree: node (start depth, 0) is the seed's voxel.
      const SubtreeSeed& s = *start_;
      par_depth_ = s.depth + 4;
      node(s.depth, 0, s.x, s.y, s.z, s.tris, s.slabs);
    } else {
      std::vector<uint32_t> all(tri_.size());
      std::iota(all.begin(), all.end(), 0u);
      node(0, 0, 0, 0, 0, all, {});
    }
    for (const auto& [d, i] : redo_list_) redo_[size_t(d)][i] = 0;
    redo_list_.clear();
    return plan_;
  }

  /// Forces the planned leaf (depth, index) to be subdivided on the next
  /// run() and marks the path to it for re-planning.
  void force(int depth, uint32_t index) {
    if (forced_.empty()) {
      forced_.resize(size_t(L_));
      redo_.resize(size_t(L_));
      for (int d = 1; d < L_; ++d) {
        forced_[size_t(d)].assign(t_.count[size_t(d)], 0);
        redo_[size_t(d)].assign(t_.count[size_t(d)], 0);
      }
    }
    if (depth < 1 || depth >= Lmax_) throw std::logic_error("esvo planner: cannot refine");
    forced_[size_t(depth)][index] = 1;
    // Up the tree: the parent of node i at depth d is the last node of
    // depth d - 1 whose first child is <= i (first_child increases).
    // A cell's planner stops below its seed's voxel, which run() always visits.
    const int top = start_ != nullptr ? start_->depth : 0;
    if (depth <= top) throw std::logic_error("esvo planner: cannot refine above the seed");
    for (int d = depth; d > top && !redo_[size_t(d)][index]; --d) {
      redo_[size_t(d)][index] = 1;
      redo_list_.push_back({d, index});
      const uint32_t* fc = t_.first_child[size_t(d) - 1];
      index = uint32_t(std::upper_bound(fc, fc + t_.count[size_t(d) - 1], index) - fc - 1);
    }
  }

 private:
  /// True if every point is within `tol` (grid units) of some triangle of `tris`.
  bool within(const std::vector<Vec3d>& pts, const std::vector<uint32_t>& tris, double tol) const {
    const double tol2 = tol * tol;
    for (const Vec3d& p : pts) {
      bool ok = false;
      for (uint32_t t : tris) {
        const auto& v = tri_[t];
        // Cheap reject by the triangle's bounding box (precomputed).
        const Vec3d bl = tlo_[t], bh = thi_[t];
        const double bx = std::max(bl.x - p.x, p.x - bh.x);
        const double by = std::max(bl.y - p.y, p.y - bh.y);
        const double bz = std::max(bl.z - p.z, p.z - bh.z);
        if (bx > tol || by > tol || bz > tol) continue;
        if (dist2_point_triangle(p, v[0], v[1], v[2]) <= tol2) {
          ok = true;
          break;
        }
      }
      if (!ok) return false;
    }
    return true;
  }

  /// Quantizes direction `dir` to the 6-bit contour normal; false for a zero
  /// direction.
  static bool quantize(Vec3d dir, int n[3]) {
    const double m = std::max({std::fabs(dir.x), std::fabs(dir.y), std::fabs(dir.z)});
    if (!(m > 0)) return false;
    n[0] = std::clamp(int(std::lround(dir.x * 31.0 / m)), -32, 31);
    n[1] = std::clamp(int(std::lround(dir.y * 31.0 / m)), -32, 31);
    n[2] = std::clamp(int(std::lround(dir.z * 31.0 / m)), -32, 31);
    return true;
  }

  /// Per candidate normal c (SoA, quantized), the range of n_c . p over
  /// `pts`, updated into mn[c] / mx[c]. One pass over the points for all
  /// candidates: the points are read once instead of once per candidate, and
  /// the inner loop over candidates is independent per lane, so it
  /// vectorizes without reordering any reduction -- each mn[c] / mx[c] sees
  /// the points in the same order and the same dot() arithmetic as a
  /// per-candidate loop, hence bit-identical extrema.
  static void ranges(const std::vector<Vec3d>& pts, size_t C, const double* nx, const double* ny,
                     const double* nz, double* mn, double* mx) {
    for (size_t c = 0; c < C; ++c) mn[c] = INFINITY, mx[c] = -INFINITY;
    for (const Vec3d& p : pts)
      for (size_t c = 0; c < C; ++c) {
        const double d = nx[c] * p.x + ny[c] * p.y + nz[c] * p.z;  // = dot(n, p)
        mn[c] = d < mn[c] ? d : mn[c];                             // = std::min(mn, d)
        mx[c] = mx[c] < d ? d : mx[c];                             // = std::max(mx, d)
      }
  }

  /// Fits the slab of quantized normal n around the surface points' range
  /// [smin, smax] (§7.2) and scores it against P's range [pmin, pmax]
  /// (Figure 22).
  bool fit(const int n_[3], double pmin, double pmax, double smin, double smax, Vec3d lo, double S,
           int depth, Candidate* out) const {
    Candidate c;
    c.n[0] = n_[0], c.n[1] = n_[1], c.n[2] = n_[2];
    const Vec3d n{double(c.n[0]), double(c.n[1]), double(c.n[2])};
    const double nl = length(n);
    const Vec3d center = lo + Vec3d{0.5 * S, 0.5 * S, 0.5 * S};
    const double nc = dot(n, center);
    // Voxel-relative range of n . (x - c) / S, widened by the margin.
    const double margin = nl * (std::ldexp(1.0, depth - 21) + 1e-6);
    const double a = (smin - nc) / S, b = (smax - nc) / S;
    const double mid = 0.5 * (a + b) / 0.75;
    unsigned best_t = 1000;
    int best_p = 0;
    for (int p : {int(std::floor(mid)), int(std::ceil(mid))}) {
      p = std::clamp(p, -64, 63);
      const double half = std::max(b - 0.75 * p, 0.75 * p - a) + margin;
      const unsigned tq = unsigned(std::ceil(half / 0.375));
      if (tq < best_t) best_t = tq, best_p = p;
    }
    if (best_t > 127) return false;
    c.pos = best_p;
    c.thick = best_t;
    c.slab.n = n;
    c.slab.lo = nc + S * (0.75 * c.pos - 0.375 * c.thick);
    c.slab.hi = nc + S * (0.75 * c.pos + 0.375 * c.thick);
    const double h = pmax - pmin;
    const double h2 = std::max(0.0, std::min(pmax, c.slab.hi) - std::max(pmin, c.slab.lo));
    c.gain = (h - h2) / nl;
    *out = c;
    return true;
  }

  /// Processes the children of node (depth, index) at cube (x, y, z) of its
  /// level; `tris` overlap the node, `slabs` are its ancestors' contours
  /// (nearest last), including its own.
  void node(int depth, uint32_t index, uint32_t x, uint32_t y, uint32_t z,
            const std::vector<uint32_t>& tris, const std::vector<GridSlab>& slabs) {
    const uint32_t mask = t_.mask[size_t(depth)][index];
    const uint32_t first = t_.first_child[size_t(depth)][index];
    // Children planned by an earlier run() are skipped unless refine()
    // marked their subtree (their plan cannot have changed otherwise).
    int rank[8], slot[8], k = 0;
    for (int i = 0, r = 0; i < 8; ++i) {
      if (!(mask >> i & 1)) continue;
      const uint32_t c = first + uint32_t(r++);
      uint8_t& seen = seen_[size_t(depth) + 1][c];
      if (seen && (redo_.empty() || depth + 1 >= L_ || !redo_[size_t(depth) + 1][c])) continue;
      seen = 1;
      rank[k] = r - 1, slot[k] = i, ++k;
    }
    auto child = [&](int j) {
      this->child(depth + 1, first + uint32_t(rank[j]), slot[j], x, y, z, tris, slabs);
    };
    if (depth < par_depth_) {
      tbb::parallel_for(0, k, child);
    } else {
      for (int j = 0; j < k; ++j) child(j);
    }
  }

  void child(int cd, uint32_t ci, int i, uint32_t px, uint32_t py, uint32_t pz,
             const std::vector<uint32_t>& tris, const std::vector<GridSlab>& slabs) {
    const uint32_t cx = 2 * px + uint32_t(i & 1), cy = 2 * py + uint32_t(i >> 1 & 1),
                   cz = 2 * pz + uint32_t(i >> 2 & 1);
    const double S = std::ldexp(1.0, L_ - cd);
    const Vec3d lo{cx * S, cy * S, cz * S};
    const Vec3d hi = lo + Vec3d{S, S, S};

    // Per-thread scratch, reused across voxels (the recursion used to spend
    // a sixth of its time in malloc/free). Only used between here and the
    // recursive node() call below -- no TBB call happens while it is live,
    // so a task stolen by this thread cannot clobber it. ct is carried down
    // the recursion and stays a per-voxel vector.
    struct Scratch {
      std::vector<Vec3d> pts, poly, tmp, cand_dirs, pv;
      std::vector<std::array<int, 3>> qn;
      std::vector<double> f;
      Polyhedron P;
    };
    thread_local Scratch sc;
    std::vector<Vec3d>& pts = sc.pts;
    std::vector<Vec3d>& poly = sc.poly;
    std::vector<Vec3d>& tmp = sc.tmp;
    std::vector<Vec3d>& cand_dirs = sc.cand_dirs;
    std::vector<Vec3d>& pv = sc.pv;
    pts.clear();
    cand_dirs.clear();

    // 1. The surface inside the cube.
    std::vector<uint32_t> ct;
    Vec3d mean{0, 0, 0};
    const Vec3d planes[6] = {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}};
    const double offs[6] = {hi.x, -lo.x, hi.y, -lo.y, hi.z, -lo.z};
    for (uint32_t t : tris) {
      const Vec3d bl = tlo_[t], bh = thi_[t];
      if (bh.x < lo.x || bl.x > hi.x || bh.y < lo.y || bl.y > hi.y || bh.z < lo.z || bl.z > hi.z)
        continue;
      const auto& v = tri_[t];
      poly.assign(v.begin(), v.end());
      // A plane the triangle's box does not cross leaves the triangle as is
      // (clip_append's fast exit, decided on the box). Only while nothing was
      // cut: a computed intersection point may stray an ulp outside the
      // box, so after a cut clip_append decides on the actual vertices.
      const bool cross_plane[6] = {bh.x > hi.x, bl.x<lo.x, bh.y> hi.y, bl.y<lo.y, bh.z> hi.z,
                                   bl.z < lo.z};
      bool cut = false;
      for (int k = 0; k < 6; ++k)
        if (cut || cross_plane[k]) {
          tmp.clear();
          clip_append(poly.data(), poly.size(), planes[k], offs[k], tmp);
          poly.swap(tmp);
          cut = true;
        }
      if (poly.empty()) continue;
      ct.push_back(t);
      pts.insert(pts.end(), poly.begin(), poly.end());
      const Vec3d an = cross(v[1] - v[0], v[2] - v[0]);  // 2 x area x normal
      mean = mean + an;
    }

    // 2. P = cube ∩ nearest ancestor slabs.
    Polyhedron& P = sc.P;
    P.reset(lo, S);
    const size_t first_slab =
        slabs.size() > size_t(kMaxAncestors) ? slabs.size() - kMaxAncestors : 0;
    for (size_t s = first_slab; s < slabs.size(); ++s) P.clip(slabs[s]);
    P.vertices(pv);

    // 3./4. The contour.
    uint32_t value = 0;
    GridSlab own{};
    if (o_.contours && !ct.empty() && !pv.empty() && !within(pv, ct, contour_tol_)) {
      // Candidates: triangle normals (evenly sampled subset), the mean
      // normal, boundary perpendiculars.
      const size_t step = std::max<size_t>(1, (ct.size() + kMaxCandidates - 1) / kMaxCandidates);
      for (size_t j = 0; j < ct.size(); j += step) {
        const uint32_t t = ct[j];
        cand_dirs.push_back(normal_[t]);
        if (boundary_[t])
          for (int e = 0; e < 3; ++e)
            if (boundary_[t] >> e & 1) {
              const Vec3d ed = tri_[t][size_t((e + 1) % 3)] - tri_[t][size_t(e)];
              cand_dirs.push_back(cross(ed, normal_[t]));
            }
      }
      cand_dirs.push_back(mean);
      // Quantize first; a normal equal to an earlier candidate's scores the
      // same, and only a strictly better gain replaces the best, so dropping
      // repeats keeps the choice (neighbouring triangles mostly quantize
      // alike). Scores in candidate order, as before.
      auto& qn = sc.qn;
      qn.clear();
      for (const Vec3d& d : cand_dirs) {
        std::array<int, 3> n;
        if (!quantize(d, n.data())) continue;
        if (std::find(qn.begin(), qn.end(), n) == qn.end()) qn.push_back(n);
      }
      const size_t C = qn.size();
      auto& f = sc.f;  // nx | ny | nz | pmin | pmax | smin | smax, C each
      f.resize(7 * C);
      for (size_t j = 0; j < C; ++j) f[j] = qn[j][0], f[C + j] = qn[j][1], f[2 * C + j] = qn[j][2];
      ranges(pv, C, &f[0], &f[C], &f[2 * C], &f[3 * C], &f[4 * C]);
      ranges(pts, C, &f[0], &f[C], &f[2 * C], &f[5 * C], &f[6 * C]);
      Candidate best{}, c{};
      best.gain = -1;
      for (size_t j = 0; j < C; ++j)
        if (fit(qn[j].data(), f[3 * C + j], f[4 * C + j], f[5 * C + j], f[6 * C + j], lo, S, cd,
                &c) &&
            c.gain > best.gain)
          best = c;
      if (best.gain >= kMinGain * S) {
        ContourValue cv;
        cv.nx = best.n[0], cv.ny = best.n[1], cv.nz = best.n[2];
        cv.position = best.pos;
        cv.thickness = best.thick;
        value = encode_contour(cv);
        own = best.slab;
        // The final shape's vertices (P ∩ own slab) are only read by
        // REFINE-GEOMETRY below (§7.1); full-depth builds skip the two cuts.
        if (o_.geometry_error > 0 && cd < Lmax_) {
          P.clip(own);
          P.vertices(pv);
        }
      }
    }
    plan_.contour[size_t(cd)][ci] = value;
    if (cd >= L_) return;  // a leaf of the full-depth tree

    // Variable depth (§7.1): leaf here, or refine?
    bool leaf = cd >= Lmax_;
    if (!leaf && !forced_.empty() && forced_[size_t(cd)][ci]) {
      leaf = false;  // the decoded attributes failed the test (refine())
    } else if (!leaf && variable_ && !ct.empty()) {
      const bool refine_geometry = o_.geometry_error > 0 && !within(pv, ct, o_.geometry_error);
      // §7.3 on the raw encoding (what a raw build decodes to); skipped when
      // the geometry already refines. The value is read only here: a
      // geometry-only plan (the slice builder's) has no attribute arrays.
      bool refine_attributes = false;
      if (!refine_geometry && (o_.color_error >= 0 || o_.normal_error >= 0)) {
        if (attr_flags_ != nullptr) {
          refine_attributes = (*attr_flags_)[size_t(cd)][ci] != 0;
        } else {
          const uint64_t v = t_.value[size_t(cd)][ci];
          refine_attributes =
              attributes_exceed(t_, cd, ci, uint32_t(v), decode_normal_cube(uint32_t(v >> 32)), o_);
        }
      }
      leaf = !refine_geometry && !refine_attributes;
    }
    plan_.leaf[size_t(cd)][ci] = uint8_t(leaf);  // a re-plan (refine()) may clear it
    if (leaf) return;
    if (cd == stop_depth_) {
      // Cell-by-cell build: the cell's own planner continues from here with
      // exactly what node() below would get (the slice builder's sizing
      // pass keeps none).
      if (!keep_seeds_) return;
      auto seed = std::make_unique<SubtreeSeed>();
      seed->depth = cd;
      seed->x = cx, seed->y = cy, seed->z = cz;
      seed->tris = std::move(ct);
      seed->slabs = slabs;
      if (value != 0) seed->slabs.push_back(own);
      seeds_[ci] = std::move(seed);
      return;
    }
    if (value != 0) {
      std::vector<GridSlab> next(slabs);
      next.push_back(own);
      node(cd, ci, cx, cy, cz, ct, next);
    } else {
      node(cd, ci, cx, cy, cz, ct, slabs);
    }
  }

  const TreeView& t_;
  const BuildOptions& o_;
  const int L_, Lmax_;
  std::shared_ptr<const PlannerMesh> mesh_;
  const std::vector<std::array<Vec3d, 3>>& tri_;
  const std::vector<Vec3d>& normal_;
  const std::vector<Vec3d>&tlo_,
      &thi_;  // triangle bounding boxes (both filters test them per voxel)
  const std::vector<uint8_t>& boundary_;
  // Cell-by-cell build (build_cells.cpp): see the constructor.
  const int stop_depth_;
  const std::vector<std::vector<uint8_t>>* attr_flags_;
  std::vector<std::unique_ptr<SubtreeSeed>> seeds_;  // [node at stop_depth_]
  int par_depth_ = 4;                                // parallel over children above this depth
  // Incremental re-planning (refine()): [depth][node], depth 1..L (seen_)
  // resp. 1..L-1 (forced_, redo_; empty until the first refine()).
  std::vector<std::vector<uint8_t>> seen_;    // planned by some run()
  std::vector<std::vector<uint8_t>> forced_;  // must be subdivided
  std::vector<std::vector<uint8_t>> redo_;    // subtree holds a newly forced voxel
  std::vector<std::pair<int, uint32_t>> redo_list_;
  double contour_tol_ = kDefaultContourTolerance;
  bool variable_ = false;
  ContourPlan plan_;

 public:
  const ContourPlan& result() const { return plan_; }
  const SubtreeSeed* start_ = nullptr;  // plan only this seed's subtree (a cell)
  bool keep_seeds_ = true;              // at stop_depth_ (else just stop there)
  std::vector<std::unique_ptr<SubtreeSeed>>& seeds() { return seeds_; }
};

}  // namespace

struct PlannerState {
  Planner planner;
};

std::shared_ptr<const PlannerMesh> make_planner_mesh(const GridTransform& g, const Mesh& mesh) {
  if (mesh.triangle_count() == 0) throw Error("cannot build contours: the mesh has no triangles");
  auto m = std::make_shared<PlannerMesh>();
  const double inv = 1.0 / g.voxel_size;
  const size_t T = mesh.triangle_count();
  m->tri.resize(T);
  m->normal.resize(T);
  m->lo.resize(T);
  m->hi.resize(T);
  m->boundary.assign(T, 0);
  for (size_t i = 0; i < T; ++i) {
    for (int k = 0; k < 3; ++k) {
      const Vec3 p = mesh.positions[mesh.indices[3 * i + size_t(k)]];
      m->tri[i][size_t(k)] = {(double(p.x) - g.origin.x) * inv, (double(p.y) - g.origin.y) * inv,
                              (double(p.z) - g.origin.z) * inv};
    }
    const auto& v = m->tri[i];
    const Vec3d n = cross(v[1] - v[0], v[2] - v[0]);
    const double l = length(n);
    m->normal[i] = l > 0 ? n * (1.0 / l) : Vec3d{0, 0, 0};
    m->lo[i] = {std::min({v[0].x, v[1].x, v[2].x}), std::min({v[0].y, v[1].y, v[2].y}),
                std::min({v[0].z, v[1].z, v[2].z})};
    m->hi[i] = {std::max({v[0].x, v[1].x, v[2].x}), std::max({v[0].y, v[1].y, v[2].y}),
                std::max({v[0].z, v[1].z, v[2].z})};
  }
  find_boundary_edges(mesh, m->boundary);
  return m;
}

ContourPlanner::ContourPlanner(const TreeView& tree, const GridTransform& grid, const Mesh& mesh,
                               const BuildOptions& options) {
  p_ = std::make_unique<PlannerState>(
      PlannerState{Planner(tree, make_planner_mesh(grid, mesh), options)});
}

ContourPlanner::ContourPlanner(const TreeView& tree, std::shared_ptr<const PlannerMesh> mesh,
                               const BuildOptions& options, int stop_depth,
                               const std::vector<std::vector<uint8_t>>* attr_flags) {
  p_ = std::make_unique<PlannerState>(
      PlannerState{Planner(tree, std::move(mesh), options, stop_depth, attr_flags)});
}

ContourPlanner::ContourPlanner(const TreeView& tree, std::shared_ptr<const PlannerMesh> mesh,
                               const BuildOptions& options, const SubtreeSeed& seed) {
  p_ = std::make_unique<PlannerState>(PlannerState{Planner(tree, std::move(mesh), options)});
  p_->planner.start_ = &seed;
}

ContourPlanner::ContourPlanner(const TreeView& tree, std::shared_ptr<const PlannerMesh> mesh,
                               const BuildOptions& options, const SubtreeSeed& seed, int stop_depth,
                               bool keep_seeds,
                               const std::vector<std::vector<uint8_t>>* attr_flags) {
  if (stop_depth <= seed.depth) throw std::logic_error("esvo planner: stop above the seed");
  if ((options.color_error >= 0 || options.normal_error >= 0) && attr_flags == nullptr)
    throw std::logic_error("esvo planner: attribute tolerances without their flags");
  p_ = std::make_unique<PlannerState>(
      PlannerState{Planner(tree, std::move(mesh), options, stop_depth, attr_flags)});
  p_->planner.start_ = &seed;
  p_->planner.keep_seeds_ = keep_seeds;
}

std::shared_ptr<const SubtreeSeed> root_seed(const PlannerMesh& mesh) {
  auto s = std::make_shared<SubtreeSeed>();
  s->tris.resize(mesh.tri.size());
  std::iota(s->tris.begin(), s->tris.end(), 0u);
  return s;
}

std::shared_ptr<const SubtreeSeed> ContourPlanner::take_seed(uint32_t index) {
  auto& seeds = p_->planner.seeds();
  if (index >= seeds.size()) return nullptr;
  return std::shared_ptr<const SubtreeSeed>(std::move(seeds[index]));
}

ContourPlanner::~ContourPlanner() = default;

const ContourPlan& ContourPlanner::plan() {
  if (!planned_) p_->planner.run();
  planned_ = true;
  return p_->planner.result();
}

void ContourPlanner::refine(const std::vector<std::pair<int, uint32_t>>& leaves) {
  for (const auto& [d, i] : leaves) p_->planner.force(d, i);
  p_->planner.run();
  planned_ = true;
}

size_t first_leaf(const TreeView& tree, int depth, size_t index) {
  for (int d = depth; d < tree.levels; ++d) {
    if (index >= tree.count[size_t(d)]) return tree.count[size_t(tree.levels)];
    index = tree.first_child[size_t(d)][index];
  }
  return index;
}

bool attributes_exceed(const TreeView& tree, int depth, size_t index, uint32_t color_abgr,
                       Vec3 normal, const BuildOptions& o) {
  const size_t b = first_leaf(tree, depth, index), e = first_leaf(tree, depth, index + 1);
  return values_exceed(tree.value[size_t(tree.levels)], b, e, color_abgr, normal, o);
}

bool values_exceed(const uint64_t* v, size_t b, size_t e, uint32_t color_abgr, Vec3 normal,
                   const BuildOptions& o) {
  if (o.color_error >= 0) {
    // 8-bit sRGB codes, max channel difference (alpha is not stored, §5.5).
    using layout::ColorChannels;
    const int c[3] = {int(ColorChannels::get(color_abgr, 0)),
                      int(ColorChannels::get(color_abgr, 1)),
                      int(ColorChannels::get(color_abgr, 2))};
    for (size_t u = b; u < e; ++u)  // raw value: color in the low word
      for (unsigned ch = 0; ch < 3; ++ch)
        if (std::abs(int(ColorChannels::get(uint32_t(v[u]), ch)) - c[ch]) > o.color_error)
          return true;
  }
  if (o.normal_error >= 0) {
    // angle > tolerance <=> cos(angle) < cos(tolerance), in double with the
    // float normals' lengths divided out (equal normals give cos 1 +- 1e-16,
    // not 1 - 1e-7); the 1e-12 slack is < 1e-4 degrees at any tolerance.
    const double cos_tol =
        std::cos(std::min(o.normal_error, 180.0) * (std::numbers::pi / 180.0)) - 1e-12;
    const double m[3] = {normal.x, normal.y, normal.z};
    const double m2 = m[0] * m[0] + m[1] * m[1] + m[2] * m[2];
    for (size_t u = b; u < e; ++u) {
      const Vec3 n = decode_normal_cube(uint32_t(v[u] >> 32));
      const double d = double(n.x) * m[0] + double(n.y) * m[1] + double(n.z) * m[2];
      const double n2 = double(n.x) * n.x + double(n.y) * n.y + double(n.z) * n.z;
      if (d < cos_tol * std::sqrt(n2 * m2)) return true;
    }
  }
  return false;
}

}  // namespace detail
}  // namespace voxcast::esvo
