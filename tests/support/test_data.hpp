#pragma once
// Test data lookup. A test that needs a file it cannot find must fail, naming
// the file: a skipped test is reported as passing by ctest, so a missing
// package or a broken checkout would silently turn a claim into no test.
// The helpers throw rather than use ASSERT_* so that they work in any helper
// function (value-returning ones and static initializers included);
// GoogleTest reports an exception escaping a test body as a failure with its
// message.
#include <filesystem>
#include <stdexcept>
#include <string>

namespace voxcast::testing {

/// Where Debian's assimp-testmodels package (installed by ./run) puts its models.
inline const std::filesystem::path kAssimpModels = "/usr/share/assimp/models";

/// `path` if it names an existing regular file or directory; otherwise throws
/// std::runtime_error naming it (and `hint`, e.g. the package that ships it).
inline std::filesystem::path require_file(const std::filesystem::path& path,
                                          const std::string& hint = "") {
  std::error_code ec;
  if (std::filesystem::is_regular_file(path, ec) || std::filesystem::is_directory(path, ec))
    return path;
  throw std::runtime_error("required test data not found: " + path.string() +
                           (hint.empty() ? "" : " (" + hint + ")"));
}

/// tests/data/meshes/NAME, shipped with the repository.
inline std::filesystem::path test_mesh(const std::string& name) {
  return require_file(std::filesystem::path(VOXCAST_TEST_DATA_DIR) / "meshes" / name,
                      "shipped in tests/data/meshes");
}

/// /usr/share/assimp/models/RELATIVE from the assimp-testmodels package.
inline std::filesystem::path assimp_model(const std::string& relative) {
  return require_file(kAssimpModels / relative,
                      "from Debian's assimp-testmodels package, which ./run installs");
}

}  // namespace voxcast::testing
