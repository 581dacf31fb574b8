// voxcast edit WORLD: brushes applied to a brickmap world (brickmap §3.2.2,
// §4.4) -- a sphere, a box, a mesh stamp or a batch file of them -- saved in
// place through the world's edit journal (brickmap_file.hpp: the edited
// chunks appended and fsync'ed as one transaction, folded into the scene
// file when the journal grows or on --checkpoint) or written whole to -o.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "cli_io.hpp"
#include "commands.hpp"
#include "voxcast/brickmap.hpp"
#include "voxcast/brickmap_file.hpp"
#include "voxcast/brickmap_live.hpp"
#include "voxcast/camera.hpp"
#include "voxcast/error.hpp"
#include "voxcast/image.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/render.hpp"
#include "voxcast/scene_file.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast::cli {

namespace {
struct EditArgs {
  std::string input, output, sphere, box, mesh, at, paint, color = "0.8,0.8,0.8", batch;
  double size = 0;
  bool add = false, remove = false, checkpoint = false;
  int snow = 0;  // --snow STEPS
  double snow_rate = 0.5;
  std::string render, render_size = "320x240";  // --snow --render: frames while it snows
};

// One edit of the command line or of a batch file.
struct EditStep {
  enum class Kind { Brush, Mesh, Snow } kind = Kind::Brush;
  uint32_t step = 0;  // Snow: the step's number
  brickmap::Brush brush;
  std::string mesh;  // Mesh: file, placed with its box center at `at`, largest side `size`
  Vec3d at;
  double size = 0;
  brickmap::EditOp op = brickmap::EditOp::Add;
  Color color;
};

std::vector<std::string> split_commas(const std::string& text) {
  std::vector<std::string> parts;
  size_t from = 0;  // (linear: a 1 MB batch line was quadratic in its copies)
  for (size_t pos; (pos = text.find(',', from)) != std::string::npos; from = pos + 1)
    parts.push_back(text.substr(from, pos - from));
  parts.push_back(text.substr(from));
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

double parse_number(const std::string& text, const char* what) {
  char* end = nullptr;
  const double v = std::strtod(text.c_str(), &end);
  if (text.empty() || *end != 0 || !std::isfinite(v))
    throw UsageError(std::string(what) + ": '" + printable(text) + "' is not a number");
  return v;
}

brickmap::Brush parse_sphere(const std::string& text) {
  const std::vector<std::string> p = split_commas(text);
  if (p.size() != 4) throw UsageError("--sphere: '" + printable(text) + "' is not x,y,z,r");
  const Vec3 c = parse_vec3(p[0] + "," + p[1] + "," + p[2], "--sphere");
  const double r = parse_number(p[3], "--sphere radius");
  if (r < 0) throw UsageError("--sphere: the radius '" + printable(p[3]) + "' is not >= 0");
  return brickmap::Brush::sphere({c.x, c.y, c.z}, r);
}

brickmap::Brush parse_box(const std::string& text) {
  const std::vector<std::string> p = split_commas(text);
  if (p.size() != 6) throw UsageError("--box: '" + printable(text) + "' is not x0,y0,z0,x1,y1,z1");
  const Vec3 lo = parse_vec3(p[0] + "," + p[1] + "," + p[2], "--box");
  const Vec3 hi = parse_vec3(p[3] + "," + p[4] + "," + p[5], "--box");
  if (!(lo.x <= hi.x && lo.y <= hi.y && lo.z <= hi.z))
    throw UsageError("--box: the first corner must be <= the second on every axis");
  return brickmap::Brush::box({lo.x, lo.y, lo.z}, {hi.x, hi.y, hi.z});
}

brickmap::EditOp parse_op(const std::string& word, const std::string& where) {
  if (word == "add") return brickmap::EditOp::Add;
  if (word == "remove") return brickmap::EditOp::Remove;
  if (word == "paint") return brickmap::EditOp::Paint;
  throw UsageError(where + ": '" + printable(word) + "' is not add, remove or paint");
}

// The batch file: one edit per line, '#' starts a comment,
//   sphere X,Y,Z,R  add|remove|paint [R,G,B]
//   box X0,Y0,Z0,X1,Y1,Z1  add|remove|paint [R,G,B]
//   mesh FILE X,Y,Z SIZE  add|remove|paint [R,G,B]
// (world units; colors sRGB in 0..1, default 0.8,0.8,0.8).
EditStep parse_batch_line(const std::vector<std::string>& w, const std::string& where);
std::vector<EditStep> parse_batch(const std::string& path) {
  require_regular_input(path, "batch file");
  std::ifstream in(path);
  std::vector<EditStep> out;
  std::string line;
  for (int n = 1; std::getline(in, line); ++n) {
    const std::string where = "--batch " + printable(path) + " line " + std::to_string(n);
    if (const size_t hash = line.find('#'); hash != std::string::npos) line.resize(hash);
    std::istringstream words(line);
    std::vector<std::string> w;
    for (std::string x; words >> x;) w.push_back(x);
    if (w.empty()) continue;
    try {
      out.push_back(parse_batch_line(w, where));
    } catch (const UsageError& e) {
      const std::string m = e.what();
      throw UsageError(m.rfind(where, 0) == 0 ? m : where + ": " + m);  // each error names its line
    }
  }
  if (out.empty()) throw UsageError("--batch " + printable(path) + " holds no edit");
  return out;
}

// One batch line's words (the grammar above parse_batch).
EditStep parse_batch_line(const std::vector<std::string>& w, const std::string& where) {
  EditStep e;
  size_t next;
  if (w[0] == "sphere" || w[0] == "box") {
    if (w.size() < 3 || w.size() > 4)
      throw UsageError(where + ": expected " + w[0] + " COORDS OP [R,G,B]");
    e.brush = w[0] == "sphere" ? parse_sphere(w[1]) : parse_box(w[1]);
    next = 2;
  } else if (w[0] == "mesh") {
    if (w.size() < 5 || w.size() > 6)
      throw UsageError(where + ": expected mesh FILE X,Y,Z SIZE OP [R,G,B]");
    e.kind = EditStep::Kind::Mesh;
    e.mesh = w[1];
    const Vec3 at = parse_vec3(w[2], "mesh position");
    e.at = {at.x, at.y, at.z};
    e.size = parse_number(w[3], "mesh size");
    if (!(e.size > 0)) throw UsageError(where + ": the mesh size must be > 0");
    next = 4;
  } else {
    throw UsageError(where + ": '" + printable(w[0]) + "' is not sphere, box or mesh");
  }
  e.op = parse_op(w[next], where);
  e.color = parse_srgb(next + 1 < w.size() ? w[next + 1] : "0.8,0.8,0.8", "batch color");
  return e;
}

// The mesh placed with its bounding-box center at `at` and its largest side
// `size` long, voxelized into the world's grid (surface voxels with the
// mesh's colors and normals).
VoxelSet stamp_voxels(const EditStep& e, const GridTransform& grid) {
  Mesh mesh = load_mesh(e.mesh);
  const Aabb b = mesh.bounds();
  const Vec3 ext = b.extent();
  const float longest = std::max({ext.x, ext.y, ext.z});
  if (!(longest > 0)) throw Error("'" + printable(e.mesh) + "' has no extent to scale");
  const float k = float(e.size) / longest;
  const Vec3 c = (b.lo + b.hi) * 0.5f;
  for (Vec3& p : mesh.positions)
    p = Vec3{float(e.at.x), float(e.at.y), float(e.at.z)} + (p - c) * k;
  VoxelizeOptions vo;
  vo.attributes = true;
  return voxelize(mesh, grid, vo);
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
  cmd->add_option("--mesh", args->mesh,
                  "Mesh-stamp brush: this mesh's surface voxels (with its colors and normals), "
                  "placed by --at and --size");
  cmd->add_option("--at", args->at, "With --mesh: world position of the mesh's box center x,y,z");
  cmd->add_option("--size", args->size, "With --mesh: the mesh's largest side in world units");
  cmd->add_option("--batch", args->batch,
                  "A file of edits, one per line: sphere X,Y,Z,R | box X0,Y0,Z0,X1,Y1,Z1 | mesh "
                  "FILE X,Y,Z SIZE, then add|remove|paint [R,G,B] ('#' comments); saved as one "
                  "transaction");
  cmd->add_option("--snow", args->snow,
                  "Snowfall (brickmap paper 5.5): this many steps, each one voxel of snow on top "
                  "of the highest solid voxel of --snow-rate of the columns");
  cmd->add_option("--snow-rate", args->snow_rate, "With --snow: share of the columns per step")
      ->capture_default_str();
  cmd->add_option("--render", args->render,
                  "Render frames while a worker thread applies the edits or snow steps (they "
                  "become visible between frames and are saved through the journal as they "
                  "finish), writing the last frame to this PNG");
  cmd->add_option("--render-size", args->render_size, "With --render: image size WxH")
      ->capture_default_str();
  cmd->add_flag("--add", args->add, "Make the brush's voxels solid (color: --color)");
  cmd->add_flag("--remove", args->remove, "Make the brush's voxels empty");
  cmd->add_option("--paint", args->paint, "Recolor the brush's solid voxels, r,g,b (sRGB, 0..1)");
  cmd->add_option("--color", args->color, "Color of added voxels, r,g,b (sRGB, 0..1)")
      ->capture_default_str();
  cmd->add_flag("--checkpoint", args->checkpoint,
                "In place: also fold the edit journal into the scene file now (it is folded in "
                "anyway once it is larger than the file and 16 MiB)");
  return [args, cmd]() {
    std::vector<EditStep> steps;
    if (cmd->count("--snow") > 0) {
      require_range("--snow", args->snow, 1, 1000000);
      require_range("--snow-rate", args->snow_rate, 0, 1);
      if (!args->batch.empty() || !args->sphere.empty() || !args->box.empty() ||
          !args->mesh.empty() || args->add || args->remove || !args->paint.empty())
        throw UsageError("--snow takes no brush or operation");
      for (int s = 0; s < args->snow; ++s) {
        EditStep e;
        e.kind = EditStep::Kind::Snow;
        e.step = uint32_t(s);
        steps.push_back(e);
      }
    } else if (!args->batch.empty()) {
      if (!args->sphere.empty() || !args->box.empty() || !args->mesh.empty() || args->add ||
          args->remove || !args->paint.empty())
        throw UsageError("--batch takes its brushes and operations from the file");
    } else if (args->checkpoint && !args->add && !args->remove && args->paint.empty() &&
               args->sphere.empty() && args->box.empty() && args->mesh.empty()) {
      // --checkpoint alone: no edit; the journal folded into the world file.
      if (!args->output.empty() || !args->render.empty())
        throw UsageError(
            "--checkpoint without an edit folds the journal in place: no -o, --render");
    } else {
      const int ops = int(args->add) + int(args->remove) + int(!args->paint.empty());
      if (ops != 1) throw UsageError("give exactly one of --add, --remove, --paint");
      if (int(!args->sphere.empty()) + int(!args->box.empty()) + int(!args->mesh.empty()) != 1)
        throw UsageError("give exactly one of --sphere, --box, --mesh, --batch");
      EditStep e;
      if (!args->mesh.empty()) {
        if (args->at.empty() || !(args->size > 0))
          throw UsageError("--mesh needs --at x,y,z and --size S > 0");
        e.kind = EditStep::Kind::Mesh;
        e.mesh = args->mesh;
        const Vec3 at = parse_vec3(args->at, "--at");
        e.at = {at.x, at.y, at.z};
        e.size = args->size;
      } else {
        e.brush = args->sphere.empty() ? parse_box(args->box) : parse_sphere(args->sphere);
      }
      e.op = args->add      ? brickmap::EditOp::Add
             : args->remove ? brickmap::EditOp::Remove
                            : brickmap::EditOp::Paint;
      e.color = e.op == brickmap::EditOp::Remove ? Color{}
                : args->add                      ? parse_srgb(args->color, "--color")
                                                 : parse_srgb(args->paint, "--paint");
      steps.push_back(e);
    }
    // One set for the world and the frame: checked against each other and
    // the inputs before any work, renamed into place together at the end.
    std::vector<std::string> inputs = {args->input};
    for (const std::string* f : {&args->batch, &args->mesh})
      if (!f->empty()) inputs.push_back(*f);
    OutputSet outputs(inputs);
    const bool write_whole = !args->output.empty(), render_frames = !args->render.empty();
    if (write_whole) outputs.add("-o", args->output, {".vxc"});
    RenderOptions ro;
    if (render_frames) {
      parse_size(args->render_size, &ro.width, &ro.height, "--render-size");
      outputs.add("--render", args->render, {".png"});
    }
    if (!args->batch.empty() && args->snow == 0) steps = parse_batch(args->batch);
    require_regular_input(args->input, "world");
    const std::string format = scene_format(ContainerReader::open(args->input));
    if (format != brickmap::kFormatName)
      throw Error("'" + printable(args->input) + "' is a " + printable(format) +
                  " scene; edit works on brickmap worlds (build --format brickmap)");
    SceneInfo info;
    brickmap::World world = brickmap::open_world(args->input, &info);
    // The brushes, timed without the file I/O (edit throughput).
    uint64_t voxels = 0;
    std::set<uint64_t> cells;
    double seconds = 0;
    uint64_t journal = 0;
    if (render_frames) {
      // The edits on LiveWorld's worker while frames render (§4.4, §5.5),
      // saved in place by the worker through the journal as they finish
      // (brickmap_live.hpp): each acknowledged edit survives a crash.
      brickmap::LiveOptions lo;
      if (!write_whole) lo.save_to = args->input;
      brickmap::LiveWorld live(world, lo);
      brickmap::SnowOptions snow;
      snow.rate = args->snow_rate;
      for (const EditStep& e : steps) {
        if (e.kind == EditStep::Kind::Snow)
          live.submit_snow(e.step, snow);
        else if (e.kind == EditStep::Kind::Mesh)
          live.submit(stamp_voxels(e, world.grid()), e.op, e.color);
        else
          live.submit(e.brush, e.op, e.color);
      }
      const char* what = args->snow > 0 ? "snow steps" : "edits";
      ro.camera = Camera::orbit(world.occupied_bounds(), ro.width, ro.height, 30.f, 35.f);
      RenderResult last;
      for (uint32_t f = 0;; ++f) {
        const bool done = live.applied() == steps.size();
        ro.frame = f;
        last = render(live, ro);  // publishes the finished steps first
        std::printf("frame %u: %llu of %zu %s visible, %.2f Mrays/s\n", f,
                    (unsigned long long)live.applied(), steps.size(), what,
                    last.seconds > 0 ? double(last.rays) / last.seconds * 1e-6 : 0.0);
        if (done) break;
      }
      live.wait_worker();
      if (!live.last_error().empty()) throw Error(live.last_error());
      if (!live.save_error().empty()) throw Error("saving the edits failed: " + live.save_error());
      outputs.write(args->render,
                    [&](const std::filesystem::path& to) { write_image(to, last.color); });
      const brickmap::LiveWorld::Throughput t = live.throughput();
      voxels = t.voxels, seconds = t.seconds;
      world = live.world();
      for (uint64_t c = 0; c < world.cells().size(); ++c)
        if (brickmap::CellFlags::get(world.cell(c)) & brickmap::kFlagEdited) cells.insert(c);
      if (!write_whole) {
        const std::filesystem::path jp = brickmap::journal_path(args->input);
        std::error_code ec;
        journal = std::filesystem::exists(jp, ec) ? std::filesystem::file_size(jp) : 0;
      }
    }
    for (const EditStep& e : render_frames ? std::vector<EditStep>{} : steps) {
      const VoxelSet stamp =
          e.kind == EditStep::Kind::Mesh ? stamp_voxels(e, world.grid()) : VoxelSet{};
      const auto t0 = std::chrono::steady_clock::now();
      brickmap::SnowOptions snow;
      snow.rate = args->snow_rate;
      const brickmap::EditResult r =
          e.kind == EditStep::Kind::Snow   ? brickmap::snow_step(world, e.step, snow)
          : e.kind == EditStep::Kind::Mesh ? brickmap::stamp(world, stamp, e.op, e.color)
                                           : brickmap::edit(world, e.brush, e.op, e.color);
      seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      voxels += r.voxels;
      cells.insert(r.cells.begin(), r.cells.end());
    }
    info.leaf_voxels = world.stats().voxels;
    std::string saved;
    if (write_whole) {
      outputs.write(args->output, [&](const std::filesystem::path& to) {
        brickmap::save_scene(to, world, info);
      });
      saved = "written whole";
    } else {
      if (!render_frames && !steps.empty()) {
        journal = brickmap::commit_edits(args->input, world,
                                         std::vector<uint64_t>(cells.begin(), cells.end()));
      } else if (!render_frames) {  // --checkpoint alone
        const std::filesystem::path jp = brickmap::journal_path(args->input);
        std::error_code ec;
        journal = std::filesystem::exists(jp, ec) ? std::filesystem::file_size(jp) : 0;
      }
      saved = "journal " + format_bytes(double(journal));
      // Replaying a journal costs about as much as reading it: fold it in
      // once it outgrows the scene file (and 16 MiB, below which a rewrite
      // would cost more than the replays it saves).
      if (args->checkpoint ||
          journal > std::max<uint64_t>(std::filesystem::file_size(args->input), 16u << 20)) {
        brickmap::checkpoint_world(args->input, world, info);
        saved = "checkpointed";
      }
    }
    outputs.commit();  // the world (-o) and the frame (--render) together
    std::printf("%s: %llu voxels changed in %zu bricks, %llu voxels in %llu bricks now (%s)\n",
                printable(write_whole ? args->output : args->input).c_str(),
                (unsigned long long)voxels, cells.size(), (unsigned long long)info.leaf_voxels,
                (unsigned long long)world.stats().bricks, saved.c_str());
    std::printf("%zu edit%s in %.3f ms: %.3g voxels/s, %.3g bricks/s\n", steps.size(),
                steps.size() == 1 ? "" : "s", seconds * 1e3,
                seconds > 0 ? double(voxels) / seconds : 0.0,
                seconds > 0 ? double(cells.size()) / seconds : 0.0);
    return 0;
  };
}

}  // namespace voxcast::cli
