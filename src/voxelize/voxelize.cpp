// Surface voxelization (Hitchhiker's guide to voxels, "Voxelization" section;
// Schwarz & Seidel 2010, "Fast Parallel Surface and Solid Voxelization on
// GPUs", sec. 3): per triangle, rasterize the projection onto the dominant
// plane row by row with 2-D edge functions, take the depth range of every
// column from the triangle plane, and keep the voxels that also pass the 2-D
// edge tests of the two side projections. Then sort the (voxel, triangle)
// pairs, merge duplicates and box-filter the attributes.
#include <fmt/format.h>
#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <memory>
#include <vector>

#include "voxcast/error.hpp"
#include "voxcast/morton.hpp"
#include "voxcast/progress.hpp"
#include "voxcast/voxelize.hpp"
#include "voxelize/internal.hpp"

namespace voxcast {

namespace {

// ---------------------------------------------------------------------------
// Per-triangle rasterization
// ---------------------------------------------------------------------------

// 2-D edge function of one projected edge, evaluated at the minimum corner
// (p, q) of an integer cell: a*p + b*q + c >= 0 <=> the cell passes the edge.
// The critical-point offset is folded into c (guide: "Critical Points",
// d_max = n_e.p + max(n_ex dp,0) + max(n_ey dp,0) - n_e.v0, constant per edge).
struct EdgeEq {
  double a = 0, b = 0, c = 0;
};

// Edge equations of the projection along `axis`, 2-D coordinates
// p = (axis+1)%3, q = (axis+2)%3. `sign` orients the inward edge normals
// (sign of the triangle normal's `axis` component). Conservative: the
// critical point is the box corner furthest inside the edge; 6-separating
// (S&S sec. 3.2): the furthest point of the box's inscribed diamond, i.e. the
// center plus 1/2 max(|n_ex|, |n_ey|).
void edge_equations(const double v[3][3], int axis, double sign, bool six, EdgeEq out[3]) {
  const int p = (axis + 1) % 3, q = (axis + 2) % 3;
  for (int e = 0; e < 3; ++e) {
    const double* s = v[e];
    const double* t = v[e == 2 ? 0 : e + 1];
    double np = -(t[q] - s[q]) * sign;
    double nq = (t[p] - s[p]) * sign;
    double c = -(np * s[p] + nq * s[q]);
    if (six)
      c += 0.5 * (np + nq) + 0.5 * std::max(std::fabs(np), std::fabs(nq));
    else
      c += std::max(np, 0.0) + std::max(nq, 0.0);
    out[e] = {np, nq, c};
  }
}

// ceil/floor of a double clamped to a safe int range first (a huge quotient
// from a nearly degenerate edge must not overflow the conversion).
inline int ceil_clamped(double x, int lo, int hi) {
  return int(std::ceil(std::clamp(x, double(lo), double(hi))));
}
inline int floor_clamped(double x, int lo, int hi) {
  return int(std::floor(std::clamp(x, double(lo), double(hi))));
}

// A zero-area triangle (segment or point): the separating-axis test reduces to
// the voxel boxes overlapping the bounding box and, for each axis a_j, the box
// straddling the line along L_j = d x a_j (d = segment direction).
template <class Emit>
void raster_segment(const double v[3][3], const int lo[3], const int hi[3], Emit& emit) {
  // Endpoints: the farthest pair of the collinear vertices.
  int ia = 0, ib = 1;
  double best = -1;
  for (int s = 0; s < 3; ++s)
    for (int t = s + 1; t < 3; ++t) {
      double d2 = 0;
      for (int k = 0; k < 3; ++k) d2 += (v[t][k] - v[s][k]) * (v[t][k] - v[s][k]);
      if (d2 > best) best = d2, ia = s, ib = t;
    }
  if (!(best > 0)) {
    // A point: exactly the voxels of its bounding box (up to 8 on a corner).
    for (int z = lo[2]; z <= hi[2]; ++z)
      for (int y = lo[1]; y <= hi[1]; ++y)
        for (int x = lo[0]; x <= hi[0]; ++x) emit(morton_encode(x, y, z));
    return;
  }
  const double* P = v[ia];
  double d[3] = {v[ib][0] - P[0], v[ib][1] - P[1], v[ib][2] - P[2]};
  int w = 0;
  for (int a = 1; a < 3; ++a)
    if (std::fabs(d[a]) > std::fabs(d[w])) w = a;
  // L_j = d x a_j for j = x, y, z; the segment projects to the single value L_j.P.
  double L[3][3] = {{0, d[2], -d[1]}, {-d[2], 0, d[0]}, {d[1], -d[0], 0}};
  double lp[3], lmin[3], lmax[3];
  for (int j = 0; j < 3; ++j) {
    lp[j] = L[j][0] * P[0] + L[j][1] * P[1] + L[j][2] * P[2];
    lmin[j] = std::min(L[j][0], 0.0) + std::min(L[j][1], 0.0) + std::min(L[j][2], 0.0);
    lmax[j] = std::max(L[j][0], 0.0) + std::max(L[j][1], 0.0) + std::max(L[j][2], 0.0);
  }
  auto ok = [&](const int c[3]) {
    for (int j = 0; j < 3; ++j) {
      double base = (L[j][0] * c[0] + L[j][1] * c[1]) + L[j][2] * c[2];
      if (base + lmin[j] > lp[j] || base + lmax[j] < lp[j]) return false;
    }
    return true;
  };
  // Walk the slabs of the dominant axis of d: inside slab [k, k+1] the other
  // coordinates move by at most one voxel, so a few candidates per slab.
  const int u = (w + 1) % 3, vv = (w + 2) % 3;
  for (int k = lo[w]; k <= hi[w]; ++k) {
    double t0 = std::clamp((double(k) - P[w]) / d[w], 0.0, 1.0);
    double t1 = std::clamp((double(k) + 1.0 - P[w]) / d[w], 0.0, 1.0);
    double u0 = P[u] + d[u] * t0, u1 = P[u] + d[u] * t1;
    double v0 = P[vv] + d[vv] * t0, v1 = P[vv] + d[vv] * t1;
    int ilo = std::max(lo[u], floor_clamped(std::min(u0, u1), -4, 1 << 22) - 2);
    int ihi = std::min(hi[u], floor_clamped(std::max(u0, u1), -4, 1 << 22) + 1);
    int jlo = std::max(lo[vv], floor_clamped(std::min(v0, v1), -4, 1 << 22) - 2);
    int jhi = std::min(hi[vv], floor_clamped(std::max(v0, v1), -4, 1 << 22) + 1);
    for (int i = ilo; i <= ihi; ++i)
      for (int j = jlo; j <= jhi; ++j) {
        int c[3];
        c[w] = k, c[u] = i, c[vv] = j;
        if (ok(c)) emit(morton_encode(c[0], c[1], c[2]));
      }
  }
}

// Emits the Morton code of every voxel [i,i+1]^3 of the n^3 grid that the
// closed triangle `v` (grid units) overlaps (conservative), or its
// 6-separating subset. Conservative is exactly the 13-axis separating-axis
// test: bounding box (3 box axes), plane (triangle normal), and the 2-D edge
// tests of the three projections (the 9 edge x axis cross products; S&S
// sec. 3.1). Every candidate is decided by the multiply-only predicates; the
// divisions only bound the loops (with one cell of slack for rounding).
template <class Emit>
void raster_triangle(const double v[3][3], int n, bool six, Emit&& emit) {
  int lo[3], hi[3];
  for (int a = 0; a < 3; ++a) {
    double mn = std::min({v[0][a], v[1][a], v[2][a]});
    double mx = std::max({v[0][a], v[1][a], v[2][a]});
    // Closed boxes: [i, i+1] meets [mn, mx] iff i <= mx and i + 1 >= mn.
    lo[a] = std::max(0, ceil_clamped(mn, -4, n + 4) - 1);
    hi[a] = std::min(n - 1, floor_clamped(mx, -4, n + 4));
    if (lo[a] > hi[a]) return;
  }

  const double e1[3] = {v[1][0] - v[0][0], v[1][1] - v[0][1], v[1][2] - v[0][2]};
  const double e2[3] = {v[2][0] - v[0][0], v[2][1] - v[0][1], v[2][2] - v[0][2]};
  double nrm[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                   e1[0] * e2[1] - e1[1] * e2[0]};
  if (nrm[0] == 0 && nrm[1] == 0 && nrm[2] == 0) {
    // Zero area: conservative segment/point voxelization in both modes (a
    // zero-area triangle separates nothing, so 6-separation needs no thinning).
    raster_segment(v, lo, hi, emit);
    return;
  }

  // Dominant axis w: the projection onto the other two axes (u, vv), taken in
  // cyclic order so that nrm[w] keeps its orientation, has the largest area.
  int w = 0;
  for (int a = 1; a < 3; ++a)
    if (std::fabs(nrm[a]) > std::fabs(nrm[w])) w = a;
  const int u = (w + 1) % 3, vv = (w + 2) % 3;

  EdgeEq dom[3], side_u[3], side_v[3];
  edge_equations(v, w, nrm[w] > 0 ? 1.0 : -1.0, six, dom);
  // A side projection with a zero normal component is a segment: its edge
  // tests degenerate to the plane test (the projected normal is the plane
  // normal), so they are left as always-true equations.
  if (nrm[u] != 0) edge_equations(v, u, nrm[u] > 0 ? 1.0 : -1.0, six, side_u);
  if (nrm[vv] != 0) edge_equations(v, vv, nrm[vv] > 0 ? 1.0 : -1.0, six, side_v);

  // Plane, oriented so that its w coefficient is positive.
  const double s = nrm[w] > 0 ? 1.0 : -1.0;
  const double nu = nrm[u] * s, nv = nrm[vv] * s, nw = nrm[w] * s;
  const double d0 = nu * v[0][u] + nv * v[0][vv] + nw * v[0][w];
  // Plane offsets over the column square [0,1]^2 in (u, vv): conservative
  // (guide, "Depth direction - conservative") uses the plane's min and max
  // over the whole box; 6-separating only the voxel's center line along w.
  double off_lo, off_hi;
  if (six) {
    off_lo = 0.5 * (nu + nv);
    off_hi = off_lo + nw;
  } else {
    off_lo = std::min(nu, 0.0) + std::min(nv, 0.0);
    off_hi = std::max(nu, 0.0) + std::max(nv, 0.0) + nw;
  }
  const double inv_nw = 1.0 / nw;

  // Morton codes are the OR of the per-axis deposits; precomputing the mask
  // of each of u, vv, w keeps the inner loop at one pdep per voxel.
  const uint64_t masks[3] = {kMortonMaskX, kMortonMaskY, kMortonMaskZ};
  const uint64_t mu = masks[u], mv = masks[vv], mw = masks[w];

  for (int i = lo[u]; i <= hi[u]; ++i) {
    // Column interval of this row from the dominant edge functions
    // (guide, "The edge function": half-intervals, combined).
    int jl = lo[vv], jh = hi[vv];
    double r[3];
    bool row_ok = true;
    for (int e = 0; e < 3; ++e) {
      r[e] = dom[e].a * i + dom[e].c;
      if (dom[e].b > 0)
        jl = std::max(jl, ceil_clamped(-r[e] / dom[e].b, -4, n + 4) - 1);
      else if (dom[e].b < 0)
        jh = std::min(jh, floor_clamped(-r[e] / dom[e].b, -4, n + 4) + 1);
      else if (r[e] < 0)
        row_ok = false;
    }
    if (!row_ok) continue;
    auto dom_ok = [&](int j) {
      return r[0] + dom[0].b * j >= 0 && r[1] + dom[1].b * j >= 0 && r[2] + dom[2].b * j >= 0;
    };
    // The slack cells are settled exactly, so the interval is exact.
    while (jl <= jh && !dom_ok(jl)) ++jl;
    while (jh >= jl && !dom_ok(jh)) --jh;

    // Side projection along vv (coordinates (w, u)): a*k + b*i + c.
    double sv_c[3], sv_k[3];
    for (int e = 0; e < 3; ++e) {
      sv_c[e] = side_v[e].b * i + side_v[e].c;
      sv_k[e] = side_v[e].a;
    }
    const uint64_t code_u = _pdep_u64(uint64_t(i), mu);
    const double hu = nu * i - d0;

    for (int j = jl; j <= jh; ++j) {
      // Side projection along u (coordinates (vv, w)): a*j + b*k + c.
      double su_c[3], su_k[3];
      for (int e = 0; e < 3; ++e) {
        su_c[e] = side_u[e].a * j + side_u[e].c;
        su_k[e] = side_u[e].b;
      }
      // Plane value at the column corner, without the w term.
      const double h = hu + nv * j;
      // nw*k + h + off_lo <= 0 <= nw*k + h + off_hi.
      int kl = std::max(lo[w], ceil_clamped(-(h + off_hi) * inv_nw, -4, n + 4) - 1);
      int kh = std::min(hi[w], floor_clamped(-(h + off_lo) * inv_nw, -4, n + 4) + 1);
      const uint64_t code_uv = code_u | _pdep_u64(uint64_t(j), mv);
      for (int k = kl; k <= kh; ++k) {
        const double pk = h + nw * k;
        bool ok = pk + off_lo <= 0 && pk + off_hi >= 0;
        for (int e = 0; e < 3; ++e) {
          ok &= su_c[e] + su_k[e] * k >= 0;
          ok &= sv_c[e] + sv_k[e] * k >= 0;
        }
        if (ok) emit(code_uv | _pdep_u64(uint64_t(k), mw));
      }
    }
  }
}

void check_resolution(uint32_t resolution) {
  if (resolution == 0 || !std::has_single_bit(resolution) || resolution > (1u << kMaxGridLevels))
    throw Error(fmt::format("grid resolution {} is not a power of two between 1 and {}", resolution,
                            1u << kMaxGridLevels));
}

// ---------------------------------------------------------------------------
// (voxel, triangle) pair records
// ---------------------------------------------------------------------------

// When 3*levels + triangle bits fit in 64, a pair is one key (code in the high
// bits, triangle in the low ones): 8 bytes a pair, and the key order is the
// (code, triangle) order. Otherwise 16 bytes.
struct PackedPair {
  uint64_t key;
};
struct WidePair {
  uint64_t code;
  uint32_t tri;
  uint32_t pad;
};

struct PackedTraits {
  using Rec = PackedPair;
  int tri_bits;
  Rec make(uint64_t code, uint32_t tri) const { return {code << tri_bits | tri}; }
  uint64_t code(const Rec& r) const { return r.key >> tri_bits; }
  uint32_t tri(const Rec& r) const { return uint32_t(r.key & ((uint64_t(1) << tri_bits) - 1)); }
};
struct WideTraits {
  using Rec = WidePair;
  Rec make(uint64_t code, uint32_t tri) const { return {code, tri, 0}; }
  uint64_t code(const Rec& r) const { return r.code; }
  uint32_t tri(const Rec& r) const { return r.tri; }
};

template <class Rec>
struct Span {
  const Rec* data;
  size_t size;
};

// Per-thread append-only storage in chunks: no reallocation copies, and at
// most one partly filled chunk per thread is wasted.
template <class Rec>
class Arena {
 public:
  void begin_block(std::vector<Span<Rec>>* spans) {
    spans_ = spans;
    start_ = cur_;
  }
  void push(const Rec& r) {
    if (cur_ == end_) grow();
    *cur_++ = r;
  }
  void end_block() {
    if (cur_ != start_) spans_->push_back({start_, size_t(cur_ - start_)});
  }
  void release() { chunks_.clear(); }

