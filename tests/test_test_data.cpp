// The test data contract: every file a test needs ships with the repository
// (tests/data) or comes from assimp-testmodels, and a missing one fails the
// test that needs it, naming the file, instead of skipping it.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "support/shared_meshes.hpp"
#include "support/test_data.hpp"

namespace voxcast {
namespace {

namespace fs = std::filesystem;

std::string require_error(const fs::path& p, const std::string& hint = "") {
  try {
    testing::require_file(p, hint);
  } catch (const std::runtime_error& e) {
    return e.what();
  }
  return "";
}

TEST(TestData, RequireFileThrowsNamingTheMissingFile) {
  const fs::path missing = fs::path(VOXCAST_TEST_DATA_DIR) / "meshes" / "no-such-mesh.obj";
  const std::string msg = require_error(missing, "some hint");
  ASSERT_FALSE(msg.empty()) << "require_file accepted " << missing;
  EXPECT_NE(msg.find(missing.string()), std::string::npos) << msg;
  EXPECT_NE(msg.find("some hint"), std::string::npos) << msg;
  // The two wrappers name the file and where it should come from.
  try {
    testing::test_mesh("no-such-mesh.obj");
    ADD_FAILURE() << "test_mesh accepted a missing mesh";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find(missing.string()), std::string::npos) << e.what();
  }
  try {
    testing::assimp_model("no/such/model.fbx");
    ADD_FAILURE() << "assimp_model accepted a missing model";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("no/such/model.fbx"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("assimp-testmodels"), std::string::npos) << e.what();
  }
}

TEST(TestData, RequireFileReturnsExistingFilesAndDirectories) {
  const fs::path dir = fs::path(VOXCAST_TEST_DATA_DIR) / "meshes";
  EXPECT_EQ(testing::require_file(dir), dir);
  EXPECT_EQ(testing::require_file(dir / "spot.obj"), dir / "spot.obj");
  EXPECT_EQ(testing::test_mesh("spot.obj"), dir / "spot.obj");
}

// A bare clone must hold every mesh the parameterized suites iterate over,
// including the files the glTF truck references.
TEST(TestData, EveryShippedMeshIsPresent) {
  for (const char* name :
       {"stanford-bunny.obj", "armadillo.off", "refined_elephant.off", "camel.off",
        "fandisk_large.off", "spot.obj", "teapot.obj", "CesiumMilkTruck/CesiumMilkTruck.gltf",
        "CesiumMilkTruck/CesiumMilkTruck.bin", "CesiumMilkTruck/CesiumMilkTruck.png"}) {
    SCOPED_TRACE(name);
    EXPECT_NO_THROW(testing::test_mesh(name));
    EXPECT_GT(fs::file_size(fs::path(VOXCAST_TEST_DATA_DIR) / "meshes" / name), 0u);
  }
}

// The policy, checked on the sources: no test skips itself (a skip is green
// in ctest), and none reads the shared folder beside a checkout, which a
// bare clone does not have. The needles are split so that this file does
// not match itself.
TEST(TestData, NoTestSkipsOrReadsSharedFolder) {
  const std::string skip = std::string("GTEST_") + "SKIP";
  const std::vector<std::string> shared = {std::string("../") + "shared",
                                           std::string("shared/") + "meshes"};
  size_t scanned = 0;
  for (const auto& e : fs::recursive_directory_iterator(fs::path(VOXCAST_SOURCE_DIR) / "tests")) {
    const fs::path& p = e.path();
    if (!e.is_regular_file() || (p.extension() != ".cpp" && p.extension() != ".hpp")) continue;
    std::ifstream in(p);
    std::stringstream text;
    text << in.rdbuf();
    const std::string s = text.str();
    ++scanned;
    EXPECT_EQ(s.find(skip), std::string::npos) << p << " skips a test";
    for (const std::string& needle : shared)
      EXPECT_EQ(s.find(needle), std::string::npos) << p << " refers to " << needle;
  }
  EXPECT_GT(scanned, 20u);  // the scan found the test sources at all
}

}  // namespace
}  // namespace voxcast
