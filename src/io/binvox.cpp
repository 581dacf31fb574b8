// .binvox in and out, raw dense grids out, and the by-extension dispatch of
// the voxel-set formats (voxel_io.hpp).
#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <cstring>
#include <nlohmann/json.hpp>
#include <sstream>

#include "io/voxel_io_internal.hpp"
#include "voxcast/error.hpp"
#include "voxcast/image.hpp"
#include "voxcast/morton.hpp"
#include "voxcast/voxel_io.hpp"

namespace voxcast {

namespace {

std::string lower_ext(const std::filesystem::path& p) {
  std::string e = p.extension().string();
  std::transform(e.begin(), e.end(), e.begin(),
                 [](unsigned char c) { return char(std::tolower(c)); });
  return e;
}

constexpr size_t kMaxBinvoxHeader = 4096;

}  // namespace

VoxelSet parse_binvox(std::span<const uint8_t> bytes, const VoxelReadOptions& options) {
  const uint64_t budget = detail::voxel_budget(options);
  // Header: "#binvox 1", then dim / translate / scale lines in any order,
  // then "data" and the run-length pairs.
  size_t pos = 0;
  auto line = [&]() -> std::string {
    const size_t start = pos;
    while (pos < bytes.size() && bytes[pos] != '\n') {
      if (pos - start > 256) throw Error("malformed .binvox: header line too long");
      ++pos;
    }
    if (pos >= bytes.size()) throw Error("malformed .binvox: header is truncated");
    std::string s(reinterpret_cast<const char*>(bytes.data()) + start, pos - start);
    ++pos;
    if (!s.empty() && s.back() == '\r') s.pop_back();
    return s;
  };
  if (line() != "#binvox 1") throw Error("not a .binvox file (no '#binvox 1' line)");
  int64_t dims[3] = {0, 0, 0};
  double translate[3] = {0, 0, 0}, scale = 1;
  bool have_dim = false;
  for (;;) {
    if (pos > kMaxBinvoxHeader) throw Error("malformed .binvox: header has no 'data' line");
    const std::string l = line();
    std::istringstream in(l);
    std::string key;
    in >> key;
    if (key == "data") break;
    if (key == "dim") {
      for (auto& d : dims) in >> d;
      have_dim = true;
    } else if (key == "translate") {
      for (auto& t : translate) in >> t;
    } else if (key == "scale") {
      in >> scale;
    } else {
      throw Error(fmt::format("malformed .binvox: unknown header line '{}'", l.substr(0, 40)));
    }
    std::string rest;
    if (in.fail() || (in >> rest))
      throw Error(fmt::format("malformed .binvox: header line '{}'", l.substr(0, 40)));
  }
  if (!have_dim) throw Error("malformed .binvox: no 'dim' line");
  const int64_t max_dim = int64_t(1) << kMaxGridLevels;
  for (int64_t d : dims)
    if (d < 1 || d > max_dim)
      throw Error(fmt::format("malformed .binvox: dimension {} is outside 1..{}", d, max_dim));
  // binvox order: x slowest, then z, then y; dim lists (x, z, y) extents.
  const uint64_t nx = uint64_t(dims[0]), nz = uint64_t(dims[1]), ny = uint64_t(dims[2]);
  const uint64_t cells = nx * nz * ny;
  const uint32_t extent = uint32_t(std::max({nx, ny, nz}));
  VoxelSet set;
  set.grid = detail::unit_grid(extent);
  set.grid.origin = {float(translate[0]), float(translate[1]), float(translate[2])};
  set.grid.voxel_size = scale / double(extent);
  if (!set.grid.placement_is_valid())
    throw Error(fmt::format("malformed .binvox: translate {} {} {} / scale {} is not a valid grid",
                            translate[0], translate[1], translate[2], scale));
  if ((bytes.size() - pos) % 2 != 0) throw Error("malformed .binvox: data ends inside a run");
  uint64_t index = 0;
  const uint64_t max_voxels = budget / kVoxelSetBytesPerVoxel;
  for (size_t i = pos; i < bytes.size(); i += 2) {
    const uint8_t value = bytes[i], count = bytes[i + 1];
    if (value > 1) throw Error(fmt::format("malformed .binvox: run value {} is not 0 or 1", value));
    if (count == 0) throw Error("malformed .binvox: run of length 0");
    if (index + count > cells)
      throw Error(fmt::format("malformed .binvox: runs cover more than the {} cells", cells));
    if (value) {
      if (set.codes.size() + count > max_voxels)
        detail::check_voxel_count(set.codes.size() + count, budget, ".binvox");
      for (uint64_t k = index; k < index + count; ++k) {
        const uint64_t x = k / (nz * ny), z = k / ny % nz, y = k % ny;
        set.codes.push_back(morton_encode(uint32_t(x), uint32_t(y), uint32_t(z)));
      }
    }
    index += count;
  }
  if (index != cells)
    throw Error(fmt::format("malformed .binvox: runs cover {} of the {} cells", index, cells));
  if (set.codes.empty()) throw Error(".binvox file holds no voxels");
  std::sort(set.codes.begin(), set.codes.end());
  set.colors.assign(set.codes.size(), Color{1, 1, 1, 1});
  detail::finish_voxel_set(set);
  return set;
}

VoxelSet read_binvox(const std::filesystem::path& path, const VoxelReadOptions& options) {
  return detail::read_voxel_file(
      path, options, [](auto bytes, const VoxelReadOptions& o) { return parse_binvox(bytes, o); });
}

std::vector<uint8_t> encode_binvox(const VoxelSet& voxels) {
  if (voxels.codes.empty()) throw Error("cannot write .binvox: the voxel set is empty");
  const uint64_t d = voxels.grid.resolution;
  const Vec3 o = voxels.grid.origin;
  const std::string header =
      fmt::format("#binvox 1\ndim {} {} {}\ntranslate {} {} {}\nscale {}\ndata\n", d, d, d, o.x,
                  o.y, o.z, double(d) * voxels.grid.voxel_size);
  std::vector<uint64_t> cells;
  cells.reserve(voxels.codes.size());
  for (uint64_t code : voxels.codes) {
    const MortonCoord c = morton_decode(code);
    if (c.x >= d || c.y >= d || c.z >= d)
      throw Error("cannot write .binvox: a voxel lies outside the grid");
    cells.push_back((uint64_t(c.x) * d + c.z) * d + c.y);
  }
  std::sort(cells.begin(), cells.end());
  std::vector<uint8_t> out(header.begin(), header.end());
  auto run = [&](uint8_t value, uint64_t n) {
    for (; n > 0; n -= std::min<uint64_t>(n, 255)) {
      out.push_back(value);
      out.push_back(uint8_t(std::min<uint64_t>(n, 255)));
    }
  };
  uint64_t next = 0;  // first cell not yet encoded
  for (size_t i = 0; i < cells.size();) {
    size_t j = i + 1;
    while (j < cells.size() && cells[j] == cells[j - 1] + 1) ++j;
    run(0, cells[i] - next);
    run(1, j - i);
    next = cells[j - 1] + 1;
    i = j;
  }
  run(0, d * d * d - next);
  return out;
}

void write_binvox(const std::filesystem::path& path, const VoxelSet& voxels) {
  const auto bytes = encode_binvox(voxels);
  write_file_atomic(path, bytes.data(), bytes.size());
}

RawGrid encode_raw_grid(const VoxelSet& voxels, uint64_t memory_budget) {
  if (voxels.codes.empty()) throw Error("cannot write a raw grid: the voxel set is empty");
  const detail::Bounds3 b = detail::occupied_bounds(voxels);
  RawGrid raw;
  for (int a = 0; a < 3; ++a) raw.dims[a] = uint64_t(b.hi[a]) + 1;
  const uint64_t* n = raw.dims;
  const uint64_t cells = n[0] * n[1] * n[2];
  const uint64_t budget = detail::voxel_budget({memory_budget});
  if (cells > budget)
    throw Error(
        fmt::format("a {}x{}x{} raw grid needs {} bytes, more than the {} byte memory budget", n[0],
                    n[1], n[2], cells, budget));
  raw.cells.assign(cells, 0);
  for (uint64_t code : voxels.codes) {
    const MortonCoord c = morton_decode(code);
    raw.cells[c.x + n[0] * (c.y + n[1] * c.z)] = 1;
  }
  nlohmann::ordered_json meta;
  meta["format"] = "voxcast raw occupancy grid";
  meta["dims"] = {n[0], n[1], n[2]};
  meta["dtype"] = "uint8";
  meta["values"] = "1 = occupied, 0 = empty";
  meta["order"] = "x fastest: index = x + nx * (y + ny * z)";
  meta["origin"] = {voxels.grid.origin.x, voxels.grid.origin.y, voxels.grid.origin.z};
  meta["voxel_size"] = voxels.grid.voxel_size;
  meta["voxels"] = voxels.codes.size();
  raw.json = meta.dump(2) + "\n";
  return raw;
}

void write_raw_grid(const std::filesystem::path& path, const VoxelSet& voxels,
                    uint64_t memory_budget) {
  const RawGrid raw = encode_raw_grid(voxels, memory_budget);
  write_file_atomic(path, raw.cells.data(), raw.cells.size());
  std::filesystem::path sidecar = path;
  sidecar += ".json";
  write_file_atomic(sidecar, raw.json.data(), raw.json.size());
}

bool is_voxel_input(const std::filesystem::path& path) {
  const std::string e = lower_ext(path);
  return e == ".vox" || e == ".binvox" || e == ".vdb";
}

VoxelSet read_voxels(const std::filesystem::path& path, const VoxelReadOptions& options) {
  const std::string e = lower_ext(path);
  if (e == ".vox") return read_vox(path, options);
  if (e == ".binvox") return read_binvox(path, options);
  if (e == ".vdb") return read_vdb(path, options);
  throw Error(fmt::format("'{}': not a voxel file (.vox, .binvox or .vdb)", path.string()));
}

bool is_voxel_output(const std::filesystem::path& path) {
  const std::string e = lower_ext(path);
  return e == ".vox" || e == ".binvox" || e == ".vdb" || e == ".raw";
}

void write_voxels(const std::filesystem::path& path, const VoxelSet& voxels,
                  uint64_t memory_budget) {
  const std::string e = lower_ext(path);
  if (e == ".vox") return write_vox(path, voxels);
  if (e == ".binvox") return write_binvox(path, voxels);
  if (e == ".vdb") return write_vdb(path, voxels);
  if (e == ".raw") return write_raw_grid(path, voxels, memory_budget);
  throw Error(
      fmt::format("'{}': unknown voxel format (use .vox, .binvox, .vdb or .raw)", path.string()));
}

}  // namespace voxcast
