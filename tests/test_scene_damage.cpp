// Damaged scene files behind valid checksums (issue 15 items 1-2): for every
// stored format, 32-bit word edits of every section payload with the section
// hash recomputed must end in either an accepted scene that renders, or a
// one-line refusal -- never a crash, an out-of-bounds read (run this suite
// under ASan/UBSan, README "Reliability") or a hang; `info` and `render`
// agree. Also the regression inputs committed under tests/data/regress.
#include <gtest/gtest.h>

#include <bit>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>

#include "esvo/layout_internal.hpp"
#include "support/cli_runner.hpp"
#include "support/scene_damage.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/scene_file.hpp"

namespace voxcast {
namespace {

namespace fs = std::filesystem;
using testing::damage_sample;
using testing::SceneKind;

constexpr uint32_t kEsvo = fourcc("ESVO");

bool is_esvo(SceneKind k) {
  return k != SceneKind::DagRaw && k != SceneKind::DagCompressed;
}

void write_file(const fs::path& p, const std::vector<uint8_t>& b) {
  std::ofstream out(p, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(b.data()), std::streamsize(b.size()));
}

// The ctest sweep size; the long sweep (README "Reliability") raises it:
// VOXCAST_DAMAGE_POSITIONS=N word positions per section, VOXCAST_DAMAGE_SEED.
uint64_t env_or(const char* name, uint64_t fallback) {
  const char* v = std::getenv(name);
  return v && *v ? std::strtoull(v, nullptr, 10) : fallback;
}

class SceneDamage : public ::testing::TestWithParam<SceneKind> {};

// The samples carry every feature the sweep is meant to hit (otherwise a
// clean sweep would prove little).
TEST_P(SceneDamage, SampleHasTheFormatsFeatures) {
  const SceneKind kind = GetParam();
  const std::vector<uint8_t>& bytes = damage_sample(kind);
  const testing::Verdict v = testing::check_scene(bytes);
  ASSERT_TRUE(v.accepted) << v.error;
  EXPECT_GT(v.hits, 20u);  // the small render sees the terrain
  const Container c = Container::parse(bytes.data(), bytes.size());
  const LoadedScene scene = load_scene(c);
  if (!is_esvo(kind)) {
    EXPECT_EQ(scene.format, "dag");
    EXPECT_EQ(c.has(fourcc("DATC")), kind == SceneKind::DagCompressed);
    EXPECT_EQ(c.has(fourcc("DATR")), kind == SceneKind::DagRaw);
    return;
  }
  const esvo::EsvoOctree& o = dynamic_cast<const esvo::EsvoStructure&>(*scene.structure).octree();
  EXPECT_GE(o.block_count, 2u);
  EXPECT_GT(o.memory_stats().far_pointer_bytes, 0u);
  const bool compressed =
      kind == SceneKind::EsvoCompressed || kind == SceneKind::EsvoContoursCompressed;
  EXPECT_EQ(o.attribute_format() == esvo::AttributeFormat::Compressed, compressed);
  EXPECT_EQ(o.has_contours(), kind != SceneKind::EsvoRaw && kind != SceneKind::EsvoCompressed);
  if (o.has_contours()) {
    EXPECT_GT(o.memory_stats().contour_count, 0u);
  }
  if (kind == SceneKind::EsvoVariableDepth) {
    // Leaves above the finest level: the variable-depth build stopped early.
    const auto levels = o.level_stats();
    uint64_t early = 0;
    for (size_t l = 0; l + 1 < levels.size(); ++l) early += levels[l].voxels - levels[l].non_leaf;
    EXPECT_GT(early, 0u);
  }
}

// The sweep: ~2,000 damaged files per format (every edit at ~150 word
// positions of each section, structure words first). Each is accepted and
// renders, or is refused with one line.
TEST_P(SceneDamage, EveryWordEditIsAcceptedOrRefusedInOneLine) {
  const SceneKind kind = GetParam();
  const std::vector<uint8_t>& good = damage_sample(kind);
  const std::vector<testing::Mutation> mutations = testing::sweep_mutations(
      good, env_or("VOXCAST_DAMAGE_POSITIONS", 150), env_or("VOXCAST_DAMAGE_SEED", 15));
  ASSERT_GT(mutations.size(), 1500u);
  size_t accepted = 0, refused = 0;
  for (const testing::Mutation& m : mutations) {
    const std::vector<uint8_t> bad = testing::apply_mutation(good, m);
    // The container layer accepts it: the damage reaches the validators.
    ASSERT_NO_THROW(Container::parse(bad.data(), bad.size())) << testing::describe(m);
    const testing::Verdict v = testing::check_scene(bad);
    if (v.accepted) {
      ++accepted;
      EXPECT_EQ(v.use_error, "") << testing::describe(m);
      continue;
    }
    ++refused;
    EXPECT_FALSE(v.error.empty()) << testing::describe(m);
    EXPECT_EQ(v.error.find('\n'), std::string::npos) << testing::describe(m) << ": " << v.error;
  }
  // Both outcomes occur: pointers and counts are checked, while e.g. color
  // bits are harmless by design.
  EXPECT_GT(refused, mutations.size() / 10) << accepted << " accepted";
  EXPECT_GT(accepted, mutations.size() / 20) << refused << " refused";
  std::printf("%s: %zu damaged files, %zu accepted, %zu refused\n", testing::scene_kind_name(kind),
              mutations.size(), accepted, refused);
}

// Through the CLI binary: for a sample of damaged files, `info` and `render`
// agree with each other and with the in-process verdict, and a refusal is
// exactly one line naming the file, exit status 1.
TEST_P(SceneDamage, CliInfoAndRenderAgree) {
  const SceneKind kind = GetParam();
  const std::vector<uint8_t>& good = damage_sample(kind);
  const std::vector<testing::Mutation> mutations = testing::sweep_mutations(good, 150, 15);
  testing::TempDir tmp;
  int accepted = 0, refused = 0;
  for (size_t i = 0; i < mutations.size() && (accepted < 2 || refused < 3); i += 37) {
    const std::vector<uint8_t> bad = testing::apply_mutation(good, mutations[i]);
    const testing::Verdict v = testing::check_scene(bad);
    if (v.accepted ? accepted >= 2 : refused >= 3) continue;
    (v.accepted ? accepted : refused)++;
    const std::string file = tmp.file("d.vxc");
    write_file(file, bad);
    const testing::CliResult info = testing::run_cli("info '" + file + "'");
    const testing::CliResult render =
        testing::run_cli("render '" + file + "' -o '" + tmp.file("d.png") + "' --size 16x12");
    const std::string what = testing::describe(mutations[i]);
    if (v.accepted) {
      EXPECT_EQ(info.exit_code, 0) << what << "\n" << info.output;
      EXPECT_EQ(render.exit_code, 0) << what << "\n" << render.output;
    } else {
      const std::string line = "voxcast: error: scene '" + file + "': " + v.error + "\n";
      EXPECT_EQ(info.exit_code, 1) << what;
      EXPECT_EQ(info.output, line) << what;
      EXPECT_EQ(render.exit_code, 1) << what;
      EXPECT_EQ(render.output, line) << what;
    }
  }
  EXPECT_EQ(accepted, 2);
  EXPECT_EQ(refused, 3);
}

INSTANTIATE_TEST_SUITE_P(Formats, SceneDamage, ::testing::ValuesIn(testing::kAllSceneKinds),
                         [](const ::testing::TestParamInfo<SceneKind>& p) {
                           return std::string(testing::scene_kind_name(p.param));
                         });

// The crash of issue 15: a descriptor whose children are all leaves, with the
// far bit and a pointer set. The beam's coarse pass and occupied_bounds()
// fetched the far pointer before looking at the masks; validate() did not
// check a pointer it never followed. Now the pointer field of such a
// descriptor must be zero.
TEST(SceneDamageRegression, LeafOnlyDescriptorWithFarBitIsRefused) {
  const std::vector<uint8_t>& good = damage_sample(SceneKind::EsvoCompressed);
  const Container c = Container::parse(good.data(), good.size());
  const LoadedScene scene = load_scene(c);
  const esvo::EsvoOctree& o = dynamic_cast<const esvo::EsvoStructure&>(*scene.structure).octree();
  // A reachable descriptor with only leaf children (independent walk).
  uint32_t target = 0;
  std::vector<uint32_t> stack{o.root_slot()};
  while (!stack.empty() && !target) {
    const uint32_t s = stack.back();
    stack.pop_back();
    const uint32_t w0 = o.words[size_t(s) * 2];
    namespace L = esvo::layout;
    const uint32_t valid = L::ValidMask::get(w0), nl = valid & ~L::LeafMask::get(w0);
    if (!nl) {
      target = s;
      break;
    }
    uint32_t g = s + L::ChildPointer::get(w0);
    if (L::FarBit::test(w0)) g = uint32_t(int64_t(s) + int32_t(o.words[size_t(g) * 2]));
    for (int k = 0; k < std::popcount(nl); ++k) stack.push_back(g + uint32_t(k));
  }
  ASSERT_NE(target, 0u);
  // A child pointer with the far bit, the far bit alone, a near pointer of
  // all but its top bit: each points below a descriptor without non-leaf
  // children.
  namespace L = esvo::layout;
  for (const uint32_t field : {L::ChildPointer::mask | L::FarBit::mask, L::FarBit::mask,
                               L::ChildPointer::put(L::ChildPointer::max >> 1)}) {
    testing::Mutation m;
    m.section = kEsvo;
    m.word = uint64_t(target) * 2;
    m.edit = testing::WordEdit::Random;
    m.arg = o.words[size_t(target) * 2] | field;
    const testing::Verdict v = testing::check_scene(testing::apply_mutation(good, m));
    EXPECT_FALSE(v.accepted);
    EXPECT_NE(v.error.find("child pointer without children"), std::string::npos) << v.error;
  }
}

// Every committed regression input (fuzzer finds and sweep cases, each a
// small .vxc) loads or is refused without a crash; the file's name says which
// outcome is expected ("accept-*" / anything else: refused).
TEST(SceneDamageRegression, CommittedInputs) {
  const fs::path dir = fs::path(VOXCAST_SOURCE_DIR) / "tests" / "data" / "regress";
  ASSERT_TRUE(fs::is_directory(dir)) << dir;
  int files = 0;
  for (const auto& entry : fs::directory_iterator(dir)) {
    if (entry.path().extension() != ".vxc") continue;
    ++files;
    std::ifstream in(entry.path(), std::ios::binary);
    const std::vector<uint8_t> bytes((std::istreambuf_iterator<char>(in)), {});
    const testing::Verdict v = testing::check_scene(bytes);
    const bool expect_accept = entry.path().filename().string().rfind("accept-", 0) == 0;
    EXPECT_EQ(v.accepted, expect_accept) << entry.path() << ": " << v.error;
    if (!v.accepted) {
      EXPECT_EQ(v.error.find('\n'), std::string::npos) << v.error;
    }
  }
  EXPECT_GT(files, 0);
}

}  // namespace
}  // namespace voxcast
