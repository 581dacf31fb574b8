// Procedural stress meshes (hairball, Menger sponge, fBm terrain) and a small
// OBJ / binary PLY writer. See generate.hpp.
#include "voxcast/generate.hpp"

#include <fmt/format.h>

#include <bit>
#include <cmath>
#include <cstring>
#include <random>
#include <string>
#include <unordered_map>
#include <vector>

#include "voxcast/error.hpp"
#include "voxcast/image.hpp"
#include "voxcast/math.hpp"

namespace voxcast::generate {
namespace {

// The generators compute in double (voxcast::Vec3d); positions are rounded to
// float only when stored. unit_of() multiplies by the reciprocal length (not
// voxcast::normalize's division): the generated meshes' bytes depend on it.
Vec3d unit_of(Vec3d a) {
  return a * (1.0 / std::sqrt(dot(a, a)));
}

// Deterministic uniform double in [0, 1) from the 53 high bits of a 64-bit
// Mersenne Twister (std::mt19937_64's output sequence is fixed by the
// standard; the <random> distributions are not).
class Rng {
 public:
  explicit Rng(uint64_t seed) : mt_(seed) {}
  double uniform() { return double(mt_() >> 11) * 0x1.0p-53; }
  double uniform(double lo, double hi) { return lo + (hi - lo) * uniform(); }
  // Uniform direction by rejection from the cube.
  Vec3d unit() {
    for (;;) {
      Vec3d v{uniform(-1, 1), uniform(-1, 1), uniform(-1, 1)};
      const double l2 = dot(v, v);
      if (l2 > 1e-6 && l2 <= 1) return v * (1.0 / std::sqrt(l2));
    }
  }
  Vec3d in_ball(double r) {
    for (;;) {
      Vec3d v{uniform(-1, 1), uniform(-1, 1), uniform(-1, 1)};
      if (dot(v, v) <= 1) return v * r;
    }
  }

