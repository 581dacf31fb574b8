#pragma once
// The camera options shared by `render` and `bench` (README "Camera
// contract"): --camera, --orbit, --look-at and --ortho, registered and
// resolved in one place so that both subcommands frame a model alike.
#include <CLI/CLI.hpp>
#include <string>

#include "voxcast/camera.hpp"

namespace voxcast::cli {

struct CameraArgs {
  std::string camera = "auto", orbit, look_at, ortho;
  CLI::Option* camera_option = nullptr;
  CLI::Option* ortho_option = nullptr;
};

/// Adds --camera, --orbit, --look-at and --ortho [WIDTH] to `cmd`.
void add_camera_options(CLI::App* cmd, CameraArgs& args);

/// The camera the options ask for, for an image of width x height showing
/// `bounds` (the occupied voxel bounds). `derived` (if set) says whether any
/// part of it was computed (auto framing, orbit, look-at defaults, --ortho),
/// in which case callers print it in the --camera form. Throws UsageError (cli_io.hpp).
Camera resolve_camera(const CameraArgs& args, const Aabb& bounds, int width, int height,
                      bool* derived = nullptr);

/// Whether any of --camera, --orbit, --look-at, --ortho was given.
bool camera_options_given(const CameraArgs& args);
/// --path (a camera path) sets the camera: a UsageError if `path` is set and
/// any camera option was given too.
void refuse_camera_options_with_path(const CameraArgs& args, const std::string& path);

/// Checks the options before any file is read (a bad camera is a usage error,
/// exit 2, whatever the scene): resolves them against a unit box.
void check_camera_options(const CameraArgs& args, int width, int height);

}  // namespace voxcast::cli
