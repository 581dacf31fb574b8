// Conformance suite (issue 9, item 7): the same properties for every voxel
// structure registered in tests/support/conformance.hpp, each built from a
// set of voxel cases, saved to a scene file and loaded with load_scene():
//   * FirstHitMatchesDda: LOD-0 first hits equal the dense-grid DDA oracle
//     (tests/support/dda_oracle.*, double precision): hit/miss, voxel, t;
//   * BeamOnEqualsBeamOff: render() with 4x4 and 8x8 beams gives the same
//     color, depth and normal images bit for bit as without;
//   * OcclusionEqualsTraceBeforeTmax: occluded() = trace() finds a hit;
//   * LodStopsAreConsistent: a constant footprint stops exactly at the DDA
//     oracle's hit on the coarsened grid; a pixel cone stops at an occupied
//     cube no later than the LOD-0 hit, and shows the colors it promises;
//   * ThreadCountInvariance: 1 thread = 2 threads for the build, the saved
//     file and the rendered image, byte for byte;
//   * DamagedFilesAreRejectedCleanly: every truncation (or a dense sample) and
//     sampled byte corruptions, with and without the section hash recomputed,
//     are rejected with voxcast::Error or load and render without a crash.
// World space of every case is the unit cube (origin 0, side 1, meshes are
// scaled into it) and ray origins are multiples of 2^-20, so the structures'
// world -> octree mapping (p + 1) is exact and they trace exactly the ray the
// oracle sees.
#include <gtest/gtest.h>
#include <tbb/global_control.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <optional>
#include <ostream>
#include <random>
#include <string>
#include <vector>

#include "support/conformance.hpp"
#include "support/dda_oracle.hpp"
#include "support/esvo_testing.hpp"
#include "support/slice_check.hpp"
#include "support/test_data.hpp"
#include "voxcast/error.hpp"
#include "voxcast/image.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/morton.hpp"
#include "voxcast/render.hpp"
#include "voxcast/scene_file.hpp"