 private:
  std::mt19937_64 mt_;
};

template <class T>
void check_range(const char* what, T v, T lo, T hi) {
  if (!(v >= lo && v <= hi)) throw Error(fmt::format("{} {} is outside {} .. {}", what, v, lo, hi));
}

Vec3 to_float(const Vec3d& v) {
  return {float(v.x), float(v.y), float(v.z)};
}

}  // namespace

Mesh hairball(const HairballOptions& o) {
  check_range("hairball: tubes", o.tubes, 1, 1000000);
  check_range("hairball: segments", o.segments, 1, 100000);
  check_range("hairball: sides", o.sides, 3, 64);
  check_range("hairball: radius", o.radius, 1e-6, 0.5);
  check_range("hairball: step", o.step, 1e-6, 1.0);
  const uint64_t rings = uint64_t(o.segments) + 1;
  const uint64_t verts = uint64_t(o.tubes) * (rings * uint64_t(o.sides) + 2);
  const uint64_t tris = uint64_t(o.tubes) * (2 * uint64_t(o.segments) + 2) * uint64_t(o.sides);
  if (verts > 0xFFFFFFFFull || tris * 3 > 0xFFFFFFFFull)
    throw Error(fmt::format("hairball: {} triangles is too many", tris));
  Rng rng(o.seed);
  Mesh m;
  m.positions.reserve(size_t(verts));
  m.indices.reserve(size_t(tris * 3));
  const double two_pi = 2.0 * 3.14159265358979323846;
  std::vector<Vec3d> path(rings);
  for (int t = 0; t < o.tubes; ++t) {
    // Random walk with a slowly turning direction, kept inside the unit ball
    // by reflecting the direction at the sphere.
    Vec3d p = rng.in_ball(1.0 - o.radius);
    Vec3d d = rng.unit();
    for (uint64_t i = 0; i < rings; ++i) {
      path[size_t(i)] = p;
      d = unit_of(d + rng.unit() * 0.35);
      Vec3d q = p + d * o.step;
      if (dot(q, q) > (1.0 - o.radius) * (1.0 - o.radius)) {
        const Vec3d n = unit_of(p);
        if (dot(d, n) > 0) d = d - n * (2 * dot(d, n));
        q = p + d * o.step;
        if (dot(q, q) > 1) q = p;  // cannot happen for step < 1, kept for safety
      }
      p = q;
    }
    // Frame transported along the polyline (rotation-minimizing by projection).
    const uint32_t base = uint32_t(m.positions.size());
    Vec3d tan = unit_of(path[1] - path[0]);
    Vec3d a = std::fabs(tan.x) < 0.9 ? Vec3d{1, 0, 0} : Vec3d{0, 1, 0};
    Vec3d u = unit_of(cross(tan, a));
    for (uint64_t i = 0; i < rings; ++i) {
      const Vec3d prev = path[size_t(i == 0 ? 0 : i - 1)];
      const Vec3d next = path[size_t(i + 1 == rings ? i : i + 1)];
      Vec3d tn = next - prev;
      if (dot(tn, tn) > 1e-24)
        tn = unit_of(tn);
      else
        tn = tan;
      Vec3d un = u - tn * dot(u, tn);
      if (dot(un, un) < 1e-12)
        un = unit_of(cross(tn, std::fabs(tn.x) < 0.9 ? Vec3d{1, 0, 0} : Vec3d{0, 1, 0}));
      u = unit_of(un);
      tan = tn;
      const Vec3d v = cross(tan, u);
      for (int s = 0; s < o.sides; ++s) {
        const double ang = two_pi * s / o.sides;
        m.positions.push_back(
            to_float(path[size_t(i)] + (u * std::cos(ang) + v * std::sin(ang)) * o.radius));
      }
    }
    const uint32_t cap0 = uint32_t(m.positions.size());
    m.positions.push_back(to_float(path[0]));
    const uint32_t cap1 = uint32_t(m.positions.size());
    m.positions.push_back(to_float(path[size_t(rings - 1)]));
    const uint32_t k = uint32_t(o.sides);
    auto ring = [&](uint64_t i, uint32_t s) { return base + uint32_t(i) * k + s % k; };
    for (uint64_t i = 0; i + 1 < rings; ++i)
      for (uint32_t s = 0; s < k; ++s) {
        const uint32_t a0 = ring(i, s), a1 = ring(i, s + 1), b0 = ring(i + 1, s),
                       b1 = ring(i + 1, s + 1);
        m.indices.insert(m.indices.end(), {a0, a1, b1, a0, b1, b0});
      }
    for (uint32_t s = 0; s < k; ++s) {
      m.indices.insert(m.indices.end(), {cap0, ring(0, s + 1), ring(0, s)});
      m.indices.insert(m.indices.end(), {cap1, ring(rings - 1, s), ring(rings - 1, s + 1)});
    }
  }
  return m;
}

Mesh menger(int level) {
  check_range("menger: level", level, 0, 5);
  int n = 1;
  for (int i = 0; i < level; ++i) n *= 3;
  // Sub-cube (x,y,z) of the 3^L grid is solid unless some base-3 digit
  // position has a 1 in at least two coordinates (the removed cross).
  auto solid = [&](int x, int y, int z) {
    if (x < 0 || y < 0 || z < 0 || x >= n || y >= n || z >= n) return false;
    for (; x || y || z; x /= 3, y /= 3, z /= 3)
      if ((x % 3 == 1) + (y % 3 == 1) + (z % 3 == 1) >= 2) return false;
    return true;
  };
  Mesh m;
  std::unordered_map<uint64_t, uint32_t> vid;
  const uint64_t stride = uint64_t(n) + 1;
  auto vertex = [&](int x, int y, int z) {
    const uint64_t key = (uint64_t(z) * stride + uint64_t(y)) * stride + uint64_t(x);
    auto [it, fresh] = vid.try_emplace(key, uint32_t(m.positions.size()));
    if (fresh)
      m.positions.push_back({float(double(x) / n), float(double(y) / n), float(double(z) / n)});
    return it->second;
  };
  // Face of axis a at the low (dir = 0) or high side: the four corners in
  // counter-clockwise order seen from outside.
  for (int z = 0; z < n; ++z)
    for (int y = 0; y < n; ++y)
      for (int x = 0; x < n; ++x) {
        if (!solid(x, y, z)) continue;
        const int c[3] = {x, y, z};
        for (int a = 0; a < 3; ++a)
          for (int side = 0; side < 2; ++side) {
            int nb[3] = {x, y, z};
            nb[a] += side ? 1 : -1;
            if (solid(nb[0], nb[1], nb[2])) continue;
            const int b = (a + 1) % 3, e = (a + 2) % 3;
            int q[4][3];
            for (int i = 0; i < 4; ++i) {
              q[i][a] = c[a] + side;
              // (0,0) (1,0) (1,1) (0,1) in (b, e): counter-clockwise around +a.
              q[i][b] = c[b] + (i == 1 || i == 2);
              q[i][e] = c[e] + (i >= 2);
            }
            uint32_t v[4];
            for (int i = 0; i < 4; ++i) v[i] = vertex(q[i][0], q[i][1], q[i][2]);
            if (side)
              m.indices.insert(m.indices.end(), {v[0], v[1], v[2], v[0], v[2], v[3]});
            else
              m.indices.insert(m.indices.end(), {v[0], v[2], v[1], v[0], v[3], v[2]});
          }
      }
  return m;
}

namespace {

// Value noise on the integer lattice: a hashed value in [-1, 1] per lattice
// point (splitmix64 of seed, octave and coordinates), smoothstep-interpolated.
double lattice(uint64_t seed, int octave, int64_t x, int64_t z) {
  uint64_t h = seed * 0x9E3779B97F4A7C15ull ^ (uint64_t(octave) << 56) ^
               (uint64_t(x) * 0xBF58476D1CE4E5B9ull) ^ (uint64_t(z) * 0x94D049BB133111EBull);
  h ^= h >> 30;
  h *= 0xBF58476D1CE4E5B9ull;
  h ^= h >> 27;
  h *= 0x94D049BB133111EBull;
  h ^= h >> 31;
  return double(h >> 11) * 0x1.0p-52 - 1.0;
}

double value_noise(uint64_t seed, int octave, double x, double z) {
  const double fx = std::floor(x), fz = std::floor(z);
  const int64_t ix = int64_t(fx), iz = int64_t(fz);
  double tx = x - fx, tz = z - fz;
  tx = tx * tx * (3 - 2 * tx);
  tz = tz * tz * (3 - 2 * tz);
  const double a = lattice(seed, octave, ix, iz), b = lattice(seed, octave, ix + 1, iz);
  const double c = lattice(seed, octave, ix, iz + 1), d = lattice(seed, octave, ix + 1, iz + 1);
  return (a + (b - a) * tx) + ((c + (d - c) * tx) - (a + (b - a) * tx)) * tz;
}

}  // namespace

Mesh terrain(const TerrainOptions& o) {
  check_range("terrain: size", o.size, 2, 8192);
  check_range("terrain: octaves", o.octaves, 1, 16);
  check_range("terrain: height", o.height, 0.0, 100.0);
  check_range("terrain: persistence", o.persistence, 0.0, 1.0);
  const int n = o.size;
  Mesh m;
  m.positions.resize(size_t(n) * size_t(n));
  double norm = 0, amp = 1;
  for (int k = 0; k < o.octaves; ++k, amp *= o.persistence) norm += amp;
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i) {
      const double x = double(i) / (n - 1), z = double(j) / (n - 1);
      // fBm: octaves of value noise, frequency x2, amplitude x persistence.
      double h = 0, f = 4, a = 1;
      for (int k = 0; k < o.octaves; ++k, f *= 2, a *= o.persistence)
        h += a * value_noise(o.seed, k, x * f, z * f);
      m.positions[size_t(j) * size_t(n) + size_t(i)] = {float(x), float(o.height * h / norm),
                                                        float(z)};
    }
  m.indices.reserve(size_t(n - 1) * size_t(n - 1) * 6);
  for (int j = 0; j + 1 < n; ++j)
    for (int i = 0; i + 1 < n; ++i) {
      const uint32_t a = uint32_t(j * n + i), b = a + 1, c = a + uint32_t(n), d = c + 1;
      // Counter-clockwise seen from +y (up).
      m.indices.insert(m.indices.end(), {a, c, b, b, c, d});
    }
  return m;
}

