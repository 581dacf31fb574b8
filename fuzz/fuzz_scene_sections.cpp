// libFuzzer target, structure-aware: inputs are always valid .vxc containers
// (every section hash correct), so the fuzzer's effort goes into the section
// payloads the validators guard -- ESVO descriptors, far pointers, page
// headers, info sections, raw lookup entries, compressed blocks, contour
// attachments, META, DAG node tables and attribute sections -- instead of
// dying at the checksum. The custom mutator edits 32-bit words of one
// section (the sweep's edits of tests/support/scene_damage.hpp, or
// libFuzzer's own byte mutations of the payload, or a resize), then
// re-serializes the container, recomputing the hashes; or re-chunks every
// section (small chunk sizes), or edits one word of the directory with its
// hash recomputed (container.hpp layout). Each input then goes
// through everything a subcommand does (testing::check_scene: load_scene,
// the info statistics, a small render with beam, shadows and AO).
//
// Seeds: the seven formats of testing::kAllSceneKinds. An input that is not
// a container is replaced by one of them when -max_len allows (libFuzzer
// takes it from the largest corpus file, so start from the seeds), and
//   VOXCAST_WRITE_SEEDS=DIR ./fuzz_scene_sections
// writes them to DIR and exits (README "Reliability" has the full recipe).
#include <tbb/global_control.h>
#include <xxhash.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <random>
#include <string>
#include <vector>

#include "support/scene_damage.hpp"
#include "voxcast/container.hpp"
#include "voxcast/error.hpp"
#include "voxcast/scene_file.hpp"

extern "C" size_t LLVMFuzzerMutate(uint8_t* data, size_t size, size_t max_size);

namespace {

using voxcast::Container;
namespace t = voxcast::testing;

std::vector<uint8_t> mutate(const std::vector<uint8_t>& file, std::mt19937& rng) {
  Container c = Container::parse(file.data(), file.size());
  const std::vector<uint32_t> ids = c.section_ids();
  if (ids.empty()) return file;
  const uint32_t id = ids[rng() % ids.size()];
  std::vector<uint8_t> bytes = c.get(id);
  const size_t words = (bytes.size() + 3) / 4;
  switch (rng() % 8) {
    case 0: {  // libFuzzer's byte-level mutations of the payload, in place
      const size_t n = bytes.size();
      bytes.resize(n + 64);
      bytes.resize(LLVMFuzzerMutate(bytes.data(), n, bytes.size()));
      break;
    }
    case 1: {  // resize: drop or append a few words
      const size_t k = 1 + rng() % 4;
      if (rng() % 2 && bytes.size() >= 4 * k)
        bytes.resize(bytes.size() - 4 * k);
      else
        bytes.resize(bytes.size() + 4 * k, uint8_t(rng() % 2 ? 0 : 0xFF));
      break;
    }
    case 2: {  // the same sections in chunks of 8..4096 bytes: chunk tables reach the reader
      std::vector<uint8_t> out;
      voxcast::ContainerWriter w(&out, 8u << (rng() % 10));
      for (const uint32_t s : ids) w.add(s, c.get(s));
      w.commit();
      return out;
    }
    case 3: {  // one directory word edited, the directory hash recomputed, so
               // the directory checks (offsets, sizes, counts) see it
      std::vector<uint8_t> out = c.serialize();
      uint64_t dir = 0;
      std::memcpy(&dir, &out[16], 8);
      const size_t span = out.size() - size_t(dir);
      if (span < 4) return out;
      const size_t at = size_t(dir) + 4 * (rng() % (span / 4));
      uint32_t v = 0;
      std::memcpy(&v, &out[at], 4);
      v = rng() % 2 ? v ^ (1u << (rng() % 32)) : v + uint32_t(rng() % 3) - 1;
      std::memcpy(&out[at], &v, 4);
      XXH64_state_t* st = XXH64_createState();
      XXH64_reset(st, 0);
      XXH64_update(st, out.data(), 32);
      XXH64_update(st, out.data() + dir, span);
      const uint64_t h = XXH64_digest(st);
      XXH64_freeState(st);
      std::memcpy(&out[32], &h, 8);
      return out;
    }
    default: {  // 1-3 word edits, mostly on non-zero (structure) words
      if (words == 0) break;
      std::vector<uint8_t> out = file;
      const int edits = 1 + int(rng() % 3);
      for (int e = 0; e < edits; ++e) {
        size_t w = rng() % words;
        for (int tries = 0; tries < 8; ++tries) {
          uint32_t v = 0;
          std::memcpy(&v, &bytes[4 * w], std::min<size_t>(4, bytes.size() - 4 * w));
          if (v != 0 || rng() % 8 == 0) break;
          w = rng() % words;
        }
        t::Mutation m;
        m.section = id;
        m.word = w;
        m.edit = t::WordEdit(rng() % t::kWordEditCount);
        m.arg = m.edit == t::WordEdit::Random ? uint32_t(rng()) : uint32_t(rng() % 32);
        out = t::apply_mutation(out, m);  // hashes recomputed
      }
      return out;
    }
  }
  c.add(id, std::move(bytes));
  return c.serialize();
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  // One thread: the fuzzer runs on one core, and a finding replays exactly.
  static tbb::global_control one_thread(tbb::global_control::max_allowed_parallelism, 1);
  if (const char* dir = std::getenv("VOXCAST_WRITE_SEEDS")) {
    for (const t::SceneKind k : t::kAllSceneKinds) {
      const std::vector<uint8_t>& b = t::damage_sample(k);
      std::ofstream out(std::string(dir) + "/" + t::scene_kind_name(k) + ".vxc", std::ios::binary);
      out.write(reinterpret_cast<const char*>(b.data()), std::streamsize(b.size()));
    }
    std::exit(0);
  }
  return 0;
}

extern "C" size_t LLVMFuzzerCustomMutator(uint8_t* data, size_t size, size_t max_size,
                                          unsigned int seed) {
  std::mt19937 rng(seed);
  std::vector<uint8_t> file(data, data + size);
  try {
    (void)Container::parse(file.data(), file.size());
  } catch (const voxcast::Error&) {
    file = t::damage_sample(t::kAllSceneKinds[rng() % std::size(t::kAllSceneKinds)]);
  }
  std::vector<uint8_t> out = mutate(file, rng);
  if (out.size() > max_size) out = file;
  if (out.size() > max_size) return size;  // -max_len below the seeds: leave it
  std::memcpy(data, out.data(), out.size());
  return out.size();
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  // check_scene never throws for a refusal; a crash, a sanitizer report or
  // an accepted scene that info or render cannot use is the finding.
  const t::Verdict v = t::check_scene(std::vector<uint8_t>(data, data + size));
  if (!v.use_error.empty()) {
    std::fprintf(stderr, "accepted, then failed: %s\n", v.use_error.c_str());
    std::abort();
  }
  return 0;
}
