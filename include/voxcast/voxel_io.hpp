#pragma once
// Voxel-set files (README "Interop"): MagicaVoxel .vox in and out, .binvox in
// and out, dense raw grids out. Each format is a pair of small free functions
// (bytes <-> VoxelSet, file <-> VoxelSet) so that a format registry can list
// them; read_voxels / write_voxels pick one by extension.
//
// Every reader validates each size, count and index before using it and
// throws voxcast::Error with a one-line message for a malformed file or one
// that would exceed the memory budget.
#include <array>
#include <cstdint>
#include <filesystem>
#include <span>
#include <string>
#include <vector>

#include "voxcast/voxelize.hpp"

namespace voxcast {

struct VoxelReadOptions {
  /// Bytes the decoded voxel set may take (kVoxelSetBytesPerVoxel per voxel,
  /// dense intermediate grids included); 0: 90% of the available memory.
  uint64_t memory_budget = 0;
};

/// What a VoxelSet holds per voxel with attributes: Morton code, linear RGBA
/// color, normal and weight.
inline constexpr uint64_t kVoxelSetBytesPerVoxel = 8 + 16 + 12 + 4;

// --- MagicaVoxel .vox --------------------------------------------------------
// Axes: MagicaVoxel is z-up, voxcast y-up; a .vox voxel (x, y, z) becomes
// voxcast (x, z, -y) (a rotation, not a mirror), and positions are taken
// relative to the lowest corner of the models' boxes: the grid has origin 0,
// voxel size 1 and the smallest power-of-two resolution that holds the world.
// Scene graph (nTRN/nGRP/nSHP): frame 0 of every transform and shape; a
// model voxel p lands on R (p + 1/2 - floor(size/2)) + t - 1/2 (rotation
// about the model's pivot, which for R = identity is MagicaVoxel's
// p - floor(size/2) + t); later shapes overwrite earlier ones where they
// overlap. Without a scene graph only model 0 is read (several models are
// then the frames of an animation). Colors come from the RGBA chunk or the
// default palette, sRGB-decoded to linear; normals from the occupancy of the
// 26 neighbours (occupancy_normals); weights 1.

/// MagicaVoxel's default palette, entry `index` (0..255) as 0xAABBGGRR
/// (R in the low byte), generated from its structure: entries 1..215 a
/// 6x6x6 cube of 0xff - 0x33 k steps (blue fastest), then ramps of red,
/// green, blue and gray over the ten multiples of 0x11 not on that cube.
uint32_t vox_default_palette(int index);

VoxelSet parse_vox(std::span<const uint8_t> bytes, const VoxelReadOptions& options = {});
VoxelSet read_vox(const std::filesystem::path& path, const VoxelReadOptions& options = {});
/// Deterministic: one model when the occupied box fits 256^3, otherwise
/// 256^3 tiles (only the non-empty ones) placed by a scene graph; colors
/// quantized to at most 255 palette entries (quantize_palette). The grid's
/// origin and voxel size are not stored (the format has neither).
std::vector<uint8_t> encode_vox(const VoxelSet& voxels);
void write_vox(const std::filesystem::path& path, const VoxelSet& voxels);

/// At most `max_entries` palette colors for `colors` (8-bit RGBA): the
/// colors themselves, sorted, when there are few enough; otherwise a
/// weighted median cut. `index[i]` is the palette entry nearest (squared RGBA
/// distance, lowest index on ties) to colors[i].
struct PaletteQuantization {
  std::vector<std::array<uint8_t, 4>> palette;
  std::vector<uint32_t> index;
};
PaletteQuantization quantize_palette(std::span<const std::array<uint8_t, 4>> colors,
                                     size_t max_entries);

// --- binvox ------------------------------------------------------------------
// Cubic D^3 grid, D = the grid's resolution, translate = grid origin, scale =
// D * voxel size, run-length encoded with y fastest, then z, then x (binvox's
// own order; binvox is y-up like voxcast). Occupancy only: read voxels are
// white with occupancy normals.
VoxelSet parse_binvox(std::span<const uint8_t> bytes, const VoxelReadOptions& options = {});
VoxelSet read_binvox(const std::filesystem::path& path, const VoxelReadOptions& options = {});
std::vector<uint8_t> encode_binvox(const VoxelSet& voxels);
void write_binvox(const std::filesystem::path& path, const VoxelSet& voxels);

// --- raw dense grid ----------------------------------------------------------
// PATH: nx*ny*nz bytes, 1 = occupied, 0 = empty, index x + nx*(y + ny*z),
// (nx, ny, nz) = the occupied voxels' largest grid coordinate + 1 (the grid
// origin stays at index 0); PATH.json beside it: dims, order, dtype, origin,
// voxel_size. Refused when the dense grid exceeds `memory_budget` bytes.
struct RawGrid {
  uint64_t dims[3] = {0, 0, 0};
  std::vector<uint8_t> cells;  // the PATH bytes
  std::string json;            // the PATH.json text
};
RawGrid encode_raw_grid(const VoxelSet& voxels, uint64_t memory_budget = 0);
void write_raw_grid(const std::filesystem::path& path, const VoxelSet& voxels,
                    uint64_t memory_budget = 0);

// --- OpenVDB .vdb -------------------------------------------------------------
// In: the first float, double or bool grid is the geometry: a level set's
// active voxels at or below 0 (the inner shell of its narrow band), a fog
// volume's (any other class) active values above 0, a bool grid's active
// true values, active tiles with every voxel they cover; colors from a Vec3S
// grid named Cd or color (linear RGB), else white. The grid's uniform voxel
// size and its placement are kept (origin = the lowest voxel's corner).
// Out: a FloatGrid "density" (fog volume, 1 in every voxel) and a Vec3SGrid
// "Cd" (linear colors), index (i, j, k) centered on voxcast voxel (i, j, k).
VoxelSet read_vdb(const std::filesystem::path& path, const VoxelReadOptions& options = {});
void write_vdb(const std::filesystem::path& path, const VoxelSet& voxels);

// --- by extension --------------------------------------------------------------
/// .vox, .binvox or .vdb (what read_voxels reads).
bool is_voxel_input(const std::filesystem::path& path);
VoxelSet read_voxels(const std::filesystem::path& path, const VoxelReadOptions& options = {});
/// .vox, .binvox, .vdb or .raw.
bool is_voxel_output(const std::filesystem::path& path);
void write_voxels(const std::filesystem::path& path, const VoxelSet& voxels,
                  uint64_t memory_budget = 0);

}  // namespace voxcast
