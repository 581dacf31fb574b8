#pragma once
// The packet kernels of the octree family (core/octree_packet_caster.hpp),
// first-hit and any-hit, one per structure and ISA: *_avx2 compiled with
// the baseline flags (8 lanes), *_avx512 with -march=x86-64-v4 (16 lanes),
// in src/esvo/packet_kernel_*.cpp and src/dag/packet_kernel_*.cpp.
#include "core/octree_packet_caster.hpp"
#include "core/octree_tile_caster.hpp"

namespace voxcast::detail {

struct EsvoNodes;
struct DagNodes;

/// The kernels of policy P (specialized below).
template <class P>
inline constexpr PacketKernels<P> kPacketKernels{};
/// Its tile casters (core/octree_tile_caster.hpp).
template <class P>
inline constexpr TileKernels<P> kTileKernels{};

#define VOXCAST_PACKET_KERNELS(name, Nodes)                                                     \
  void name##_packet_kernel_avx2(const Nodes& nodes, const PacketQueue& q, float size_coef,     \
                                 float size_bias, PacketOut* out);                              \
  void name##_packet_kernel_avx512(const Nodes& nodes, const PacketQueue& q, float size_coef,   \
                                   float size_bias, PacketOut* out);                            \
  void name##_anyhit_kernel_avx2(const Nodes& nodes, const PacketQueue& q, float size_coef,     \
                                 float size_bias, uint8_t* hit);                                \
  void name##_anyhit_kernel_avx512(const Nodes& nodes, const PacketQueue& q, float size_coef,   \
                                   float size_bias, uint8_t* hit);                              \
  void name##_tile_kernel_avx2(const Nodes& nodes, const TileRays& rays, int col0,              \
                               float size_coef, float size_bias, bool any_hit, TileOut* out);   \
  void name##_tile_kernel_avx512(const Nodes& nodes, const TileRays& rays, int col0,            \
                                 float size_coef, float size_bias, bool any_hit, TileOut* out); \
  template <>                                                                                   \
  inline constexpr TileKernels<Nodes> kTileKernels<Nodes>{&name##_tile_kernel_avx2,             \
                                                          &name##_tile_kernel_avx512};          \
  template <>                                                                                   \
  inline constexpr PacketKernels<Nodes> kPacketKernels<Nodes>{                                  \
      &name##_packet_kernel_avx2, &name##_packet_kernel_avx512, &name##_anyhit_kernel_avx2,     \
      &name##_anyhit_kernel_avx512};
VOXCAST_PACKET_KERNELS(esvo, EsvoNodes)
VOXCAST_PACKET_KERNELS(dag, DagNodes)
#undef VOXCAST_PACKET_KERNELS

}  // namespace voxcast::detail
