// Runtime ISA dispatch (voxcast/isa.hpp): every kernel variant computes the
// same bits, scene files are byte-identical whichever variant runs, and
// `voxcast --version` reports the variant in use.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <random>
#include <vector>

#include "dag/attribute_sum.hpp"
#include "support/cli_runner.hpp"
#include "voxcast/esvo.hpp"
#include "voxcast/isa.hpp"

using namespace voxcast;
using voxcast::testing::read_text;
using voxcast::testing::run_cli;
using voxcast::testing::TempDir;

namespace {

// Sets VOXCAST_ISA for the CLI runs of one scope.
struct IsaEnv {
  explicit IsaEnv(const char* isa) { setenv("VOXCAST_ISA", isa, 1); }
  ~IsaEnv() { unsetenv("VOXCAST_ISA"); }
};

}  // namespace

TEST(Isa, AttributeSumVariantsMatchTheDecoders) {
  // Random colors and normals, including the face codes 6 and 7 that the
  // decoders map to +z, and the u/v extremes.
  std::mt19937 rng(5);
  std::vector<uint32_t> colors(10007), normals(colors.size());  // odd: remainder loops
  for (size_t i = 0; i < colors.size(); ++i)
    colors[i] = uint32_t(rng()), normals[i] = uint32_t(rng());
  normals[0] = 0, normals[1] = 0xFFFFFFFFu, normals[2] = esvo::encode_normal_cube({0, -1, 0});
  // Oracle: the public decoders, rounded to the documented fixed point.
  const auto fixed = [](float v) {
    const double x = double(v) * 16777216.0;
    return int64_t(x + (x >= 0 ? 0.5 : -0.5));
  };
  for (const auto& [first, count] :
       {std::pair<size_t, size_t>{0, colors.size()}, {3, 126}, {17, 1}, {5, 0}}) {
    dag::detail::AttributeSum want{};
    for (size_t i = first; i < first + count; ++i) {
      const Color c = esvo::decode_color_abgr(colors[i]);
      const Vec3 n = esvo::decode_normal_cube(normals[i]);
      const float v[7] = {c.r, c.g, c.b, c.a, n.x, n.y, n.z};
      for (int k = 0; k < 7; ++k) want[size_t(k)] += fixed(v[k]);
    }
    EXPECT_EQ(dag::detail::avx2::attribute_sum(colors.data(), normals.data(), first, count), want)
        << first << " " << count;
    if (cpu_supports(Isa::Avx512)) {
      EXPECT_EQ(dag::detail::avx512::attribute_sum(colors.data(), normals.data(), first, count),
                want)
          << first << " " << count;
    }
  }
  // On a CPU without AVX-512 only the AVX2 variant was checked above.
  if (!cpu_supports(Isa::Avx512)) std::printf("CPU without AVX-512: AVX2 variant only\n");
}

TEST(Isa, SceneFilesAreByteIdenticalForEveryIsa) {
  // With one kernel there is nothing to compare (not a skip: the other tests
  // cover the AVX2 variant against the decoders).
  if (!cpu_supports(Isa::Avx512)) {
    std::printf("CPU without AVX-512: one variant only\n");
    return;
  }
  TempDir dir;
  const std::string mesh = std::string(VOXCAST_TEST_DATA_DIR) + "/meshes/spot.obj";
  for (const char* args :
       {"--resolution 128", "--resolution 64 --contours --attributes compressed",
        "--resolution 128 --format dag", "--resolution 128 --format dag --attributes compressed"}) {
    std::string bytes[2];
    int k = 0;
    for (const char* isa : {"avx2", "avx512"}) {
      IsaEnv env(isa);
      const std::string out = dir.file(std::string(isa) + ".vxc");
      const auto r = run_cli("build " + mesh + " -o " + out + " " + args);
      ASSERT_EQ(r.exit_code, 0) << r.output;
      bytes[k++] = read_text(out);
    }
    ASSERT_FALSE(bytes[0].empty());
    EXPECT_TRUE(bytes[0] == bytes[1]) << args;
  }
  // LOD shading reads the DAG's attribute prefix sums (the dispatched
  // kernel): a coarse render must not depend on the ISA either.
  std::string image[2];
  int k = 0;
  for (const char* isa : {"avx2", "avx512"}) {
    IsaEnv env(isa);
    const std::string scene = dir.file("lod.vxc"), png = dir.file(std::string(isa) + ".png");
    ASSERT_EQ(
        run_cli("build " + mesh + " -o " + scene + " --resolution 256 --format dag").exit_code, 0);
    const auto r = run_cli("render " + scene + " -o " + png + " --size 96x72 --lod 8");
    ASSERT_EQ(r.exit_code, 0) << r.output;
    image[k++] = read_text(png);
  }
  ASSERT_FALSE(image[0].empty());
  EXPECT_TRUE(image[0] == image[1]);
}

TEST(Isa, VersionReportsBuildAndIsa) {
  {
    IsaEnv env("avx2");
    const auto r = run_cli("--version");
    ASSERT_EQ(r.exit_code, 0) << r.output;
    EXPECT_NE(r.output.find("kernel ISA: avx2"), std::string::npos) << r.output;
    EXPECT_NE(r.output.find("build type: "), std::string::npos) << r.output;
    EXPECT_NE(r.output.find("assimp "), std::string::npos) << r.output;
    EXPECT_NE(r.output.find("oneTBB "), std::string::npos) << r.output;
    EXPECT_NE(r.output.find("OpenEXR 3."), std::string::npos) << r.output;
    EXPECT_NE(r.output.find("OpenVDB "), std::string::npos) << r.output;
    EXPECT_NE(r.output.find("GLFW 3."), std::string::npos) << r.output;
    EXPECT_NE(r.output.find("Dear ImGui 1."), std::string::npos) << r.output;
    EXPECT_NE(r.output.find("stb_image "), std::string::npos) << r.output;
  }
  if (cpu_supports(Isa::Avx512)) {
    IsaEnv env("avx512");
    EXPECT_NE(run_cli("--version").output.find("kernel ISA: avx512"), std::string::npos);
  }
  IsaEnv bad("sse2");
  EXPECT_NE(run_cli("--version").output.find("VOXCAST_ISA=sse2: expected avx2 or avx512"),
            std::string::npos);
}