namespace voxcast {
namespace {

using testing::DdaHit;
using testing::DenseGrid;
using testing::DVec3;
using testing::StructureFactory;

// ---------------------------------------------------------------------------
// Voxel cases.

struct VoxelCase {
  std::string name;
  int levels = 0;
  const char* mesh = nullptr;                // tests/data/meshes file, or null
  std::function<VoxelSet()> make = nullptr;  // code-generated set (mesh == null)
};

VoxelSet plates(int levels) {
  // A one-voxel-thick axis-aligned plate and a plate along a diagonal plane:
  // rays graze their faces and run inside their grid planes.
  const uint32_t n = 1u << levels;
  VoxelSet v = testing::make_dense_grid(levels, [n](uint32_t x, uint32_t y, uint32_t z) {
    return x == n / 2 || (y + z == n - 1 && x < n / 2);
  });
  testing::fill_random_attributes(v, 17);
  return v;
}

const std::vector<VoxelCase>& voxel_cases() {
  static const std::vector<VoxelCase> cases = {
      {"empty", 4, nullptr, [] { return testing::make_random_voxels(4, 0, 1); }},
      {"single_voxel", 5, nullptr, [] { return testing::make_random_voxels(5, 1, 5); }},
      {"sparse", 6, nullptr, [] { return testing::make_random_voxels(6, 60, 2); }},
      {"half_dense", 5, nullptr, [] { return testing::make_random_voxels(5, 16384, 3); }},
      {"nearly_full", 4, nullptr, [] { return testing::make_random_voxels(4, 3900, 4); }},
      {"full_grid", 4, nullptr,
       [] {
         VoxelSet v = testing::make_full_grid(4);
         testing::fill_random_attributes(v, 6);
         return v;
       }},
      {"sphere_shell", 6, nullptr, [] { return testing::make_sphere_shell(6); }},
      {"plates", 6, nullptr, [] { return plates(6); }},
      {"spot_mesh", 6, "spot.obj", nullptr},
      {"teapot_mesh", 5, "teapot.obj", nullptr},
  };
  return cases;
}

// The mesh scaled into the unit cube the way GridTransform::fit places it.
Mesh unit_cube_mesh(const char* file, int levels) {
  Mesh m = load_mesh(testing::test_mesh(file));
  const GridTransform g = GridTransform::fit(m.bounds(), 1u << levels);
  const float inv = float(1.0 / g.side());
  for (Vec3& p : m.positions) p = (p - g.origin) * inv;
  return m;
}

// ---------------------------------------------------------------------------
// Built structures, cached per (factory, case): every property reuses them.

struct Built {
  VoxelSet voxels;
  std::optional<Mesh> mesh;
  std::vector<uint8_t> file;  // the saved scene file
  LoadedScene scene;          // load_scene(file)
  std::string rejected;       // non-empty: the factory refused the input (voxcast::Error)
};

std::vector<uint8_t> read_bytes(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

std::filesystem::path temp_scene(const std::string& tag) {
  return std::filesystem::temp_directory_path() /
         ("voxcast_conformance_" + tag + "_" + std::to_string(::getpid()) + ".vxc");
}

// Builds with the factory and returns the file bytes (throws what it throws).
std::vector<uint8_t> build_file(const StructureFactory& f, const VoxelSet& v, const Mesh* mesh,
                                const std::string& tag) {
  const std::filesystem::path path = temp_scene(tag);
  f.build(v, mesh, path);
  std::vector<uint8_t> bytes = read_bytes(path);
  std::filesystem::remove(path);
  return bytes;
}

struct CaseInputs {
  VoxelSet voxels;
  std::optional<Mesh> mesh;
};

CaseInputs make_inputs(const VoxelCase& c) {
  CaseInputs in;
  if (c.mesh != nullptr) {
    in.mesh = unit_cube_mesh(c.mesh, c.levels);
    in.voxels = voxelize(*in.mesh, testing::unit_grid(c.levels), {});
  } else {
    in.voxels = c.make();
  }
  return in;
}

const Built& built(size_t factory, size_t vcase) {
  static std::map<std::pair<size_t, size_t>, std::unique_ptr<Built>> cache;
  auto& slot = cache[{factory, vcase}];
  if (slot) return *slot;
  const StructureFactory& f = testing::conformance_structures()[factory];
  const VoxelCase& c = voxel_cases()[vcase];
  auto b = std::make_unique<Built>();
  CaseInputs in = make_inputs(c);
  b->voxels = std::move(in.voxels);
  b->mesh = std::move(in.mesh);
  try {
    b->file = build_file(f, b->voxels, b->mesh ? &*b->mesh : nullptr, f.name + "_" + c.name);
  } catch (const Error& e) {
    b->rejected = e.what();
  }
  if (b->rejected.empty()) {
    const std::filesystem::path path = temp_scene(f.name + "_" + c.name + "_load");
    write_file_atomic(path, b->file.data(), b->file.size());
    b->scene = load_scene(path);
    std::filesystem::remove(path);
  }
  slot = std::move(b);
  return *slot;
}

DenseGrid grid_at_level(const VoxelSet& v, int level) {
  DenseGrid g(level);
  const int shift = 3 * (v.grid.levels - level);
  for (uint64_t code : v.codes) {
    const MortonCoord c = morton_decode(code >> shift);
    g.set(c.x, c.y, c.z);
  }
  return g;
}

// ---------------------------------------------------------------------------
// Rays (world = unit cube).

float quantize(float x) {  // multiple of 2^-20: p + 1 is exact in float
  return std::round(x * 0x1p20f) * 0x1p-20f;
}

Vec3 random_unit(std::mt19937_64& rng) {
  std::normal_distribution<float> n(0.f, 1.f);
  for (;;) {
    const Vec3 d{n(rng), n(rng), n(rng)};
    if (length(d) > 1e-3f) return normalize(d);
  }
}

// A mix of ray kinds: outside -> inside, inside with random directions,
// axis-aligned (origins on voxel planes half the time, +-0 components),
// grazing (nearly parallel to a grid plane, on a voxel plane), from lattice
// points (voxel corners) and, with `aim`, from outside at a random point of
// a random voxel of the set (so that sparse sets get hits too).
// `generic` (optional) receives per ray whether it is of a generic kind
// (random origin and direction) rather than built on grid planes or corners.
std::vector<Ray> make_rays(int levels, size_t count, uint64_t seed, const VoxelSet* aim = nullptr,
                           std::vector<char>* generic = nullptr) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> U(0.f, 1.f);
  const float n = float(1u << levels);
  const auto lattice = [&](float lo, float hi, float step) {
    const int k = int(std::floor((hi - lo) / step));
    return lo + step * float(std::uniform_int_distribution<int>(0, k)(rng));
  };
  std::vector<Ray> rays;
  rays.reserve(count);
  for (size_t i = 0; i < count; ++i) {
    Ray r;
    const bool aimed = aim != nullptr && !aim->codes.empty() && i % 3 == 0;
    const size_t kind = aimed ? 5 : i % 5;
    if (generic != nullptr) generic->push_back(kind == 0 || kind == 1 || kind == 5);
    switch (kind) {
      case 0: {
        const Vec3 c{0.5f, 0.5f, 0.5f};
        Vec3 from = c + random_unit(rng) * (0.9f + U(rng));
        from = {quantize(from.x), quantize(from.y), quantize(from.z)};
        const Vec3 to{U(rng), U(rng), U(rng)};
        r = {from, normalize(to - from), INFINITY};
        break;
      }
      case 1:
        r = {{quantize(U(rng)), quantize(U(rng)), quantize(U(rng))}, random_unit(rng), INFINITY};
        break;
      case 2: {
        const int axis = int(rng() % 3);
        Vec3 o, d;
        for (int a = 0; a < 3; ++a) {
          o[a] = lattice(-0.25f, 1.25f, 0.5f / n);
          d[a] = std::copysign(0.f, U(rng) - 0.5f);
        }
        d[axis] = U(rng) < 0.5f ? 1.f : -1.f;
        r = {o, d, INFINITY};
        break;
      }
      case 3: {
        const int axis = int(rng() % 3);
        const float sign = U(rng) < 0.5f ? 1.f : -1.f;
        Vec3 o, d;
        for (int a = 0; a < 3; ++a) {
          o[a] = lattice(0.f, 1.f, 1.f / n);
          d[a] = (U(rng) - 0.5f) * 2e-3f;
        }
        o[axis] = sign > 0 ? -0.5f : 1.5f;
        d[axis] = sign;
        r = {o, normalize(d), INFINITY};
        break;
      }
      case 5: {
        const MortonCoord c = morton_decode(aim->codes[rng() % aim->codes.size()]);
        const Vec3 to{(float(c.x) + U(rng)) / n, (float(c.y) + U(rng)) / n,
                      (float(c.z) + U(rng)) / n};
        Vec3 from = to + random_unit(rng) * (1.f + U(rng));
        from = {quantize(from.x), quantize(from.y), quantize(from.z)};
        r = {from, normalize(to - from), INFINITY};
        break;
      }
      default:
        r = {{lattice(0.f, 1.f, 1.f / n), lattice(0.f, 1.f, 1.f / n), lattice(0.f, 1.f, 1.f / n)},
             random_unit(rng),
             INFINITY};
        break;
    }
    rays.push_back(r);
  }
  return rays;
}

// ---------------------------------------------------------------------------
// Oracle comparison (grid space of a level-l DenseGrid: voxel (x,y,z) is
// [x,x+1]x[y,y+1]x[z,z+1], world p maps to p * 2^l; t is unchanged).

// t tolerance. The casters compute a plane crossing as c / d_a - p_a / d_a
// in float (octree coordinates in [1, 3]): an error of a few ulps of p_a / d_a,
// i.e. ~2^-22 / |d_a| world units for the crossing axis a. Origins inside a
// voxel give t = 0 exactly (both clip to the ray start).
constexpr double kTolBase = 1e-6;
constexpr double kTolPerInvDir = 3 * 0x1p-22;
constexpr double kSlackOct = 0x1p-18;     // rounding slack of the float caster, octree units
constexpr double kMaxTieFraction = 0.01;  // generic rays that may resolve a near-tie either way

struct GridRay {
  DVec3 o, d;
  double tmax;
  int level;
};
GridRay to_grid(const Ray& r, int level) {
  const double n = double(1u << level);
  return {{r.origin.x * n, r.origin.y * n, r.origin.z * n},
          {r.dir.x * n, r.dir.y * n, r.dir.z * n},
          double(r.tmax),
          level};
}

// [t0, t1] of the ray in the box [v - grow, v + 1 + grow]^3 (t >= 0).
bool box_span(const GridRay& r, int x, int y, int z, double grow, double* t0, double* t1) {
  const int v[3] = {x, y, z};
  double a0 = 0, a1 = r.tmax;
  for (int a = 0; a < 3; ++a) {
    const double lo = v[a] - grow, hi = v[a] + 1 + grow;
    if (r.d[a] == 0) {
      if (r.o[a] < lo || r.o[a] > hi) return false;
      continue;
    }
    double ta = (lo - r.o[a]) / r.d[a], tb = (hi - r.o[a]) / r.d[a];
    if (ta > tb) std::swap(ta, tb);
    a0 = std::max(a0, ta), a1 = std::min(a1, tb);
  }
  *t0 = a0, *t1 = a1;
  return a0 <= a1;
}

// Tolerance for a t the caster reports as the entry of voxel (x, y, z): the
// entry is the latest of the three entry-plane crossings, each off by up to
// its axis' error, so every axis whose crossing may be (or tie with) the
// latest one counts, also when the origin lies on its plane (t = 0 then,
// clipped); an origin inside the voxel by more than the error gives t = 0.
double t_tolerance(const GridRay& r, int x, int y, int z) {
  const int v[3] = {x, y, z};
  double ta[3], err[3], latest = -INFINITY;
  for (int a = 0; a < 3; ++a) {
    ta[a] = -INFINITY, err[a] = 0;
    if (r.d[a] == 0) continue;
    ta[a] = (v[a] + (r.d[a] > 0 ? 0 : 1) - r.o[a]) / r.d[a];
    err[a] = kTolPerInvDir / (std::fabs(r.d[a]) / double(1u << r.level));
    latest = std::max(latest, ta[a]);
  }
  double tol = kTolBase;
  for (int a = 0; a < 3; ++a)
    if (r.d[a] != 0 && ta[a] + err[a] >= 0 && ta[a] + err[a] >= latest)
      tol = std::max(tol, kTolBase + err[a]);
  return tol;
}

// True if the ray crosses the voxel shrunk by `shrink` over a non-empty span:
// a hit no rounding can remove.
bool robustly_crossed(const GridRay& r, int x, int y, int z, double shrink) {
  double t0, t1;
  return box_span(r, x, y, z, -shrink, &t0, &t1) && t1 > t0;
}

// The first occupied voxel along the ray that it crosses robustly, walking
// the oracle's hits in order; its t_enter is that of the full voxel. None:
// every occupied voxel is grazed.
DdaHit robust_first_hit(const DenseGrid& g, const GridRay& r, double shrink) {
  double t_from = 0;
  for (int guard = 0; guard < 8 * int(g.resolution()); ++guard) {
    const DVec3 o{r.o.x + r.d.x * t_from, r.o.y + r.d.y * t_from, r.o.z + r.d.z * t_from};
    DdaHit h = g.cast(o, r.d, r.tmax - t_from);
    if (!h.hit) return {};
    h.t_enter += t_from, h.t_exit += t_from;
    if (robustly_crossed(r, h.x, h.y, h.z, shrink)) return h;
    // Grazed: go on just past it (the nudge is far below a voxel).
    t_from = std::max(h.t_exit, t_from) + 1e-9 * (1 + h.t_exit);
    if (t_from > r.tmax) return {};
  }
  return {};
}

enum class Verdict { Exact, Tie, Fail };

struct Tally {
  size_t rays = 0, hits = 0, exact = 0, ties = 0, generic_rays = 0, generic_ties = 0, fails = 0;
  std::string first_fail;
  void add(Verdict v, bool hit, bool generic, const std::string& why) {
    ++rays, hits += hit, generic_rays += generic;
    if (v == Verdict::Exact) ++exact;
    if (v == Verdict::Tie) ++ties, generic_ties += generic;
    if (v == Verdict::Fail && fails++ == 0) first_fail = why;
  }
  // Degenerate rays (on grid planes, from voxel corners) tie often by design;
  // on generic rays a tie is a measure-zero event and must stay rare.
  void expect_ok(const std::string& what) const {
    std::printf(
        "%s: %zu rays, %zu hits, %zu exact, %zu ties (%zu of %zu generic rays), %zu "
        "failures\n",
        what.c_str(), rays, hits, exact, ties, generic_ties, generic_rays, fails);
    EXPECT_EQ(fails, 0u) << what << ": first failure: " << first_fail;
    EXPECT_LE(double(generic_ties), kMaxTieFraction * double(generic_rays) + 2) << what;
  }
};

// The hit voxel of `h` at its level, from its position (clamped into the voxel).
void hit_voxel(const SurfaceHit& h, int* x, int* y, int* z) {
  const double n = double(1u << h.level);
  *x = int(std::floor(double(h.position.x) * n));
  *y = int(std::floor(double(h.position.y) * n));
  *z = int(std::floor(double(h.position.z) * n));
}

std::string describe(const Ray& r, bool hit, const SurfaceHit& h, const DdaHit& ref) {
  char buf[400];
  int x = -1, y = -1, z = -1;
  if (hit) hit_voxel(h, &x, &y, &z);
  std::snprintf(buf, sizeof buf,
                "ray o=(%.9g,%.9g,%.9g) d=(%.9g,%.9g,%.9g) tmax=%g: structure %s (%d,%d,%d) "
                "level %d t=%.9g; oracle %s (%d,%d,%d) t=%.9g",
                r.origin.x, r.origin.y, r.origin.z, r.dir.x, r.dir.y, r.dir.z, r.tmax,
                hit ? "hit" : "miss", x, y, z, hit ? h.level : -1, hit ? h.t : 0.f,
                ref.hit ? "hit" : "miss", ref.x, ref.y, ref.z, ref.t_enter);
  return buf;
}

// One ray against the oracle grid `g` (the level the cast must stop at).
Verdict judge(const DenseGrid& g, testing::VoxelGeometry geometry, const Ray& ray, bool hit,
              const SurfaceHit& h, std::string* why) {
  const int level = g.levels();
  const GridRay r = to_grid(ray, level);
  const double slack = kSlackOct * g.resolution();
  const DdaHit ref = g.cast(r.o, r.d, r.tmax);
  *why = describe(ray, hit, h, ref);
  int x = -1, y = -1, z = -1;
  double tol = kTolBase;
  if (hit) {
    if (h.level != level) return Verdict::Fail;
    hit_voxel(h, &x, &y, &z);
    if (!g.occupied(x, y, z)) return Verdict::Fail;  // a hit in empty space
    tol = t_tolerance(r, x, y, z);
    // The hit is an occupied voxel the ray (nearly) enters at t.
    double t0, t1;
    if (!box_span(r, x, y, z, slack, &t0, &t1)) return Verdict::Fail;
    if (h.t < t0 - tol || h.t > t1 + tol) return Verdict::Fail;
  }
  const bool grazed_hit = hit && !robustly_crossed(r, x, y, z, slack);
  if (geometry == testing::VoxelGeometry::ContourNarrowed) {
    // The shape lies inside the cube: a miss is always possible, a hit is
    // never before the oracle's first cube unless it only grazes its own.
    if (!hit) return Verdict::Exact;
    if (ref.hit && h.t >= ref.t_enter - tol) return Verdict::Exact;
    return grazed_hit ? Verdict::Tie : Verdict::Fail;
  }
  if (!hit && !ref.hit) return Verdict::Exact;
  const bool same_voxel = hit && ref.hit && x == ref.x && y == ref.y && z == ref.z;
  if (same_voxel)
    return std::fabs(double(h.t) - ref.t_enter) <= tol ? Verdict::Exact : Verdict::Fail;
  // Disagreement: only acceptable where the ray passes within rounding slack
  // of a voxel boundary. The structure must never miss a robustly crossed
  // voxel nor stop after one, and one of the two voxels must be grazed.
  const DdaHit robust = robust_first_hit(g, r, slack);
  if (!hit) return robust.hit ? Verdict::Fail : Verdict::Tie;
  if (robust.hit && h.t > robust.t_enter + t_tolerance(r, robust.x, robust.y, robust.z))
    return Verdict::Fail;
  const bool grazed_ref = ref.hit && !robustly_crossed(r, ref.x, ref.y, ref.z, slack);
  return grazed_hit || grazed_ref ? Verdict::Tie : Verdict::Fail;
}

// ---------------------------------------------------------------------------
// The parameterized suite.

struct Param {
  size_t factory, vcase;
};

std::string param_name(const ::testing::TestParamInfo<Param>& info) {
  return testing::conformance_structures()[info.param.factory].name + "_" +
         voxel_cases()[info.param.vcase].name;
}

// Readable ctest names (gtest_discover_tests prints the parameter).
void PrintTo(const Param& p, std::ostream* os) {
  *os << param_name(::testing::TestParamInfo<Param>(p, 0));
}

std::vector<Param> params(bool empty_cases) {
  std::vector<Param> out;
  for (size_t f = 0; f < testing::conformance_structures().size(); ++f) {
    for (size_t c = 0; c < voxel_cases().size(); ++c) {
      const VoxelCase& vc = voxel_cases()[c];
      const bool is_empty = vc.name == "empty";
      if (is_empty != empty_cases) continue;
      if (testing::conformance_structures()[f].needs_mesh && vc.mesh == nullptr) continue;
      out.push_back({f, c});
    }
  }
  return out;
}

class Conformance : public ::testing::TestWithParam<Param> {
 protected:
  const StructureFactory& factory() const {
    return testing::conformance_structures()[GetParam().factory];
  }
  const VoxelCase& vcase() const { return voxel_cases()[GetParam().vcase]; }
  // The built and loaded structure; a factory may not refuse a non-empty set.
  const Built& structure() const {
    const Built& b = built(GetParam().factory, GetParam().vcase);
    EXPECT_EQ(b.rejected, "") << "the factory refused a non-empty voxel set";
    return b;
  }
  std::string label() const { return factory().name + "/" + vcase().name; }
};

TEST_P(Conformance, FirstHitMatchesDda) {
  TraceContext ctx;
  const Built& b = structure();
  if (!b.rejected.empty()) return;
  const SurfaceQuery& s = *b.scene.structure->surface();
  const DenseGrid g = grid_at_level(b.voxels, b.voxels.grid.levels);
  Tally tally;
  std::vector<char> generic;
  const std::vector<Ray> rays =
      make_rays(g.levels(), 3000, 11 + GetParam().vcase, &b.voxels, &generic);
  for (size_t i = 0; i < rays.size(); ++i) {
    SurfaceHit h;
    const bool hit = s.trace(rays[i], LodFootprint{}, ctx, &h);
    std::string why;
    tally.add(judge(g, factory().geometry, rays[i], hit, h, &why), hit, generic[i], why);
  }
  tally.expect_ok(label() + " LOD 0");
  EXPECT_GT(tally.hits, tally.rays / 20) << "too few hits to test anything";
}

// Renders with the given beam block size; images with depth and normals.
RenderResult render_with(const Structure& s, const Camera& camera, int beam, float lod,
                         bool effects = false) {
  RenderOptions o;
  o.width = 37, o.height = 29;  // partial beam blocks at the borders
  o.camera = camera;
  o.lod_pixels = lod;
  o.beam = beam;
  o.want_depth = o.want_normal = true;
  if (effects) {
    o.effects.shadows = ShadowMode::Hard;
    o.effects.ao_rays = 2;
  }
  return render(s, o);
}

bool same_pixels(const Image& a, const Image& b) {
  return a.width == b.width && a.height == b.height && a.channels == b.channels &&
         a.pixels.size() == b.pixels.size() &&
         std::memcmp(a.pixels.data(), b.pixels.data(), a.pixels.size() * sizeof(float)) == 0;
}

std::vector<Camera> test_cameras() {
  Camera outside;  // framing the unit cube from front-right-above
  outside = Camera::frame(Aabb{{0, 0, 0}, {1, 1, 1}}, 37, 29);
  Camera inside;
  inside.eye = {0.52f, 0.47f, 0.55f};
  inside.target = {0.1f, 0.9f, 0.2f};
  inside.fovy_degrees = 80.f;
  Camera grazing;  // along a grid plane from outside
  grazing.eye = {0.5f, 0.5f, -1.5f};
  grazing.target = {0.5f, 0.5f, 0.5f};
  grazing.fovy_degrees = 30.f;
  return {outside, inside, grazing};
}

TEST_P(Conformance, BeamOnEqualsBeamOff) {
  const Built& b = structure();
  if (!b.rejected.empty()) return;
  const Structure& s = *b.scene.structure;
  uint64_t hits = 0;
  for (const Camera& cam : test_cameras()) {
    for (float lod : {0.f, 1.5f}) {
      const RenderResult off = render_with(s, cam, 0, lod);
      hits += off.hits;
      for (int beam : {4, 8}) {
        const RenderResult on = render_with(s, cam, beam, lod);
        const std::string what = label() + " beam " + std::to_string(beam) + " lod " +
                                 std::to_string(lod) + " camera " + cam.to_string();
        EXPECT_EQ(on.hits, off.hits) << what;
        EXPECT_TRUE(same_pixels(on.color, off.color)) << what;
        EXPECT_TRUE(same_pixels(on.depth, off.depth)) << what;
        EXPECT_TRUE(same_pixels(on.normal, off.normal)) << what;
      }
    }
  }
  EXPECT_GT(hits, 0u) << "the cameras must see the structure";
}

TEST_P(Conformance, OcclusionEqualsTraceBeforeTmax) {
  TraceContext ctx;
  const Built& b = structure();
  if (!b.rejected.empty()) return;
  const SurfaceQuery& s = *b.scene.structure->surface();
  std::mt19937_64 rng(23 + GetParam().vcase);
  std::uniform_real_distribution<float> U(0.f, 1.f);
  size_t occluded = 0, free = 0, mismatches = 0;
  std::string first;
  const float voxel = float(b.voxels.grid.voxel_size);
  for (Ray ray : make_rays(b.voxels.grid.levels, 3000, 29 + GetParam().vcase, &b.voxels)) {
    ray.tmax = U(rng) * 1.8f;
    for (const LodFootprint lod : {LodFootprint{}, LodFootprint{0.f, voxel * 2.f}}) {
      SurfaceHit h;
      const bool traced = s.trace(ray, lod, ctx, &h);
      const bool any = s.occluded(ray, lod, ctx);
      (any ? occluded : free)++;
      if (any != traced && mismatches++ == 0)
        first = "tmax " + std::to_string(ray.tmax) + ": occluded " + std::to_string(any) +
                ", trace " + std::to_string(traced) + " (t " + std::to_string(h.t) + ")";
      if (traced) {
        EXPECT_LE(h.t, ray.tmax);
      }
    }
  }
  std::printf("%s: %zu occluded, %zu free segments\n", label().c_str(), occluded, free);
  EXPECT_EQ(mismatches, 0u) << label() << ": " << first;
  EXPECT_GT(occluded, 0u);
}

// The leaf voxels (Morton codes at the finest level) inside the cube of
// `level` with coordinates (x, y, z).
std::vector<size_t> voxels_in_cube(const VoxelSet& v, int level, int x, int y, int z) {
  const int shift = 3 * (v.grid.levels - level);
  const uint64_t cube = morton_encode(uint32_t(x), uint32_t(y), uint32_t(z));
  const auto lo = std::lower_bound(v.codes.begin(), v.codes.end(), cube << shift);
  const auto hi = std::lower_bound(v.codes.begin(), v.codes.end(), (cube + 1) << shift);
  std::vector<size_t> out;
  for (auto it = lo; it != hi; ++it) out.push_back(size_t(it - v.codes.begin()));
  return out;
}

// The linear color and normal the structure shows for leaf voxel `i` at LOD
// 0: a ray starting at its center hits it at t = 0.
void leaf_attributes(const SurfaceQuery& s, const VoxelSet& v, size_t i, Color* col, Vec3* nrm) {
  TraceContext ctx;
  const MortonCoord c = morton_decode(v.codes[i]);
  const float n = float(v.grid.resolution);
  const Ray ray{{(float(c.x) + 0.5f) / n, (float(c.y) + 0.5f) / n, (float(c.z) + 0.5f) / n},
                {1, 0, 0},
                INFINITY};
  SurfaceHit h;
  EXPECT_TRUE(s.trace(ray, LodFootprint{}, ctx, &h));
  EXPECT_EQ(h.t, 0.f);
  s.attributes(h, ctx, col, nrm);
}

// The color promise of an LOD hit cube (StructureFactory::lod_colors).
void check_lod_color(const StructureFactory& f, const SurfaceQuery& s, const VoxelSet& v,
                     const SurfaceHit& h, size_t* checked) {
  TraceContext ctx;
  if (f.lod_colors == testing::LodColors::None || v.colors.empty()) return;
  int x, y, z;
  hit_voxel(h, &x, &y, &z);
  const std::vector<size_t> inside = voxels_in_cube(v, h.level, x, y, z);
  ASSERT_FALSE(inside.empty());
  Color shown;
  Vec3 normal;
  s.attributes(h, ctx, &shown, &normal);
  double e[3] = {0, 0, 0}, wsum = 0, nsum[3] = {0, 0, 0};
  for (size_t i : inside) {
    if (f.lod_colors == testing::LodColors::AreaWeightedMean) {
      const double w = v.weights.empty() ? 1.0 : v.weights[i];
      e[0] += w * v.colors[i].r, e[1] += w * v.colors[i].g, e[2] += w * v.colors[i].b;
      wsum += w;
    } else {
      Color c;
      Vec3 n;
      leaf_attributes(s, v, i, &c, &n);
      e[0] += c.r, e[1] += c.g, e[2] += c.b;
      nsum[0] += n.x, nsum[1] += n.y, nsum[2] += n.z;
      wsum += 1;
    }
  }
  const float got[3] = {shown.r, shown.g, shown.b};
  for (int k = 0; k < 3; ++k) {
    const double want = e[k] / wsum;
    if (f.lod_colors == testing::LodColors::AreaWeightedMean) {
      // Stored as 8-bit sRGB: half a code step plus float slack.
      EXPECT_NEAR(linear_to_srgb(got[k]), linear_to_srgb(float(want)), 0.5 / 255 + 1e-4)
          << "channel " << k << " of a level-" << h.level << " cube of " << inside.size();
    } else {
      // dag.hpp: exact fixed-point sums (2^-24) of the leaves' linear values.
      EXPECT_NEAR(got[k], want, 1e-5)
          << "channel " << k << " of a level-" << h.level << " cube of " << inside.size();
    }
  }
  if (f.lod_colors == testing::LodColors::MeanOfLeaves) {
    // ... and the normalized mean of the leaves' normals (where it is defined).
    const double len = std::sqrt(nsum[0] * nsum[0] + nsum[1] * nsum[1] + nsum[2] * nsum[2]);
    if (len > 1e-3 * double(inside.size())) {
      const double cosine = (normal.x * nsum[0] + normal.y * nsum[1] + normal.z * nsum[2]) / len;
      EXPECT_GT(cosine, std::cos(1e-3)) << "normal of a level-" << h.level << " cube";
    }
  }
  ++*checked;
}

TEST_P(Conformance, LodStopsAreConsistent) {
  TraceContext ctx;
  const Built& b = structure();
  if (!b.rejected.empty()) return;
  const SurfaceQuery& s = *b.scene.structure->surface();
  const int L = b.voxels.grid.levels;
  std::vector<DenseGrid> grids;
  for (int l = 0; l <= L; ++l) grids.push_back(grid_at_level(b.voxels, l));
  // (1) A constant footprint of one level-l cube stops exactly at level l:
  // the result is the oracle's first hit on the grid coarsened to level l.
  Tally constant;
  size_t colors_checked = 0;
  std::vector<char> generic;
  const std::vector<Ray> rays = make_rays(L, 2000, 31 + GetParam().vcase, &b.voxels, &generic);
  for (size_t i = 0; i < rays.size(); ++i) {
    const int level = 1 + int(i % size_t(L - 1));  // 1 .. L-1
    const LodFootprint lod{std::ldexp(1.f, -level), 0.f};
    SurfaceHit h;
    const bool hit = s.trace(rays[i], lod, ctx, &h);
    std::string why;
    constant.add(judge(grids[size_t(level)], factory().geometry, rays[i], hit, h, &why), hit,
                 generic[i], why);
    if (hit && colors_checked < 40 && i % 3 == 0)
      check_lod_color(factory(), s, b.voxels, h, &colors_checked);
  }
  constant.expect_ok(label() + " constant footprint");
  // (2) A pixel cone (size grows with t, as render() traces): the stop is an
  // occupied cube no later than the LOD-0 hit, which it contains whenever
  // the ray reaches the LOD-0 voxel's ancestor first; a LOD-0 hit implies an
  // LOD hit. (A coarse cube may stop a ray that passes through its holes at
  // LOD 0, so "both miss or ancestor" alone would be false.)
  size_t cone_hits = 0, ancestors = 0, coarse = 0, fails = 0;
  std::string first;
  for (size_t i = 0; i < rays.size(); ++i) {
    const float per_t = std::ldexp(1.f, -L) * float(1 + i % 8);
    SurfaceHit h0, hk;
    const bool hit0 = s.trace(rays[i], LodFootprint{}, ctx, &h0);
    const bool hitk = s.trace(rays[i], LodFootprint{0.f, per_t}, ctx, &hk);
    std::string why = describe(rays[i], hitk, hk, DdaHit{});
    bool ok = !hit0 || hitk;
    if (hitk) {
      ++cone_hits;
      int x, y, z;
      hit_voxel(hk, &x, &y, &z);
      ok = ok && hk.level >= 0 && hk.level <= L && grids[size_t(hk.level)].occupied(x, y, z);
      coarse += hk.level < L;
      if (hit0) {
        int x0, y0, z0;
        hit_voxel(h0, &x0, &y0, &z0);
        ok = ok &&
             double(hk.t) <= double(h0.t) + t_tolerance(to_grid(rays[i], h0.level), x0, y0, z0);
        const int up = h0.level - hk.level;
        ancestors += up >= 0 && (x0 >> up) == x && (y0 >> up) == y && (z0 >> up) == z;
      }
      if (hk.level < L && colors_checked < 80 && i % 3 == 0)
        check_lod_color(factory(), s, b.voxels, hk, &colors_checked);
    }
    if (!ok && fails++ == 0) first = why;
  }
  std::printf("%s pixel cone: %zu hits, %zu coarse, %zu ancestors of the LOD-0 hit, %zu colors\n",
              label().c_str(), cone_hits, coarse, ancestors, colors_checked);
  EXPECT_EQ(fails, 0u) << first;
  if (L > 2 && b.voxels.size() > 8) {
    EXPECT_GT(coarse, 0u) << "the cone never stopped early";
  }
}

// Hits of every kind for the attribute tests below: leaf hits, LOD stops at
// every level and pixel cones, in turn (600 rays, seeded by `seed`).
std::vector<SurfaceHit> mixed_hits(const SurfaceQuery& s, const VoxelSet& voxels, uint32_t seed) {
  TraceContext ctx;
  const int L = voxels.grid.levels;
  const std::vector<Ray> rays = make_rays(L, 600, seed, &voxels, nullptr);
  std::vector<SurfaceHit> hits;
  for (size_t i = 0; i < rays.size(); ++i) {
    LodFootprint lod{};
    if (i % 3 == 1) lod = LodFootprint{std::ldexp(1.f, -(1 + int(i / 3 % size_t(L)))), 0.f};
    if (i % 3 == 2) lod = LodFootprint{0.f, std::ldexp(1.f, -L) * float(1 + i % 8)};
    SurfaceHit h;
    if (s.trace(rays[i], lod, ctx, &h)) hits.push_back(h);
  }
  return hits;
}

// The attribute prefetch hints (SurfaceQuery::prefetch_attribute_index and
// prefetch_attributes, which the integrator calls for every hit) are hints:
// on every kind of hit they read nothing out of bounds (the ASan subset of
// ./run runs this case) and change no answer.
TEST_P(Conformance, AttributePrefetchHintsChangeNothing) {
  TraceContext ctx;
  const Built& b = structure();
  if (!b.rejected.empty()) return;
  const SurfaceQuery& s = *b.scene.structure->surface();
  const std::vector<SurfaceHit> hits = mixed_hits(s, b.voxels, 57 + GetParam().vcase);
  for (size_t i = 0; i < hits.size(); ++i) {
    Color c0, c1;
    Vec3 n0, n1;
    s.attributes(hits[i], ctx, &c0, &n0);
    s.prefetch_attribute_index(hits[i]);
    s.prefetch_attributes(hits[i]);
    s.attributes(hits[i], ctx, &c1, &n1);
    ASSERT_EQ(std::memcmp(&c0, &c1, sizeof c0), 0) << label() << " hit " << i;
    ASSERT_EQ(std::memcmp(&n0, &n1, sizeof n0), 0) << label() << " hit " << i;
  }
  if (b.voxels.size() > 8) {
    EXPECT_FALSE(hits.empty()) << label();
  }
}

// attributes_batch (the integrator's call for a group of hits) answers and
// counts what attributes() does hit by hit, for every kind of hit and for
// groups that span a structure's internal chunks.
TEST_P(Conformance, AttributesBatchMatchesOneAtATime) {
  const Built& b = structure();
  if (!b.rejected.empty()) return;
  const SurfaceQuery& s = *b.scene.structure->surface();
  const std::vector<SurfaceHit> hits = mixed_hits(s, b.voxels, 91 + GetParam().vcase);
  const int n = int(hits.size());
  std::vector<const SurfaceHit*> ptr(hits.size());
  for (size_t i = 0; i < hits.size(); ++i) ptr[i] = &hits[i];
  std::vector<Color> c0(hits.size()), c1(hits.size());
  std::vector<Vec3> n0(hits.size()), n1(hits.size());
  TraceContext one, many;
  one.counting = many.counting = true;
  for (int i = 0; i < n; ++i) s.attributes(hits[size_t(i)], one, &c0[size_t(i)], &n0[size_t(i)]);
  // All at once, then in odd-sized groups (chunk edges fall elsewhere).
  for (int group : {n, 13}) {
    many.counters = RayCounters{};
    for (int g = 0; g < n; g += group)
      s.attributes_batch(ptr.data() + g, std::min(group, n - g), many, c1.data() + g,
                         n1.data() + g);
    for (int i = 0; i < n; ++i) {
      ASSERT_EQ(std::memcmp(&c0[size_t(i)], &c1[size_t(i)], sizeof(Color)), 0)
          << label() << " hit " << i << " group " << group;
      ASSERT_EQ(std::memcmp(&n0[size_t(i)], &n1[size_t(i)], sizeof(Vec3)), 0)
          << label() << " hit " << i << " group " << group;
    }
    EXPECT_EQ(many.counters.attribute_bytes, one.counters.attribute_bytes) << label();
  }
  if (b.voxels.size() > 8) {
    EXPECT_GT(n, 0) << label();
  }
}

// The first `size` bytes of a scene file through the generic loader: a
// container parsed in memory, or a file type of its own (own_file: slice
// files) written to a file first (it is opened by path only).
LoadedScene load_bytes(bool own_file, const std::vector<uint8_t>& bytes, size_t size) {
  if (!own_file) return load_scene(Container::parse(bytes.data(), size));
  const std::filesystem::path path = temp_scene("bytes");
  {
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out.write(reinterpret_cast<const char*>(bytes.data()), std::streamsize(size));
  }
  struct Remove {
    std::filesystem::path p;
    ~Remove() { std::filesystem::remove(p); }
  } remove{path};
  return load_scene(path);
}

TEST_P(Conformance, ThreadCountInvariance) {
  const Built& b = structure();
  if (!b.rejected.empty()) return;
  std::vector<uint8_t> file[2];
  RenderResult image[2];
  for (int k = 0; k < 2; ++k) {
    tbb::global_control gc(tbb::global_control::max_allowed_parallelism, size_t(k + 1));
    // The voxelization too, for the mesh cases: the input must not differ.
    const CaseInputs in = make_inputs(vcase());
    file[k] = build_file(factory(), in.voxels, in.mesh ? &*in.mesh : nullptr,
                         factory().name + "_threads");
    LoadedScene scene = load_bytes(factory().own_file, file[k], file[k].size());
    image[k] = render_with(*scene.structure, test_cameras()[0], 4, 1.f, true);
  }
  EXPECT_TRUE(file[0] == file[1]) << "the saved file depends on the thread count";
  EXPECT_TRUE(file[0] == b.file) << "the file differs from the default-thread build";
  EXPECT_TRUE(same_pixels(image[0].color, image[1].color));
  EXPECT_TRUE(same_pixels(image[0].depth, image[1].depth));
  EXPECT_TRUE(same_pixels(image[0].shadow, image[1].shadow));
  EXPECT_TRUE(same_pixels(image[0].ao, image[1].ao));
  EXPECT_GT(image[0].hits, 0u);
}

// Loads `bytes` with the generic loader; when accepted, renders and traces
// with it. Any exception other than voxcast::Error is a failure.
enum class Outcome { Rejected, Rendered, Failed };
Outcome load_and_use(bool own_file, const std::vector<uint8_t>& bytes, size_t size,
                     std::string* why) {
  TraceContext ctx;
  LoadedScene scene;
  try {
    scene = load_bytes(own_file, bytes, size);
  } catch (const Error&) {
    return Outcome::Rejected;
  } catch (const std::exception& e) {
    *why = std::string("non-voxcast exception: ") + e.what();
    return Outcome::Failed;
  } catch (...) {
    *why = "unknown exception";
    return Outcome::Failed;
  }
  try {
    RenderOptions o;
    o.width = 12, o.height = 10;
    o.camera = test_cameras()[0];
    o.beam = 4;
    o.effects.shadows = ShadowMode::Hard;
    render(*scene.structure, o);
    const SurfaceQuery& q = *scene.structure->surface();
    for (const Ray& ray : make_rays(4, 20, 3)) {
      SurfaceHit h;
      if (q.trace(ray, LodFootprint{0.f, 0.01f}, ctx, &h)) {
        Color c;
        Vec3 n;
        q.attributes(h, ctx, &c, &n);
      }
      q.occluded(ray, LodFootprint{}, ctx);
    }
  } catch (const std::exception& e) {
    *why = std::string("accepted, then threw: ") + e.what();
    return Outcome::Failed;
  }
  return Outcome::Rendered;
}

TEST_P(Conformance, DamagedFilesAreRejectedCleanly) {
  const Built& b = structure();
  if (!b.rejected.empty()) return;
  const std::vector<uint8_t>& file = b.file;
  std::mt19937_64 rng(41 + GetParam().vcase);
  std::string why;
  // Every truncation of a small file, else all near both ends and a sample.
  std::vector<size_t> lengths;
  if (file.size() <= 40000) {
    for (size_t n = 0; n < file.size(); ++n) lengths.push_back(n);
  } else {
    for (size_t n = 0; n < 2048; ++n) lengths.push_back(n), lengths.push_back(file.size() - 1 - n);
    for (int k = 0; k < 2000; ++k) lengths.push_back(size_t(rng() % file.size()));
  }
  size_t rejected = 0, failed = 0;
  std::string first;
  for (size_t n : lengths) {
    const Outcome o = load_and_use(factory().own_file, file, n, &why);
    rejected += o == Outcome::Rejected;
    if (o == Outcome::Failed && failed++ == 0) first = "length " + std::to_string(n) + ": " + why;
  }
  EXPECT_EQ(failed, 0u) << first;
  // The container covers every byte by a fixed value or a hash: a truncated
  // file is never a valid file.
  EXPECT_EQ(rejected, lengths.size()) << "a truncated file was accepted";
  // Byte corruptions as stored (hashes stale): every one is detected.
  size_t stale_rejected = 0;
  for (int k = 0; k < 300; ++k) {
    std::vector<uint8_t> bad = file;
    bad[rng() % bad.size()] ^= uint8_t(1 + rng() % 255);
    const Outcome o = load_and_use(factory().own_file, bad, bad.size(), &why);
    stale_rejected += o == Outcome::Rejected;
    if (o == Outcome::Failed && failed++ == 0) first = "stale-hash flip: " + why;
  }
  EXPECT_EQ(failed, 0u) << first;
  EXPECT_EQ(stale_rejected, 300u) << "a corrupted byte went unnoticed by the section hashes";
  // Corruptions with the hashes recomputed: the structure's own validation
  // is what stands between them and the caster. Rejected, or accepted and
  // rendered without harm. A container: inside a section (Container::add +
  // serialize rehash); a file type of its own (slice files): anywhere, with
  // every hash of the file recomputed (testing::rehash_slice_file).
  const bool own = factory().own_file;
  std::optional<Container> original;
  std::vector<uint32_t> ids;
  if (!own) {
    original = Container::parse(file.data(), file.size());
    ids = original->section_ids();
  }
  size_t fresh_rejected = 0, fresh_rendered = 0;
  for (int k = 0; k < 400; ++k) {
    std::vector<uint8_t> bytes;
    if (own) {
      bytes = file;
      const int flips = 1 + int(rng() % 3);
      for (int j = 0; j < flips; ++j) bytes[rng() % bytes.size()] ^= uint8_t(1u << (rng() % 8));
      testing::rehash_slice_file(bytes);
    } else {
      Container c = *original;
      const uint32_t id = ids[rng() % ids.size()];
      std::vector<uint8_t> sec = c.get(id);
      if (sec.empty()) continue;
      const int flips = 1 + int(rng() % 3);
      for (int j = 0; j < flips; ++j) sec[rng() % sec.size()] ^= uint8_t(1u << (rng() % 8));
      if (k % 10 == 0) sec.resize(rng() % sec.size());  // a section cut short, rehashed
      c.add(id, std::move(sec));
      bytes = c.serialize();
    }
    const Outcome o = load_and_use(own, bytes, bytes.size(), &why);
    fresh_rejected += o == Outcome::Rejected;
    fresh_rendered += o == Outcome::Rendered;
    if (o == Outcome::Failed && failed++ == 0) first = "rehashed flip: " + why;
  }
  std::printf(
      "%s: %zu truncations, %zu stale flips rejected; rehashed: %zu rejected, %zu "
      "accepted and rendered\n",
      label().c_str(), lengths.size(), stale_rejected, fresh_rejected, fresh_rendered);
  EXPECT_EQ(failed, 0u) << first;
  EXPECT_GT(fresh_rejected, 0u) << "validation rejected no rehashed corruption";
}

INSTANTIATE_TEST_SUITE_P(Structures, Conformance, ::testing::ValuesIn(params(false)), param_name);

// Negative controls: the oracle comparison catches a caster that reports the
// neighbouring voxel, one that stops a little late, and one that drops hits.
class Tampered final : public SurfaceQuery {
 public:
  enum class Fault { NextVoxel, LateT, DropHits };
  Tampered(const SurfaceQuery& inner, Fault fault) : inner_(inner), fault_(fault) {}
  bool trace(const Ray& ray, const LodFootprint& lod, TraceContext& ctx, SurfaceHit* hit,
             const BeamStart* beam = nullptr) const override {
    if (!inner_.trace(ray, lod, ctx, hit, beam)) return false;
    if (fault_ == Fault::DropHits) return (++calls_ % 2) == 0;
    if (fault_ == Fault::NextVoxel) hit->position.x += hit->voxel_size;
    if (fault_ == Fault::LateT) hit->t += 1e-4f;
    return true;
  }
  void attributes(const SurfaceHit& hit, TraceContext& ctx, Color* color,
                  Vec3* normal) const override {
    inner_.attributes(hit, ctx, color, normal);
  }

