#pragma once
// The grids of a .vdb file, read the way read_vdb reads them (and written
// the way write_vdb writes them) (vdb.cpp): the whole file's structure
// walked first (every declared length, offset, node mask and compressed
// value block checked, vdb_check.cpp), then OpenVDB's reader, without
// delayed loading, over the same checked bytes. For modules that need the grids themselves (the GigaVoxels VDB
// producer); links libopenvdb.
#include <openvdb/openvdb.h>

#include <cstdint>
#include <filesystem>

namespace voxcast::detail {

/// Every grid of the file. Throws voxcast::Error ("'PATH': not a readable
/// .vdb file (...)") for a damaged or unreadable file. The whole file is
/// read into memory and walked first (vdb_check.cpp); `file_budget` bounds
/// its size (0: 90% of the available memory).
openvdb::GridPtrVecPtr read_vdb_grids(const std::filesystem::path& path, uint64_t file_budget = 0);
/// Writes `grids` the way write_vdb does: beside `path`, the header's UUID
/// derived from the content (same grids, same bytes), renamed into place.
/// Throws voxcast::Error.
void write_vdb_grids(const std::filesystem::path& path, const openvdb::GridPtrVec& grids);

}  // namespace voxcast::detail
