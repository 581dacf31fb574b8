#pragma once
// Reading and writing the JSON 'META' section of .vxc scene files: the checked
// field accessors every scene format uses, and the grid placement they share.
// Every failure is a one-line voxcast::Error starting "corrupt scene:".
#include <cmath>
#include <cstdint>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "voxcast/container.hpp"
#include "voxcast/error.hpp"
#include "voxcast/scene_file.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast::meta {

inline constexpr uint32_t kSection = fourcc("META");

/// An nlohmann::json error as a user reads it: without the library's
/// "[json.exception.parse_error.101] " tag, and for a parse error only its
/// position ("parse error at line L, column C"), not the parser's terms and
/// the raw bytes it last read.
inline std::string json_error_text(const nlohmann::json::exception& e) {
  std::string s = e.what();
  if (s.rfind("[json.exception.", 0) == 0) {
    const size_t close = s.find("] ");
    if (close != std::string::npos) s.erase(0, close + 2);
  }
  if (const size_t at = s.find("parse error at line "); at != std::string::npos)
    if (const size_t colon = s.find(':', at); colon != std::string::npos) s.resize(colon);
  return s;
}

[[noreturn]] inline void bad(const std::string& what) {
  throw Error("corrupt scene: META section " + what);
}

inline const nlohmann::json& field(const nlohmann::json& j, const char* key) {
  if (!j.is_object()) bad("is not a JSON object");
  auto it = j.find(key);
  if (it == j.end()) bad(std::string("has no '") + key + "'");
  return *it;
}

inline uint64_t get_uint(const nlohmann::json& j, const char* key, uint64_t lo, uint64_t hi) {
  const nlohmann::json& v = field(j, key);
  if (!v.is_number_unsigned() && !(v.is_number_integer() && v.get<int64_t>() >= 0))
    bad(std::string("'") + key + "' is not a non-negative integer");
  const uint64_t x = v.get<uint64_t>();
  if (x < lo || x > hi) bad(std::string("'") + key + "' out of range");
  return x;
}

inline double get_finite(const nlohmann::json& v, const char* key) {
  if (!v.is_number()) bad(std::string("'") + key + "' is not a number");
  const double x = v.get<double>();
  if (!std::isfinite(x)) bad(std::string("'") + key + "' is not finite");
  return x;
}

inline std::string get_string(const nlohmann::json& j, const char* key) {
  const nlohmann::json& v = field(j, key);
  if (!v.is_string()) bad(std::string("'") + key + "' is not a string");
  return v.get<std::string>();
}

/// Parses the META section; throws voxcast::Error when absent or not JSON.
inline nlohmann::json parse(const ContainerReader& c) {
  const std::vector<uint8_t> bytes = c.read(kSection);
  try {
    return nlohmann::json::parse(bytes.begin(), bytes.end());
  } catch (const nlohmann::json::exception& e) {
    throw Error("corrupt scene: META section is not valid JSON: " + json_error_text(e));
  }
}

/// Serializes META (invalid UTF-8, e.g. odd file names, is replaced, not fatal).
inline std::vector<uint8_t> dump(const nlohmann::json& j) {
  const std::string text = j.dump(2, ' ', false, nlohmann::json::error_handler_t::replace);
  return {text.begin(), text.end()};
}

inline nlohmann::json grid_to_json(const GridTransform& g) {
  return {{"origin", {g.origin.x, g.origin.y, g.origin.z}},
          {"voxel_size", g.voxel_size},
          {"resolution", g.resolution},
          {"levels", g.levels}};
}

/// The "grid" object, checked: min_levels..20 levels, resolution = 2^levels,
/// finite origin within float range, positive voxel size.
inline GridTransform grid_from_json(const nlohmann::json& meta, int min_levels) {
  const nlohmann::json& grid = field(meta, "grid");
  GridTransform g;
  g.levels = int(get_uint(grid, "levels", uint64_t(min_levels), kMaxGridLevels));
  const uint64_t resolution =
      get_uint(grid, "resolution", uint64_t(1) << min_levels, uint64_t(1) << kMaxGridLevels);
  if (resolution != (uint64_t(1) << g.levels)) bad("resolution is not 2^levels");
  g.resolution = uint32_t(resolution);
  const nlohmann::json& origin = field(grid, "origin");
  if (!origin.is_array() || origin.size() != 3) bad("'origin' is not an array of 3 numbers");
  g.voxel_size = get_finite(field(grid, "voxel_size"), "voxel_size");
  if (!(g.voxel_size > 0)) bad("'voxel_size' is not positive");
  for (int i = 0; i < 3; ++i) {
    const double o = get_finite(origin[size_t(i)], "origin");
    if (!std::isfinite(float(o))) bad("'origin' is out of float range");
    g.origin[i] = float(o);
  }
  return g;
}

/// The SceneInfo fields every format records.
inline nlohmann::json info_to_json(const SceneInfo& info) {
  return {{"source", info.source},
          {"voxelization", info.voxelization},
          {"source_triangles", info.source_triangles}};
}

inline void info_from_json(const nlohmann::json& meta, SceneInfo* si) {
  si->source = get_string(meta, "source");
  si->voxelization = get_string(meta, "voxelization");
  si->source_triangles = get_uint(meta, "source_triangles", 0, UINT64_MAX);
}

}  // namespace voxcast::meta
