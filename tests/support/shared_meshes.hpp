#pragma once
// The shipped test meshes (tests/data/meshes) as a GoogleTest parameter list,
// with readable test names ("stanford_bunny", "CesiumMilkTruck", ...).
#include <gtest/gtest.h>

#include <cctype>
#include <filesystem>
#include <string>

namespace voxcast::testing {

inline auto all_shared_meshes() {
  return ::testing::Values("stanford-bunny.obj", "armadillo.off", "refined_elephant.off",
                           "camel.off", "fandisk_large.off", "spot.obj", "teapot.obj",
                           "CesiumMilkTruck/CesiumMilkTruck.gltf");
}

inline std::string mesh_test_name(const ::testing::TestParamInfo<const char*>& info) {
  std::string s = std::filesystem::path(info.param).stem().string();
  for (char& ch : s)
    if (!std::isalnum(static_cast<unsigned char>(ch))) ch = '_';
  return s;
}

}  // namespace voxcast::testing
