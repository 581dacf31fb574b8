// `voxcast bench --json` (issue 10, the fair benchmark) on a tiny mesh and
// image: every mode is reported, the Embree modes see the same rays (same
// hits, same occlusion answers), and the coverage is what a brute-force
// ray/triangle test of the same camera finds. No timing is asserted.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <map>
#include <nlohmann/json.hpp>
#include <set>
#include <string>
#include <vector>

#include "support/cli_runner.hpp"
#include "voxcast/camera.hpp"
#include "voxcast/mesh.hpp"

namespace voxcast {
namespace {

using testing::run_cli;
using testing::TempDir;

const std::string kMesh =
    (std::filesystem::path(VOXCAST_TEST_DATA_DIR) / "meshes" / "spot.obj").string();
constexpr int kW = 40, kH = 30;

// Möller-Trumbore, in double: an oracle independent of Embree's intersector.
bool hits_any_triangle(const Mesh& m, const Ray& r) {
  for (size_t t = 0; t < m.triangle_count(); ++t) {
    const Vec3 a = m.positions[m.indices[3 * t]], b = m.positions[m.indices[3 * t + 1]],
               c = m.positions[m.indices[3 * t + 2]];
    const double e1[3] = {double(b.x) - a.x, double(b.y) - a.y, double(b.z) - a.z};
    const double e2[3] = {double(c.x) - a.x, double(c.y) - a.y, double(c.z) - a.z};
    const double d[3] = {r.dir.x, r.dir.y, r.dir.z};
    const double p[3] = {d[1] * e2[2] - d[2] * e2[1], d[2] * e2[0] - d[0] * e2[2],
                         d[0] * e2[1] - d[1] * e2[0]};
    const double det = e1[0] * p[0] + e1[1] * p[1] + e1[2] * p[2];
    if (std::fabs(det) < 1e-300) continue;
    const double s[3] = {double(r.origin.x) - a.x, double(r.origin.y) - a.y,
                         double(r.origin.z) - a.z};
    const double u = (s[0] * p[0] + s[1] * p[1] + s[2] * p[2]) / det;
    if (u < 0 || u > 1) continue;
    const double q[3] = {s[1] * e1[2] - s[2] * e1[1], s[2] * e1[0] - s[0] * e1[2],
                         s[0] * e1[1] - s[1] * e1[0]};
    const double v = (d[0] * q[0] + d[1] * q[1] + d[2] * q[2]) / det;
    if (v < 0 || u + v > 1) continue;
    if ((e2[0] * q[0] + e2[1] * q[1] + e2[2] * q[2]) / det > 0) return true;
  }
  return false;
}

TEST(FairBench, JsonHasEveryModeAndEmbreeModesAgree) {
  ASSERT_TRUE(std::filesystem::exists(kMesh)) << kMesh;
  TempDir dir;
  const std::string json_path = dir.file("bench.json");
  const auto r =
      run_cli("bench " + kMesh + " --resolution 64 --size " + std::to_string(kW) + "x" +
              std::to_string(kH) +
              " --repeat 1 --threads 2 --beam 4 --effects --ao-rays 4 --json " + json_path);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  // The readable tables and the header lines are on stdout too.
  for (const char* text :
       {"command ", "machine ", "embree ", "trace only", "trace + the same shading",
        "cycles per ray", "shadow rays", "ao rays", "ratio voxcast/embree:"})
    EXPECT_NE(r.output.find(text), std::string::npos) << text << "\n" << r.output;

  const nlohmann::json j = nlohmann::json::parse(testing::read_text(json_path));
  EXPECT_NE(j["command"].get<std::string>().find("bench"), std::string::npos);
  EXPECT_FALSE(j["machine"]["cpu"].get<std::string>().empty());
  EXPECT_FALSE(j["machine"]["embree_isa"].get<std::string>().empty());
  EXPECT_EQ(j["machine"]["threads"].get<int>(), 2);
  ASSERT_EQ(j["runs"].size(), 1u);
  const nlohmann::json& run = j["runs"][0];

  // Every primary mode, trace only and shaded; voxel casters at LOD 0 and 1.
  std::set<std::string> seen;
  std::set<uint64_t> embree_hits;
  std::map<std::string, uint64_t> hits_of;
  for (const auto& row : run["primary"]) {
    const std::string key = row["caster"].get<std::string>() + "|" +
                            (row["lod"].is_null() ? "-" : std::to_string(row["lod"].get<float>())) +
                            "|" + (row["shaded"].get<bool>() ? "shaded" : "trace");
    seen.insert(key);
    hits_of[key] = row["hits"].get<uint64_t>();
    EXPECT_EQ(row["rays"].get<uint64_t>(), uint64_t(kW) * kH) << key;
    EXPECT_GT(row["mrays_per_s"].get<double>(), 0.0) << key;
    if (key.rfind("embree ", 0) == 0) embree_hits.insert(row["hits"].get<uint64_t>());
  }
  for (const char* mode : {"x1", "x4", "x8", "x16", "1M"})
    for (const char* kind : {"trace", "shaded"})
      EXPECT_TRUE(seen.count(std::string("embree ") + mode + "|-|" + kind)) << mode << kind;
  for (const char* caster : {"voxcast esvo", "voxcast dag"})
    for (float lod : {0.f, 1.f})
      for (const char* kind : {"trace", "shaded"})
        EXPECT_TRUE(seen.count(std::string(caster) + "|" + std::to_string(lod) + "|" + kind))
            << caster << lod << kind;
  EXPECT_TRUE(seen.count("voxcast esvo+beam|" + std::to_string(1.f) + "|shaded"));
  // The packet caster's rows (trace only, shaded, with the beam start) find
  // exactly the scalar caster's hits: its hits are bit-identical.
  for (const char* caster : {"voxcast esvo", "voxcast dag"})
    for (float lod : {0.f, 1.f}) {
      // Built by append: GCC 12 misreads "literal" + std::string chains (-Wrestrict).
      std::string l = "|";
      l.append(std::to_string(lod)).append("|");
      std::string packet = caster;
      packet.append(" packet");
      ASSERT_TRUE(seen.count(packet + l + "trace") && seen.count(packet + l + "shaded") &&
                  seen.count(packet + "+beam" + l + "trace"))
          << packet << lod;
      EXPECT_EQ(hits_of[packet + l + "trace"], hits_of[caster + l + "trace"]) << packet << lod;
      EXPECT_EQ(hits_of[packet + l + "shaded"], hits_of[caster + l + "trace"]) << packet << lod;
      EXPECT_EQ(hits_of[packet + "+beam" + l + "trace"], hits_of[caster + l + "trace"])
          << packet << lod;
    }
  // Same rays -> same hits, in every Embree mode, with and without shading.
  EXPECT_EQ(embree_hits.size(), 1u);

  // Coverage in (0, 1), and what a brute-force intersector finds for the
  // same camera (a pixel or two may differ on triangle edges).
  const double coverage = run["coverage"].get<double>();
  EXPECT_GT(coverage, 0.0);
  EXPECT_LT(coverage, 1.0);
  const Mesh mesh = load_mesh(kMesh);
  const CameraRays cam(Camera::parse(run["camera"].get<std::string>()), kW, kH);
  int brute = 0;
  for (int y = 0; y < kH; ++y)
    for (int x = 0; x < kW; ++x) brute += hits_any_triangle(mesh, cam.ray(x, y));
  EXPECT_NEAR(coverage * kW * kH, double(brute), 2.0);

  // Occlusion: the same pre-generated rays for every caster; the Embree
  // modes give identical answers; voxcast's any-hit answers mostly agree.
  for (const char* kind : {"shadow", "ao"}) {
    const nlohmann::json& occ = run["occlusion"][kind];
    const uint64_t n = occ["rays"].get<uint64_t>();
    EXPECT_GT(n, 0u) << kind;
    std::map<std::string, nlohmann::json> by_name;
    for (const auto& c : occ["casters"]) by_name[c["caster"].get<std::string>()] = c;
    for (const char* name :
         {"voxcast esvo", "voxcast dag", "embree x1", "embree x8", "embree x16", "embree 1M"}) {
      ASSERT_TRUE(by_name.count(name)) << kind << " " << name;
      EXPECT_EQ(by_name[name]["rays"].get<uint64_t>(), n);
    }
    for (const char* name : {"embree x8", "embree x16", "embree 1M"}) {
      EXPECT_EQ(by_name[name]["same_as_embree_x1"].get<uint64_t>(), n) << kind << " " << name;
      EXPECT_EQ(by_name[name]["occluded"], by_name["embree x1"]["occluded"]) << kind << " " << name;
    }
    EXPECT_GT(by_name["voxcast esvo"]["same_as_embree_x1"].get<double>(), 0.8 * double(n)) << kind;
    // Occlusion packets answer every ray as the scalar casters do.
    for (const char* name : {"voxcast esvo packet", "voxcast dag packet"}) {
      ASSERT_TRUE(by_name.count(name)) << kind << " " << name;
      EXPECT_EQ(by_name[name]["occluded"], by_name["voxcast esvo"]["occluded"]) << kind << name;
    }
    EXPECT_EQ(occ["packet_equals_scalar"].get<uint64_t>(), n) << kind;
    // So do the any-hit packets (from the root; AO also point-major from the
    // root and with the deep start; shadow rays also the lanes alone, the
    // packet rows having the parallel walks).
    std::vector<std::string> anyhit = {"voxcast esvo anyhit", "voxcast dag anyhit"};
    if (std::string(kind) == "shadow")
      for (const char* name : {"voxcast esvo lanes", "voxcast dag lanes"}) anyhit.push_back(name);
    if (std::string(kind) == "ao")
      for (const char* name :
           {"voxcast esvo ao point", "voxcast dag ao point", "voxcast esvo ao deep",
            "voxcast dag ao deep", "voxcast esvo ao deep+cull", "voxcast dag ao deep+cull"})
        anyhit.push_back(name);
    for (const std::string& name : anyhit) {
      ASSERT_TRUE(by_name.count(name)) << kind << " " << name;
      EXPECT_EQ(by_name[name]["occluded"], by_name["voxcast esvo"]["occluded"]) << kind << name;
    }
    EXPECT_EQ(occ["anyhit_equals_scalar"].get<uint64_t>(), n) << kind;
  }
  EXPECT_EQ(run["occlusion"]["ao"]["rays"].get<uint64_t>(),
            4u * run["occlusion"]["points"].get<uint64_t>());

  // The instrumented profile splits every caster's cycles into the stages.
  std::set<std::string> profiled;
  for (const auto& p : run["cycles_per_ray"]) {
    profiled.insert(p["caster"].get<std::string>());
    const double sum = p["ray_generation"].get<double>() + p["traversal"].get<double>() +
                       p["attributes"].get<double>() + p["shading"].get<double>();
    EXPECT_NEAR(sum, p["total"].get<double>(), 1e-6 * sum + 1e-9);
    EXPECT_GT(p["traversal"].get<double>(), 0.0);
  }
  EXPECT_TRUE(profiled.count("embree x1"));
  EXPECT_TRUE(profiled.count("voxcast esvo"));
  EXPECT_TRUE(profiled.count("voxcast dag"));
}

}  // namespace
}  // namespace voxcast
