// The `voxcast` Python module (pybind11): build, load and save scenes, render
// them into numpy arrays, trace numpy arrays of rays, read voxel sets.
//
// Every call into the voxcast library is in this file, so a change of the
// library's structure/render interfaces is adapted here only. The Python
// side sees plain numbers, strings, dicts and numpy arrays.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "pipeline.hpp"  // apps/voxcast: the build `voxcast build` runs
#include "voxcast/camera.hpp"
#include "voxcast/dag.hpp"
#include "voxcast/environment.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/format_registry.hpp"
#include "voxcast/gi_integrator.hpp"
#include "voxcast/image.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/morton.hpp"
#include "voxcast/render.hpp"
#include "voxcast/scene_file.hpp"
#include "voxcast/surface_query.hpp"
#include "voxcast/trace_context.hpp"

namespace py = pybind11;
using namespace voxcast;

namespace {

// A scene as `voxcast render` sees it after load_scene(): one structure, its
// occupied bounds (for automatic cameras) and the metadata saved with it.
struct Scene {
  std::string format;  // a registered format (format_registry.hpp): "esvo", "dag", ...
  std::shared_ptr<const Structure> structure;
  Aabb occupied;
  SceneInfo info;
  // The structure's own data when it is one of these (info(), voxels()).
  const esvo::EsvoOctree* octree = nullptr;
  const dag::SparseVoxelDag* dag = nullptr;
};

std::shared_ptr<Scene> scene_of(std::string format, LoadedStructure structure, Aabb occupied,
                                SceneInfo info) {
  auto s = std::make_shared<Scene>();
  s->format = std::move(format);
  s->structure = std::move(structure);
  s->occupied = occupied;
  s->info = std::move(info);
  if (auto* e = dynamic_cast<const esvo::EsvoStructure*>(s->structure.get()))
    s->octree = &e->octree();
  if (auto* d = dynamic_cast<const dag::DagStructure*>(s->structure.get())) s->dag = &d->dag();
  return s;
}

std::shared_ptr<Scene> load(const std::string& path) {
  py::gil_scoped_release release;
  LoadedScene loaded = load_scene(path);
  return scene_of(loaded.format, std::move(loaded.structure), loaded.occupied, loaded.info);
}

void save(const Scene& s, const std::string& path) {
  py::gil_scoped_release release;
  save_scene(path, s.format, *s.structure, s.info);
}

py::tuple vec3(Vec3 v) {
  return py::make_tuple(v.x, v.y, v.z);
}

py::dict info(const Scene& s) {
  py::dict d;
  d["format"] = s.format;
  const GridTransform g = s.octree ? s.octree->grid
                          : s.dag  ? s.dag->grid
                                  : format_registry().get(s.format).describe(*s.structure, {}).grid;
  d["resolution"] = g.resolution;
  d["levels"] = g.levels;
  d["voxel_size"] = g.voxel_size;
  d["grid_origin"] = vec3(g.origin);
  const Aabb b = s.structure->bounds();
  d["bounds"] = py::make_tuple(vec3(b.lo), vec3(b.hi));
  d["occupied_bounds"] = py::make_tuple(vec3(s.occupied.lo), vec3(s.occupied.hi));
  d["voxels"] = s.info.leaf_voxels;
  d["source"] = s.info.source;
  d["voxelization"] = s.info.voxelization;
  d["source_triangles"] = s.info.source_triangles;
  py::dict mem;
  if (s.octree) {
    const esvo::MemoryStats m = s.octree->memory_stats();
    d["attributes"] =
        m.attribute_format == esvo::AttributeFormat::Compressed ? "compressed" : "raw";
    d["contours"] = s.octree->has_contours();
    mem["descriptors"] = m.descriptor_bytes;
    mem["far_pointers"] = m.far_pointer_bytes;
    mem["page_headers"] = m.page_header_bytes;
    mem["padding"] = m.padding_bytes;
    mem["pair_padding"] = m.pair_padding_bytes;
    mem["info"] = m.info_bytes;
    mem["attribute_lookup"] = m.attribute_lookup_bytes;
    mem["colors"] = m.color_bytes;
    mem["normals"] = m.normal_bytes;
    mem["contours"] = m.contour_bytes;
    mem["total"] = m.total_bytes;
  } else if (s.dag) {
    const dag::DagStats st = s.dag->stats();
    d["attributes"] = st.compressed_attributes ? "compressed" : "raw";
    mem["nodes"] = st.dag_bytes;
    mem["index"] = st.index_bytes;
    mem["attributes"] = st.attribute_bytes;
    mem["total"] = st.dag_bytes + st.index_bytes + st.attribute_bytes;
    d["dag_nodes"] = st.dag_nodes;
    d["bits_per_voxel"] = st.bits_per_voxel;
  }
  d["memory"] = mem;
  return d;
}

// ---- build ----

cli::BuildSettings settings(uint32_t resolution, double voxel_size, const std::string& format,
                            const std::string& attributes, const std::string& voxelization,
                            bool contours, bool dag_attributes, bool out_of_core) {
  cli::BuildSettings s;
  // The checks `voxcast build` makes on its options, with the same words.
  if (resolution == 0 || (resolution & (resolution - 1)) != 0 || resolution > (1u << 20))
    throw Error("resolution must be a power of two in 1..1048576");
  s.resolution = resolution;
  if (voxel_size != 0) {
    if (!(voxel_size >= 1e-30 && voxel_size <= 1e30))
      throw Error("voxel_size must be a finite number > 0");
    s.voxel_size = voxel_size;
  }
  const SceneFormat& f = format_registry().get(format);  // "unknown scene format ... (known: ...)"
  if (!f.builds()) throw Error("format " + f.name + " is not built from a mesh here");
  s.format = f.name;
  s.compress_attributes = cli::parse_compressed_attributes(attributes);
  s.mode = cli::parse_voxelization(voxelization);
  if (contours && !f.contours) throw Error("contours: format " + f.name + " stores no contours");
  s.contours = contours;
  s.dag_attributes = dag_attributes;
  if (!dag_attributes && !f.attributes_optional)
    throw Error("dag_attributes=False: format " + f.name + " needs colors and normals");
  s.out_of_core = out_of_core;
  return s;
}

std::shared_ptr<Scene> finish_build(cli::BuiltScene built, const cli::BuildSettings& s,
                                    const std::string& source) {
  SceneInfo info;
  info.source = source;
  info.voxelization = cli::voxelization_name(s.mode);
  info.source_triangles = built.mesh.triangle_count();
  info.leaf_voxels = built.leaf_voxels;
  // What load_scene() derives from a file, from the built structure.
  const Aabb occupied = format_registry().get(s.format).occupied(*built.structure);
  return scene_of(s.format, std::move(built.structure), occupied, info);
}

template <class T>
using CArray = py::array_t<T, py::array::c_style | py::array::forcecast>;

void require_rows(const py::array& a, int cols, const char* name) {
  if (a.ndim() != 2 || a.shape(1) != cols)
    throw py::value_error(std::string(name) + " must be an N x " + std::to_string(cols) + " array");
}

std::vector<Vec3> vec3_rows(const float* p, size_t n) {
  std::vector<Vec3> out(n);
  for (size_t i = 0; i < n; ++i) out[i] = Vec3{p[3 * i], p[3 * i + 1], p[3 * i + 2]};
  return out;
}

// Area-weighted vertex normals for a mesh given without them (Mesh requires
// unit normals); vertices of only degenerate triangles get +z.
void compute_normals(Mesh& m) {
  m.normals.assign(m.positions.size(), Vec3{0, 0, 0});
  for (size_t t = 0; t < m.triangle_count(); ++t) {
    const uint32_t* i = &m.indices[3 * t];
    const Vec3 n =
        cross(m.positions[i[1]] - m.positions[i[0]], m.positions[i[2]] - m.positions[i[0]]);
    for (int k = 0; k < 3; ++k) m.normals[i[k]] = m.normals[i[k]] + n;
  }
  for (Vec3& n : m.normals) {
    const float l = length(n);
    n = l > 0 && std::isfinite(l) ? n * (1.f / l) : Vec3{0, 0, 1};
  }
}

Mesh mesh_from_arrays(const CArray<float>& vertices, const CArray<int64_t>& faces,
                      const std::optional<CArray<float>>& normals,
                      const std::optional<CArray<float>>& colors,
                      const std::optional<std::vector<float>>& color) {
  require_rows(vertices, 3, "vertices");
  require_rows(faces, 3, "faces");
  Mesh m;
  const size_t n = size_t(vertices.shape(0));
  m.positions = vec3_rows(vertices.data(), n);
  const size_t f = size_t(faces.shape(0));
  m.indices.resize(3 * f);
  const int64_t* fi = faces.data();
  for (size_t k = 0; k < 3 * f; ++k) {
    if (fi[k] < 0 || uint64_t(fi[k]) >= n)
      throw py::value_error("faces: index " + std::to_string(fi[k]) + " is not a vertex (0.." +
                            std::to_string(n) + ")");
    m.indices[k] = uint32_t(fi[k]);
  }
  if (normals) {
    require_rows(*normals, 3, "normals");
    if (size_t(normals->shape(0)) != n) throw py::value_error("normals: one row per vertex");
    m.normals = vec3_rows(normals->data(), n);
  } else {
    compute_normals(m);
  }
  if (colors) {
    const int c = colors->ndim() == 2 ? int(colors->shape(1)) : 0;
    if (colors->ndim() != 2 || (c != 3 && c != 4) || size_t(colors->shape(0)) != n)
      throw py::value_error("colors must be an N x 3 or N x 4 array, one row per vertex");
    m.colors.resize(n);
    for (size_t v = 0; v < n; ++v) {
      const float* p = colors->data() + v * size_t(c);
      m.colors[v] = Color{p[0], p[1], p[2], c == 4 ? p[3] : 1.f};
    }
  }
  if (color) {
    if (color->size() != 3 && color->size() != 4)
      throw py::value_error("color must be (r, g, b) or (r, g, b, a)");
    Material mat;
    mat.base_color =
        Color{(*color)[0], (*color)[1], (*color)[2], color->size() == 4 ? (*color)[3] : 1.f};
    m.materials.push_back(mat);
    m.triangle_material.assign(f, 0);
  }
  return m;
}

std::shared_ptr<Scene> build(const std::optional<std::string>& mesh,
                             const std::optional<CArray<float>>& vertices,
                             const std::optional<CArray<int64_t>>& faces,
                             const std::optional<CArray<float>>& normals,
                             const std::optional<CArray<float>>& colors,
                             const std::optional<std::vector<float>>& color, uint32_t resolution,
                             double voxel_size, const std::string& format,
                             const std::string& attributes, const std::string& voxelization,
                             bool contours, bool dag_attributes, bool out_of_core) {
  cli::BuildSettings s = settings(resolution, voxel_size, format, attributes, voxelization,
                                  contours, dag_attributes, out_of_core);
  if (mesh.has_value() == (vertices.has_value() || faces.has_value()))
    throw py::value_error("build: give either a mesh file or vertices and faces");
  if (mesh) {
    s.mesh_path = *mesh;
    py::gil_scoped_release release;
    if (!std::filesystem::is_regular_file(*mesh))
      throw Error("'" + *mesh + "' is not a readable mesh file");
    cli::BuiltScene built = cli::build_scene(s);
    return finish_build(std::move(built), s, std::filesystem::path(*mesh).filename().string());
  }
  if (!vertices || !faces) throw py::value_error("build: vertices and faces go together");
  Mesh m = mesh_from_arrays(*vertices, *faces, normals, colors, color);
  py::gil_scoped_release release;
  validate_mesh(m);  // what load_mesh checks on a file's mesh
  MeshLoadStats stats;
  stats.input_triangles = m.triangle_count();
  cli::BuiltScene built = cli::build_scene(s, std::move(m), stats);
  return finish_build(std::move(built), s, "numpy arrays");
}

py::dict load_mesh_arrays(const std::string& path) {
  Mesh m;
  {
    py::gil_scoped_release release;
    m = load_mesh(path);
  }
  py::dict d;
  const py::ssize_t n = py::ssize_t(m.positions.size()), f = py::ssize_t(m.triangle_count());
  py::array_t<float> v({n, py::ssize_t(3)}), nn({n, py::ssize_t(3)});
  std::memcpy(v.mutable_data(), m.positions.data(), size_t(n) * sizeof(Vec3));
  std::memcpy(nn.mutable_data(), m.normals.data(), size_t(n) * sizeof(Vec3));
  py::array_t<int64_t> fa({f, py::ssize_t(3)});
  for (size_t k = 0; k < m.indices.size(); ++k) fa.mutable_data()[k] = m.indices[k];
  d["vertices"] = v;
  d["faces"] = fa;
  d["normals"] = nn;
  if (m.colors.size() == m.positions.size() && n > 0) {
    py::array_t<float> c({n, py::ssize_t(4)});
    std::memcpy(c.mutable_data(), m.colors.data(), size_t(n) * sizeof(Color));
    d["colors"] = c;
  }
  // One untextured material for every triangle: its color (what build()'s
  // `color` argument takes); several materials or textures are not arrays.
  bool one = m.materials.size() == 1 && m.materials[0].texture < 0;
  for (uint32_t t : m.triangle_material) one = one && t == 0;
  if (one) {
    const Color c = m.materials[0].base_color;
    d["color"] = py::make_tuple(c.r, c.g, c.b, c.a);
  }
  d["materials"] = m.materials.size();
  return d;
}

// ---- cameras ----

Vec3 vec3_of(const py::handle& h, const char* name) {
  auto v = h.cast<std::vector<float>>();
  if (v.size() != 3) throw py::value_error(std::string("camera ") + name + " must be (x, y, z)");
  return Vec3{v[0], v[1], v[2]};
}

std::string csv(const py::handle& h) {
  if (py::isinstance<py::str>(h)) return h.cast<std::string>();
  std::string out;
  for (auto x : h.cast<std::vector<double>>()) {
    if (!out.empty()) out += ",";
    out += py::str(py::float_(x)).cast<std::string>();
  }
  return out;
}

// The CLI's camera forms (README "Camera contract"): None/"auto",
// "ortho", the --camera string, or a dict {"orbit": "AZ,EL[,DIST]"},
// {"look_at": "ex,ey,ez,tx,ty,tz[,...]"}, {"eye", "target", "up", "fovy"},
// each with an optional "ortho": True or a width.
Camera resolve_camera(const py::object& cam, const Aabb& bounds, int w, int h) {
  if (cam.is_none()) return Camera::frame(bounds, w, h);
  if (py::isinstance<py::str>(cam)) {
    const std::string text = cam.cast<std::string>();
    if (text == "auto") return Camera::frame(bounds, w, h);
    if (text == "ortho") return Camera::frame(bounds, w, h).orthographic(bounds, w, h);
    return Camera::parse(text);
  }
  if (!py::isinstance<py::dict>(cam))
    throw py::type_error("camera must be None, a camera string or a dict");
  const py::dict d = cam.cast<py::dict>();
  for (auto item : d) {
    const std::string key = item.first.cast<std::string>();
    if (key != "orbit" && key != "look_at" && key != "eye" && key != "target" && key != "up" &&
        key != "fovy" && key != "ortho")
      throw py::value_error("camera: unknown key '" + key + "'");
  }
  Camera c;
  if (d.contains("orbit")) {
    c = Camera::parse_orbit(csv(d["orbit"]), bounds, w, h);
  } else if (d.contains("look_at")) {
    c = Camera::parse_look_at(csv(d["look_at"]));
  } else if (d.contains("eye") || d.contains("target")) {
    if (!d.contains("eye") || !d.contains("target"))
      throw py::value_error("camera: 'eye' and 'target' go together");
    c.eye = vec3_of(d["eye"], "eye");
    c.target = vec3_of(d["target"], "target");
    c.up = d.contains("up") ? vec3_of(d["up"], "up") : Vec3{0, 1, 0};
    c.fovy_degrees = d.contains("fovy") ? d["fovy"].cast<float>() : Camera::kDefaultFovy;
    c.validate();
  } else {
    c = Camera::frame(bounds, w, h);
  }
  if (d.contains("ortho")) {
    const py::object o = d["ortho"];
    if (py::isinstance<py::bool_>(o)) {
      if (o.cast<bool>()) c = c.orthographic(bounds, w, h);
    } else {
      const float width = o.cast<float>();
      if (!(width > 0) || !std::isfinite(width))
        throw Error("camera: ortho width must be a positive number");
      c = c.orthographic(bounds, w, h, width);
    }
  }
  return c;
}

std::pair<int, int> size_of(const std::pair<int, int>& size) {
  if (size.first < 1 || size.second < 1 || size.first > 32768 || size.second > 32768)
    throw Error("size must be (W, H) with 1 <= W, H <= 32768");
  return size;
}

py::array_t<float> image_array(const Image& im) {
  std::vector<py::ssize_t> shape{im.height, im.width};
  if (im.channels > 1) shape.push_back(im.channels);
  py::array_t<float> a(shape);
  std::memcpy(a.mutable_data(), im.pixels.data(), im.pixels.size() * sizeof(float));
  return a;
}

Vec3 light_of(const std::optional<std::vector<float>>& light) {
  if (!light) return RenderOptions{}.light_dir;
  if (light->size() != 3) throw py::value_error("light must be (dx, dy, dz)");
  const Vec3 l{(*light)[0], (*light)[1], (*light)[2]};
  if (!(length(l) > 0) || !std::isfinite(length(l)))
    throw Error("light must be a non-zero, finite vector");
  return normalize(l);
}

// GI's arguments of render() (the --gi options of `voxcast render`).
struct GiArgs {
  int spp = 0;  // 0 = the surface shading
  int bounces = 8;
  std::optional<std::string> env;
  float env_scale = 1.f;
  bool env_sampling = true;
  std::optional<std::vector<float>> sun;
  float sun_intensity = 3.f, bounce_cone = GiOptions{}.bounce_cone_deg;
};

GiOptions gi_options_of(const GiArgs& a, uint32_t seed, bool depth, bool normal) {
  GiOptions o;
  o.spp = a.spp;
  o.bounces = a.bounces;
  o.bounce_cone_deg = a.bounce_cone;
  o.seed = seed;
  o.env_sampling = a.env_sampling;
  o.want_depth = depth, o.want_normal = normal;
  if (!(a.env_scale >= 0) || !std::isfinite(a.env_scale))
    throw Error("env_scale must be finite and >= 0");
  if (a.sun) {
    if (a.sun->size() != 3) throw py::value_error("sun must be (dx, dy, dz)");
    const Vec3 d{(*a.sun)[0], (*a.sun)[1], (*a.sun)[2]};
    if (!(length(d) > 0) || !std::isfinite(length(d)))
      throw Error("sun must be a non-zero, finite vector");
    o.sun = true;
    o.sun_dir = normalize(d);  // as the CLI does
    const float e = a.sun_intensity;
    o.sun_irradiance = {e, e, e, 1.f};
  }
  o.environment =
      a.env
          ? std::make_shared<const Environment>(load_environment(*a.env, a.env_scale))
          : std::make_shared<const Environment>(Color{a.env_scale, a.env_scale, a.env_scale, 1.f});
  validate(o);
  return o;
}

py::dict render_scene(const Scene& s, std::pair<int, int> size, const py::object& camera, float lod,
                      const std::string& shadows, int ao, float ao_radius,
                      const std::optional<std::vector<float>>& light, bool depth, bool normal,
                      bool filter, int beam, uint32_t seed, int spp, int gi, int bounces,
                      const std::optional<std::string>& env, float env_scale, bool env_sampling,
                      const std::optional<std::vector<float>>& sun, float sun_intensity,
                      float bounce_cone) {
  RenderOptions opt;
  std::tie(opt.width, opt.height) = size_of(size);
  if (!(lod >= 0 && lod <= 1e6)) throw Error("lod must be in 0..1e6");
  opt.lod_pixels = lod;
  opt.light_dir = light_of(light);
  if (beam != 0 && (beam < 2 || beam > 64))
    throw Error("beam must be 0 (off) or a block size in 2..64");
  opt.beam = beam;
  if (spp < 1 || spp > 4096) throw Error("spp must be in 1..4096");
  opt.spp = spp;
  EffectOptions& fx = opt.effects;
  if (shadows == "none")
    fx.shadows = ShadowMode::None;
  else if (shadows == "hard")
    fx.shadows = ShadowMode::Hard;
  else
    throw Error("shadows must be none or hard");
  if (ao < 0 || ao > 4096) throw Error("ao must be in 0..4096");
  if (gi < 0 || gi > 65536) throw Error("gi must be 0 (off) or samples per pixel in 1..65536");
  if (gi > 0) {
    // As `voxcast render --gi`: the surface shading's options do not apply.
    if (shadows != "none" || ao > 0 || filter || beam != 0 || spp != 1)
      throw Error(
          "shadows, ao, filter, beam and spp are options of the surface shading, not of gi");
  } else if (env || sun) {
    throw Error("env and sun are options of gi (gi=SPP)");
  }
  fx.ao_rays = ao;
  // The CLI's default AO radius: 5% of the occupied bounds' diagonal.
  fx.ao_radius = ao > 0 ? (ao_radius > 0 ? ao_radius : 0.05f * length(s.occupied.extent())) : 0;
  fx.seed = seed;
  opt.camera = resolve_camera(camera, s.occupied, opt.width, opt.height);
  opt.want_depth = depth;
  opt.want_normal = normal;
  opt.filter = filter;
  RenderResult r;
  py::dict d;
  if (gi > 0) {
    const GiArgs a{gi, bounces, env, env_scale, env_sampling, sun, sun_intensity, bounce_cone};
    const GiOptions o = gi_options_of(a, seed, depth, normal);
    GiResult g;
    {
      py::gil_scoped_release release;
      g = render_gi(*s.structure, opt.camera, opt.width, opt.height, opt.lod_pixels, o);
    }
    r.color = std::move(g.film.color);
    r.depth = std::move(g.film.depth);
    r.normal = std::move(g.film.normal);
    r.rays = g.stats.rays;
    r.seconds = g.stats.seconds;
    d["samples"] = g.stats.samples;
  } else {
    py::gil_scoped_release release;
    r = voxcast::render(*s.structure, opt);
  }
  d["color"] = image_array(r.color);
  if (depth) d["depth"] = image_array(r.depth);
  if (normal) d["normal"] = image_array(r.normal);
  if (ao > 0) d["ao"] = image_array(r.ao);
  d["camera"] = opt.camera.to_string();
  d["rays"] = r.rays;
  if (gi == 0) d["hits"] = r.hits;
  d["seconds"] = r.seconds;
  return d;
}

// The primary rays render() casts for a camera (CameraRays), row-major.
py::tuple camera_rays(const Scene& s, std::pair<int, int> size, const py::object& camera) {
  const auto [w, h] = size_of(size);
  const Camera cam = resolve_camera(camera, s.occupied, w, h);
  const CameraRays rays(cam, w, h);
  py::array_t<float> o({py::ssize_t(h), py::ssize_t(w), py::ssize_t(3)}),
      dir({py::ssize_t(h), py::ssize_t(w), py::ssize_t(3)});
  float *po = o.mutable_data(), *pd = dir.mutable_data();
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const Ray r = rays.ray(x, y);
      const size_t i = (size_t(y) * size_t(w) + size_t(x)) * 3;
      std::memcpy(po + i, &r.origin, sizeof(Vec3));
      std::memcpy(pd + i, &r.dir, sizeof(Vec3));
    }
  return py::make_tuple(o, dir, py::float_(rays.pixel_size()), py::float_(rays.pixel_angle()));
}

