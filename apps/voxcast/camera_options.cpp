// --camera / --orbit / --look-at / --ortho for `render` and `bench`.
#include "camera_options.hpp"

#include <cerrno>
#include <cmath>
#include <cstdlib>

#include "cli_io.hpp"
#include "voxcast/error.hpp"

namespace voxcast::cli {

void add_camera_options(CLI::App* cmd, CameraArgs& args) {
  args.camera_option =
      cmd->add_option("--camera", args.camera,
                      "auto | ex,ey,ez,tx,ty,tz,ux,uy,uz,fovy | "
                      "ortho,ex,ey,ez,tx,ty,tz,ux,uy,uz,width | ortho (auto, orthographic); "
                      "auto keeps the whole model in view")
          ->capture_default_str();
  cmd->add_option("--orbit", args.orbit,
                  "AZ,EL[,DIST]: look at the model's center from azimuth AZ and elevation EL "
                  "(degrees; 0,0 = from +z, 90,0 = from +x) at distance DIST (default: framing)");
  cmd->add_option("--look-at", args.look_at,
                  "ex,ey,ez,tx,ty,tz[,ux,uy,uz[,fovy]]: eye and target (up 0,1,0, fovy 40 "
                  "unless given)");
  args.ortho_option = cmd->add_option("--ortho", args.ortho,
                                      "Orthographic (parallel rays) camera of the given world "
                                      "width (default: the width framing the model)")
                          ->expected(0, 1);
}

namespace {

// The camera parsers throw voxcast::Error; from the command line their input
// is an option's text, so the error is a usage error naming the option.
template <class F>
Camera as_usage_error(const char* option, F&& parse) {
  try {
    return parse();
  } catch (const UsageError&) {
    throw;
  } catch (const Error& e) {
    std::string why = e.what();
    if (why.rfind("camera: ", 0) == 0) why.erase(0, 8);
    throw UsageError(std::string(option) + ": " + why);
  }
}

}  // namespace

Camera resolve_camera(const CameraArgs& args, const Aabb& bounds, int width, int height,
                      bool* derived) {
  const bool explicit_camera = args.camera_option != nullptr && args.camera_option->count() > 0;
  if (int(explicit_camera) + int(!args.orbit.empty()) + int(!args.look_at.empty()) > 1)
    throw UsageError("--camera, --orbit and --look-at are mutually exclusive");
  const bool want_ortho = args.ortho_option != nullptr && args.ortho_option->count() > 0;
  float ortho_width = 0.f;  // 0: framing width
  if (want_ortho && !args.ortho.empty()) {
    char* end = nullptr;
    errno = 0;
    ortho_width = std::strtof(args.ortho.c_str(), &end);
    if (end == args.ortho.c_str() || *end != '\0' || errno == ERANGE ||
        !std::isfinite(ortho_width) || !(ortho_width > 0))
      throw UsageError("--ortho: '" + args.ortho + "' is not a positive width");
  }
  const bool ortho_name = args.camera == "ortho";  // --camera ortho = --camera auto --ortho
  bool is_derived = true;
  Camera camera;
  if (!args.orbit.empty()) {
    camera = as_usage_error("--orbit",
                            [&] { return Camera::parse_orbit(args.orbit, bounds, width, height); });
  } else if (!args.look_at.empty()) {
    camera = as_usage_error("--look-at", [&] { return Camera::parse_look_at(args.look_at); });
  } else if (args.camera == "auto" || ortho_name) {
    camera = Camera::frame(bounds, width, height);
  } else {
    camera = parse_camera_option(args.camera);
    is_derived = want_ortho;
  }
  // The orthographic projection comes last and keeps the eye, target and up
  // of whichever camera was asked for (Camera::orthographic).
  if (want_ortho || ortho_name) camera = camera.orthographic(bounds, width, height, ortho_width);
  if (derived != nullptr) *derived = is_derived;
  return camera;
}

bool camera_options_given(const CameraArgs& args) {
  return (args.camera_option != nullptr && args.camera_option->count() > 0) ||
         !args.orbit.empty() || !args.look_at.empty() ||
         (args.ortho_option != nullptr && args.ortho_option->count() > 0);
}

void refuse_camera_options_with_path(const CameraArgs& args, const std::string& path) {
  if (!path.empty() && camera_options_given(args))
    throw UsageError("--path sets the camera; it excludes --camera, --orbit, --look-at, --ortho");
}

void check_camera_options(const CameraArgs& args, int width, int height) {
  Aabb unit;
  unit.extend(Vec3{0, 0, 0});
  unit.extend(Vec3{1, 1, 1});
  (void)resolve_camera(args, unit, width, height);
}

}  // namespace voxcast::cli
