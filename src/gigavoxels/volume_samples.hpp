#pragma once
// Raw sample decoding shared by the volume file readers (INRIMAGE-4 in
// inrimage.cpp, MetaImage in metaimage.cpp): fixed-width integers or floats
// of either byte order, converted to float and checked finite.
#include <bit>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <string>
#include <type_traits>
#include <vector>

#include "voxcast/error.hpp"

namespace voxcast::giga::detail {

enum class SampleType { U8, I8, U16, I16, U32, I32, F32, F64 };

inline size_t sample_bytes(SampleType t) {
  switch (t) {
    case SampleType::U8:
    case SampleType::I8:
      return 1;
    case SampleType::U16:
    case SampleType::I16:
      return 2;
    case SampleType::U32:
    case SampleType::I32:
    case SampleType::F32:
      return 4;
    case SampleType::F64:
      return 8;
  }
  return 0;
}

template <class T>
T load_sample(const unsigned char* p, bool big) {
  using U = std::conditional_t<
      sizeof(T) == 1, uint8_t,
      std::conditional_t<sizeof(T) == 2, uint16_t,
                         std::conditional_t<sizeof(T) == 4, uint32_t, uint64_t>>>;
  U u = 0;
  for (size_t i = 0; i < sizeof(T); ++i) u |= U(U(p[big ? sizeof(T) - 1 - i : i]) << (8 * i));
  return std::bit_cast<T>(u);
}

/// Decodes `count` samples at `p` into `out` (resized); a non-finite sample
/// throws voxcast::Error "<format>: sample N is not a finite number".
inline void decode_samples(const unsigned char* p, size_t count, SampleType type, bool big,
                           const char* format, std::vector<float>* out) {
  out->resize(count);
  const size_t width = sample_bytes(type);
  for (size_t i = 0; i < count; ++i, p += width) {
    float x = 0.f;
    switch (type) {
      case SampleType::U8:
        x = float(load_sample<uint8_t>(p, big));
        break;
      case SampleType::I8:
        x = float(load_sample<int8_t>(p, big));
        break;
      case SampleType::U16:
        x = float(load_sample<uint16_t>(p, big));
        break;
      case SampleType::I16:
        x = float(load_sample<int16_t>(p, big));
        break;
      case SampleType::U32:
        x = float(load_sample<uint32_t>(p, big));
        break;
      case SampleType::I32:
        x = float(load_sample<int32_t>(p, big));
        break;
      case SampleType::F32:
        x = load_sample<float>(p, big);
        break;
      case SampleType::F64:
        x = float(load_sample<double>(p, big));
        break;
    }
    if (!std::isfinite(x))
      throw Error(std::string(format) + ": sample " + std::to_string(i) +
                  " is not a finite number");
    (*out)[i] = x;
  }
}

}  // namespace voxcast::giga::detail