py::dict trace(const Scene& s, const CArray<float>& origins, const CArray<float>& directions,
               float tmax, float lod_size, float lod_angle) {
  require_rows(origins, 3, "origins");
  require_rows(directions, 3, "directions");
  if (origins.shape(0) != directions.shape(0))
    throw py::value_error("origins and directions must have the same number of rows");
  if (!(lod_size >= 0) || !(lod_angle >= 0) || !std::isfinite(lod_size) ||
      !std::isfinite(lod_angle))
    throw Error("lod_size and lod_angle must be finite numbers >= 0");
  const py::ssize_t n = origins.shape(0);
  py::array_t<bool> hit(n);
  py::array_t<float> t(n), pos({n, py::ssize_t(3)}), nor({n, py::ssize_t(3)}),
      col({n, py::ssize_t(3)});
  bool* ph = hit.mutable_data();
  float *pt = t.mutable_data(), *pp = pos.mutable_data(), *pn = nor.mutable_data(),
        *pc = col.mutable_data();
  const float* o = origins.data();
  const float* dir = directions.data();
  const SurfaceQuery* query = s.structure->surface();
  if (query == nullptr) throw Error("trace: the " + s.format + " structure has no surface query");
  {
    py::gil_scoped_release release;
    TraceContext ctx;  // per call: one thread traces all the rays
    // The footprint render() uses: lod_size (orthographic pixel size) plus
    // lod_angle (perspective pixel angle) per unit distance, times LOD pixels.
    LodFootprint lod;
    lod.size_at_origin = lod_size;
    lod.size_per_t = lod_angle;
    for (py::ssize_t i = 0; i < n; ++i) {
      Ray ray;
      ray.origin = Vec3{o[3 * i], o[3 * i + 1], o[3 * i + 2]};
      const Vec3 d{dir[3 * i], dir[3 * i + 1], dir[3 * i + 2]};
      const float l = length(d);
      SurfaceHit h;
      bool found = false;
      if (l > 0 && std::isfinite(l)) {
        // The casters take unit directions; t is then a world distance.
        // Directions already unit to float rounding (camera_rays) are kept
        // as given, so their hits are bit-identical to render()'s.
        ray.dir = std::fabs(l - 1.f) <= 1e-6f ? d : d * (1.f / l);
        ray.tmax = tmax;
        found = query->trace(ray, lod, ctx, &h);
      }
      ph[i] = found;
      Color c{0, 0, 0, 0};
      Vec3 nn{0, 0, 0}, p{NAN, NAN, NAN};
      if (found) {
        query->attributes(h, ctx, &c, &nn);
        p = h.position;
      }
      pt[i] = found ? h.t : INFINITY;
      std::memcpy(pp + 3 * i, &p, sizeof(Vec3));
      std::memcpy(pn + 3 * i, &nn, sizeof(Vec3));
      pc[3 * i] = c.r, pc[3 * i + 1] = c.g, pc[3 * i + 2] = c.b;
    }
  }
  py::dict d;
  d["hit"] = hit;
  d["t"] = t;
  d["position"] = pos;
  d["normal"] = nor;
  d["color"] = col;
  return d;
}

