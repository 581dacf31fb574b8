#include "voxcast/isa.hpp"

#include <fmt/format.h>

#include <cstdlib>
#include <cstring>

#include "voxcast/error.hpp"
#include "voxcast/version.hpp"

namespace voxcast {

bool cpu_supports(Isa isa) {
  switch (isa) {
    case Isa::Avx2:
      return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma") &&
             __builtin_cpu_supports("bmi2");
    case Isa::Avx512:
      // x86-64-v4: AVX-512 F, BW, CD, DQ, VL (what -march=x86-64-v4 may emit).
      return cpu_supports(Isa::Avx2) && __builtin_cpu_supports("avx512f") &&
             __builtin_cpu_supports("avx512bw") && __builtin_cpu_supports("avx512cd") &&
             __builtin_cpu_supports("avx512dq") && __builtin_cpu_supports("avx512vl");
  }
  return false;
}

const char* isa_name(Isa isa) {
  return isa == Isa::Avx512 ? "avx512" : "avx2";
}

namespace {

Isa choose_isa() {
  const char* env = std::getenv("VOXCAST_ISA");
  if (env != nullptr && *env != '\0') {
    Isa want;
    if (std::strcmp(env, "avx2") == 0)
      want = Isa::Avx2;
    else if (std::strcmp(env, "avx512") == 0)
      want = Isa::Avx512;
    else
      throw Error(fmt::format("VOXCAST_ISA={}: expected avx2 or avx512", env));
    if (!cpu_supports(want))
      throw Error(fmt::format("VOXCAST_ISA={}: this CPU does not support it", env));
    return want;
  }
  return cpu_supports(Isa::Avx512) ? Isa::Avx512 : Isa::Avx2;
}

}  // namespace

Isa active_isa() {
  static const Isa isa = choose_isa();  // once per process (thread-safe static init)
  return isa;
}

std::string build_description() {
  std::string isa;
  try {
    isa = isa_name(active_isa());
  } catch (const Error& e) {
    isa = e.what();
  }
  return fmt::format(
      "voxcast {}\n"
      "build type: {}\n"
      "compiler: {}\n"
      "baseline ISA: -march={}\n"
      "kernel ISA: {} (cpu: avx2 {}, avx512 {}; override with VOXCAST_ISA=avx2|avx512)\n",
      VOXCAST_VERSION_STRING, VOXCAST_BUILD_TYPE, VOXCAST_COMPILER_STRING, VOXCAST_ARCH_STRING, isa,
      cpu_supports(Isa::Avx2) ? "yes" : "no", cpu_supports(Isa::Avx512) ? "yes" : "no");
}

}  // namespace voxcast
