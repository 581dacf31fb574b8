// Sparse voxel DAG ray caster (svdag §4: "The main traversal loop closely
// resembles that of Laine and Karras [2010a] ... the DAG data structure
// requires only minor changes") and the DagStructure (Structure +
// SurfaceQuery). The loop, the coarse beam walk (esvo §6.2), the world <->
// octree frame and the profiling counters (esvo §8.5) are the octree
// family's (core/octree_caster.hpp), the very code the ESVO runs, so a DAG
// and an ESVO octree of the same voxels give bit-identical hits; the DAG
// contributes its node access and voxel indexing (dag/octree_nodes.hpp). The any-hit variant
// (shadow rays) skips the index bookkeeping; the loop visits voxels front to back, so the first
// leaf found is also the closest one.

#include <algorithm>
#include <cstdint>
#include <vector>

#include "core/octree_caster.hpp"
#include "core/octree_packets.hpp"
#include "core/prefetch.hpp"
#include "core/tile_frustum.hpp"
#include "dag/octree_nodes.hpp"
#include "voxcast/dag.hpp"
#include "voxcast/error.hpp"

namespace voxcast::dag {
namespace {

using Nodes = ::voxcast::detail::DagNodes;

/// What attributes(hit) reads for a DAG with attributes: one decision for
/// the read and its prefetch (prefetch_attributes), so they stay in step.
struct AttributeRead {
  enum class Kind {
    kFineMean,   // an 8^3 cube at L - 3: its fine_means entry
    kMeanTable,  // a coarser cube of more than kCubeMeanMin voxels (or no
                 // count named): the mean table, else the voxels' mean
    kSmallCube,  // a cube of at most kCubeMeanMin voxels: their mean
    kVoxel,      // a leaf voxel (or an index past them: voxel_attributes)
  } kind;
  const SparseVoxelDag::FineMean* fine;  // kFineMean
  uint64_t count;                        // kMeanTable, kSmallCube: the voxels named (0: none)
};
AttributeRead attribute_read(const SparseVoxelDag& d, const SurfaceHit& hit) {
  using K = AttributeRead::Kind;
  if (hit.level >= d.levels() || hit.voxel_ref >= d.leaf_voxels) return {K::kVoxel, nullptr, 0};
  if (hit.level == d.levels() - 3)
    if (const SparseVoxelDag::FineMean* f = d.fine_mean(hit.voxel_ref)) return {K::kFineMean, f, 0};
  const uint64_t count = Nodes::child_count(hit.child);
  if (count == 0 || count > SparseVoxelDag::kCubeMeanMin) return {K::kMeanTable, nullptr, count};
  return {K::kSmallCube, nullptr, count};
}

// What attributes(hit) reads first (prefetch_attributes, attributes_batch).
// core/prefetch.hpp: the hints are asm statements, which GCC keeps.
inline void prefetch_read(const SparseVoxelDag& d, const SurfaceHit& hit) {
  using ::voxcast::detail::prefetch_line;
  const AttributeRead r = attribute_read(d, hit);
  using K = AttributeRead::Kind;
  if (r.kind == K::kFineMean) {  // 28 bytes: they may straddle two cache lines
    prefetch_line(r.fine);
    prefetch_line(reinterpret_cast<const char*>(r.fine + 1) - 1);
    return;
  }
  const uint64_t i = hit.voxel_ref;
  // A mean table lookup is not prefetched; nor is voxel_attributes' default
  // past the voxels.
  if (r.kind == K::kMeanTable || i >= d.leaf_voxels) return;
  // Leaf voxel i's value, or the first of a small cube's voxels.
  if (!d.attribute_blocks.empty()) {
    const uint32_t* block = &d.attribute_blocks[size_t(i / SparseVoxelDag::kCompressedSlots) *
                                                SparseVoxelDag::kCompressedBlockWords];
    prefetch_line(block);  // 24 bytes: one or two lines
    prefetch_line(block + SparseVoxelDag::kCompressedBlockWords - 1);
  } else {
    prefetch_line(&d.colors[size_t(i)]);
    prefetch_line(&d.normals[size_t(i)]);
  }
}

}  // namespace

// The SurfaceQuery tracing methods are the octree family's
// (core/octree_caster.hpp). The coarse beam pass walks the tree (positions),
// not the DAG: a node shared by many positions is visited once per occurrence.
::voxcast::detail::OctreeWorld<Nodes> DagStructure::world() const {
  return ::voxcast::detail::OctreeWorld<Nodes>(*dag_);
}

CastResult cast_ray(const SparseVoxelDag& dag, Vec3 origin, Vec3 dir, float tmax, float size_coef,
                    float size_bias) {
  const auto r = ::voxcast::detail::cast_octree<Nodes, false, false>(
      dag, origin, dir, tmax, size_coef, size_bias, nullptr, nullptr);
  auto out = ::voxcast::detail::cast_result<CastResult>(r);
  out.voxel_index = r.index;
  out.face = r.face;
  return out;
}

bool cast_occluded(const SparseVoxelDag& dag, Vec3 origin, Vec3 dir, float tmax, float size_coef,
                   float size_bias) {
  return ::voxcast::detail::cast_octree<Nodes, false, true>(dag, origin, dir, tmax, size_coef,
                                                            size_bias, nullptr, nullptr)
      .hit;
}

// ---------------------------------------------------------------------------

DagStructure::DagStructure(std::shared_ptr<const SparseVoxelDag> dag) : dag_(std::move(dag)) {
  if (!dag_) throw Error("DagStructure: no DAG");
  if (dag_->words.empty() || dag_->voxel_prefix.size() != dag_->words.size())
    throw Error("DagStructure: the DAG is empty or not finalized");
  if (!(dag_->grid.side() > 0)) throw Error("DagStructure: DAG has a non-positive side");
}

void DagStructure::prefetch_attributes(const SurfaceHit& hit) const {
  if (dag_->has_attributes()) prefetch_read(*dag_, hit);
}

void DagStructure::attributes(const SurfaceHit& hit, TraceContext& ctx, Color* color,
                              Vec3* normal) const {
  // Raw: one 32-bit color and one 32-bit normal per voxel (dag.hpp);
  // compressed: the voxel's 24-byte esvo §5.5 block (as the ESVO counts it).
  // The index itself came with the traversal (prefix sums next to the pointers).
  if (ctx.counting && dag_->has_attributes())
    ctx.counters.attribute_bytes += dag_->compressed_attributes() ? 24 : 8;
  read_attributes(hit, color, normal);
}

void DagStructure::attributes_batch(const SurfaceHit* const* hits, int n, TraceContext& ctx,
                                    Color* colors, Vec3* normals) const {
  const SparseVoxelDag& d = *dag_;
  if (!d.has_attributes() || d.compressed_attributes()) {
    SurfaceQuery::attributes_batch(hits, n, ctx, colors, normals);
    return;
  }
  if (ctx.counting) ctx.counters.attribute_bytes += 8 * uint64_t(std::max(n, 0));
  // The small cubes (at 1 px, nearly every LOD hit: a 2^3 or 4^3 cube)
  // through the batched mean, 64 at a time; the other hits one at a time,
  // each one's reads prefetched 16 hits ahead (as the default batch).
  constexpr int kChunk = 64, kAhead = 16;
  VoxelRange ranges[kChunk];
  int small[kChunk];
  Color c[kChunk];
  Vec3 nrm[kChunk];
  thread_local std::vector<int> other;
  other.clear();
  using K = AttributeRead::Kind;
  int k = 0;
  auto flush = [&] {
    d.mean_attributes(ranges, size_t(k), c, nrm);
    for (int j = 0; j < k; ++j) colors[small[j]] = c[j], normals[small[j]] = nrm[j];
    k = 0;
  };
  for (int i = 0; i < n; ++i) {
    const AttributeRead r = attribute_read(d, *hits[i]);
    if (r.kind != K::kSmallCube) {
      other.push_back(i);
      continue;
    }
    ranges[k] = {hits[i]->voxel_ref, r.count}, small[k++] = i;
    if (k == kChunk) flush();
  }
  flush();
  const int o = int(other.size());
  for (int j = 0; j < o && j < kAhead; ++j) prefetch_read(d, *hits[other[size_t(j)]]);
  for (int j = 0; j < o; ++j) {
    if (j + kAhead < o) prefetch_read(d, *hits[other[size_t(j + kAhead)]]);
    const int i = other[size_t(j)];
    read_attributes(*hits[i], &colors[i], &normals[i]);
  }
}

void DagStructure::read_attributes(const SurfaceHit& hit, Color* color, Vec3* normal) const {
  if (dag_->has_attributes()) {
    // A coarse (LOD) hit shows the mean of all its leaf voxels (dag.hpp),
    // as an ESVO parent shows its children's average (esvo §5.4).
    // Coarser cubes of more than kCubeMeanMin voxels: one lookup in the mean table.
    // The others: the cube's voxels are the hit's first voxel and the count
    // the traversal named (Nodes::name_hit), or cube_range's where it has none.
    const AttributeRead r = attribute_read(*dag_, hit);
    using K = AttributeRead::Kind;
    if (r.kind == K::kFineMean) {  // one starts word and one entry (dag.hpp fine_means)
      *color = r.fine->color, *normal = r.fine->normal;
      return;
    }
    if (r.kind == K::kVoxel) {
      dag_->voxel_attributes(hit.voxel_ref, color, normal);
      return;
    }
    if (r.kind == K::kMeanTable) {
      if (const SparseVoxelDag::CubeMean* m = dag_->cached_mean(hit.voxel_ref, hit.level)) {
        *color = m->color, *normal = m->normal;
        return;
      }
    }
    dag_->mean_attributes(r.count != 0 ? VoxelRange{hit.voxel_ref, r.count}
                                       : dag_->cube_range(hit.voxel_ref, hit.level),
                          color, normal);
    return;
  }
  // Geometry-only DAG: gray, normal of the entered cube face.
  *color = {0.5f, 0.5f, 0.5f, 1.f};
  Vec3 n{0, 0, 0};
  const uint32_t face = Nodes::child_face(hit.child);
  const int axis = int(face >> 1) % 3;
  n[axis] = (face & 1) ? -1.f : 1.f;
  *normal = n;
}

}  // namespace voxcast::dag

namespace voxcast {
template class OctreeStructure<dag::DagStructure>;
}  // namespace voxcast
