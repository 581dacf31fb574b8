// io_library_versions() (voxcast/version.hpp): run-time versions where the
// library reports one (assimp, libpng, TBB, xxHash), else the headers'.
#include <OpenEXR/OpenEXRConfig.h>
#include <assimp/version.h>
#include <fmt/format.h>
#include <openvdb/version.h>
#include <png.h>
#include <tbb/version.h>
#include <xxhash.h>

#include <nlohmann/json.hpp>

#include "voxcast/version.hpp"

namespace voxcast {

std::string io_library_versions() {
  const unsigned png = png_access_version_number();  // xyyzz: x.yy.zz
  const unsigned xxh = XXH_versionNumber();          // x*10000 + y*100 + z
  return fmt::format(
      "assimp {}.{}.{}\nlibpng {}.{}.{}\noneTBB {}\nxxHash {}.{}.{}\nnlohmann_json {}.{}.{}\nfmt "
      "{}.{}.{}\nOpenEXR {}\nOpenVDB {}\n",
      aiGetVersionMajor(), aiGetVersionMinor(), aiGetVersionPatch(), png / 10000, png / 100 % 100,
      png % 100, TBB_runtime_version(), xxh / 10000, xxh / 100 % 100, xxh % 100,
      NLOHMANN_JSON_VERSION_MAJOR, NLOHMANN_JSON_VERSION_MINOR, NLOHMANN_JSON_VERSION_PATCH,
      FMT_VERSION / 10000, FMT_VERSION / 100 % 100, FMT_VERSION % 100, OPENEXR_VERSION_STRING,
      openvdb::getLibraryVersionString());
}

}  // namespace voxcast
