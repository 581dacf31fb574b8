// libFuzzer target: arbitrary bytes as a .vxc scene file. The container
// parser, the META reader, the structure validators (ESVO and DAG) and, when
// a scene is accepted, the ray casters and attribute lookups must never crash,
// hang or read out of bounds (run under ASan/UBSan).
#include <cstddef>
#include <cstdint>

#include "voxcast/camera.hpp"
#include "voxcast/error.hpp"
#include "voxcast/scene_file.hpp"
#include "voxcast/structure.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace voxcast;
  try {
    const Container c = Container::parse(data, size);
    LoadedScene scene = load_scene(c);
    // Accepted: every ray of a small frame must traverse and shade safely.
    Aabb box = scene.structure->bounds();
    const Camera cam = Camera::frame(box, 12, 9);
    const CameraRays rays(cam, 12, 9);
    for (int y = 0; y < 9; ++y)
      for (int x = 0; x < 12; ++x) {
        SurfaceHit hit;
        if (scene.structure->trace(rays.ray(x, y), LodFootprint{}, &hit)) {
          Color color;
          Vec3 normal;
          scene.structure->attributes(hit, &color, &normal);
        }
      }
  } catch (const Error&) {
    // A clean rejection is the expected outcome for most inputs.
  }
  return 0;
}
