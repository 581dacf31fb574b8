#pragma once
// Damaged scene files that still pass the container's checksums: the input
// class a buggy writer, a tool that rewrites sections or a hostile file
// produces (issue 15). Small scenes of every stored format, 32-bit word edits
// of one section payload with the section hash recomputed, and what every
// reader does with the result. Used by tests/test_scene_damage.cpp (the
// deterministic sweep) and fuzz/fuzz_scene_sections.cpp (the libFuzzer
// custom mutator); no GoogleTest dependency so the fuzzer can link it.
#include <cstdint>
#include <string>
#include <vector>

namespace voxcast::testing {

/// Every stored scene format (the .vxc variants `voxcast build` writes).
enum class SceneKind {
  EsvoRaw,
  EsvoCompressed,
  EsvoContours,
  EsvoContoursCompressed,
  EsvoVariableDepth,
  DagRaw,
  DagCompressed,
};
inline constexpr SceneKind kAllSceneKinds[] = {
    SceneKind::EsvoRaw,           SceneKind::EsvoCompressed,
    SceneKind::EsvoContours,      SceneKind::EsvoContoursCompressed,
    SceneKind::EsvoVariableDepth, SceneKind::DagRaw,
    SceneKind::DagCompressed,
};
const char* scene_kind_name(SceneKind kind);  // e.g. "esvo_contours_compressed"

/// A small scene of `kind` as file bytes, built in code from a generated
/// terrain mesh at 32^3 (deterministic). ESVO scenes use tiny blocks, so
/// several blocks, info sections, attachments and far pointers are present.
/// Cached: repeated calls return the same bytes cheaply.
const std::vector<uint8_t>& damage_sample(SceneKind kind);

/// One 32-bit word edit of one section payload.
enum class WordEdit : uint8_t { AllOnes, Zero, HighBit, Random, PlusOne, MinusOne, BitFlip };
inline constexpr int kWordEditCount = 7;
struct Mutation {
  uint32_t section = 0;  // fourcc
  uint64_t word = 0;     // word index in the payload (a trailing partial word is padded)
  WordEdit edit = WordEdit::Zero;
  uint32_t arg = 0;  // Random: the value; BitFlip: the bit (0..31)
};
std::string describe(const Mutation& m);  // "ESVO word 17: 0xFFFFFFFF"

/// The serialized container `file` with `m` applied to its section and every
/// section hash recomputed (so the container layer accepts it). `file` must
/// parse; a word past the end of the section is a no-op.
std::vector<uint8_t> apply_mutation(const std::vector<uint8_t>& file, const Mutation& m);

/// A deterministic sweep over `file`: for each section, `positions` word
/// positions (every structure word first: the non-zero words, spread evenly
/// when there are more; then random ones) times every WordEdit. Seeded by
/// `seed` (random values, flipped bits, the extra positions).
std::vector<Mutation> sweep_mutations(const std::vector<uint8_t>& file, size_t positions,
                                      uint64_t seed);

/// What the readers make of a file, in process.
struct Verdict {
  bool accepted = false;  // by the loader (load_scene)
  std::string error;      // the one-line voxcast::Error message when refused
  std::string use_error;  // accepted, but info or render failed: always a bug
  uint64_t hits = 0;      // pixels of the small render that hit
  uint64_t voxels = 0;    // leaves counted by the info statistics
};
/// Everything a subcommand does with a scene, through the one loader:
/// Container::parse, load_scene (validation, occupied bounds), the `info`
/// statistics of the loaded structure, then a 16 x 12 render with the auto
/// camera, the beam, hard shadows and AO (every hit shades and fetches its
/// attributes). Throws nothing for a voxcast::Error (from the loader:
/// accepted = false; after it: use_error); any other failure is a bug the
/// caller sees (a crash under the sanitizers).
Verdict check_scene(const std::vector<uint8_t>& file);

}  // namespace voxcast::testing