// The leaf voxels: grid coordinates (x, y, z) in Morton order and their
// colors as 8-bit sRGB (the CLI's PNG encoding of the stored linear colors).
py::dict voxels(const Scene& s) {
  if (!s.dag)
    throw Error(
        "voxels(): reading the voxel set is implemented for dag scenes only (build with "
        "format='dag')");
  std::vector<uint64_t> codes;
  {
    py::gil_scoped_release release;
    codes = s.dag->decode_leaves();
  }
  const py::ssize_t n = py::ssize_t(codes.size());
  py::array_t<int32_t> xyz({n, py::ssize_t(3)});
  int32_t* px = xyz.mutable_data();
  const bool attrs = s.dag->stats().attribute_bytes > 0;
  py::array_t<uint8_t> col({n, py::ssize_t(3)});
  py::array_t<float> nor({n, py::ssize_t(3)});
  uint8_t* pc = col.mutable_data();
  float* pn = nor.mutable_data();
  for (py::ssize_t i = 0; i < n; ++i) {
    const MortonCoord m = morton_decode(codes[size_t(i)]);
    px[3 * i] = int32_t(m.x), px[3 * i + 1] = int32_t(m.y), px[3 * i + 2] = int32_t(m.z);
    Color c{0, 0, 0, 1};
    Vec3 nn{0, 0, 0};
    if (attrs) s.dag->voxel_attributes(uint64_t(i), &c, &nn);
    const float lin[3] = {c.r, c.g, c.b};
    for (int k = 0; k < 3; ++k) {
      const float v = linear_to_srgb(std::fmin(std::fmax(lin[k], 0.f), 1.f));
      pc[3 * i + k] = uint8_t(std::lround(v * 255.f));
    }
    std::memcpy(pn + 3 * i, &nn, sizeof(Vec3));
  }
  py::dict d;
  d["coords"] = xyz;
  if (attrs) {
    d["colors"] = col;
    d["normals"] = nor;
  }
  return d;
}

