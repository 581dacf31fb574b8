// voxcast edit WORLD: one brush applied to a brickmap world (brickmap
// §3.2.2, §4.4), written back in place (atomically) or to -o.
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include "cli_io.hpp"
#include "commands.hpp"
#include "voxcast/brickmap.hpp"
#include "voxcast/error.hpp"
#include "voxcast/image.hpp"
#include "voxcast/scene_file.hpp"

namespace voxcast::cli {

namespace {
struct EditArgs {
  std::string input, output, sphere, box, paint, color = "0.8,0.8,0.8";
  bool add = false, remove = false;
};

std::vector<std::string> split_commas(const std::string& text) {
  std::vector<std::string> parts;
  std::string rest = text;
  for (size_t pos; (pos = rest.find(',')) != std::string::npos; rest = rest.substr(pos + 1))
    parts.push_back(rest.substr(0, pos));
  parts.push_back(rest);
  return parts;
}

// "r,g,b" sRGB components in [0, 1] -> a linear color.
Color parse_srgb(const std::string& text, const char* what) {
  const Vec3 c = parse_vec3(text, what);
  for (int a = 0; a < 3; ++a)
    if (!(c[a] >= 0.f && c[a] <= 1.f))
      throw UsageError(std::string(what) + ": '" + printable(text) +
                       "' is not r,g,b with components in [0, 1]");
  return {srgb_to_linear(c.x), srgb_to_linear(c.y), srgb_to_linear(c.z), 1.f};
}

brickmap::Brush parse_brush(const EditArgs& a) {
  if (a.sphere.empty() == a.box.empty()) throw UsageError("give exactly one of --sphere, --box");
  if (!a.sphere.empty()) {
    const std::vector<std::string> p = split_commas(a.sphere);
    if (p.size() != 4) throw UsageError("--sphere: '" + printable(a.sphere) + "' is not x,y,z,r");
    const Vec3 c = parse_vec3(p[0] + "," + p[1] + "," + p[2], "--sphere");
    char* end = nullptr;
    const double r = std::strtod(p[3].c_str(), &end);
    if (p[3].empty() || *end != 0 || !std::isfinite(r) || r < 0)
      throw UsageError("--sphere: the radius '" + printable(p[3]) + "' is not a number >= 0");
    return brickmap::Brush::sphere({c.x, c.y, c.z}, r);
  }
  const std::vector<std::string> p = split_commas(a.box);
  if (p.size() != 6) throw UsageError("--box: '" + printable(a.box) + "' is not x0,y0,z0,x1,y1,z1");
  const Vec3 lo = parse_vec3(p[0] + "," + p[1] + "," + p[2], "--box");
  const Vec3 hi = parse_vec3(p[3] + "," + p[4] + "," + p[5], "--box");
  if (!(lo.x <= hi.x && lo.y <= hi.y && lo.z <= hi.z))
    throw UsageError("--box: the first corner must be <= the second on every axis");
  return brickmap::Brush::box({lo.x, lo.y, lo.z}, {hi.x, hi.y, hi.z});
}
}  // namespace

Runner add_edit(CLI::App& app) {
  auto args = std::make_shared<EditArgs>();
  CLI::App* cmd =
      app.add_subcommand("edit", "Edit a brickmap world with a brush: add, remove or paint voxels");
  cmd->add_option("WORLD", args->input, "Brickmap scene file (voxcast build --format brickmap)")
      ->required();
  cmd->add_option("-o,--output", args->output, "Write the edited world here (default: in place)");
  cmd->add_option("--sphere", args->sphere,
                  "Sphere brush x,y,z,r (world units): voxels whose centers are inside");
  cmd->add_option("--box", args->box, "Box brush x0,y0,z0,x1,y1,z1 (world units)");
  cmd->add_flag("--add", args->add, "Make the brush's voxels solid (color: --color)");
  cmd->add_flag("--remove", args->remove, "Make the brush's voxels empty");
  cmd->add_option("--paint", args->paint, "Recolor the brush's solid voxels, r,g,b (sRGB, 0..1)");
  cmd->add_option("--color", args->color, "Color of added voxels, r,g,b (sRGB, 0..1)")
      ->capture_default_str();
  return [args]() {
    const int ops = int(args->add) + int(args->remove) + int(!args->paint.empty());
    if (ops != 1) throw UsageError("give exactly one of --add, --remove, --paint");
    const brickmap::Brush brush = parse_brush(*args);
    const brickmap::EditOp op = args->add      ? brickmap::EditOp::Add
                                : args->remove ? brickmap::EditOp::Remove
                                               : brickmap::EditOp::Paint;
    const Color color = op == brickmap::EditOp::Remove ? Color{}
                        : args->add                    ? parse_srgb(args->color, "--color")
                                                       : parse_srgb(args->paint, "--paint");
    std::unique_ptr<OutputSet> outputs;
    if (!args->output.empty()) {
      outputs = std::make_unique<OutputSet>(std::vector<std::string>{args->input});
      outputs->add("-o", args->output, {".vxc"});
    }
    require_regular_input(args->input, "world");
    const Container in = Container::read(args->input);
    const std::string format = scene_format(in);
    if (format != brickmap::kFormatName)
      throw Error("'" + printable(args->input) + "' is a " + printable(format) +
                  " scene; edit works on brickmap worlds (build --format brickmap)");
    SceneInfo info;
    brickmap::World world = brickmap::load_world(in, &info);
    const brickmap::EditResult r = brickmap::edit(world, brush, op, color);
    info.leaf_voxels = world.stats().voxels;
    if (outputs) {
      outputs->write(args->output, [&](const std::filesystem::path& to) {
        brickmap::save_scene(to, world, info);
      });
      outputs->commit();
    } else {
      brickmap::save_scene(args->input, world, info);  // temporary file + rename
    }
    std::printf("%s: %llu voxels changed in %zu bricks, %llu voxels in %llu bricks now\n",
                printable(outputs ? args->output : args->input).c_str(),
                (unsigned long long)r.voxels, r.cells.size(), (unsigned long long)info.leaf_voxels,
                (unsigned long long)world.stats().bricks);
    return 0;
  };
}

}  // namespace voxcast::cli
