// Solid voxelization (solid.hpp) against a brute-force inside test: the
// winding number of every voxel center, from the triangles' solid angles by
// Girard's theorem (angle excess of the spherical triangle), a formula of
// its own rather than the library's. On closed meshes the fill must equal
// surface + {centers inside}; on a mesh with a hole it must stay close to
// the closed mesh's fill.
#include <gtest/gtest.h>
#include <oneapi/tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <numbers>
#include <set>

#include "support/cli_runner.hpp"
#include "support/test_data.hpp"
#include "voxcast/error.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/morton.hpp"
#include "voxcast/solid.hpp"
#include "voxcast/voxelize.hpp"

using namespace voxcast;

namespace {

// Solid angle of triangle (a, b, c) seen from the origin: the spherical
// excess A + B + C - pi of the projected triangle, signed by orientation.
double girard_solid_angle(Vec3d a, Vec3d b, Vec3d c) {
  auto unit = [](Vec3d v) { return v / std::sqrt(dot(v, v)); };
  a = unit(a), b = unit(b), c = unit(c);
  // Angle at vertex p between the great circles to q and r.
  auto corner = [&](Vec3d p, Vec3d q, Vec3d r) {
    Vec3d n1 = cross(p, q), n2 = cross(p, r);
    const double l1 = std::sqrt(dot(n1, n1)), l2 = std::sqrt(dot(n2, n2));
    if (l1 == 0 || l2 == 0) return 0.0;
    return std::acos(std::clamp(dot(n1, n2) / (l1 * l2), -1.0, 1.0));
  };
  const double excess = corner(a, b, c) + corner(b, c, a) + corner(c, a, b) - std::numbers::pi;
  const double det = dot(a, cross(b, c));
  return det >= 0 ? excess : -excess;
}

bool inside_oracle(const Mesh& m, Vec3d p) {
  double sum = 0;
  for (size_t t = 0; t < m.triangle_count(); ++t) {
    Vec3d v[3];
    for (int k = 0; k < 3; ++k) {
      const Vec3& q = m.positions[m.indices[3 * t + size_t(k)]];
      v[k] = Vec3d{q.x - p.x, q.y - p.y, q.z - p.z};
    }
    sum += girard_solid_angle(v[0], v[1], v[2]);
  }
  return std::fabs(sum / (4 * std::numbers::pi)) > 0.5;
}

// The expected solid set: the surface voxels plus every voxel whose center
// the oracle finds inside.
std::vector<uint64_t> oracle_fill(const Mesh& m, const VoxelSet& surface) {
  const GridTransform& g = surface.grid;
  std::set<uint64_t> out(surface.codes.begin(), surface.codes.end());
  const Aabb b = m.bounds();
  auto range = [&](int a, int64_t* lo, int64_t* hi) {
    *lo = std::max<int64_t>(0, int64_t(std::floor((b.lo[a] - g.origin[a]) / g.voxel_size)));
    *hi = std::min<int64_t>(g.resolution - 1,
                            int64_t(std::floor((b.hi[a] - g.origin[a]) / g.voxel_size)));
  };
  int64_t lo[3], hi[3];
  for (int a = 0; a < 3; ++a) range(a, &lo[a], &hi[a]);
  // One slice per task; each writes only its own slice's list.
  std::vector<std::vector<uint64_t>> slices(size_t(hi[2] - lo[2] + 1));
  tbb::parallel_for(lo[2], hi[2] + 1, [&](int64_t z) {
    for (int64_t y = lo[1]; y <= hi[1]; ++y)
      for (int64_t x = lo[0]; x <= hi[0]; ++x) {
        const uint64_t code = morton_encode(uint32_t(x), uint32_t(y), uint32_t(z));
        if (out.count(code)) continue;
        const Vec3d p{g.origin.x + (double(x) + 0.5) * g.voxel_size,
                      g.origin.y + (double(y) + 0.5) * g.voxel_size,
                      g.origin.z + (double(z) + 0.5) * g.voxel_size};
        if (inside_oracle(m, p)) slices[size_t(z - lo[2])].push_back(code);
      }
  });
  for (const auto& s : slices) out.insert(s.begin(), s.end());
  return {out.begin(), out.end()};
}

// A torus (closed, genus 1: columns through the hole cross it four times).
Mesh torus(double R, double r, int nu, int nv) {
  Mesh m;
  for (int i = 0; i < nu; ++i)
    for (int j = 0; j < nv; ++j) {
      const double u = 2 * std::numbers::pi * i / nu, v = 2 * std::numbers::pi * j / nv;
      m.positions.push_back({float((R + r * std::cos(v)) * std::cos(u)),
                             float((R + r * std::cos(v)) * std::sin(u)), float(r * std::sin(v))});
    }
  auto id = [&](int i, int j) { return uint32_t((i % nu) * nv + (j % nv)); };
  for (int i = 0; i < nu; ++i)
    for (int j = 0; j < nv; ++j) {
      m.indices.insert(m.indices.end(), {id(i, j), id(i + 1, j), id(i + 1, j + 1)});
      m.indices.insert(m.indices.end(), {id(i, j), id(i + 1, j + 1), id(i, j + 1)});
    }
  m.normals.assign(m.positions.size(), Vec3{0, 0, 1});
  return m;
}

VoxelSet surface_of(const Mesh& m, uint32_t resolution) {
  return voxelize(m, GridTransform::fit(m.bounds(), resolution), {});
}

}  // namespace

