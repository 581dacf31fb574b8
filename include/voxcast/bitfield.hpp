#pragma once
// Named bit fields of the on-disk and in-memory word layouts (ESVO child
// descriptors, lookup entries, cube normals, contours, compressed blocks, DAG
// headers). Each layout names its fields once, next to its documentation
// (esvo.hpp, dag.hpp), and pins them with static_asserts against the
// documented masks; code reads and writes words only through these, so a
// shift or a mask cannot drift from the documented layout in one place.
#include <cstdint>
#include <type_traits>

namespace voxcast {

/// Bits Lo .. Lo+Width-1 of a Word (bit 0 = least significant).
template <unsigned Lo, unsigned Width, class Word = uint32_t>
struct BitField {
  static_assert(std::is_unsigned_v<Word>);
  static constexpr unsigned kWordBits = sizeof(Word) * 8;
  static_assert(Width >= 1 && Lo + Width <= kWordBits, "field outside its word");
  static constexpr unsigned lo = Lo, width = Width;
  /// Largest value the field holds.
  static constexpr Word max = Width == kWordBits ? Word(~Word(0)) : Word((Word(1) << Width) - 1);
  /// The field's bits in place.
  static constexpr Word mask = Word(max << Lo);

  static constexpr Word get(Word w) { return Word(w >> Lo) & max; }
  /// The field as a two's-complement signed value of Width bits.
  static constexpr std::make_signed_t<Word> get_signed(Word w) {
    using S = std::make_signed_t<Word>;
    return S(Word(w << (kWordBits - Lo - Width))) >> (kWordBits - Width);
  }
  /// `v` (masked to Width bits) in place, other bits zero: fields of one
  /// word are combined with `|`.
  static constexpr Word put(Word v) { return Word((v & max) << Lo); }
  static constexpr Word put_signed(std::make_signed_t<Word> v) { return put(Word(v)); }
  /// `w` with the field replaced by `v` (masked to Width bits).
  static constexpr Word set(Word w, Word v) { return Word((w & ~mask) | put(v)); }
  static constexpr bool test(Word w) { return (w & mask) != 0; }
};

/// An array of equal Width-bit fields packed from bit 0 up: element i is bits
/// Width*i .. Width*i+Width-1 (e.g. the 2-bit color indices of a compressed
/// block, the 8 child-slot bytes of a DAG leaf mask).
template <unsigned Width, class Word = uint32_t>
struct PackedFields {
  static constexpr unsigned kWordBits = sizeof(Word) * 8;
  static_assert(Width >= 1 && Width <= kWordBits && kWordBits % Width == 0);
  static constexpr unsigned count = kWordBits / Width;
  static constexpr Word max = Width == kWordBits ? Word(~Word(0)) : Word((Word(1) << Width) - 1);

  static constexpr Word get(Word w, unsigned i) { return Word(w >> (Width * i)) & max; }
  /// Element i as a two's-complement signed value of Width bits.
  static constexpr std::make_signed_t<Word> get_signed(Word w, unsigned i) {
    using S = std::make_signed_t<Word>;
    return S(Word(w << (kWordBits - Width * (i + 1)))) >> (kWordBits - Width);
  }
  static constexpr Word put(Word v, unsigned i) { return Word((v & max) << (Width * i)); }
};

/// True iff the fields are pairwise disjoint and together cover exactly
/// `covered` (all bits of the word by default): used to pin a layout.
template <class F0, class... F>
constexpr bool fields_tile(uint64_t covered = ~uint64_t(0) >> (64 - F0::kWordBits)) {
  uint64_t seen = uint64_t(F0::mask);
  bool disjoint = true;
  ((disjoint = disjoint && (seen & uint64_t(F::mask)) == 0, seen |= uint64_t(F::mask)), ...);
  return disjoint && seen == covered;
}

}  // namespace voxcast