 private:
  const SurfaceQuery& inner_;
  Fault fault_;
  mutable uint64_t calls_ = 0;
};

TEST(ConformanceOracle, CatchesWrongHits) {
  TraceContext ctx;
  const size_t esvo = 0, half_dense = 3;
  ASSERT_EQ(voxel_cases()[half_dense].name, "half_dense");
  const Built& b = built(esvo, half_dense);
  ASSERT_EQ(b.rejected, "");
  const DenseGrid g = grid_at_level(b.voxels, b.voxels.grid.levels);
  const std::vector<Ray> rays = make_rays(g.levels(), 300, 99, &b.voxels);
  for (const auto fault :
       {Tampered::Fault::NextVoxel, Tampered::Fault::LateT, Tampered::Fault::DropHits}) {
    const Tampered s(*b.scene.structure->surface(), fault);
    size_t fails = 0, hits = 0;
    for (const Ray& ray : rays) {
      SurfaceHit h;
      const bool hit = s.trace(ray, LodFootprint{}, ctx, &h);
      std::string why;
      hits += hit;
      fails += judge(g, testing::VoxelGeometry::Cubes, ray, hit, h, &why) == Verdict::Fail;
    }
    EXPECT_GT(fails, hits / 4) << "fault " << int(fault);
  }
}

// An empty voxel set: the factory refuses it with voxcast::Error, or the
// structure it builds misses every ray and renders nothing.
class ConformanceEmpty : public ::testing::TestWithParam<Param> {};

TEST_P(ConformanceEmpty, RejectedOrMissesEverything) {
  TraceContext ctx;
  const Built& b = built(GetParam().factory, GetParam().vcase);
  ASSERT_EQ(b.voxels.size(), 0u);
  if (!b.rejected.empty()) {
    std::printf("%s refuses an empty set: %s\n",
                param_name(::testing::TestParamInfo<Param>(GetParam(), 0)).c_str(),
                b.rejected.c_str());
    return;
  }
  const Structure& s = *b.scene.structure;
  const SurfaceQuery& q = *s.surface();
  for (const Ray& ray : make_rays(b.voxels.grid.levels, 500, 7)) {
    SurfaceHit h;
    EXPECT_FALSE(q.trace(ray, LodFootprint{}, ctx, &h));
    EXPECT_FALSE(q.occluded(ray, LodFootprint{}, ctx));
  }
  EXPECT_EQ(render_with(s, test_cameras()[0], 4, 1.f).hits, 0u);
}

INSTANTIATE_TEST_SUITE_P(Structures, ConformanceEmpty, ::testing::ValuesIn(params(true)),
                         param_name);

}  // namespace
}  // namespace voxcast
