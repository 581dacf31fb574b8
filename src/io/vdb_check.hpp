#pragma once
// The structure walk of a .vdb file before libopenvdb reads it (vdb.cpp).
#include <cstddef>
#include <cstdint>
#include <functional>
#include <string>

namespace voxcast::detail {

/// Walks a whole .vdb file (format versions 222-224, as libopenvdb 10's
/// io::File reads it: header, file metadata, grid descriptors, and per grid
/// its metadata, transform, tree topology — root tiles and children,
/// internal and leaf node masks, node values — and leaf buffers), checking
/// every declared length, count, offset and compressed block against the
/// bytes present. Every compressed value block (zlib or Blosc) is decoded
/// here and must give exactly the size OpenVDB will decode it into; bool
/// values must be 0 or 1. Throws voxcast::Error (the reason, without the
/// file name) for anything OpenVDB would mis-handle or voxcast does not read.
/// `registered_metadata` tells whether OpenVDB has a reader of its own for a
/// metadata type name this walk does not know (those are refused).
void check_vdb_bytes(const uint8_t* data, size_t size,
                     const std::function<bool(const std::string&)>& registered_metadata);

}  // namespace voxcast::detail
