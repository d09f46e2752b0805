// Reading a glTF 2.0 file with its buffers and embedded images (gltf_files.h).
#include "common/scene_loader/gltf_files.h"

#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <nlohmann/json.hpp>
#include <system_error>

#include "common/scene_loader/path_sandbox.h"
#include "common/scene_loader/text.h"

namespace epr::loader {
namespace {

namespace fs = std::filesystem;

/// What tinygltf's callbacks share: the files they may read and the first failure.
struct ReadContext {
  const LoadOptions* opts = nullptr;
  LoadReport* report = nullptr;
  std::map<fs::path, FileRef> allowed;  // canonical path -> the buffer file checked for it
  std::map<int, std::string>* embedded = nullptr;
  std::string error;  // a SceneError message from a callback
};

fs::path canonical_or_empty(const std::string& p) {
  std::error_code ec;
  fs::path c = fs::weakly_canonical(fs::path(p), ec);
  return ec ? fs::path() : c;
}

bool file_exists(const std::string& abs, void* user) {
  auto* ctx = static_cast<ReadContext*>(user);
  return ctx->allowed.count(canonical_or_empty(abs)) > 0;
}

std::string expand_path(const std::string& p, void*) { return p; }

bool read_whole_file(std::vector<unsigned char>* out, std::string* err, const std::string& abs, void* user) {
  auto* ctx = static_cast<ReadContext*>(user);
  const auto it = ctx->allowed.find(canonical_or_empty(abs));
  if (it == ctx->allowed.end()) {
    if (err) *err = "not a checked file";
    return false;
  }
  try {
    const std::string data = read_file(it->second, ctx->opts->max_file_bytes, ctx->report);
    out->assign(data.begin(), data.end());
    return true;
  } catch (const SceneError& e) {
    if (ctx->error.empty()) ctx->error = e.what();
    if (err) *err = e.what();
    return false;
  }
}

bool write_whole_file(std::string* err, const std::string&, const std::vector<unsigned char>&, void*) {
  if (err) *err = "the loader writes no files";
  return false;
}

bool keep_image_bytes(tinygltf::Image*, const int index, std::string*, std::string*, int, int,
                      const unsigned char* bytes, int size, void* user) {
  auto* ctx = static_cast<ReadContext*>(user);
  (*ctx->embedded)[index] = std::string(reinterpret_cast<const char*>(bytes), size_t(std::max(size, 0)));
  return true;
}

uint32_t le32(const std::string& s, size_t at) {
  uint32_t v = 0;
  for (int i = 3; i >= 0; --i) v = (v << 8) | static_cast<unsigned char>(s[at + size_t(i)]);
  return v;
}

/// The JSON chunk of a .glb file (the binary chunk is tinygltf's to read).
std::string glb_json(const std::string& bytes, const std::string& display) {
  if (bytes.size() < 20) fail_file(display, "not a valid .glb file: shorter than its header");
  if (le32(bytes, 4) != 2) fail_file(display, fmt::format("glTF binary version {} (only 2 is read)", le32(bytes, 4)));
  const uint32_t length = le32(bytes, 12);
  if (le32(bytes, 16) != 0x4E4F534Au) fail_file(display, "not a valid .glb file: the first chunk is not JSON");
  if (uint64_t(length) + 20 > bytes.size())
    fail_file(display,
              fmt::format("not a valid .glb file: its JSON chunk of {} bytes runs past the end of the file", length));
  return bytes.substr(20, length);
}

/// The first line of tinygltf's error text.
std::string first_line(std::string s) {
  const size_t nl = s.find('\n');
  if (nl != std::string::npos) s.resize(nl);
  return s.empty() ? "tinygltf could not parse it" : s;
}

/// Checks the uri of buffers[i] or images[i] before tinygltf reads anything.
void check_uri(const nlohmann::json& item, const char* kind, size_t i, const GltfInput& in, const fs::path& root,
               const FileRef& f, const LoadOptions& opts, ReadContext* ctx) {
  if (!item.is_object() || !item.contains("uri") || !item["uri"].is_string()) return;  // tinygltf checks the rest
  const std::string uri = item["uri"].get<std::string>();
  const std::string where = fmt::format("{}[{}]", kind, i);
  if (uri.rfind("data:", 0) == 0) {
    const size_t comma = uri.find(',');
    const size_t payload = comma == std::string::npos ? uri.size() : uri.size() - comma - 1;
    const size_t decoded = payload / 4 * 3;
    if (decoded > kMaxGltfDataUriBytes)
      fail_file(f.display, fmt::format("{}: data URI of about {} bytes, over the limit of {}; put the data in a file "
                                       "next to the glTF",
                                       where, decoded, kMaxGltfDataUriBytes));
    return;
  }
  const FileRef ref = resolve_inside(root, in.dir, in.display_dir, decode_uri(uri), f.display + ": " + where, 0, "uri");
  if (std::strcmp(kind, "buffers") != 0) return;  // images are read with the textures
  if (auto problem = file_problem(ref.real, opts.max_file_bytes))
    fail_file(f.display, fmt::format("{}: uri {} {}", where, quote_token(uri), *problem));
  ctx->allowed.emplace(ref.real, ref);
}

/// What tinygltf would pass over or report without naming the element, checked on the JSON first:
/// extensionsRequired (before anything else: a Draco file's accessors have no bufferView) and the
/// shape of every mesh's primitives (tinygltf skips a "primitives" that is not an array, and a
/// primitive without attributes, which would shift the indices messages name).
void check_structure(const nlohmann::json& doc, const std::string& display) {
  if (doc.contains("extensionsRequired")) {
    const nlohmann::json& req = doc["extensionsRequired"];
    if (!req.is_array()) fail_file(display, "extensionsRequired must be an array of extension names");
    for (const nlohmann::json& ext : req) {
      if (!ext.is_string()) fail_file(display, "extensionsRequired must be an array of extension names");
      const std::string name = ext.get<std::string>();
      if (std::find(std::begin(kSupportedGltfExtensions), std::end(kSupportedGltfExtensions), name) ==
          std::end(kSupportedGltfExtensions))
        fail_file(
            display,
            fmt::format("requires the extension {}, which is not supported{}", quote_token(name),
                        name == "KHR_draco_mesh_compression" ? " (export the meshes without Draco compression)" : ""));
    }
  }
  if (!doc.contains("meshes")) return;
  if (!doc["meshes"].is_array()) fail_file(display, "meshes must be an array");
  for (size_t m = 0; m < doc["meshes"].size(); ++m) {
    const nlohmann::json& mesh = doc["meshes"][m];
    if (!mesh.is_object()) fail_file(display, fmt::format("meshes[{}] must be an object", m));
    if (!mesh.contains("primitives") || !mesh["primitives"].is_array() || mesh["primitives"].empty())
      fail_file(display, fmt::format("meshes[{}]: primitives must be a non-empty array", m));
    for (size_t p = 0; p < mesh["primitives"].size(); ++p) {
      const nlohmann::json& prim = mesh["primitives"][p];
      if (!prim.is_object() || !prim.contains("attributes") || !prim["attributes"].is_object())
        fail_file(display, fmt::format("meshes[{}].primitives[{}] must be an object with attributes", m, p));
    }
  }
}

}  // namespace

std::string decode_uri(const std::string& str) {
  auto hex = [](unsigned char c) -> unsigned char {
    if (c >= '0' && c <= '9') return static_cast<unsigned char>(c - '0');
    if (c >= 'a' && c <= 'f') return static_cast<unsigned char>(c - 'a' + 10);
    if (c >= 'A' && c <= 'F') return static_cast<unsigned char>(c - 'A' + 10);
    return 0;
  };
  std::string out;
  for (size_t i = 0; i < str.size(); ++i) {
    if (str[i] == '+') {
      out += ' ';
    } else if (str[i] == '%' && str.size() > i + 2) {
      out += static_cast<char>((hex(static_cast<unsigned char>(str[i + 1])) << 4) |
                               hex(static_cast<unsigned char>(str[i + 2])));
      i += 2;
    } else {
      out += str[i];
    }
  }
  return out;
}

void read_gltf(const FileRef& f, const fs::path& root, const LoadOptions& opts, LoadReport& report, GltfInput* in) {
  in->dir = f.real.parent_path();
  in->display_dir = fs::path(f.display).parent_path().string();
  const std::string bytes = read_file(f, opts.max_file_bytes, &report);
  const bool binary = bytes.size() >= 4 && bytes.compare(0, 4, "glTF") == 0;
  const std::string json_text = binary ? glb_json(bytes, f.display) : bytes;
  if (json_text.find('\0') != std::string::npos) fail_file(f.display, "NUL byte in the JSON text");

  nlohmann::json doc;
  try {
    doc = nlohmann::json::parse(json_text);
  } catch (const nlohmann::json::parse_error& e) {
    const size_t end = std::min(e.byte > 0 ? e.byte - 1 : 0, json_text.size());
    const size_t line = 1 + size_t(std::count(json_text.begin(), json_text.begin() + std::ptrdiff_t(end), '\n'));
    std::string what = e.what();
    if (const size_t p = what.find("] "); p != std::string::npos) what = what.substr(p + 2);
    fail(f.display, line, "invalid JSON: " + what);
  } catch (const nlohmann::json::exception& e) {
    fail_file(f.display, std::string("invalid JSON: ") + e.what());
  }
  if (!doc.is_object()) fail_file(f.display, "a glTF file must hold a JSON object");
  check_structure(doc, f.display);

  ReadContext ctx;
  ctx.opts = &opts;
  ctx.report = &report;
  ctx.embedded = &in->embedded_images;
  for (const char* kind : {"buffers", "images"}) {
    if (!doc.contains(kind) || !doc[kind].is_array()) continue;
    for (size_t i = 0; i < doc[kind].size(); ++i) check_uri(doc[kind][i], kind, i, *in, root, f, opts, &ctx);
  }

  tinygltf::TinyGLTF parser;
  parser.SetImageLoader(&keep_image_bytes, &ctx);
  parser.SetFsCallbacks({&file_exists, &expand_path, &read_whole_file, &write_whole_file, &ctx});
  std::string err, warnings;
  const std::string base = in->dir.string();
  const bool ok = binary ? parser.LoadBinaryFromMemory(&in->model, &err, &warnings,
                                                       reinterpret_cast<const unsigned char*>(bytes.data()),
                                                       unsigned(bytes.size()), base)
                         : parser.LoadASCIIFromString(&in->model, &err, &warnings, json_text.data(),
                                                      unsigned(json_text.size()), base);
  if (!ctx.error.empty()) throw SceneError(ctx.error);
  if (!ok) fail_file(f.display, "invalid glTF: " + first_line(err));
}

Texture decode_image_bytes(const std::string& bytes, const std::string& name, const std::string& where,
                           const LoadOptions& opts, size_t* pixels, bool alpha, bool linear_data) {
  const char* ext = nullptr;
  if (bytes.size() >= 8 && bytes.compare(0, 4, "\x89PNG") == 0) ext = "embedded.png";
  if (bytes.size() >= 3 && static_cast<unsigned char>(bytes[0]) == 0xFF && static_cast<unsigned char>(bytes[1]) == 0xD8)
    ext = "embedded.jpg";
  if (!ext) fail_file(where, fmt::format("image '{}' is neither PNG nor JPEG", name));
  OIIO::Filesystem::IOMemReader mem(bytes.data(), bytes.size());
  OIIO::ImageSpec config;  // colour as stored, not multiplied by alpha; read through `mem`
  config.attribute("oiio:UnassociatedAlpha", 1);
  OIIO::Filesystem::IOProxy* proxy = &mem;
  config.attribute("oiio:ioproxy", OIIO::TypeDesc::PTR, &proxy);
  auto input = OIIO::ImageInput::open(ext, &config, &mem);
  if (!input) fail_file(where, fmt::format("cannot read image '{}': {}", name, OIIO::geterror()));
  const OIIO::ImageSpec spec = input->spec();
  const double count = double(std::max(spec.width, 0)) * double(std::max(spec.height, 0));
  if (spec.width <= 0 || spec.height <= 0 || spec.nchannels < 1 || spec.nchannels > 16)
    fail_file(where, fmt::format("image '{}' has {} x {} pixels and {} channels", name, spec.width, spec.height,
                                 spec.nchannels));
  if (count + double(*pixels) > double(opts.max_texture_pixels))
    fail_file(where, fmt::format("image '{}' has {} x {} pixels: the scene's textures exceed the limit of {} pixels",
                                 name, spec.width, spec.height, opts.max_texture_pixels));
  std::vector<float> data(size_t(spec.width) * size_t(spec.height) * size_t(spec.nchannels));
  if (!input->read_image(0, 0, 0, spec.nchannels, OIIO::TypeDesc::FLOAT, data.data()))
    fail_file(where, fmt::format("cannot read image '{}': {}", name, input->geterror()));
  // 8- and 16-bit images hold sRGB-encoded colour (glTF's base colour and emissive textures are sRGB).
  const bool srgb = !linear_data && (spec.format == OIIO::TypeDesc::UINT8 || spec.format == OIIO::TypeDesc::UINT16);
  Texture t;
  t.path = name;
  t.width = spec.width;
  t.height = spec.height;
  t.rgb.resize(size_t(spec.width) * size_t(spec.height) * 3);
  const size_t n = size_t(spec.nchannels);
  for (size_t p = 0; p < size_t(spec.width) * size_t(spec.height); ++p)
    for (size_t k = 0; k < 3; ++k) {
      float v = data[p * n + (n >= 3 ? k : 0)];
      if (!std::isfinite(v)) fail_file(where, fmt::format("image '{}' has non-finite texels", name));
      if (srgb) v = v <= 0.04045f ? v / 12.92f : std::pow((v + 0.055f) / 1.055f, 2.4f);
      t.rgb[p * 3 + k] = std::clamp(v, 0.f, 1.f);
    }
  if (alpha) {  // alpha is stored linear
    t.alpha.assign(size_t(spec.width) * size_t(spec.height), 1.f);
    if (n == 2 || n == 4)
      for (size_t p = 0; p < t.alpha.size(); ++p) {
        const float a = data[p * n + n - 1];
        if (!std::isfinite(a)) fail_file(where, fmt::format("image '{}' has non-finite texels", name));
        t.alpha[p] = std::clamp(a, 0.f, 1.f);
      }
  }
  *pixels += size_t(spec.width) * size_t(spec.height);
  return t;
}

}  // namespace epr::loader
