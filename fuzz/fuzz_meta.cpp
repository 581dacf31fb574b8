// libFuzzer target: the JSON 'META' section of a scene file. The input's
// first byte picks one of the seven stored formats (testing::kAllSceneKinds),
// the rest replaces that sample's META payload, and the container is
// re-serialized with every section hash recomputed, so each input reaches
// the META reader (JSON syntax, every field's type and range, the grid
// placement, the format and section names it selects) behind a valid
// checksum, with a structure section it must agree with. Byte-level
// mutations suit JSON text better than the word edits of
// fuzz_scene_sections, which only seldom keep a META section parseable.
// Each input then goes through everything a subcommand does
// (testing::check_scene); an accepted scene that info or render cannot use
// aborts.
//
//   VOXCAST_WRITE_SEEDS=DIR ./fuzz_meta
// writes the seven samples' META sections (with their format byte) to DIR
// and exits;
//   VOXCAST_REFUSALS=DIR ./fuzz_meta -runs=0 CORPUS
// replays CORPUS and writes, for each distinct refusal (its message with
// numbers as "n"), the smallest scene file refused with it to
// DIR/fuzz-meta-<message>.vxc: regression inputs for tests/data/regress.
#include <tbb/global_control.h>

#include <cctype>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "support/scene_damage.hpp"
#include "voxcast/error.hpp"
#include "voxcast/scene_file.hpp"

namespace {

namespace t = voxcast::testing;

const uint32_t kMeta = voxcast::fourcc("META");

// "corrupt scene: META 'levels' is 99, expected 2..20" -> "meta-levels-is-n-expected-n-n".
std::string refusal_name(std::string message) {
  for (const char* prefix : {"corrupt scene: "})
    if (message.rfind(prefix, 0) == 0) message.erase(0, std::char_traits<char>::length(prefix));
  std::string out;
  for (size_t i = 0; i < message.size() && out.size() < 45; ++i) {
    const unsigned char c = static_cast<unsigned char>(message[i]);
    if (std::isdigit(c)) {
      while (i + 1 < message.size() &&
             (std::isdigit(static_cast<unsigned char>(message[i + 1])) || message[i + 1] == '.'))
        ++i;
      out += 'n';
    } else if (std::isalpha(c)) {
      out += char(std::tolower(c));
    } else if (!out.empty() && out.back() != '-') {
      out += '-';
    }
  }
  while (!out.empty() && out.back() == '-') out.pop_back();
  return out;
}

void keep_smallest_refusal(const char* dir, const std::string& error,
                           const std::vector<uint8_t>& file) {
  const std::filesystem::path path =
      std::filesystem::path(dir) / ("fuzz-meta-" + refusal_name(error) + ".vxc");
  std::error_code ec;
  const auto size = std::filesystem::file_size(path, ec);
  if (!ec && size <= file.size()) return;
  std::ofstream out(path, std::ios::binary);
  out.write(reinterpret_cast<const char*>(file.data()), std::streamsize(file.size()));
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  // One thread: the fuzzer runs on one core, and a finding replays exactly.
  static tbb::global_control one_thread(tbb::global_control::max_allowed_parallelism, 1);
  if (const char* dir = std::getenv("VOXCAST_WRITE_SEEDS")) {
    for (size_t k = 0; k < std::size(t::kAllSceneKinds); ++k) {
      const std::vector<uint8_t>& file = t::damage_sample(t::kAllSceneKinds[k]);
      const voxcast::Container c = voxcast::Container::parse(file.data(), file.size());
      const std::vector<uint8_t> meta = c.get(kMeta);
      std::ofstream out(std::string(dir) + "/meta_" + t::scene_kind_name(t::kAllSceneKinds[k]),
                        std::ios::binary);
      out.put(char(k));
      out.write(reinterpret_cast<const char*>(meta.data()), std::streamsize(meta.size()));
    }
    std::exit(0);
  }
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 1) return 0;
  const std::vector<uint8_t>& sample =
      t::damage_sample(t::kAllSceneKinds[data[0] % std::size(t::kAllSceneKinds)]);
  voxcast::Container c = voxcast::Container::parse(sample.data(), sample.size());
  c.add(kMeta, std::vector<uint8_t>(data + 1, data + size));  // replaces the section
  const std::vector<uint8_t> file = c.serialize();
  const t::Verdict v = t::check_scene(file);
  if (const char* dir = std::getenv("VOXCAST_REFUSALS"); dir && !v.accepted)
    keep_smallest_refusal(dir, v.error, file);
  if (!v.use_error.empty()) {
    std::fprintf(stderr, "accepted, then failed: %s\n", v.use_error.c_str());
    std::abort();
  }
  return 0;
}
