#pragma once
// What `voxcast --version` prints.
#include <string>

namespace voxcast {

/// voxcast version, build type, compiler, -march level and the active kernel
/// ISA (voxcast/isa.hpp), one fact per line (core module).
std::string build_description();
/// Versions of the libraries the I/O module is linked with (assimp, libpng,
/// TBB, xxHash, nlohmann_json), one per line (io module).
std::string io_library_versions();

}  // namespace voxcast
