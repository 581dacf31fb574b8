#pragma once
// `voxcast render --gi SPP`: the GI integrator's options on the render
// command and one view rendered with it (cmd_render.cpp calls these).
#include <CLI/CLI.hpp>
#include <string>

#include "voxcast/gi_integrator.hpp"
#include "voxcast/render.hpp"
#include "voxcast/structure.hpp"

namespace voxcast::cli {

struct GiArgs {
  int spp = 0;  // 0 = the surface integrator
  int bounces = 8;
  std::string env, sun;
  bool no_env_sampling = false;  // cosine bounces alone (no environment sampling)
  float env_scale = 1.f, sun_intensity = 3.f, bounce_cone = GiOptions{}.bounce_cone_deg;
};

void add_gi_options(CLI::App* cmd, GiArgs& args);

/// The GI options for the command line (usage errors for bad values, and
/// for surface-integrator options that GI does not use: `surface_only`
/// names the first of those given, empty when none). Reads no file: the
/// environment is the uniform sky until load_gi_environment().
GiOptions gi_options(const GiArgs& args, const std::string& surface_only, uint32_t seed);
/// Reads --env (when given) into o->environment; voxcast::Error for a
/// missing or malformed file.
void load_gi_environment(const GiArgs& args, GiOptions* o);

/// One view: `options` (size, camera, LOD, AOVs) rendered with GI, in frames
/// of a few samples so that a progress bar can follow (the result does not
/// depend on the split, gi_integrator.hpp). Fills color, depth, normal,
/// rays (pixels), hits (pixels whose sample-0 ray hit), seconds; prints the
/// samples and rays per second.
RenderResult render_gi_view(const Structure& structure, const RenderOptions& options, GiOptions gi,
                            bool verbose);

}  // namespace voxcast::cli
