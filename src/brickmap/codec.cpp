// Chunk, LZ4 and brickgrid header encodings of brickmap worlds (codec.hpp).
#include "brickmap/codec.hpp"

#include <lz4.h>
#include <xxhash.h>

#include <algorithm>

#include "voxcast/error.hpp"
#include "voxcast/esvo.hpp"

namespace voxcast::brickmap::codec {

void corrupt(const std::string& what) {
  throw Error("corrupt scene: " + what);
}

std::vector<uint8_t> compress(const uint8_t* data, size_t size) {
  std::vector<uint8_t> out(static_cast<size_t>(LZ4_compressBound(int(size))));
  const int n =
      LZ4_compress_default(reinterpret_cast<const char*>(data), reinterpret_cast<char*>(out.data()),
                           int(size), int(out.size()));
  if (n <= 0) throw Error("brickmap: LZ4 compression failed");
  out.resize(size_t(n));
  return out;
}

void decompress_to(const uint8_t* src, size_t size, uint8_t* dst, size_t raw,
                   const std::string& what) {
  const int n = LZ4_decompress_safe(reinterpret_cast<const char*>(src),
                                    reinterpret_cast<char*>(dst), int(size), int(raw));
  if (n < 0 || size_t(n) != raw) corrupt(what + " does not decompress to its size");
}

std::vector<uint8_t> decompress(const uint8_t* src, size_t size, size_t raw,
                                const std::string& what) {
  std::vector<uint8_t> out(raw);
  decompress_to(src, size, out.data(), raw, what);
  return out;
}

ChunkGrid chunk_grid(const std::array<uint32_t, 3>& dims) {
  ChunkGrid c;
  for (int a = 0; a < 3; ++a) c.n[a] = (dims[size_t(a)] + kChunkSide - 1) >> kChunkLog2;
  return c;
}

uint64_t chunk_of(const World& w, uint64_t index) {
  const ChunkGrid g = chunk_grid(w.dims());
  const std::array<uint32_t, 3>& d = w.dims();
  const uint64_t i = index % d[0], j = index / d[0] % d[1], k = index / d[0] / d[1];
  return g.index(uint32_t(i >> kChunkLog2), uint32_t(j >> kChunkLog2), uint32_t(k >> kChunkLog2));
}

std::string chunk_name(const ChunkGrid& g, uint64_t index) {
  return "chunk (" + std::to_string(index % g.n[0]) + "," +
         std::to_string(index / g.n[0] % g.n[1]) + "," + std::to_string(index / g.n[0] / g.n[1]) +
         ")";
}

void encode_chunk(const World& w, const ChunkGrid& g, uint64_t chunk, std::vector<uint8_t>* raw) {
  raw->clear();
  for_chunk_cells(w, g, chunk, [&](uint64_t ci, uint32_t) {
    const uint32_t c = w.cell(ci);
    if (c == 0) return;
    if (cell_state(c) != kStateResident)
      throw Error("brickmap: cannot save a world with bricks that are not resident");
    if (w.dxt1()) throw Error("brickmap: a world with DXT1 colors is render-side only");
    const Brick& b = w.brick(cell_brick(c));
    append_brick(raw, b.mask, &w.colors()[b.color],
                 w.has_normals() ? &w.normals()[b.color] : nullptr, size_t(brick_popcount(b)));
  });
}

void append_brick(std::vector<uint8_t>* raw, const uint64_t mask[8], const uint32_t* colors,
                  const uint32_t* normals, size_t count) {
  const size_t at = raw->size();
  raw->resize(at + 64 + count * (normals ? 8 : 4));
  std::memcpy(&(*raw)[at], mask, 64);
  std::memcpy(&(*raw)[at + 64], colors, count * 4);
  if (normals) std::memcpy(&(*raw)[at + 64 + count * 4], normals, count * 4);
}

uint32_t mean_color_abgr(const uint32_t* colors, size_t count) {
  double sum[3] = {0, 0, 0};
  for (size_t i = 0; i < count; ++i) {
    const Color c = esvo::decode_color_abgr(colors[i]);
    sum[0] += c.r, sum[1] += c.g, sum[2] += c.b;
  }
  const double inv = 1.0 / double(count);
  return esvo::encode_color_abgr(
      {float(sum[0] * inv), float(sum[1] * inv), float(sum[2] * inv), 1.f});
}

std::vector<uint8_t> encode_grid_header(const World& w) {
  std::vector<uint32_t> header(w.cells().size(), 0);
  for (size_t i = 0; i < header.size(); ++i) {
    const uint32_t c = w.cells()[i];
    if (c == 0) continue;
    header[i] = not_resident_cell(cell_state(c) == kStateResident ? w.brick(cell_brick(c)).lod
                                                                  : cell_lod_abgr(c));
  }
  return pack_grid_header(header);
}

std::vector<uint8_t> pack_grid_header(const std::vector<uint32_t>& header) {
  const uint8_t* hb = reinterpret_cast<const uint8_t*>(header.data());
  const size_t hbytes = header.size() * 4;
  std::vector<uint8_t> gh;
  const std::vector<uint8_t> hz = compress(hb, hbytes);
  put_le<uint32_t>(gh, uint32_t(hbytes));
  put_le<uint32_t>(gh, uint32_t(hz.size()));
  put_le<uint64_t>(gh, XXH64(hb, hbytes, 0));
  gh.insert(gh.end(), hz.begin(), hz.end());
  return gh;
}

std::vector<uint32_t> decode_grid_header(const uint8_t* gh, size_t size, uint64_t cells,
                                         const std::string& what) {
  if (size < kHeaderPrefix) corrupt(what + " is shorter than its 16-byte prefix");
  const uint64_t raw_size = load_le<uint32_t>(gh), z_size = load_le<uint32_t>(gh + 4);
  if (raw_size != cells * 4)
    corrupt(what + " raw size " + std::to_string(raw_size) + " is not 4 bytes per brickgrid cell");
  if (z_size != size - kHeaderPrefix) corrupt(what + " LZ4 size does not match its length");
  const std::vector<uint8_t> hraw =
      decompress(gh + kHeaderPrefix, size_t(z_size), size_t(raw_size), what + " brickgrid");
  if (XXH64(hraw.data(), hraw.size(), 0) != load_le<uint64_t>(gh + 8))
    corrupt(what + " brickgrid checksum mismatch");
  std::vector<uint32_t> header(static_cast<size_t>(cells));
  if (!header.empty()) std::memcpy(header.data(), hraw.data(), hraw.size());
  for (uint32_t h : header)
    if (h != 0 && (cell_state(h) != kStateNotResident || CellFlags::get(h) != 0))
      corrupt(what + " holds a cell that is neither empty nor a brick's LOD color");
  return header;
}

}  // namespace voxcast::brickmap::codec
