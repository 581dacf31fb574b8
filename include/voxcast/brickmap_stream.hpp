#pragma once
// Streaming a brickmap world from its scene file (van Wingerden 2015 §3.2.1,
// §3.2.3, §4.2; issue 11 item 6): only the brickgrid header stays in RAM,
// bricks are loaded when rays ask for them.
//
// Opening reads META, the brickgrid header and the chunk table; every
// non-empty cell starts not resident with its LOD color. A ray that reaches
// a not-resident brick answers with that LOD color and pushes a request
// (BrickmapStructure::kRequestBrick, key = cell) into its TraceContext; the
// frame loop (integrator.hpp) hands each pass's requests to end_pass sorted
// and deduplicated (the bounded feedback list: each brick asked for once
// per pass, at most FrameOptions::requests_per_thread per thread). end_pass
// serves the most urgent ones, up to StreamOptions::uploads_per_pass:
//   * the brick's chunk comes from an LRU cache of decoded chunks (read from
//     the file, checked against its own xxh64, LZ4-decoded on a miss); a
//     chunk that fails is refused: its bricks are left out (their cells
//     emptied), the rest of the world streams on;
//   * hidden-voxel removal (§4.2): voxels whose six neighbours are solid
//     (a neighbour brick in another chunk is read through the chunk cache,
//     loading its chunk if needed; outside the world or in a refused chunk
//     it counts as empty) are dropped before upload,
//     unless that would drop the whole brick; the brick keeps the LOD color
//     of all its voxels, so that coarse hits do not change;
//   * when the resident bricks would exceed their budget, the bricks seen
//     least recently (the frame stamp rays leave on the bricks they enter)
//     are evicted back to not resident; bricks seen in the current frame are
//     never evicted (uploading stops for the pass instead).
// Budgets: half of StreamOptions::budget_bytes for resident bricks (72 B +
// 4 or 8 B per voxel, the color run's size class), half for the chunk cache
// (decoded bytes; it keeps at least the chunk in use). The brickgrid header
// and the pyramid are outside the budget.
//
// A world with an edit journal streams in its saved state: the journal's
// last committed brickgrid header and the latest image of each chunk it
// rewrote (kept LZ4-compressed in RAM, outside the budget) replace the
// file's.
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <list>
#include <memory>
#include <string>
#include <unordered_map>
#include <vector>

#include "voxcast/brickmap.hpp"
#include "voxcast/brickmap_file.hpp"

namespace voxcast::brickmap {

struct StreamOptions {
  uint64_t budget_bytes = uint64_t(512) << 20;
  uint32_t uploads_per_pass = 4096;  // N: bricks made resident per end_pass
  bool hidden_voxel_removal = true;
  /// Colors of the uploaded bricks as DXT1 blocks (§3.1.3, brickmap.hpp;
  /// World::use_dxt1): 0.5 B per voxel instead of 4 in the brick budget.
  bool dxt1 = false;
};

struct StreamStats {
  uint64_t uploaded = 0;     // bricks made resident
  uint64_t evicted = 0;      // bricks evicted
  uint64_t chunk_loads = 0;  // chunks read and decoded
  uint64_t chunk_evictions = 0;
  uint64_t hidden_voxels = 0;  // voxels dropped by hidden-voxel removal
  uint64_t resident_bytes = 0, peak_resident_bytes = 0;
  uint64_t cache_bytes = 0, peak_cache_bytes = 0;
  // Chunk decoding (checksum, LZ4, brick index; not the file read): raw bytes
  // produced and the wall time it took, the decode rate of the benchmark.
  uint64_t decoded_bytes = 0;
  double decode_seconds = 0;
  double decode_cpu_seconds = 0;      // the same time as the thread's CPU time (user + system)
  std::vector<ChunkFailure> refused;  // chunks that failed their checksum or decoding
};

/// Chunk decode throughput (`voxcast bench --brickmap`): the world's
/// chunks stored in memory as the scene writer stores them (raw bytes, LZ4,
/// xxh64), then decoded by the streamer's decode (checksum, LZ4, brick
/// index; not the file read), single-threaded, the best of `rounds` passes.
/// The hashes cover every brick's mask with its cell, in chunk order: the
/// decoded bricks equal the source bricks when count and hash agree.
/// Every non-empty cell of `w` must be resident.
struct ChunkDecodeRate {
  uint64_t chunks = 0;            // non-empty chunks
  uint64_t raw_bytes = 0;         // decoded bytes per pass
  uint64_t compressed_bytes = 0;  // their LZ4 blocks
  double seconds = 0;             // the best pass's decode time
  uint64_t source_bricks = 0, decoded_bricks = 0;
  uint64_t source_hash = 0, decoded_hash = 0;
  double bytes_per_second() const { return seconds > 0 ? double(raw_bytes) / seconds : 0.0; }
};
ChunkDecodeRate measure_chunk_decode(const World& w, int rounds = 5);

class StreamingWorld final : public BrickmapView {
 public:
  /// Throws voxcast::Error for a file that is not a valid brickmap world (a
  /// damaged META, header or chunk table, or a damaged edit journal).
  StreamingWorld(const std::filesystem::path& path, const StreamOptions& options);
  ~StreamingWorld() override;

  void begin_frame(const FrameView& view) override;
  PassOutcome end_pass(std::span<const Request> requests) override;

  const World& world() const { return *world_; }
  const StreamStats& stats() const { return stats_; }
  uint64_t brick_budget() const { return brick_budget_; }
  uint64_t cache_budget() const { return cache_budget_; }
  /// Bricks not resident yet (non-empty cells a ray could still ask for).
  uint64_t missing() const;

 private:
  struct Chunk;
  const Chunk* chunk(uint64_t index);  // null when refused
  void evict_chunks(uint64_t need);    // LRU chunks out until `need` bytes fit
  bool upload(uint64_t cell);          // false: no budget left this pass
  uint64_t brick_bytes(uint32_t voxels) const;

  std::filesystem::path path_;
  StreamOptions options_;
  uint64_t brick_budget_ = 0, cache_budget_ = 0;
  std::shared_ptr<World> world_;
  std::vector<uint32_t> header_;  // the BMGH cells (LOD colors)
  std::vector<uint8_t> table_;    // BMCT
  // Chunk images of the edit journal: chunk -> (raw size, LZ4 block).
  std::unordered_map<uint64_t, std::pair<uint32_t, std::vector<uint8_t>>> journal_;
  uint64_t chunk_data_offset_ = 0, chunk_data_size_ = 0;
  std::vector<uint32_t> seen_;      // per brick slot (BrickmapStructure)
  std::vector<uint64_t> resident_;  // resident cells
  std::list<uint64_t> lru_;         // cached chunks, most recent first
  std::unordered_map<uint64_t, std::pair<std::unique_ptr<Chunk>, std::list<uint64_t>::iterator>>
      cache_;
  std::vector<char> refused_chunk_;
  std::unique_ptr<Chunk> recycled_;  // an evicted chunk whose buffer the next decode reuses
  std::ifstream file_;               // the scene file, opened once
  std::vector<uint8_t> z_;           // a chunk's LZ4 block as read
  uint32_t frame_ = 0;
  StreamStats stats_;
};

}  // namespace voxcast::brickmap
