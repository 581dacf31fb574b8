#pragma once
// The grids of a .vdb file, read the way read_vdb reads them (and written
// the way write_vdb writes them) (vdb.cpp): the
// file-level structure pre-walked first (every declared length and offset
// checked against the file's size), then OpenVDB's reader without delayed
// loading. For modules that need the grids themselves (the GigaVoxels VDB
// producer); links libopenvdb.
#include <openvdb/openvdb.h>

#include <filesystem>

namespace voxcast::detail {

/// Every grid of the file. Throws voxcast::Error ("'PATH': not a readable
/// .vdb file (...)") for a damaged or unreadable file.
openvdb::GridPtrVecPtr read_vdb_grids(const std::filesystem::path& path);
/// Writes `grids` the way write_vdb does: beside `path`, the header's UUID
/// derived from the content (same grids, same bytes), renamed into place.
/// Throws voxcast::Error.
void write_vdb_grids(const std::filesystem::path& path, const openvdb::GridPtrVec& grids);

}  // namespace voxcast::detail
