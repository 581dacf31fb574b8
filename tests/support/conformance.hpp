#pragma once
// The structure registry of the conformance suite (tests/test_conformance.cpp).
//
// Every voxel structure the renderer can load is listed once, below, in
// conformance_structures(), as a factory "build this structure from this
// voxel set (and, if it needs one, the source mesh) and save it to a scene
// file". The suite then loads the file through the generic loader
// (load_scene), so it tests what a user gets, and runs every property on it:
// first hit = the dense-grid DDA oracle, beam on = beam off through render(),
// occlusion = first hit before t_max, LOD stops, 1 thread = 2 threads (build,
// file, image), and truncated / corrupted files rejected cleanly.
//
// How a new structure registers (brickmap, GigaVoxels, streamed ESVO, ...):
// add one StructureFactory to the list in conformance_structures() with
//   * name        a test-name-safe identifier ("brickmap_raw");
//   * needs_mesh  true if build() needs the source mesh (it then only runs on
//                 the mesh cases);
//   * geometry    Cubes when a voxel's shape is its cube (first hits must
//                 match the DDA oracle exactly); ContourNarrowed when the
//                 structure documents a narrower shape inside the cube;
//   * lod_colors  what a coarse (LOD) hit's color promises (LodColors);
//   * build       the factory itself; it must be deterministic for a given
//                 input and may throw voxcast::Error for inputs it documents
//                 as unsupported (e.g. an empty voxel set).
// Nothing else changes: every property then runs on it for every case.
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "voxcast/brickmap.hpp"
#include "voxcast/dag.hpp"
#include "voxcast/dag_format.hpp"
#include "voxcast/esvo.hpp"
#include "voxcast/esvo_format.hpp"
#include "voxcast/esvo_slices.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/scene_file.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast::testing {

/// The shape of a voxel as the structure traces it.
enum class VoxelGeometry {
  Cubes,            // the voxel's cube: hits equal the DDA oracle's
  ContourNarrowed,  // cube ∩ contour slabs (esvo §5.2-5.3): hits lie in
                    // occupied cubes, never before the oracle's first hit
};

/// What the color of a coarse (LOD) hit cube is promised to be.
enum class LodColors {
  None,              // no promise (lossy compressed parents)
  AreaWeightedMean,  // mean of the input colors of its voxels weighted by
                     // VoxelSet::weights, 8-bit sRGB rounded (esvo §5.4, §7.1)
  MeanOfLeaves,      // unweighted mean of the linear colors its leaf voxels
                     // show at LOD 0, and the normalized mean of their
                     // normals (dag.hpp "Attributes")
};

struct StructureFactory {
  std::string name;
  bool needs_mesh = false;
  VoxelGeometry geometry = VoxelGeometry::Cubes;
  LodColors lod_colors = LodColors::None;
  /// Builds the structure from `voxels` (`mesh`: its source, or null when the
  /// case has none) and writes it as a scene file to `path`.
  std::function<void(const VoxelSet& voxels, const Mesh* mesh, const std::filesystem::path& path)>
      build;
  /// The scene file is a file type of its own (SceneFormat::sniff, e.g. a
  /// slice file), not a container: loaded from a path only, and its damage
  /// property rehashes the file's own hashes instead of container sections.
  bool own_file = false;
};

/// The registry: every structure the conformance suite runs on.
inline const std::vector<StructureFactory>& conformance_structures() {
  static const std::vector<StructureFactory> factories = [] {
    std::vector<StructureFactory> f;
    const auto esvo_with = [](esvo::BuildOptions options) {
      return [options](const VoxelSet& v, const Mesh* mesh, const std::filesystem::path& path) {
        const esvo::EsvoOctree o = mesh != nullptr ? esvo::build_octree(v, *mesh, options)
                                                   : esvo::build_octree(v, options);
        save_esvo_scene(path, o, SceneInfo{"conformance", "conservative", 0, v.size()});
      };
    };
    esvo::BuildOptions raw;
    esvo::BuildOptions compressed;
    compressed.attributes = esvo::AttributeFormat::Compressed;
    esvo::BuildOptions contours;
    contours.contours = true;
    f.push_back(
        {"esvo_raw", false, VoxelGeometry::Cubes, LodColors::AreaWeightedMean, esvo_with(raw)});
    f.push_back(
        {"esvo_compressed", false, VoxelGeometry::Cubes, LodColors::None, esvo_with(compressed)});
    f.push_back({"esvo_contours", true, VoxelGeometry::ContourNarrowed, LodColors::AreaWeightedMean,
                 esvo_with(contours)});
    const auto dag_with = [](bool compress) {
      return [compress](const VoxelSet& v, const Mesh*, const std::filesystem::path& path) {
        dag::SparseVoxelDag d = dag::build_dag(v);
        if (compress) d.compress_attributes();
        save_dag_scene(path, d, SceneInfo{"conformance", "conservative", 0, v.size()});
      };
    };
    f.push_back({"dag_raw", false, VoxelGeometry::Cubes, LodColors::MeanOfLeaves, dag_with(false)});
    // dag.hpp: compressed LOD means are means of the decoded leaf values.
    f.push_back(
        {"dag_compressed", false, VoxelGeometry::Cubes, LodColors::MeanOfLeaves, dag_with(true)});
    // brickmap.hpp: a brick's LOD color is the mean of its voxels' linear
    // colors, coarser cubes' the voxel-weighted mean of their bricks'; no
    // promise is made for the cubes inside a brick (they show the brick's).
    f.push_back({"brickmap", false, VoxelGeometry::Cubes, LodColors::None,
                 [](const VoxelSet& v, const Mesh*, const std::filesystem::path& path) {
                   brickmap::save_scene(path, brickmap::build_world(v),
                                        SceneInfo{"conformance", "conservative", 0, v.size()});
                 }});
    // The streamed ESVO of a slice file (esvo §7), opened by load_scene with
    // an unlimited budget: every slice resident, so its hits are the in-core
    // ESVO's. Small slices, so that even the small cases have a hierarchy.
    const auto sliced_with = [](esvo::BuildOptions options) {
      return [options](const VoxelSet& v, const Mesh* mesh, const std::filesystem::path& path) {
        const esvo::EsvoOctree o = mesh != nullptr ? esvo::build_octree(v, *mesh, options)
                                                   : esvo::build_octree(v, options);
        esvo::SliceOptions so;
        so.slice_bytes = 512;
        esvo::write_slices(o, path, so);
      };
    };
    StructureFactory sliced{"esvo_sliced", false, VoxelGeometry::Cubes, LodColors::AreaWeightedMean,
                            sliced_with(raw)};
    sliced.own_file = true;
    f.push_back(sliced);
    StructureFactory sliced_contours{"esvo_sliced_contours", true, VoxelGeometry::ContourNarrowed,
                                     LodColors::AreaWeightedMean, sliced_with(contours)};
    sliced_contours.own_file = true;
    f.push_back(sliced_contours);
    return f;
  }();
  return factories;
}

}  // namespace voxcast::testing
