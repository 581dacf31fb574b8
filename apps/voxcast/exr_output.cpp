#include "exr_output.hpp"

#include <algorithm>
#include <cctype>
#include <sstream>

#include "cli_io.hpp"
#include "voxcast/exr.hpp"

namespace voxcast::cli {

ExrLayers parse_exr_layers(const std::string& list, const std::string& output) {
  ExrLayers layers;
  if (list.empty()) return layers;
  std::string ext = std::filesystem::path(output).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return char(std::tolower(c)); });
  if (ext != ".exr") throw UsageError("--aov needs an .exr output (-o X.exr)");
  std::stringstream ss(list);
  std::string item;
  while (std::getline(ss, item, ',')) {
    if (item == "depth")
      layers.depth = true;
    else if (item == "normal")
      layers.normal = true;
    else
      throw UsageError("--aov: '" + printable(item) + "' is not depth or normal");
  }
  if (!layers.depth && !layers.normal) throw UsageError("--aov: no layer named");
  return layers;
}

void write_exr_layers(const std::filesystem::path& path, const RenderResult& result,
                      const ExrLayers& layers) {
  std::vector<ExrChannel> channels = {
      {"R", &result.color, 0, true}, {"G", &result.color, 1, true}, {"B", &result.color, 2, true}};
  if (layers.depth) channels.push_back({"Z", &result.depth, 0, false});
  // The renderer stores normals as n * 0.5 + 0.5 (for PNG); the EXR layer
  // holds n itself (a miss, 0.5, becomes 0).
  Image normal;
  if (layers.normal) {
    normal = result.normal;
    for (float& v : normal.pixels) v = 2.f * v - 1.f;
    channels.push_back({"N.x", &normal, 0, false});
    channels.push_back({"N.y", &normal, 1, false});
    channels.push_back({"N.z", &normal, 2, false});
  }
  write_exr(path, channels);
}

}  // namespace voxcast::cli
