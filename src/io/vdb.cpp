// OpenVDB .vdb in and out (voxel_io.hpp) through libopenvdb.
#include <fmt/format.h>
#include <openvdb/openvdb.h>
#include <sys/mman.h>
#include <unistd.h>
#include <xxhash.h>

#include <algorithm>
#include <bit>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "io/vdb_check.hpp"
#include "io/vdb_grids.hpp"
#include "io/voxel_io_internal.hpp"
#include "voxcast/error.hpp"
#include "voxcast/morton.hpp"
#include "voxcast/voxel_io.hpp"

namespace voxcast {

namespace {

void init_openvdb() {
  static std::once_flag once;
  std::call_once(once, [] { openvdb::initialize(); });
}

/// Index-space voxels of `grid` that are voxcast voxels, as (coord) list:
/// a level set's active voxels at or below zero (the inner shell of its
/// narrow band), a fog volume's active values above zero, a BoolGrid's
/// active true values. Active tiles count with every voxel they cover.
template <class GridT, class Keep>
std::vector<openvdb::Coord> occupied(const GridT& grid, Keep keep, uint64_t max_voxels) {
  std::vector<openvdb::Coord> out;
  for (auto it = grid.cbeginValueOn(); it; ++it) {
    if (!keep(*it)) continue;
    const openvdb::CoordBBox box = it.getBoundingBox();
    const uint64_t n = box.volume();
    if (out.size() + n > max_voxels)
      throw Error(
          fmt::format(".vdb grid '{}' holds more than {} voxels, more than the memory "
                      "budget allows",
                      grid.getName(), max_voxels));
    for (auto c = box.begin(); c; ++c) out.push_back(*c);
  }
  return out;
}

// OpenVDB's io::File writes a random UUID into every file header (for its
// own caches of delayed-loaded files), so the same voxels would give
// different bytes on every run. Replaced, after the write, by one derived
// from the file's other bytes: same content, same UUID (issue 15 item 9,
// DeterministicVoxels). Header: magic (8 bytes), file version, library major
// and minor (4 each), the grid-offsets flag (1), then the UUID as 36 ASCII
// characters.
void content_uuid(const std::filesystem::path& path) {
  constexpr size_t kAt = 21, kLen = 36;
  std::FILE* f = std::fopen(path.c_str(), "r+b");
  if (!f) throw Error(fmt::format("cannot write {}: cannot reopen it", path.string()));
  std::vector<char> bytes;
  char buf[1 << 16];
  for (size_t n; (n = std::fread(buf, 1, sizeof buf, f)) > 0;)
    bytes.insert(bytes.end(), buf, buf + n);
  auto is_uuid = [&] {
    if (bytes.size() < kAt + kLen) return false;
    for (size_t i = 0; i < kLen; ++i) {
      const char c = bytes[kAt + i];
      if ((i == 8 || i == 13 || i == 18 || i == 23) ? c != '-'
                                                    : !std::isxdigit(static_cast<unsigned char>(c)))
        return false;
    }
    return true;
  };
  if (!is_uuid()) {  // another header layout: leave OpenVDB's UUID alone
    std::fclose(f);
    return;
  }
  std::fill(bytes.begin() + kAt, bytes.begin() + kAt + kLen, '0');
  const uint64_t h[2] = {XXH64(bytes.data(), bytes.size(), 1),
                         XXH64(bytes.data(), bytes.size(), 2)};
  uint8_t b[16];
  for (int i = 0; i < 16; ++i) b[i] = uint8_t(h[i / 8] >> (8 * (i % 8)));
  b[6] = uint8_t((b[6] & 0x0F) | 0x40);  // RFC 4122 layout: "version 4", variant 10
  b[8] = uint8_t((b[8] & 0x3F) | 0x80);
  std::string uuid;
  for (int i = 0; i < 16; ++i) {
    if (i == 4 || i == 6 || i == 8 || i == 10) uuid += '-';
    uuid += fmt::format("{:02x}", b[i]);
  }
  const bool ok =
      std::fseek(f, long(kAt), SEEK_SET) == 0 && std::fwrite(uuid.data(), 1, kLen, f) == kLen;
  if (std::fclose(f) != 0 || !ok)
    throw Error(fmt::format("cannot write {}: I/O error", path.string()));
}

}  // namespace

openvdb::GridPtrVecPtr detail::read_vdb_grids(const std::filesystem::path& path,
                                              uint64_t file_budget) {
  init_openvdb();
  const uint64_t budget = file_budget ? file_budget : detail::voxel_budget(VoxelReadOptions{});
  // The whole file is walked first (vdb_check.cpp: libopenvdb trusts every
  // size a file declares), then OpenVDB reads these same checked bytes from
  // a private in-memory file, so the file cannot change in between.
  std::vector<uint8_t> bytes = detail::read_file_bytes(path, budget);
  try {
    detail::check_vdb_bytes(bytes.data(), bytes.size(), [](const std::string& type) {
      return openvdb::Metadata::isRegisteredType(type);
    });
  } catch (const Error& e) {
    throw Error(fmt::format("'{}': not a readable .vdb file ({})", path.string(), e.what()));
  }
  const int fd = memfd_create("voxcast-vdb", MFD_CLOEXEC);
  if (fd < 0)
    throw Error(fmt::format("'{}': cannot read it: no in-memory file ({})", path.string(),
                            std::strerror(errno)));
  struct Closer {
    int fd;
    ~Closer() { ::close(fd); }
  } closer{fd};
  for (size_t done = 0; done < bytes.size();) {
    const ssize_t n = ::write(fd, bytes.data() + done, bytes.size() - done);
    if (n <= 0)
      throw Error(fmt::format("'{}': cannot read it: in-memory copy failed ({})", path.string(),
                              std::strerror(errno)));
    done += size_t(n);
  }
  // The memfd holds the checked bytes now: one copy in memory while OpenVDB
  // builds the grids, not two.
  std::vector<uint8_t>().swap(bytes);
  openvdb::GridPtrVecPtr grids;
  try {
    openvdb::io::File file("/proc/self/fd/" + std::to_string(fd));
    file.open(false);  // no delayed loading: the whole file is read and checked now
    grids = file.getGrids();
    file.close();
  } catch (const std::exception& e) {
    throw Error(fmt::format("'{}': not a readable .vdb file ({})", path.string(), e.what()));
  }
  return grids;
}

VoxelSet read_vdb(const std::filesystem::path& path, const VoxelReadOptions& options) {
  const uint64_t budget = detail::voxel_budget(options);
  const uint64_t max_voxels = budget / kVoxelSetBytesPerVoxel;
  const openvdb::GridPtrVecPtr grids = detail::read_vdb_grids(path, budget);
  // The first scalar or boolean grid is the geometry; a Vec3S grid named
  // Cd or color (the usual names) gives the colors.
  openvdb::GridBase::Ptr geometry;
  openvdb::Vec3SGrid::Ptr colors;
  for (const auto& g : *grids) {
    if (!geometry && (g->isType<openvdb::FloatGrid>() || g->isType<openvdb::DoubleGrid>() ||
                      g->isType<openvdb::BoolGrid>()))
      geometry = g;
    if (!colors && g->isType<openvdb::Vec3SGrid>() &&
        (g->getName() == "Cd" || g->getName() == "color"))
      colors = openvdb::gridPtrCast<openvdb::Vec3SGrid>(g);
  }
  if (!geometry)
    throw Error(fmt::format("'{}': no float, double or bool grid in the .vdb file", path.string()));
  const openvdb::math::Transform& xf = geometry->transform();
  if (!xf.isLinear() || !xf.hasUniformScale())
    throw Error(fmt::format("'{}': grid '{}' has a non-uniform or non-linear transform",
                            path.string(), geometry->getName()));
  std::vector<openvdb::Coord> coords;
  const bool level_set = geometry->getGridClass() == openvdb::GRID_LEVEL_SET;
  if (auto f = openvdb::gridPtrCast<openvdb::FloatGrid>(geometry))
    coords = level_set ? occupied(
                             *f, [](float v) { return v <= 0.f; }, max_voxels)
                       : occupied(
                             *f, [](float v) { return v > 0.f; }, max_voxels);
  else if (auto d = openvdb::gridPtrCast<openvdb::DoubleGrid>(geometry))
    coords = level_set ? occupied(
                             *d, [](double v) { return v <= 0.0; }, max_voxels)
                       : occupied(
                             *d, [](double v) { return v > 0.0; }, max_voxels);
  else
    coords = occupied(
        *openvdb::gridPtrCast<openvdb::BoolGrid>(geometry), [](bool v) { return v; }, max_voxels);
  if (coords.empty())
    throw Error(fmt::format("'{}': the .vdb grid holds no voxels", path.string()));
  openvdb::Coord lo = coords[0], hi = coords[0];
  for (const auto& c : coords) lo.minComponent(c), hi.maxComponent(c);
  int64_t extent = 1;
  for (int a = 0; a < 3; ++a) extent = std::max<int64_t>(extent, int64_t(hi[a]) - lo[a] + 1);
  if (extent > (int64_t(1) << kMaxGridLevels))
    throw Error(
        fmt::format("'{}': the .vdb voxels span {} voxels, more than the {} voxel grid limit",
                    path.string(), extent, 1 << kMaxGridLevels));
  VoxelSet set;
  set.grid = detail::unit_grid(uint32_t(extent));
  // VDB index coordinates are voxel centers: voxcast's voxel 0 starts half a
  // voxel below the lowest one.
  const double h = xf.voxelSize()[0];
  const openvdb::Vec3d corner =
      xf.indexToWorld(openvdb::Vec3d(lo.x() - 0.5, lo.y() - 0.5, lo.z() - 0.5));
  set.grid.voxel_size = h;
  set.grid.origin = {float(corner.x()), float(corner.y()), float(corner.z())};
  if (!set.grid.placement_is_valid())
    throw Error(fmt::format("'{}': the .vdb grid's placement is outside voxcast's world range",
                            path.string()));
  std::vector<std::pair<uint64_t, size_t>> order;
  order.reserve(coords.size());
  for (size_t i = 0; i < coords.size(); ++i)
    order.push_back(
        {morton_encode(uint32_t(coords[i].x() - lo.x()), uint32_t(coords[i].y() - lo.y()),
                       uint32_t(coords[i].z() - lo.z())),
         i});
  std::sort(order.begin(), order.end());
  auto accessor = colors ? std::optional(colors->getConstAccessor()) : std::nullopt;
  for (const auto& [code, i] : order) {
    set.codes.push_back(code);
    Color c{1, 1, 1, 1};
    if (accessor) {
      // The color grid may have its own transform: sample it at the voxel's
      // world position (nearest voxel).
      const openvdb::Vec3d world = xf.indexToWorld(coords[i]);
      const openvdb::Coord ci = colors->transform().worldToIndexNodeCentered(world);
      const openvdb::Vec3s v = accessor->getValue(ci);
      c = {v.x(), v.y(), v.z(), 1.f};
    }
    set.colors.push_back(c);
  }
  detail::finish_voxel_set(set);
  return set;
}

void write_vdb(const std::filesystem::path& path, const VoxelSet& voxels) {
  if (voxels.codes.empty()) throw Error("cannot write .vdb: the voxel set is empty");
  init_openvdb();
  // A fog volume (1 in every voxel, 0 outside) and the linear colors.
  auto density = openvdb::FloatGrid::create(0.f);
  density->setName("density");
  density->setGridClass(openvdb::GRID_FOG_VOLUME);
  auto color = openvdb::Vec3SGrid::create(openvdb::Vec3s(0.f));
  color->setName("Cd");
  // Index (i, j, k) at voxel centers: origin + (i + 1/2) * size.
  const double h = voxels.grid.voxel_size;
  auto xf = openvdb::math::Transform::createLinearTransform(h);
  xf->postTranslate(openvdb::Vec3d(voxels.grid.origin.x + 0.5 * h, voxels.grid.origin.y + 0.5 * h,
                                   voxels.grid.origin.z + 0.5 * h));
  density->setTransform(xf);
  color->setTransform(xf->copy());
  auto d = density->getAccessor();
  auto c = color->getAccessor();
  for (size_t i = 0; i < voxels.codes.size(); ++i) {
    const MortonCoord m = morton_decode(voxels.codes[i]);
    const openvdb::Coord ijk(int(m.x), int(m.y), int(m.z));
    d.setValue(ijk, 1.f);
    const Color& col = voxels.colors.empty() ? Color{1, 1, 1, 1} : voxels.colors[i];
    c.setValue(ijk, openvdb::Vec3s(col.r, col.g, col.b));
  }
  detail::write_vdb_grids(path, {density, color});
}

void detail::write_vdb_grids(const std::filesystem::path& path, const openvdb::GridPtrVec& grids) {
  init_openvdb();
  // Written beside the target and renamed into place, like every output.
  std::filesystem::path tmp = path;
  tmp += ".tmp";
  try {
    // io::File::write's bytes (Archive::write, seekable: grid offsets), but
    // through a stream we check afterwards: io::File does not, so a full
    // disk or a file size limit gave a truncated file and no error.
    struct CheckedArchive : openvdb::io::Archive {
      bool write_to(std::ostream& os, const openvdb::GridPtrVec& g) const {
        Archive::write(os, g, /*seekable=*/true);
        os.flush();
        return bool(os);
      }
    };
    std::ofstream os(tmp, std::ios::binary | std::ios::trunc);
    if (!os) throw Error(fmt::format("cannot write {}: {}", path.string(), std::strerror(errno)));
    errno = 0;
    if (!CheckedArchive().write_to(os, grids))
      throw Error(fmt::format("cannot write {}: {}", path.string(),
                              errno != 0 ? std::strerror(errno) : "I/O error"));
    os.close();
    if (!os) throw Error(fmt::format("cannot write {}: I/O error", path.string()));
  } catch (const Error&) {
    std::error_code ec;
    std::filesystem::remove(tmp, ec);
    throw;
  } catch (const std::exception& e) {
    std::error_code ec;
    std::filesystem::remove(tmp, ec);
    throw Error(fmt::format("cannot write {}: {}", path.string(), e.what()));
  }
  try {
    content_uuid(tmp);
  } catch (const Error&) {
    std::error_code ec;
    std::filesystem::remove(tmp, ec);
    throw;
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) throw Error(fmt::format("cannot write {}: {}", path.string(), ec.message()));
}

}  // namespace voxcast
