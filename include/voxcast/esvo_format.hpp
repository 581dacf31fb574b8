#pragma once
// ESVO scene files (META + 'ESVO' sections, layout in src/esvo/format.cpp)
// and the ESVO entry of the format registry (format_registry.hpp).
#include <filesystem>

#include "voxcast/container.hpp"
#include "voxcast/esvo.hpp"
#include "voxcast/scene_file.hpp"

namespace voxcast {

class FormatRegistry;

void save_esvo_scene(const std::filesystem::path& path, const esvo::EsvoOctree& octree,
                     const SceneInfo& info);
/// Writes the META and ESVO sections of `octree` into an open writer.
void write_esvo_scene(ContainerWriter& writer, const esvo::EsvoOctree& octree,
                      const SceneInfo& info);
/// Loads and fully validates; throws voxcast::Error with a one-line reason.
esvo::EsvoOctree load_esvo_scene(const std::filesystem::path& path, SceneInfo* info = nullptr);
/// load_esvo_scene() without the file: interprets and fully validates the
/// META and ESVO sections of a container (e.g. from memory).
esvo::EsvoOctree esvo_scene_from_container(const ContainerReader& reader,
                                           SceneInfo* info = nullptr);
esvo::EsvoOctree esvo_scene_from_container(const Container& container, SceneInfo* info = nullptr);

namespace esvo {
/// Adds the "esvo" format (called by register_builtin_formats()).
void register_format(FormatRegistry& registry);
}  // namespace esvo

}  // namespace voxcast