py::array_t<float> read_pfm_array(const std::string& path) {
  return image_array(read_pfm(path));
}

}  // namespace

PYBIND11_MODULE(voxcast, m) {
  // Every scene format before anything builds, loads or saves (as the CLI's main()).
  register_builtin_formats();
  m.doc() = "voxcast: triangle meshes -> sparse voxel structures (ESVO, DAG) -> CPU ray casting";
  // One exception type for every library error, with the library's message.
  static py::exception<Error> error(m, "Error", PyExc_RuntimeError);
  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const Error& e) {
      error(e.what());
    }
  });
  m.attr("__version__") = VOXCAST_PYTHON_VERSION;

  py::class_<Scene, std::shared_ptr<Scene>>(m, "Scene")
      .def_property_readonly("format", [](const Scene& s) { return s.format; })
      .def("info", &info, "Format, grid, bounds, voxel count and memory per component (bytes)")
      .def("save", &save, py::arg("path"), "Write the scene file (.vxc), as `voxcast build` does")
      .def("voxels", &voxels, "Leaf voxels: coords N x 3 int32, colors N x 3 uint8 (sRGB)")
      .def("__repr__", [](const Scene& s) {
        return "<voxcast.Scene " + s.format + ", " + std::to_string(s.info.leaf_voxels) +
               " voxels>";
      });

  m.def("load", &load, py::arg("path"), "Load a scene file written by `voxcast build`");
  m.def("build", &build, py::arg("mesh") = py::none(), py::kw_only(),
        py::arg("vertices") = py::none(), py::arg("faces") = py::none(),
        py::arg("normals") = py::none(), py::arg("colors") = py::none(),
        py::arg("color") = py::none(), py::arg("resolution") = 1024, py::arg("voxel_size") = 0.0,
        py::arg("format") = "esvo", py::arg("attributes") = "raw",
        py::arg("voxelization") = "conservative", py::arg("contours") = false,
        py::arg("dag_attributes") = true, py::arg("out_of_core") = false,
        "Voxelize a mesh file, or vertices (N x 3 float) and faces (M x 3 int), like "
        "`voxcast build`");
  m.def("load_mesh", &load_mesh_arrays, py::arg("path"),
        "A mesh file as numpy arrays (vertices, faces, normals[, colors][, color])");
  m.def("render", &render_scene, py::arg("scene"), py::arg("size") = std::pair<int, int>{1024, 768},
        py::arg("camera") = py::none(), py::arg("lod") = 1.f, py::arg("shadows") = "none",
        py::arg("ao") = 0, py::arg("ao_radius") = 0.f, py::arg("light") = py::none(),
        py::arg("depth") = false, py::arg("normal") = false, py::arg("filter") = false,
        py::arg("beam") = 0, py::arg("seed") = 0u, py::arg("spp") = 1, py::arg("gi") = 0,
        py::arg("bounces") = 8, py::arg("env") = py::none(), py::arg("env_scale") = 1.f,
        py::arg("env_sampling") = true, py::arg("sun") = py::none(), py::arg("sun_intensity") = 3.f,
        py::arg("bounce_cone") = GiOptions{}.bounce_cone_deg,
        "Ray cast the scene: dict with color (H x W x 3 float32, linear), depth/normal on "
        "request, the camera used (--camera form) and ray counts. spp: antialiasing samples "
        "per pixel (render --spp); gi=SPP: progressive diffuse GI (render --gi) with "
        "bounces, env (a .hdr/.exr path), env_scale, env_sampling, sun (dx, dy, dz), "
        "sun_intensity, bounce_cone");
  m.def("camera_rays", &camera_rays, py::arg("scene"), py::arg("size"),
        py::arg("camera") = py::none(),
        "The primary rays render() casts: origins, directions (H x W x 3), pixel_size, "
        "pixel_angle");
  m.def("trace", &trace, py::arg("scene"), py::arg("origins"), py::arg("directions"),
        py::arg("tmax") = INFINITY, py::arg("lod_size") = 0.f, py::arg("lod_angle") = 0.f,
        "First hits of N rays: hit mask, t (world distance), position, normal, color (linear)");
  m.def("read_pfm", &read_pfm_array, py::arg("path"), "A .pfm image as a numpy array");
}
