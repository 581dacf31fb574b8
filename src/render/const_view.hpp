#pragma once
// A const structure seen by the frame loop (integrator.hpp): its queries,
// and none of its frame-loop hooks, so it serves no requests. The const
// overloads of render() and render_gi() render through it in one pass.
#include <string>

#include "voxcast/structure.hpp"

namespace voxcast::detail {

class ConstView final : public Structure {
 public:
  explicit ConstView(const Structure& s) : s_(s) {}
  std::string name() const override { return s_.name(); }
  Aabb bounds() const override { return s_.bounds(); }
  const SurfaceQuery* surface() const override { return s_.surface(); }
  const VolumeQuery* volume() const override { return s_.volume(); }

 private:
  const Structure& s_;
};

}  // namespace voxcast::detail
