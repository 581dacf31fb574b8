// Camera path JSON (camera_path.hpp): parsing with one-line errors, writing,
// and interpolation between keyframes.
#include "view/camera_path.hpp"

#include <cmath>
#include <fstream>
#include <iterator>
#include <nlohmann/json.hpp>
#include <set>

#include "voxcast/error.hpp"
#include "voxcast/image.hpp"

namespace voxcast::view {

namespace {

using nlohmann::json;

[[noreturn]] void fail(size_t index, const std::string& why) {
  throw Error("camera path: keyframe " + std::to_string(index) + ": " + why);
}

Vec3 vec3_at(const json& k, size_t index, const char* key) {
  const json& v = k.at(key);
  if (!v.is_array() || v.size() != 3) fail(index, std::string("'") + key + "' must be [x, y, z]");
  Vec3 out;
  for (int i = 0; i < 3; ++i) {
    if (!v[size_t(i)].is_number())
      fail(index, std::string("'") + key + "' must hold three numbers");
    const double d = v[size_t(i)].get<double>();
    if (!std::isfinite(d) || std::fabs(d) > 3.4e38)
      fail(index, std::string("'") + key + "' must hold finite floats");
    out[i] = float(d);
  }
  return out;
}

float number_at(const json& k, size_t index, const char* key) {
  const json& v = k.at(key);
  if (!v.is_number()) fail(index, std::string("'") + key + "' must be a number");
  const double d = v.get<double>();
  if (!std::isfinite(d) || std::fabs(d) > 3.4e38)
    fail(index, std::string("'") + key + "' must be a finite float");
  return float(d);
}

Vec3 lerp(Vec3 a, Vec3 b, float w) {
  return a + (b - a) * w;
}

}  // namespace

CameraPath CameraPath::parse(const std::string& json_text) {
  json doc = json::parse(json_text, nullptr, /*allow_exceptions=*/false);
  if (doc.is_discarded()) throw Error("camera path: not valid JSON");
  if (!doc.is_object()) throw Error("camera path: the top level must be a JSON object");
  for (auto it = doc.begin(); it != doc.end(); ++it)
    if (it.key() != "voxcast_camera_path" && it.key() != "keyframes")
      throw Error("camera path: unknown key '" + it.key() + "'");
  if (!doc.contains("voxcast_camera_path") || !doc["voxcast_camera_path"].is_number_integer())
    throw Error("camera path: missing \"voxcast_camera_path\": 1 (the format version)");
  if (doc["voxcast_camera_path"].get<int64_t>() != kCameraPathVersion)
    throw Error("camera path: version " + doc["voxcast_camera_path"].dump() +
                " is not supported (this voxcast reads version 1)");
  if (!doc.contains("keyframes") || !doc["keyframes"].is_array() || doc["keyframes"].empty())
    throw Error("camera path: \"keyframes\" must be a non-empty array");
  static const std::set<std::string> known = {"name", "time", "eye",        "target",
                                              "up",   "fovy", "projection", "ortho_width"};
  CameraPath path;
  std::set<std::string> names;
  const json& frames = doc["keyframes"];
  for (size_t i = 0; i < frames.size(); ++i) {
    const json& k = frames[i];
    if (!k.is_object()) fail(i, "must be a JSON object");
    for (auto it = k.begin(); it != k.end(); ++it)
      if (!known.count(it.key())) fail(i, "unknown key '" + it.key() + "'");
    for (const char* required : {"time", "eye", "target"})
      if (!k.contains(required)) fail(i, std::string("missing '") + required + "'");
    CameraKeyframe kf;
    if (k.contains("name")) {
      if (!k["name"].is_string() || k["name"].get<std::string>().empty())
        fail(i, "'name' must be a non-empty string");
      kf.name = k["name"].get<std::string>();
      if (!names.insert(kf.name).second) fail(i, "name '" + kf.name + "' is used twice");
    }
    if (!k["time"].is_number()) fail(i, "'time' must be a number");
    kf.time = k["time"].get<double>();
    if (!std::isfinite(kf.time) || kf.time < 0) fail(i, "'time' must be finite and >= 0");
    if (!path.keyframes.empty() && !(kf.time > path.keyframes.back().time))
      fail(i, "'time' must be greater than the previous keyframe's");
    Camera& c = kf.camera;
    c.eye = vec3_at(k, i, "eye");
    c.target = vec3_at(k, i, "target");
    c.up = k.contains("up") ? vec3_at(k, i, "up") : Vec3{0, 1, 0};
    c.fovy_degrees = k.contains("fovy") ? number_at(k, i, "fovy") : Camera::kDefaultFovy;
    std::string projection = "perspective";
    if (k.contains("projection")) {
      if (!k["projection"].is_string()) fail(i, "'projection' must be a string");
      projection = k["projection"].get<std::string>();
    }
    if (projection == "orthographic") {
      if (!k.contains("ortho_width")) fail(i, "an orthographic keyframe needs 'ortho_width'");
      c.projection = Projection::Orthographic;
      c.ortho_width = number_at(k, i, "ortho_width");
    } else if (projection == "perspective") {
      if (k.contains("ortho_width"))
        fail(i, "'ortho_width' needs \"projection\": \"orthographic\"");
    } else {
      fail(i, "'projection' must be \"perspective\" or \"orthographic\"");
    }
    try {
      c.validate();
    } catch (const Error& e) {
      fail(i, e.what());
    }
    path.keyframes.push_back(std::move(kf));
  }
  return path;
}

CameraPath CameraPath::load(const std::filesystem::path& file) {
  std::ifstream in(file, std::ios::binary);
  if (!in) throw Error("cannot open camera path '" + file.string() + "'");
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (in.bad()) throw Error("cannot read camera path '" + file.string() + "'");
  try {
    return parse(text);
  } catch (const Error& e) {
    // "camera path: ..." -> "camera path 'FILE': ..."
    std::string why = e.what();
    const std::string prefix = "camera path: ";
    if (why.rfind(prefix, 0) == 0) why.erase(0, prefix.size());
    throw Error("camera path '" + file.string() + "': " + why);
  }
}

std::string CameraPath::to_json() const {
  // One keyframe per line, keys in the documented order. Each float goes
  // through double with the shortest digits that read back to the same
  // double (nlohmann's number output), hence to the same float: longer than
  // a float's shortest form, but exact. (Appends, not operator+ chains,
  // which GCC 12 misreads under -Wrestrict.)
  std::string out;
  auto number = [&](double v) { out += json(v).dump(); };
  auto key = [&](const char* k) {
    out += ", \"";
    out += k;
    out += "\": ";
  };
  auto vec = [&](const char* k, Vec3 v) {
    key(k);
    out += '[';
    number(v.x);
    out += ", ";
    number(v.y);
    out += ", ";
    number(v.z);
    out += ']';
  };
  out += "{\n  \"voxcast_camera_path\": ";
  out += std::to_string(kCameraPathVersion);
  out += ",\n  \"keyframes\": [\n";
  for (size_t i = 0; i < keyframes.size(); ++i) {
    const CameraKeyframe& kf = keyframes[i];
    const Camera& c = kf.camera;
    out += "    {";
    if (!kf.name.empty()) {
      out += "\"name\": ";
      out += json(kf.name).dump();
      out += ", ";
    }
    out += "\"time\": ";
    number(kf.time);
    vec("eye", c.eye);
    vec("target", c.target);
    vec("up", c.up);
    if (c.projection == Projection::Orthographic) {
      key("projection");
      out += "\"orthographic\"";
      key("ortho_width");
      number(c.ortho_width);
    } else {
      key("fovy");
      number(c.fovy_degrees);
    }
    out += i + 1 < keyframes.size() ? "},\n" : "}\n";
  }
  out += "  ]\n}\n";
  return out;
}

void CameraPath::save(const std::filesystem::path& file) const {
  const std::string text = to_json();
  write_file_atomic(file, text.data(), text.size());
}

Camera CameraPath::at(double t) const {
  if (keyframes.empty()) throw Error("camera path: no keyframes");
  if (!(t > keyframes.front().time)) return keyframes.front().camera;
  if (t >= keyframes.back().time) return keyframes.back().camera;
  size_t i = 0;
  while (keyframes[i + 1].time <= t) ++i;  // keyframes[i].time <= t < keyframes[i+1].time
  const CameraKeyframe& a = keyframes[i];
  const CameraKeyframe& b = keyframes[i + 1];
  if (t == a.time) return a.camera;
  const float w = float((t - a.time) / (b.time - a.time));
  Camera c = a.camera;
  c.eye = lerp(a.camera.eye, b.camera.eye, w);
  c.target = lerp(a.camera.target, b.camera.target, w);
  c.fovy_degrees = a.camera.fovy_degrees + (b.camera.fovy_degrees - a.camera.fovy_degrees) * w;
  if (a.camera.projection == Projection::Orthographic &&
      b.camera.projection == Projection::Orthographic)
    c.ortho_width = a.camera.ortho_width + (b.camera.ortho_width - a.camera.ortho_width) * w;
  // A blend of two valid up vectors can still be parallel to the blended view
  // (or vanish): keep the earlier keyframe's up then.
  const Vec3 up = lerp(a.camera.up, b.camera.up, w);
  c.up = up;
  try {
    c.validate();
  } catch (const Error&) {
    c.up = a.camera.up;
    try {
      c.validate();
    } catch (const Error&) {
      return a.camera;  // eye met target in between: hold the earlier keyframe
    }
  }
  return c;
}

size_t CameraPath::find(const std::string& key) const {
  for (size_t i = 0; i < keyframes.size(); ++i)
    if (keyframes[i].name == key) return i;
  if (!key.empty() && key.find_first_not_of("0123456789") == std::string::npos && key.size() < 10) {
    const size_t index = std::stoul(key);
    if (index < keyframes.size()) return index;
  }
  std::string names;
  for (const CameraKeyframe& kf : keyframes) {
    if (kf.name.empty()) continue;
    if (!names.empty()) names += ", ";
    names += kf.name;
  }
  throw Error("camera path has no keyframe '" + key + "' (indices 0.." +
              std::to_string(keyframes.size() - 1) + (names.empty() ? "" : "; names: " + names) +
              ")");
}

}  // namespace voxcast::view
