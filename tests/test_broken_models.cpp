// Deliberately broken models from Debian's assimp-testmodels (copied into
// tests/data/broken, tests/data/NOTICE.md) through the real CLI: `build` and
// `convert` each refuse them with exit status 1 and one stderr line that
// names the file and the cause (issue 15 item 5) — never Assimp's bare "No
// suitable reader found", never a crash, a hang or stray importer output.
// The whole package is swept by tests/sweep/assimp_models.sh.
#include <gtest/gtest.h>

#include <cctype>
#include <string>

#include "support/cli_runner.hpp"

namespace voxcast {
namespace {

struct Broken {
  const char* file;   // under tests/data/broken
  const char* cause;  // in the message
};

class BrokenModels : public ::testing::TestWithParam<Broken> {};

TEST_P(BrokenModels, RefusedInOneLineNamingTheFileAndTheCause) {
  const std::string path = std::string(VOXCAST_TEST_DATA_DIR) + "/broken/" + GetParam().file;
  testing::TempDir dir;
  for (const std::string& cmd :
       {"build '" + path + "' -o '" + dir.file("s.vxc") + "' --resolution 32",
        "convert '" + path + "' '" + dir.file("s.vox") + "' --resolution 32"}) {
    const testing::CliResult r = testing::run_cli_split(cmd, 60);
    SCOPED_TRACE(cmd);
    EXPECT_EQ(r.exit_code, 1) << r.errors;
    EXPECT_EQ(r.output, "");
    ASSERT_FALSE(r.errors.empty());
    EXPECT_EQ(r.errors.find('\n'), r.errors.size() - 1) << "more than one line: " << r.errors;
    EXPECT_EQ(r.errors.rfind("voxcast: error: " + path + ": ", 0), 0u) << r.errors;
    EXPECT_NE(r.errors.find(GetParam().cause), std::string::npos) << r.errors;
    EXPECT_EQ(r.errors.find("No suitable reader"), std::string::npos) << r.errors;
  }
}

INSTANTIATE_TEST_SUITE_P(
    AssimpTestModels, BrokenModels,
    ::testing::Values(
        // out-of-range vertex indices
        Broken{"malformed.obj", "Invalid face index"},
        // a face count no file of 309 bytes can hold (Assimp would reserve it)
        Broken{"OutOfMemory.off", "more than the 309-byte file can hold"},
        Broken{"invalid.off", "references vertex 20 but the file has 3"},
        // glTF faces Assimp drops with only a log line
        Broken{"IndexOutOfRange/IndexOutOfRange.gltf", "vertices that do not exist"},
        Broken{"IncorrectVertexArrays/Cube.gltf", "vertices that do not exist"},
        // the .bin is not there: Assimp says "No suitable reader found"
        Broken{"MissingBin/BoxTextured.gltf", "'BoxTextured0.bin', which is not next to the model"},
        Broken{"BoxWithInfinites.glb", "non-finite coordinate"},
        Broken{"RecursiveNodes.gltf", "recursive reference"},
        Broken{"wrongTypes/badArray.gltf", "\"primitives\" was not of type \"array\""}),
    [](const ::testing::TestParamInfo<Broken>& p) {
      std::string name;
      for (const char* c = p.param.file; *c; ++c)
        name += std::isalnum(static_cast<unsigned char>(*c)) ? *c : '_';
      return name;
    });

}  // namespace
}  // namespace voxcast