void write_mesh(const std::filesystem::path& path, const Mesh& mesh) {
  validate_mesh(mesh);
  std::string ext = path.extension().string();
  for (char& ch : ext) ch = char(std::tolower(static_cast<unsigned char>(ch)));
  std::string out;
  if (ext == ".obj") {
    fmt::memory_buffer buf;
    fmt::format_to(std::back_inserter(buf), "# voxcast generate: {} vertices, {} triangles\n",
                   mesh.positions.size(), mesh.triangle_count());
    // "{}" prints the shortest representation that round-trips the float.
    for (const Vec3& p : mesh.positions)
      fmt::format_to(std::back_inserter(buf), "v {} {} {}\n", p.x, p.y, p.z);
    for (size_t t = 0; t < mesh.triangle_count(); ++t)
      fmt::format_to(std::back_inserter(buf), "f {} {} {}\n", mesh.indices[3 * t] + 1,
                     mesh.indices[3 * t + 1] + 1, mesh.indices[3 * t + 2] + 1);
    out.assign(buf.data(), buf.size());
  } else if (ext == ".ply") {
    out = fmt::format(
        "ply\nformat binary_little_endian 1.0\ncomment voxcast generate\nelement vertex {}\n"
        "property float x\nproperty float y\nproperty float z\nelement face {}\n"
        "property list uchar uint vertex_indices\nend_header\n",
        mesh.positions.size(), mesh.triangle_count());
    static_assert(std::endian::native == std::endian::little, "PLY is written little-endian");
    const size_t head = out.size();
    out.resize(head + mesh.positions.size() * 12 + mesh.triangle_count() * 13);
    char* w = out.data() + head;
    for (const Vec3& p : mesh.positions) {
      const float xyz[3] = {p.x, p.y, p.z};
      std::memcpy(w, xyz, 12);
      w += 12;
    }
    for (size_t t = 0; t < mesh.triangle_count(); ++t) {
      *w++ = 3;
      std::memcpy(w, &mesh.indices[3 * t], 12);
      w += 12;
    }
  } else {
    throw Error("mesh output '" + path.string() + "' must end in .obj or .ply");
  }
  write_file_atomic(path, out.data(), out.size());
}

}  // namespace voxcast::generate
