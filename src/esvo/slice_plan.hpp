#pragma once
// What the two slice writers share (private to src/esvo): the split plan of
// a slice's next level (§7.1, planned by the parent) and the file header
// with its directory hash. Layout: include/voxcast/esvo_slices.hpp.
#include <cstdint>
#include <span>
#include <vector>

#include "voxcast/esvo_slices.hpp"

namespace voxcast::esvo::detail {

/// A descriptor of the next level as the planner sees it: its Morton code
/// (at its level) and the bytes of its slice record.
struct PlanNode {
  uint64_t code;
  uint32_t bytes;
};

/// The child slices of slice `parent` (index in the directory) whose node
/// level is n and region depth r: `next` are the descriptors of level n + 1
/// inside its region, in Morton order. The region is split at the shallowest
/// depth k (r <= k <= n + 1) where every non-empty sub-cube holds at most
/// `slice_bytes` of records and kMaxSliceNodes descriptors; one child per
/// non-empty sub-cube, in Morton order, appended to `out` (only region,
/// level, depth and parent are set).
void plan_child_slices(std::span<const PlanNode> next, int n, int r, uint32_t parent,
                       uint64_t slice_bytes, std::vector<slice_layout::SliceEntry>* out);

/// The bytes a descriptor with `children` valid children, `contours` of
/// them with a contour, adds to its slice, as the planner counts them: raw
/// 4 + 8 per child + 4 per contour; compressed 4 + 12 (half a compression
/// block) + 4 per contour (slice_data_bytes() adds the odd slice's other half).
inline uint32_t slice_record_bytes(int children, int contours, bool compressed) {
  return compressed ? uint32_t(16 + 4 * contours) : uint32_t(4 + 8 * children + 4 * contours);
}
/// data_bytes of a slice of N descriptors, V children and C contours.
inline uint64_t slice_data_bytes(uint64_t n, uint64_t v, uint64_t c, bool compressed) {
  return compressed ? 4 * n + 24 * ((n + 1) / 2) + 4 * c : 4 * n + 8 * v + 4 * c;
}
/// The same from the sum of its N descriptors' slice_record_bytes().
inline uint64_t slice_data_bytes_from_records(uint64_t record_sum, uint64_t n, bool compressed) {
  return record_sum + (compressed && (n & 1) != 0 ? 12 : 0);  // an odd slice's last block
}

/// The compression blocks (esvo_slices.hpp layout) of a slice whose
/// descriptor words are `descriptors` and whose children's raw attribute
/// words (color, normal per child, descriptor by descriptor, slot order) are
/// `raw`: ceil(N/2) blocks of 6 words.
std::vector<uint32_t> compress_slice_attributes(std::span<const uint32_t> descriptors,
                                                std::span<const uint32_t> raw);
/// The inverse: the raw attribute words (color, cube normal per child, in
/// that order) the blocks at `blocks` (ceil(N/2) x 6 words) decode to, for
/// the children the descriptors' valid masks name. What SliceFile::read()
/// hands out, and what the top-down builder's §7.3 test compares.
std::vector<uint32_t> decode_slice_attributes(std::span<const uint32_t> descriptors,
                                              const uint32_t* blocks);

/// The header of a slice file with these slices (data right after the
/// directory), its totals and directory hash filled in.
slice_layout::FileHeader slice_file_header(const GridTransform& grid, bool contours,
                                           bool compressed, uint64_t slice_bytes,
                                           const std::vector<slice_layout::SliceEntry>& slices);

}  // namespace voxcast::esvo::detail
