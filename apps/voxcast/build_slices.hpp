#pragma once
// `voxcast build … --slices`: ESVO slice files (esvo §7, voxcast/esvo_slices.hpp).
// Kept apart from cmd_build.cpp, which names no structure (the format
// registry builds every scene format; a slice file is not one of them yet).
#include <cstdint>
#include <filesystem>
#include <string>

#include "pipeline.hpp"
#include "voxcast/structure.hpp"

namespace voxcast::cli {

/// Throws UsageError unless `s` can be written as a slice file (ESVO; with
/// --attributes compressed and a color/normal tolerance, built top-down).
void check_slice_settings(const BuildSettings& s);

/// The top-down slice builder (esvo §7.1) from the mesh of `s` straight into
/// `to`, never holding the octree; prints nothing. Returns the summary line's
/// text (without the path and time).
/// `compressed`: §5.5 compression blocks per slice (esvo_slices.hpp).
std::string build_slices_top_down(const BuildSettings& s, uint64_t slice_bytes, bool compressed,
                                  const std::filesystem::path& to);

/// Writes the in-core built ESVO `structure` (raw attributes) as a slice
/// file at `to`, its slices' attributes compressed if `compressed`.
void write_slice_file(const Structure& structure, uint64_t slice_bytes, bool compressed,
                      const std::filesystem::path& to);

/// "N slices (target X), Y" for the slice file at `path`.
std::string describe_slice_file(const std::string& path, uint64_t slice_bytes);

}  // namespace voxcast::cli