TEST(SolidFill, ClosedMeshesMatchTheWindingNumberOracle) {
  struct Case {
    std::string name;
    Mesh mesh;
    uint32_t resolution;
  };
  std::vector<Case> cases;
  cases.push_back({"torus", torus(1.0, 0.35, 48, 24), 32});
  cases.push_back({"spot.obj", load_mesh(voxcast::testing::test_mesh("spot.obj")), 16});
  cases.push_back({"camel.off", load_mesh(voxcast::testing::test_mesh("camel.off")), 16});
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    const VoxelSet surface = surface_of(c.mesh, c.resolution);
    SolidFillStats st;
    const VoxelSet solid = fill_solid(c.mesh, surface, &st);
    EXPECT_EQ(solid.codes, oracle_fill(c.mesh, surface));
    EXPECT_GT(st.interior_voxels, 0u);
    EXPECT_EQ(st.ambiguous_columns, 0u);  // closed: parity decides every column
    EXPECT_EQ(solid.colors.size(), solid.size());
    EXPECT_EQ(solid.normals.size(), solid.size());
  }
}

TEST(SolidFill, MeshWithAHoleStaysCloseToTheClosedFill) {
  const Mesh closed = load_mesh(voxcast::testing::test_mesh("spot.obj"));
  const VoxelSet closed_surface = surface_of(closed, 32);
  const VoxelSet closed_solid = fill_solid(closed, closed_surface);
  // Cut a hole: drop the triangles whose centroid is in the top tenth.
  Mesh open = closed;
  open.indices.clear();
  open.triangle_material.clear();
  const Aabb b = closed.bounds();
  const float cut = b.hi.y - 0.1f * (b.hi.y - b.lo.y);
  size_t dropped = 0;
  for (size_t t = 0; t < closed.triangle_count(); ++t) {
    float y = 0;
    for (int k = 0; k < 3; ++k) y += closed.positions[closed.indices[3 * t + size_t(k)]].y / 3;
    if (y > cut) {
      ++dropped;
      continue;
    }
    for (int k = 0; k < 3; ++k) open.indices.push_back(closed.indices[3 * t + size_t(k)]);
    if (!closed.triangle_material.empty())
      open.triangle_material.push_back(closed.triangle_material[t]);
  }
  ASSERT_GT(dropped, 20u);
  const VoxelSet open_surface = voxelize(open, closed_surface.grid, {});
  SolidFillStats st;
  const VoxelSet open_solid = fill_solid(open, open_surface, &st);
  // The fallback was needed and used (parity alone fails through the hole).
  EXPECT_GT(st.ambiguous_columns, 0u);
  EXPECT_GT(st.winding_evaluations, 0u);
  // Same interior up to a thin layer near the hole.
  std::vector<uint64_t> common;
  std::set_intersection(open_solid.codes.begin(), open_solid.codes.end(),
                        closed_solid.codes.begin(), closed_solid.codes.end(),
                        std::back_inserter(common));
  const size_t differ = open_solid.size() + closed_solid.size() - 2 * common.size();
  EXPECT_LT(double(differ), 0.03 * double(closed_solid.size()))
      << differ << " of " << closed_solid.size();
  // Nothing outside the mesh's box was filled.
  const VoxelSet box_surface = open_surface;
  for (uint64_t c : open_solid.codes) {
    const MortonCoord m = morton_decode(c);
    const float x =
        open_surface.grid.origin.x + (float(m.x) + 0.5f) * float(open_surface.grid.voxel_size);
    ASSERT_GE(x, b.lo.x - float(open_surface.grid.voxel_size));
    ASSERT_LE(x, b.hi.x + float(open_surface.grid.voxel_size));
  }
}

TEST(SolidFill, LimitAndCli) {
  const Mesh m = torus(1.0, 0.35, 48, 24);
  const VoxelSet surface = surface_of(m, 32);
  EXPECT_THROW(fill_solid(m, surface, nullptr, 10), Error);
  // Through the CLI: the scene holds the solid set's voxels.
  voxcast::testing::TempDir dir;
  const std::string spot = voxcast::testing::test_mesh("spot.obj").string();
  auto r = voxcast::testing::run_cli("build " + spot + " --resolution 32 --fill solid -o " +
                                     dir.file("s.vxc"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const Mesh sm = load_mesh(spot);
  const size_t expect = fill_solid(sm, surface_of(sm, 32)).size();
  r = voxcast::testing::run_cli("info --json " + dir.file("s.vxc"));
  EXPECT_NE(r.output.find("\"leaf_voxels\": " + std::to_string(expect)), std::string::npos)
      << r.output;
  r = voxcast::testing::run_cli("build " + spot + " --fill solid --contours -o " +
                                dir.file("c.vxc"));
  EXPECT_EQ(r.exit_code, 2) << r.output;
  r = voxcast::testing::run_cli("build " + spot + " --fill bogus -o " + dir.file("c.vxc"));
  EXPECT_EQ(r.exit_code, 2) << r.output;
}
