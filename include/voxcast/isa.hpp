#pragma once
// Runtime ISA dispatch. The library is compiled for a fixed baseline
// (VOXCAST_ARCH, x86-64-v3 = AVX2); a few kernels also exist as AVX-512
// variants compiled in their own translation units (*_avx512.cpp with
// -march=x86-64-v4). The variant is chosen once per process, at the first
// call of active_isa(): the best the CPU supports (cpuid), or the one the
// environment variable VOXCAST_ISA names ("avx2" or "avx512"), so tests can
// force each variant. Every variant computes bit-identical results (same IEEE
// operations, -ffp-contract=off), so scene files do not depend on the ISA.
namespace voxcast {

enum class Isa { Avx2, Avx512 };

/// The kernel variant this process uses. Throws voxcast::Error if
/// VOXCAST_ISA is set to an unknown name or to an ISA the CPU lacks.
Isa active_isa();
/// True if the CPU can run `isa`'s kernels.
bool cpu_supports(Isa isa);
/// "avx2" or "avx512".
const char* isa_name(Isa isa);

}  // namespace voxcast
