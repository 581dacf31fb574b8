#pragma once
// Sparse voxel DAG scene files (META + 'SDAG' [+ 'DATR' | 'DATC'] sections,
// layout in src/dag/format.cpp) and the DAG entry of the format registry
// (format_registry.hpp).
#include <filesystem>

#include "voxcast/container.hpp"
#include "voxcast/dag.hpp"
#include "voxcast/scene_file.hpp"

namespace voxcast {

class FormatRegistry;

void save_dag_scene(const std::filesystem::path& path, const dag::SparseVoxelDag& dag,
                    const SceneInfo& info);
/// Writes the META and DAG sections of `dag` into an open writer.
void write_dag_scene(ContainerWriter& writer, const dag::SparseVoxelDag& dag,
                     const SceneInfo& info);
/// Loads and fully validates (SparseVoxelDag::finalize); throws voxcast::Error.
dag::SparseVoxelDag load_dag_scene(const std::filesystem::path& path, SceneInfo* info = nullptr);
dag::SparseVoxelDag dag_scene_from_container(const ContainerReader& reader,
                                             SceneInfo* info = nullptr);
dag::SparseVoxelDag dag_scene_from_container(const Container& container, SceneInfo* info = nullptr);

namespace dag {
/// Adds the "dag" format (called by register_builtin_formats()).
void register_format(FormatRegistry& registry);
}  // namespace dag

}  // namespace voxcast
