// MetaImage volumes (ITK's .mhd header + raw data file, or .mha with the data
// after the header): gigavoxels.hpp parse_metaimage / read_metaimage.
#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <string_view>

#include "volume_samples.hpp"
#include "voxcast/error.hpp"
#include "voxcast/gigavoxels.hpp"

namespace voxcast::giga {
namespace {

constexpr size_t kMaxHeader = 64 * 1024;
constexpr uint64_t kMaxVoxels = uint64_t(1) << 28;

[[noreturn]] void fail(const std::string& what) {
  throw Error("MetaImage: " + what);
}

std::string_view trim(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t' || s.back() == '\r'))
    s.remove_suffix(1);
  return s;
}

/// Whitespace-separated fields of a value.
std::vector<std::string_view> words(std::string_view s) {
  std::vector<std::string_view> out;
  size_t i = 0;
  while (i < s.size()) {
    while (i < s.size() && s[i] == ' ') ++i;
    const size_t j = std::min(s.find(' ', i), s.size());
    if (j > i) out.push_back(s.substr(i, j - i));
    i = j;
  }
  return out;
}

template <class T>
T number(std::string_view key, std::string_view v) {
  T x{};
  const auto [end, ec] = std::from_chars(v.data(), v.data() + v.size(), x);
  if (ec != std::errc() || end != v.data() + v.size() || v.empty())
    fail(std::string(key) + " = '" + std::string(v) + "' is not a number");
  return x;
}

bool boolean(std::string_view key, std::string_view v) {
  if (v == "True" || v == "true" || v == "1") return true;
  if (v == "False" || v == "false" || v == "0") return false;
  fail(std::string(key) + " = '" + std::string(v) + "' must be True or False");
}

// Keys ITK writes that do not change the samples (placement, orientation,
// provenance): accepted and ignored. Any other key is refused, so that a
// damaged header line does not pass unnoticed.
constexpr std::string_view kIgnored[] = {"Comment",
                                         "ObjectSubType",
                                         "TransformType",
                                         "Offset",
                                         "Origin",
                                         "Position",
                                         "CenterOfRotation",
                                         "TransformMatrix",
                                         "Rotation",
                                         "Orientation",
                                         "AnatomicalOrientation",
                                         "ElementMin",
                                         "ElementMax",
                                         "Name",
                                         "ID",
                                         "ParentID",
                                         "Color",
                                         "BinaryData",
                                         "Modality",
                                         "ElementSize"};

}  // namespace

ScalarVolume parse_metaimage(
    std::span<const unsigned char> bytes,
    const std::function<std::vector<unsigned char>(const std::string&)>& read_data_file) {
  const std::string_view text(reinterpret_cast<const char*>(bytes.data()),
                              std::min(bytes.size(), kMaxHeader));
  std::map<std::string, std::string, std::less<>> fields;
  size_t pos = 0, data_at = std::string_view::npos;
  while (pos < text.size()) {
    size_t nl = text.find('\n', pos);
    if (nl == std::string_view::npos) nl = text.size();
    const std::string_view line = trim(text.substr(pos, nl - pos));
    pos = nl + 1;
    if (line.empty()) continue;
    const size_t eq = line.find('=');
    if (eq == std::string_view::npos)
      fail("header line '" + std::string(line.substr(0, 60)) + "' is not 'Key = Value'");
    const std::string key(trim(line.substr(0, eq)));
    const std::string value(trim(line.substr(eq + 1)));
    if (key.empty() || !std::all_of(key.begin(), key.end(), [](char c) {
          return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9');
        }))
      fail("header key '" + key.substr(0, 60) + "' is not a MetaImage key");
    if (!fields.emplace(key, value).second) fail("header field " + key + " appears twice");
    // ElementDataFile ends the header (MetaImage's rule): with LOCAL the
    // samples start on the next byte.
    if (key == "ElementDataFile") {
      data_at = std::min(pos, bytes.size());
      break;
    }
  }
  if (data_at == std::string_view::npos)
    fail(bytes.size() > kMaxHeader && pos >= kMaxHeader
             ? "no ElementDataFile within the first 64 KiB"
             : "the header has no ElementDataFile line");
  auto get = [&](const char* key) -> const std::string* {
    const auto it = fields.find(key);
    return it == fields.end() ? nullptr : &it->second;
  };
  auto need = [&](const char* key) -> const std::string& {
    const std::string* s = get(key);
    if (s == nullptr) fail(std::string("the header has no ") + key);
    return *s;
  };
  static const std::string_view kKnown[] = {"ObjectType",
                                            "NDims",
                                            "DimSize",
                                            "ElementType",
                                            "ElementSpacing",
                                            "ElementNumberOfChannels",
                                            "BinaryDataByteOrderMSB",
                                            "ElementByteOrderMSB",
                                            "CompressedData",
                                            "HeaderSize",
                                            "ElementDataFile"};
  for (const auto& [key, value] : fields)
    if (std::find(std::begin(kKnown), std::end(kKnown), key) == std::end(kKnown) &&
        std::find(std::begin(kIgnored), std::end(kIgnored), key) == std::end(kIgnored))
      fail("unknown header key '" + key + "'");

  if (const std::string* s = get("ObjectType"); s && *s != "Image")
    fail("ObjectType = '" + *s + "': only Image is supported");
  if (need("NDims") != "3") fail("NDims = '" + need("NDims") + "': only 3-D volumes are supported");
  const auto dims = words(need("DimSize"));
  if (dims.size() != 3) fail("DimSize must hold three sizes");
  ScalarVolume v;
  int* n[3] = {&v.nx, &v.ny, &v.nz};
  for (int a = 0; a < 3; ++a) {
    *n[a] = number<int>("DimSize", dims[size_t(a)]);
    if (*n[a] < 1 || *n[a] > 65536) fail("DimSize values must be in 1..65536");
  }
  if (const std::string* s = get("ElementSpacing")) {
    const auto sp = words(*s);
    if (sp.size() != 3) fail("ElementSpacing must hold three numbers");
    float* out[3] = {&v.vx, &v.vy, &v.vz};
    for (int a = 0; a < 3; ++a) {
      *out[a] = number<float>("ElementSpacing", sp[size_t(a)]);
      if (!std::isfinite(*out[a]) || !(*out[a] > 0.f))
        fail("ElementSpacing values must be positive numbers");
    }
  }
  if (const std::string* s = get("ElementNumberOfChannels"); s && *s != "1")
    fail("ElementNumberOfChannels = " + *s + ": only scalar volumes are supported");
  if (const std::string* s = get("CompressedData"); s && boolean("CompressedData", *s))
    fail("compressed MetaImage data is not supported");
  bool big = false;
  if (const std::string* s = get("BinaryDataByteOrderMSB"))
    big = boolean("BinaryDataByteOrderMSB", *s);
  if (const std::string* s = get("ElementByteOrderMSB")) big = boolean("ElementByteOrderMSB", *s);
  using detail::SampleType;
  static const std::pair<std::string_view, SampleType> kTypes[] = {
      {"MET_UCHAR", SampleType::U8},   {"MET_CHAR", SampleType::I8},
      {"MET_USHORT", SampleType::U16}, {"MET_SHORT", SampleType::I16},
      {"MET_UINT", SampleType::U32},   {"MET_INT", SampleType::I32},
      {"MET_FLOAT", SampleType::F32},  {"MET_DOUBLE", SampleType::F64}};
  const std::string& et = need("ElementType");
  const auto type = std::find_if(std::begin(kTypes), std::end(kTypes),
                                 [&](const auto& t) { return t.first == et; });
  if (type == std::end(kTypes))
    fail("ElementType = '" + et +
         "' must be MET_(U)CHAR, MET_(U)SHORT, MET_(U)INT, MET_FLOAT or MET_DOUBLE");

  const uint64_t count = uint64_t(v.nx) * uint64_t(v.ny) * uint64_t(v.nz);
  if (count > kMaxVoxels) fail(std::to_string(count) + " voxels exceed the limit of 2^28");
  const uint64_t want = count * detail::sample_bytes(type->second);
  const std::string& file = need("ElementDataFile");
  std::vector<unsigned char> external;
  std::span<const unsigned char> data;
  if (file == "LOCAL") {
    data = bytes.subspan(data_at);
  } else {
    if (!read_data_file) fail("ElementDataFile = '" + file + "': the data file is not available");
    if (file.empty() || file.find('/') != std::string::npos ||
        file.find('\\') != std::string::npos || file == "." || file == "..")
      fail("ElementDataFile = '" + file +
           "' must name a file next to the header (a list or pattern is not supported)");
    external = read_data_file(file);
    data = external;
  }
  // HeaderSize: bytes to skip before the samples; -1 = the samples are the
  // file's last bytes (MetaImage's convention).
  uint64_t skip = 0;
  if (const std::string* s = get("HeaderSize")) {
    const int64_t h = number<int64_t>("HeaderSize", *s);
    if (h == -1)
      skip = data.size() >= want ? data.size() - want : 0;
    else if (h < 0)
      fail("HeaderSize = " + *s + " must be -1 or >= 0");
    else
      skip = uint64_t(h);
  }
  const uint64_t have = data.size() > skip ? data.size() - skip : 0;
  if (have < want)
    fail("truncated: the header announces " + std::to_string(want) + " bytes of data, there are " +
         std::to_string(have));
  if (have > want)
    fail(std::to_string(have - want) + " bytes after the announced " + std::to_string(want) +
         " bytes of data");
  detail::decode_samples(data.data() + skip, size_t(count), type->second, big, "MetaImage",
                         &v.values);
  return v;
}

ScalarVolume read_metaimage(const std::string& path) {
  auto slurp = [](const std::string& p) {
    std::ifstream in(p, std::ios::binary);
    if (!in) throw Error("cannot open '" + p + "'");
    std::vector<unsigned char> bytes((std::istreambuf_iterator<char>(in)),
                                     std::istreambuf_iterator<char>());
    if (in.bad()) throw Error("cannot read '" + p + "'");
    return bytes;
  };
  const std::vector<unsigned char> header = slurp(path);
  const std::filesystem::path dir = std::filesystem::path(path).parent_path();
  try {
    return parse_metaimage(header,
                           [&](const std::string& name) { return slurp((dir / name).string()); });
  } catch (const Error& e) {
    throw Error(path + ": " + e.what());
  }
}

std::vector<unsigned char> write_metaimage(const ScalarVolume& v) {
  char buf[3][32];
  const float sp[3] = {v.vx, v.vy, v.vz};
  std::string h = "ObjectType = Image\nNDims = 3\nDimSize =";
  for (int n : {v.nx, v.ny, v.nz}) h.append(" ").append(std::to_string(n));
  h.append("\nElementSpacing =");
  for (int a = 0; a < 3; ++a) {
    const auto r = std::to_chars(buf[a], buf[a] + sizeof buf[a], sp[a]);
    h.append(" ").append(buf[a], r.ptr);
  }
  h += "\nElementType = MET_FLOAT\nBinaryDataByteOrderMSB = False\nElementDataFile = LOCAL\n";
  std::vector<unsigned char> out(h.begin(), h.end());
  for (float x : v.values) {
    const uint32_t u = std::bit_cast<uint32_t>(x);
    for (int i = 0; i < 4; ++i) out.push_back(uint8_t(u >> (8 * i)));
  }
  return out;
}

ScalarVolume read_volume_file(const std::string& path) {
  std::string lower = path;
  std::transform(lower.begin(), lower.end(), lower.begin(),
                 [](unsigned char c) { return char(std::tolower(c)); });
  if (lower.ends_with(".inr") || lower.ends_with(".inr.gz")) return read_inrimage(path);
  if (lower.ends_with(".mhd") || lower.ends_with(".mha")) return read_metaimage(path);
  throw Error(path + ": not a volume file (expected .inr, .inr.gz, .mhd or .mha)");
}

}  // namespace voxcast::giga
