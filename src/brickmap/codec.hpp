#pragma once
// The byte encodings a brickmap world is stored in (src/brickmap/format.cpp
// documents the scene sections, src/brickmap/persist.cpp the edit journal):
// chunks of 16^3 brickgrid cells, LZ4 blocks, the compressed brickgrid
// header. Shared by the scene format and the journal, private to the module.
#include <array>
#include <bit>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <nlohmann/json_fwd.hpp>
#include <optional>
#include <string>
#include <unordered_map>
#include <vector>

#include "voxcast/brickmap.hpp"

namespace voxcast::brickmap::codec {

inline constexpr uint32_t kChunkSide = 1u << kChunkLog2;
inline constexpr uint32_t kChunkCells = kChunkSide * kChunkSide * kChunkSide;
inline constexpr size_t kHeaderPrefix = 16;
// Largest raw chunk: every cell a full brick with colors and normals.
inline constexpr uint64_t kMaxChunkRaw = uint64_t(kChunkCells) * (64 + kBrickVoxels * 8);
static_assert(kMaxChunkRaw < (uint64_t(1) << 31), "LZ4 sizes are ints");
static_assert(std::endian::native == std::endian::little, "brickmap files are little-endian");

template <class T>
T load_le(const uint8_t* p) {
  T v;
  std::memcpy(&v, p, sizeof(T));
  return v;
}
template <class T>
void put_le(std::vector<uint8_t>& out, T v) {
  const size_t at = out.size();
  out.resize(at + sizeof(T));
  std::memcpy(&out[at], &v, sizeof(T));
}

/// The brickgrid height (cells in z) of META "dims", validated against
/// `grid` (the x and z dims are ceil(N / 8), y in 1 .. ceil(N / 8)), or a
/// one-line META error.
uint32_t meta_height_cells(const nlohmann::json& meta, const GridTransform& grid);

/// The generated terrain of META "terrain" (nullopt without one), validated
/// against `grid` and the brickgrid height (terrain_grid()), or a one-line
/// META error.
std::optional<TerrainSource> meta_terrain(const nlohmann::json& meta, const GridTransform& grid,
                                          uint32_t height_cells);

/// Throws voxcast::Error("corrupt scene: " + what).
[[noreturn]] void corrupt(const std::string& what);

std::vector<uint8_t> compress(const uint8_t* data, size_t size);
/// Exactly `raw` bytes from the LZ4 block [src, src + size), or corrupt().
std::vector<uint8_t> decompress(const uint8_t* src, size_t size, size_t raw,
                                const std::string& what);
/// The same into dst[0, raw) (every byte written; the streamer's reused
/// buffers, which need no zero-filling first).
void decompress_to(const uint8_t* src, size_t size, uint8_t* dst, size_t raw,
                   const std::string& what);

struct ChunkGrid {
  uint32_t n[3] = {0, 0, 0};
  uint64_t count() const { return uint64_t(n[0]) * n[1] * n[2]; }
  uint64_t index(uint32_t cx, uint32_t cy, uint32_t cz) const {
    return cx + uint64_t(n[0]) * (cy + uint64_t(n[1]) * cz);
  }
};
ChunkGrid chunk_grid(const std::array<uint32_t, 3>& dims);
/// The chunk holding brickgrid cell `index`.
uint64_t chunk_of(const World& w, uint64_t cell_index);
/// "chunk (x,y,z)" of chunk `index`.
std::string chunk_name(const ChunkGrid& g, uint64_t index);

/// Calls fn(cell index, position in the chunk 0..4095) for every brickgrid
/// cell of chunk `chunk`, x fastest.
template <class Fn>
void for_chunk_cells(const World& w, const ChunkGrid& g, uint64_t chunk, Fn&& fn) {
  const std::array<uint32_t, 3>& d = w.dims();
  const uint32_t cx = uint32_t(chunk % g.n[0]), cy = uint32_t(chunk / g.n[0] % g.n[1]),
                 cz = uint32_t(chunk / g.n[0] / g.n[1]);
  for (uint32_t k = cz * kChunkSide; k < std::min(d[2], (cz + 1) * kChunkSide); ++k)
    for (uint32_t j = cy * kChunkSide; j < std::min(d[1], (cy + 1) * kChunkSide); ++j)
      for (uint32_t i = cx * kChunkSide; i < std::min(d[0], (cx + 1) * kChunkSide); ++i)
        fn(w.cell_index(i, j, k),
           (i - cx * kChunkSide) +
               kChunkSide * ((j - cy * kChunkSide) + kChunkSide * (k - cz * kChunkSide)));
}

/// The raw bytes of a chunk: for every non-empty cell of the chunk (in
/// for_chunk_cells order) the brick's 64-byte mask, one u32 ABGR8 color per
/// solid voxel in bit order, then (with normals) one u32 normal each. Every
/// non-empty cell must be resident.
void encode_chunk(const World& w, const ChunkGrid& g, uint64_t chunk, std::vector<uint8_t>* raw);

/// Appends one brick's bytes (its mask, `count` colors, then `count`
/// normals unless `normals` is null) to a chunk's raw bytes.
void append_brick(std::vector<uint8_t>* raw, const uint64_t mask[8], const uint32_t* colors,
                  const uint32_t* normals, size_t count);
/// The LOD color of a brick (World::set_brick): the mean of its voxels'
/// linear colors, ABGR8 sRGB.
uint32_t mean_color_abgr(const uint32_t* colors, size_t count);

/// What a streamer needs of a world's edit journal (persist.cpp): the
/// brickgrid header of the last committed transaction (empty without one)
/// and the latest image of every chunk the transactions rewrote, as its LZ4
/// block and raw size (raw 0: the chunk lost all its bricks). Records are
/// validated as replay_journal does; a damaged journal head throws.
struct JournalChunks {
  std::vector<uint32_t> header;
  std::unordered_map<uint64_t, std::pair<uint32_t, std::vector<uint8_t>>> chunks;
  uint64_t transactions = 0;
};
JournalChunks read_journal_chunks(const std::filesystem::path& world_path, const World& w);

/// One decoded brick of a chunk.
struct ChunkBrick {
  uint64_t cell = 0;
  uint64_t mask[8] = {};
  std::vector<uint32_t> colors, normals;
};
/// Decodes the raw bytes of `chunk` whose non-empty cells are those with
/// present(cell index, position) true; validates every count (corrupt()
/// naming `name`). Nothing is written into the world.
template <class Present>
std::vector<ChunkBrick> decode_chunk(const World& w, const ChunkGrid& g, uint64_t chunk,
                                     const std::vector<uint8_t>& raw, const std::string& name,
                                     Present&& present) {
  std::vector<ChunkBrick> out;
  size_t at = 0;
  const bool normals = w.has_normals();
  for_chunk_cells(w, g, chunk, [&](uint64_t ci, uint32_t pos) {
    if (!present(ci, pos)) return;
    if (raw.size() - at < 64) corrupt(name + " ends inside a brick mask");
    ChunkBrick b;
    b.cell = ci;
    std::memcpy(b.mask, &raw[at], 64);
    at += 64;
    size_t count = 0;
    for (uint64_t m : b.mask) count += size_t(std::popcount(m));
    if (count == 0) corrupt(name + " holds an empty brick");
    const size_t need = count * (normals ? 8 : 4);
    if (raw.size() - at < need) corrupt(name + " ends inside a brick's colors");
    b.colors.resize(count);
    std::memcpy(b.colors.data(), &raw[at], count * 4);
    if (normals) {
      b.normals.resize(count);
      std::memcpy(b.normals.data(), &raw[at + count * 4], count * 4);
    } else {
      b.normals.assign(count, 0);
    }
    at += need;
    out.push_back(std::move(b));
  });
  if (at != raw.size()) corrupt(name + " has bytes after its last brick");
  return out;
}

/// The compressed brickgrid header (the BMGH section's bytes): u32 raw size
/// 4 C, u32 LZ4 size S, u64 xxh64 of the raw cells, S bytes of LZ4; each
/// cell 0 (empty) or not resident (state 2, flags 0) with the brick's LOD
/// color.
std::vector<uint8_t> encode_grid_header(const World& w);
/// The same bytes for the header cells themselves (each 0 or not resident).
std::vector<uint8_t> pack_grid_header(const std::vector<uint32_t>& header);
/// The header's cells, validated (`cells` of them, each empty or a plain
/// LOD color), or corrupt() naming `what`.
std::vector<uint32_t> decode_grid_header(const uint8_t* bytes, size_t size, uint64_t cells,
                                         const std::string& what);

}  // namespace voxcast::brickmap::codec