 private:
  void grow() {
    if (cur_ != start_) spans_->push_back({start_, size_t(cur_ - start_)});
    size_t n = chunks_.empty() ? (size_t(1) << 14) : std::min(next_ * 2, size_t(1) << 20);
    next_ = n;
    chunks_.emplace_back(new Rec[n]);
    cur_ = start_ = chunks_.back().get();
    end_ = cur_ + n;
  }
  std::vector<std::unique_ptr<Rec[]>> chunks_;
  std::vector<Span<Rec>>* spans_ = nullptr;
  Rec* start_ = nullptr;
  Rec* cur_ = nullptr;
  Rec* end_ = nullptr;
  size_t next_ = 0;
};

// One pass of a stable LSD radix sort: scatters the records of `in` (taken in
// order) into `out` by the digit `dig(rec)` in [0, buckets). Consecutive spans
// are grouped into about `parts` tasks; the per-task histograms give every
// (digit, task) pair its own output range, so the result does not depend on
// scheduling.
template <class Rec, class Digit>
void radix_pass(const std::vector<Span<Rec>>& in, size_t parts, Rec* out, int buckets, Digit dig) {
  size_t total = 0;
  for (const auto& s : in) total += s.size;
  std::vector<size_t> group{0};  // task g covers spans [group[g], group[g+1])
  size_t acc = 0;
  for (size_t s = 0; s < in.size(); ++s) {
    acc += in[s].size;
    if (acc * parts >= total * group.size() || s + 1 == in.size()) group.push_back(s + 1);
  }
  const size_t ng = group.size() - 1;
  std::vector<size_t> hist(ng * size_t(buckets), 0);
  tbb::parallel_for(size_t(0), ng, [&](size_t g) {
    size_t* h = &hist[g * buckets];
    for (size_t s = group[g]; s < group[g + 1]; ++s) {
      const Rec* p = in[s].data;
      for (size_t i = 0, m = in[s].size; i < m; ++i) ++h[dig(p[i])];
    }
  });
  size_t run = 0;
  for (int d = 0; d < buckets; ++d)
    for (size_t g = 0; g < ng; ++g) {
      size_t c = hist[g * buckets + d];
      hist[g * buckets + d] = run;
      run += c;
    }
  tbb::parallel_for(size_t(0), ng, [&](size_t g) {
    size_t* h = &hist[g * buckets];
    for (size_t s = group[g]; s < group[g + 1]; ++s) {
      const Rec* p = in[s].data;
      for (size_t i = 0, m = in[s].size; i < m; ++i) out[h[dig(p[i])]++] = p[i];
    }
  });
}

// `parts` contiguous spans of a flat array.
template <class Rec>
std::vector<Span<Rec>> split(const Rec* data, size_t n, size_t parts) {
  std::vector<Span<Rec>> spans;
  for (size_t p = 0; p < parts; ++p) {
    size_t b = n * p / parts, e = n * (p + 1) / parts;
    if (e > b) spans.push_back({data + b, e - b});
  }
  return spans;
}

// Touch-only pairs (the triangle meets the voxel in a point or segment) get
// this area so that every voxel has defined attributes; it is far below any
// real contribution, so weights still sum to the surface area (1e-9 voxel^2
// per touching pair).
constexpr double kTouchWeight = 1e-9;

template <class Traits>
VoxelSet voxelize_impl(const Mesh& mesh, const GridTransform& grid, const VoxelizeOptions& opt,
                       const Traits& tr) {
  using Rec = typename Traits::Rec;
  const size_t ntri = mesh.triangle_count();
  const int n = int(grid.resolution);
  const bool six = opt.mode == VoxelizationMode::SixSeparating;

  // Vertices in grid units, in double: voxel (i,j,k) is [i,i+1]x[j,j+1]x[k,k+1].
  std::vector<std::array<double, 3>> gv(mesh.positions.size());
  const double inv = 1.0 / grid.voxel_size;
  tbb::parallel_for(tbb::blocked_range<size_t>(0, gv.size(), 1 << 14), [&](const auto& r) {
    for (size_t i = r.begin(); i < r.end(); ++i)
      for (int a = 0; a < 3; ++a)
        gv[i][a] = (double(mesh.positions[i][a]) - double(grid.origin[a])) * inv;
  });
  auto tri_verts = [&](size_t t, double out[3][3]) {
    for (int k = 0; k < 3; ++k)
      for (int a = 0; a < 3; ++a) out[k][a] = gv[mesh.indices[3 * t + k]][a];
  };

  // 1. Rasterize blocks of triangles. Each block's pairs come out in triangle
  // order and blocks are read back in block order, so the concatenation is
  // sorted by triangle and a stable sort on the code alone yields the
  // (code, triangle) order, whatever the thread count.
  constexpr size_t kBlock = 256;
  const size_t nblocks = (ntri + kBlock - 1) / kBlock;
  std::vector<std::vector<Span<Rec>>> block_spans(nblocks);
  tbb::enumerable_thread_specific<Arena<Rec>> arenas;
  tbb::parallel_for(size_t(0), nblocks, [&](size_t b) {
    Arena<Rec>& arena = arenas.local();
    arena.begin_block(&block_spans[b]);
    const size_t t0 = b * kBlock, t1 = std::min(ntri, t0 + kBlock);
    for (size_t t = t0; t < t1; ++t) {
      double tri[3][3];
      tri_verts(t, tri);
      raster_triangle(tri, n, six,
                      [&](uint64_t code) { arena.push(tr.make(code, uint32_t(t))); });
    }
    arena.end_block();
    if (opt.progress) opt.progress->advance(t1 - t0);
  });
  std::vector<Span<Rec>> spans;
  size_t total = 0;
  for (auto& bs : block_spans)
    for (auto& s : bs) {
      spans.push_back(s);
      total += s.size;
    }
  block_spans.clear();
  block_spans.shrink_to_fit();

  // 2. Stable LSD radix sort on the code bits. The first pass reads the arenas
  // directly (no concatenation copy) and frees them.
  const int code_bits = 3 * grid.levels;
  const int passes = std::max(1, (code_bits + 10) / 11);
  const int digit_bits = code_bits == 0 ? 1 : (code_bits + passes - 1) / passes;
  const int buckets = 1 << digit_bits;
  std::unique_ptr<Rec[]> buf_a(new Rec[std::max<size_t>(total, 1)]);
  std::unique_ptr<Rec[]> buf_b;
  auto digit = [&](int pass) {
    const int shift = pass * digit_bits;
    const uint64_t mask = uint64_t(buckets - 1);
    return [&tr, shift, mask](const Rec& r) { return size_t((tr.code(r) >> shift) & mask); };
  };
  const size_t parts = std::clamp<size_t>(total / (size_t(1) << 16), 1, 64);
  radix_pass(spans, parts, buf_a.get(), buckets, digit(0));
  arenas.combine_each([](Arena<Rec>& a) { a.release(); });
  spans.clear();
  if (passes > 1) buf_b.reset(new Rec[std::max<size_t>(total, 1)]);
  for (int p = 1; p < passes; ++p) {
    radix_pass(split<Rec>(buf_a.get(), total, parts), parts, buf_b.get(), buckets, digit(p));
    std::swap(buf_a, buf_b);
  }
  buf_b.reset();
  const Rec* pairs = buf_a.get();

  // 3. Merge runs of equal codes. Chunk boundaries are moved to the start of a
  // run so that every voxel is reduced by one task, in (code, triangle) order.
  std::vector<size_t> bound(parts + 1);
  for (size_t p = 0; p <= parts; ++p) {
    size_t b = total * p / parts;
    while (b > 0 && b < total && tr.code(pairs[b]) == tr.code(pairs[b - 1])) ++b;
    bound[p] = b;
  }
  std::vector<size_t> first_voxel(parts + 1, 0);
  tbb::parallel_for(size_t(0), parts, [&](size_t p) {
    size_t c = 0;
    for (size_t i = bound[p]; i < bound[p + 1]; ++i)
      c += (i == bound[p] || tr.code(pairs[i]) != tr.code(pairs[i - 1]));
    first_voxel[p + 1] = c;
  });
  for (size_t p = 0; p < parts; ++p) first_voxel[p + 1] += first_voxel[p];
  const size_t nvox = first_voxel[parts];

  VoxelSet out;
  out.grid = grid;
  out.codes.resize(nvox);
  if (opt.attributes) {
    out.colors.resize(nvox);
    out.normals.resize(nvox);
    out.weights.resize(nvox);
  }
  tbb::parallel_for(size_t(0), parts, [&](size_t p) {
    size_t vox = first_voxel[p];
    size_t i = bound[p];
    const size_t end = bound[p + 1];
    while (i < end) {
      const uint64_t code = tr.code(pairs[i]);
      size_t j = i;
      if (!opt.attributes) {
        while (j < end && tr.code(pairs[j]) == code) ++j;
        out.codes[vox++] = code;
        i = j;
        continue;
      }
      // Box filter (area-weighted means) over this voxel's triangles.
      const MortonCoord xyz = morton_decode(code);
      double wsum = 0, col[4] = {0, 0, 0, 0}, nsum[3] = {0, 0, 0};
      double best_w = -1;
      uint32_t best_tri = 0;
      for (; j < end && tr.code(pairs[j]) == code; ++j) {
        const uint32_t t = tr.tri(pairs[j]);
        double tri[3][3];
        tri_verts(t, tri);
        detail::VoxelClip clip = detail::clip_triangle_to_voxel(tri, xyz.x, xyz.y, xyz.z);
        const double wgt = std::max(clip.area, kTouchWeight);
        const Color c = mesh.surface_color(t, clip.bary_u, clip.bary_v);
        const Vec3 nm = mesh.surface_normal(t, clip.bary_u, clip.bary_v);
        wsum += wgt;
        col[0] += wgt * c.r, col[1] += wgt * c.g, col[2] += wgt * c.b, col[3] += wgt * c.a;
        nsum[0] += wgt * nm.x, nsum[1] += wgt * nm.y, nsum[2] += wgt * nm.z;
        if (wgt > best_w) best_w = wgt, best_tri = t;
      }
      out.codes[vox] = code;
      out.colors[vox] = {float(col[0] / wsum), float(col[1] / wsum), float(col[2] / wsum),
                         float(col[3] / wsum)};
      double len = std::sqrt(nsum[0] * nsum[0] + nsum[1] * nsum[1] + nsum[2] * nsum[2]);
      if (len > 1e-6 * wsum) {
        out.normals[vox] = {float(nsum[0] / len), float(nsum[1] / len), float(nsum[2] / len)};
      } else {
        // Opposite sheets cancel (e.g. both sides of a thin wall in one
        // voxel): the face normal of the largest contribution.
        double tri[3][3];
        tri_verts(best_tri, tri);
        double a[3], b[3];
        for (int k = 0; k < 3; ++k) a[k] = tri[1][k] - tri[0][k], b[k] = tri[2][k] - tri[0][k];
        double fn[3] = {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                        a[0] * b[1] - a[1] * b[0]};
        double fl = std::sqrt(fn[0] * fn[0] + fn[1] * fn[1] + fn[2] * fn[2]);
        out.normals[vox] = fl > 0 ? Vec3{float(fn[0] / fl), float(fn[1] / fl), float(fn[2] / fl)}
                                  : Vec3{0, 0, 1};
      }
      out.weights[vox] = float(wsum);
      ++vox;
      i = j;
    }
  });
  return out;
}

}  // namespace

void triangle_voxels(const double tri[3][3], uint32_t resolution, VoxelizationMode mode,
                     std::vector<uint64_t>& out) {
  check_resolution(resolution);
  for (int k = 0; k < 3; ++k)
    for (int a = 0; a < 3; ++a)
      if (!std::isfinite(tri[k][a])) throw Error("triangle_voxels: non-finite vertex coordinate");
  raster_triangle(tri, int(resolution), mode == VoxelizationMode::SixSeparating,
                  [&out](uint64_t code) { out.push_back(code); });
}

VoxelSet voxelize(const Mesh& mesh, const GridTransform& grid, const VoxelizeOptions& options) {
  check_resolution(grid.resolution);
  if (grid.levels != std::countr_zero(grid.resolution))
    throw Error(fmt::format("grid levels {} do not match resolution {}", grid.levels,
                            grid.resolution));
  if (!(grid.voxel_size > 0) || !std::isfinite(grid.voxel_size) || !is_finite(grid.origin))
    throw Error("grid voxel size must be positive and its origin finite");
  validate_mesh(mesh);
  const size_t ntri = mesh.triangle_count();
  if (ntri > size_t(UINT32_MAX))
    throw Error(fmt::format("mesh has {} triangles, more than 2^32-1", ntri));
  if (ntri == 0) {
    VoxelSet empty;
    empty.grid = grid;
    return empty;
  }
  const int tri_bits = std::max(1, int(std::bit_width(uint64_t(ntri - 1))));
  if (3 * grid.levels + tri_bits <= 64) return voxelize_impl(mesh, grid, options, PackedTraits{tri_bits});
  return voxelize_impl(mesh, grid, options, WideTraits{});
}

}  // namespace voxcast
