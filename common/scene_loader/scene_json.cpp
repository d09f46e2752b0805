// Scene JSON files (scenes/README.md): an OBJ or glTF inside the file's folder or a built-in scene, plus
// camera and material overrides. Problems raise SceneError naming the file and the line of the
// offending value.
#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <memory>
#include <nlohmann/json.hpp>
#include <string_view>
#include <unordered_map>
#include <vector>

#include "common/builtin_scenes.h"
#include "common/camera_animation.h"
#include "common/scene_loader.h"
#include "common/scene_loader/environment.h"
#include "common/scene_loader/gltf.h"
#include "common/scene_loader/obj.h"
#include "common/scene_loader/path_sandbox.h"
#include "common/scene_loader/text.h"

namespace epr {
namespace {

namespace fs = std::filesystem;
using namespace loader;

// Scene JSON files are a few lines; this keeps a hostile one from costing much memory.
constexpr size_t kMaxJsonBytes = size_t(16) << 20;

std::string pointer_token(std::string_view s) {
  std::string out;
  for (char c : s) {
    if (c == '~')
      out += "~0";
    else if (c == '/')
      out += "~1";
    else
      out += c;
  }
  return out;
}

/// The line each value of an (already parsed) JSON text starts on, by JSON pointer ("/camera/fov"):
/// nlohmann::json keeps no source positions.
class JsonLines {
 public:
  explicit JsonLines(std::string_view text) {
    struct Frame {
      bool object;
      std::string path;
      std::string key;
      size_t index = 0;
      bool expect_key = true;
    };
    // Only the first levels get pointers (the schema is 4 deep): deeper nesting would make the paths
    // grow with the square of the depth.
    constexpr size_t kMaxDepth = 8;
    std::vector<Frame> stack;
    size_t line = 1;
    bool in_scalar = false;
    auto value_path = [&]() -> std::string {
      if (stack.empty()) return "";
      const Frame& f = stack.back();
      if (stack.size() > kMaxDepth) return f.path;
      return f.path + "/" + (f.object ? pointer_token(f.key) : std::to_string(f.index));
    };
    auto record = [&](const std::string& path) {
      if (stack.size() <= kMaxDepth) lines_[path] = line;
    };
    for (size_t i = 0; i < text.size(); ++i) {
      const char c = text[i];
      const bool scalar_char = std::isalnum(static_cast<unsigned char>(c)) || c == '-' || c == '+' || c == '.';
      if (scalar_char) {
        if (!in_scalar) record(value_path());
        in_scalar = true;
        continue;
      }
      in_scalar = false;
      if (c == '\n') {
        ++line;
      } else if (c == '/' && i + 1 < text.size() && text[i + 1] == '/') {
        while (i + 1 < text.size() && text[i + 1] != '\n') ++i;
      } else if (c == '/' && i + 1 < text.size() && text[i + 1] == '*') {
        i += 2;
        while (i + 1 < text.size() && !(text[i] == '*' && text[i + 1] == '/')) line += text[i++] == '\n';
        ++i;
      } else if (c == '"') {
        size_t j = i + 1;
        while (j < text.size() && text[j] != '"') j += text[j] == '\\' ? 2 : 1;
        const std::string_view raw = text.substr(i, std::min(j, text.size() - 1) - i + 1);
        if (!stack.empty() && stack.back().object && stack.back().expect_key) {
          try {
            stack.back().key = nlohmann::json::parse(raw).get<std::string>();
          } catch (const std::exception&) {
            stack.back().key = std::string(raw);
          }
          stack.back().expect_key = false;
        } else {
          record(value_path());
        }
        i = j;
      } else if (c == ',') {
        if (!stack.empty()) {
          if (stack.back().object)
            stack.back().expect_key = true;
          else
            ++stack.back().index;
        }
      } else if (c == '{' || c == '[') {
        const std::string path = value_path();
        record(path);
        stack.push_back({c == '{', path, "", 0, true});
      } else if ((c == '}' || c == ']') && !stack.empty()) {
        stack.pop_back();
      }
    }
  }

  /// Line of the value at `pointer`, or of its nearest recorded ancestor.
  size_t line(std::string pointer) const {
    for (;;) {
      if (auto it = lines_.find(pointer); it != lines_.end()) return it->second;
      if (pointer.empty()) return 1;
      pointer.resize(pointer.rfind('/'));
    }
  }

 private:
  std::unordered_map<std::string, size_t> lines_;
};

class JsonSceneReader {
 public:
  JsonSceneReader(const std::string& path, const LoadOptions& opts, LoadReport& report,
                  CameraAnimation* animation = nullptr)
      : path_(path), opts_(opts), report_(report), animation_(animation) {}

  Scene read() {
    const FileRef self{canonical_or_fail(path_, path_), path_};
    const std::string text = read_file(self, std::min(opts_.max_file_bytes, kMaxJsonBytes), &report_);
    nlohmann::json doc;
    try {
      doc = nlohmann::json::parse(text, nullptr, /*allow_exceptions=*/true, /*ignore_comments=*/true);
    } catch (const nlohmann::json::parse_error& e) {
      fail(path_, line_at_byte(text, e.byte), "invalid JSON: " + json_reason(e));
    } catch (const nlohmann::json::exception& e) {
      // Number overflow ("number overflow parsing '1e999'") carries no position: find the number.
      const std::string what = e.what();
      const size_t open = what.find('\''), close = what.rfind('\'');
      size_t at = 0;
      if (open != std::string::npos && close > open + 1) at = text.find(what.substr(open + 1, close - open - 1));
      fail(path_, at == std::string::npos ? 1 : line_at_byte(text, at + 1), "invalid JSON: " + json_reason(e));
    }
    lines_ = std::make_unique<JsonLines>(text);
    if (!doc.is_object()) error("", "a scene file must be a JSON object");
    check_keys(doc, "",
               {"obj", "builtin", "tessellation", "camera", "materials", "animation", "environment", "sun", "lights"});

    Scene scene;
    std::vector<GlossyDefaults> glossy;
    const bool has_obj = doc.contains("obj"), has_builtin = doc.contains("builtin");
    if (has_obj == has_builtin) error("", "give exactly one of \"obj\" and \"builtin\"");
    if (has_obj) {
      if (doc.contains("tessellation")) error("/tessellation", "\"tessellation\" applies to built-in scenes only");
      const std::string obj = string_at(doc, "/obj");
      const fs::path root = self.real.parent_path();
      const std::string display_dir = fs::path(path_).parent_path().string();
      const FileRef ref = resolve_inside(root, root, display_dir, obj, path_, line("/obj"), "obj");
      if (auto problem = file_problem(ref.real, opts_.max_file_bytes))
        error("/obj", fmt::format("obj file '{}' {}", obj, *problem));
      if (is_gltf_path(obj)) {
        scene = load_gltf_inside(ref, root, opts_, report_);
        for (const Material& m : scene.materials) glossy.push_back({m.ks, m.exponent});
      } else {
        scene = load_obj_inside(ref, root, opts_, report_, &glossy);
      }
    } else {
      BuiltinSpec spec;
      try {
        spec = parse_builtin_spec(string_at(doc, "/builtin"));
        if (doc.contains("tessellation")) {
          const auto& t = doc["tessellation"];
          if (!t.is_number_integer()) error("/tessellation", "\"tessellation\" must be an integer");
          if (spec.tessellation != 1) error("/tessellation", "tessellation given both here and in \"builtin\"");
          spec.tessellation = int(std::clamp<int64_t>(t.get<int64_t>(), -1, 1 << 20));
        }
        scene = make_builtin_scene(spec, opts_.max_triangles);
      } catch (const SceneError& e) {
        if (std::string_view(e.what()).rfind(path_ + ":", 0) == 0) throw;
        fail(path_, line(doc.contains("tessellation") ? "/tessellation" : "/builtin"), e.what());
      }
      for (const Material& m : scene.materials) glossy.push_back({m.ks, m.exponent});
    }
    if (doc.contains("camera")) apply_camera(doc["camera"], &scene.camera);
    if (doc.contains("materials")) apply_materials(doc["materials"], glossy, &scene);
    CameraAnimation animation{path_, {}};
    if (doc.contains("animation")) animation = read_animation(doc["animation"], scene.camera);
    if (animation_) *animation_ = std::move(animation);
    scene.name = path_;
    scene.folder = self.real.parent_path().string();
    if (doc.contains("environment")) scene.lighting.environment = read_environment(doc["environment"], scene.folder);
    if (doc.contains("sun")) scene.lighting.sun = read_sun(doc["sun"], "/sun");
    if (doc.contains("lights")) read_lights(doc["lights"], &scene);
    validate_or_fail(scene, path_);
    return scene;
  }

 private:
  /// nlohmann's message without its "[json.exception.parse_error.101] " tag.
  static std::string json_reason(const nlohmann::json::exception& e) {
    std::string what = e.what();
    if (const size_t p = what.find("] "); what.rfind("[json.exception", 0) == 0 && p != std::string::npos)
      what = what.substr(p + 2);
    return what;
  }

  static size_t line_at_byte(const std::string& text, size_t byte) {
    const size_t end = std::min(byte > 0 ? byte - 1 : 0, text.size());
    return 1 + size_t(std::count(text.begin(), text.begin() + std::ptrdiff_t(end), '\n'));
  }

  size_t line(const std::string& pointer) const { return lines_->line(pointer); }

  [[noreturn]] void error(const std::string& pointer, const std::string& reason) const {
    fail(path_, line(pointer), reason);
  }

  void check_keys(const nlohmann::json& obj, const std::string& pointer, std::initializer_list<const char*> known) {
    for (const auto& item : obj.items()) {
      const std::string& key = item.key();
      if (std::none_of(known.begin(), known.end(), [&](const char* k) { return key == k; }))
        error(pointer + "/" + pointer_token(key),
              fmt::format("unknown key {} (known: {})", quote_token(key), fmt::join(known, ", ")));
    }
  }

  std::string string_at(const nlohmann::json& doc, const std::string& pointer) {
    const auto& v = doc.at(nlohmann::json::json_pointer(pointer));
    if (!v.is_string()) error(pointer, fmt::format("\"{}\" must be a string", pointer.substr(1)));
    return v.get<std::string>();
  }

  float number_at(const nlohmann::json& v, const std::string& pointer, const char* what) {
    if (!v.is_number()) error(pointer, fmt::format("{} must be a number", what));
    const double d = v.get<double>();
    if (!std::isfinite(d) || std::abs(d) > 1e30) error(pointer, fmt::format("{} is out of range", what));
    return float(d);
  }

  Vec3 vec3_at(const nlohmann::json& v, const std::string& pointer, const char* what) {
    if (!v.is_array() || v.size() != 3) error(pointer, fmt::format("{} must be an array of 3 numbers", what));
    Vec3 out;
    for (int k = 0; k < 3; ++k) out[k] = number_at(v[size_t(k)], pointer + "/" + std::to_string(k), what);
    return out;
  }

  Vec3 colour_at(const nlohmann::json& v, const std::string& pointer, const char* what, float hi) {
    const Vec3 c = vec3_at(v, pointer, what);
    if (!(c.x >= 0 && c.y >= 0 && c.z >= 0 && c.x <= hi && c.y <= hi && c.z <= hi))
      error(pointer, fmt::format("{} values must lie in [0, {}]", what, hi));
    return c;
  }

  void apply_camera(const nlohmann::json& cam, CameraSpec* spec) {
    if (!cam.is_object()) error("/camera", "\"camera\" must be an object");
    check_keys(cam, "/camera", {"eye", "look", "up", "fov"});
    if (cam.contains("eye")) spec->eye = vec3_at(cam["eye"], "/camera/eye", "camera eye");
    if (cam.contains("look")) spec->look = vec3_at(cam["look"], "/camera/look", "camera look");
    if (cam.contains("up")) spec->up = vec3_at(cam["up"], "/camera/up", "camera up");
    if (cam.contains("fov")) spec->fov_y_degrees = number_at(cam["fov"], "/camera/fov", "camera fov");
    if (auto reason = spec->validate()) error("/camera", *reason);
  }

  // "animation": {"camera": [{"frame": F, "eye": ..., "look": ..., "up": ..., "fov": ...}, ...]}; each
  // key's missing fields come from the key before it (the first key's from `still`).
  CameraAnimation read_animation(const nlohmann::json& anim, const CameraSpec& still) {
    if (!anim.is_object()) error("/animation", "\"animation\" must be an object");
    check_keys(anim, "/animation", {"camera"});
    CameraAnimation out{path_, {}};
    if (!anim.contains("camera")) return out;
    const auto& keys = anim["camera"];
    const std::string base = "/animation/camera";
    if (!keys.is_array() || keys.empty())
      error(base, "animation camera must be an array of keys like {\"frame\": 1, \"eye\": [0, 1, 4]}");
    CameraSpec previous = still;
    for (size_t i = 0; i < keys.size(); ++i) {
      const auto& k = keys[i];
      const std::string p = base + "/" + std::to_string(i);
      if (!k.is_object()) error(p, "a camera key must be an object like {\"frame\": 1, \"eye\": [0, 1, 4]}");
      check_keys(k, p, {"frame", "eye", "look", "up", "fov"});
      if (!k.contains("frame")) error(p, "camera key has no \"frame\"");
      const auto& f = k["frame"];
      if (!f.is_number_integer() || f.get<int64_t>() < 0 || f.get<int64_t>() > int64_t(kMaxFrame))
        error(p + "/frame", fmt::format("camera key frame must be an integer from 0 to {}", kMaxFrame));
      CameraKey key{uint32_t(f.get<int64_t>()), previous, line(p)};
      if (!out.keys.empty() && key.frame <= out.keys.back().frame)
        error(p + "/frame", fmt::format("camera key frame {} does not come after frame {} (line {}): keys go in "
                                        "increasing frame order",
                                        key.frame, out.keys.back().frame, out.keys.back().line));
      if (k.contains("eye")) key.camera.eye = vec3_at(k["eye"], p + "/eye", "camera key eye");
      if (k.contains("look")) key.camera.look = vec3_at(k["look"], p + "/look", "camera key look");
      if (k.contains("up")) key.camera.up = vec3_at(k["up"], p + "/up", "camera key up");
      if (k.contains("fov")) key.camera.fov_y_degrees = number_at(k["fov"], p + "/fov", "camera key fov");
      if (auto reason = key.camera.validate()) error(p, fmt::format("camera key at frame {}: {}", key.frame, *reason));
      previous = key.camera;
      out.keys.push_back(key);
    }
    return out;
  }

  // "environment": {"color": [r, g, b]} or {"image": "sky.hdr"}, with "strength" and "rotation_deg".
  EnvironmentLight read_environment(const nlohmann::json& env, const std::string& folder) {
    const std::string p = "/environment";
    if (!env.is_object())
      error(p, "\"environment\" must be an object like {\"color\": [1, 1, 1]} or {\"image\": \"sky.hdr\"}");
    check_keys(env, p, {"color", "image", "strength", "rotation_deg"});
    if (env.contains("color") == env.contains("image"))
      error(p, "give exactly one of \"color\" and \"image\" for the environment");
    EnvironmentLight e;
    if (env.contains("color")) e.color = colour_at(env["color"], p + "/color", "environment color", 1e6f);
    if (env.contains("strength")) {
      e.strength = number_at(env["strength"], p + "/strength", "environment strength");
      if (!(e.strength >= 0 && e.strength <= 1e6f)) error(p + "/strength", "environment strength must lie in [0, 1e6]");
    }
    if (env.contains("rotation_deg"))
      e.rotation_deg = number_at(env["rotation_deg"], p + "/rotation_deg", "environment rotation_deg");
    if (env.contains("image")) {
      if (!env["image"].is_string()) error(p + "/image", "environment image must be a string (a file name)");
      e.image = env["image"].get<std::string>();
      load_environment_image(e, folder, fmt::format("{}:{}", path_, line(p + "/image")), &report_);
    }
    return e;
  }

  // "sun": {"direction": [x, y, z], "angle_deg": 0.53, "irradiance": E or [r, g, b]} ("radiance" instead
  // of "irradiance" gives the disc's radiance).
  SunLight read_sun(const nlohmann::json& sun, const std::string& p, bool typed = false) {
    if (!sun.is_object()) error(p, "\"sun\" must be an object like {\"direction\": [1, 2, 1], \"irradiance\": 3}");
    if (typed)
      check_keys(sun, p, {"type", "name", "direction", "angle_deg", "irradiance", "radiance"});
    else
      check_keys(sun, p, {"direction", "angle_deg", "irradiance", "radiance"});
    if (!sun.contains("direction")) error(p, "the sun needs a \"direction\" (towards the sun)");
    if (sun.contains("irradiance") && sun.contains("radiance"))
      error(p, "give at most one of \"irradiance\" and \"radiance\" for the sun");
    SunLight s;
    s.direction = vec3_at(sun["direction"], p + "/direction", "sun direction");
    if (sun.contains("angle_deg")) s.angle_deg = number_at(sun["angle_deg"], p + "/angle_deg", "sun angle_deg");
    const auto colour_or_grey = [&](const char* key) {
      const auto& v = sun[key];
      const std::string at = p + "/" + key;
      if (v.is_number()) {
        const float g = number_at(v, at, key);
        if (!(g >= 0)) error(at, fmt::format("sun {} must be >= 0", key));
        return Vec3(g);
      }
      return colour_at(v, at, key, 1e9f);
    };
    if (sun.contains("irradiance")) s.irradiance = colour_or_grey("irradiance");
    if (auto reason = check_sun(s)) error(p, *reason);
    s.direction = normalize(s.direction);
    if (sun.contains("radiance")) {
      const float h = std::sin(0.5f * s.angle_deg * kPi / 180);
      s.irradiance = colour_or_grey("radiance") * (kPi * h * h);
    }
    return s;
  }

  // "lights": [{"type": "point" | "spot" | "sun" | "area", ...}] (scenes/README.md, "Lamps").
  void read_lights(const nlohmann::json& lights, Scene* scene) {
    if (!lights.is_array()) error("/lights", "\"lights\" must be an array of lights like {\"type\": \"point\", ...}");
    constexpr size_t kMaxLights = 4096;
    if (lights.size() > kMaxLights) error("/lights", fmt::format("at most {} lights", kMaxLights));
    for (size_t i = 0; i < lights.size(); ++i) {
      const nlohmann::json& o = lights[i];
      const std::string p = "/lights/" + std::to_string(i);
      if (scene->triangle_count() > opts_.max_triangles)
        error(p, fmt::format("the lamps' triangles exceed the limit of {} triangles", opts_.max_triangles));
      if (!o.is_object() || !o.contains("type") || !o["type"].is_string())
        error(p, "a light must be an object with a \"type\": \"point\", \"spot\", \"sun\" or \"area\"");
      const std::string type = o["type"].get<std::string>();
      const std::string name =
          o.contains("name") && o["name"].is_string() ? o["name"].get<std::string>() : fmt::format("light {}", i);
      const auto grey_or_rgb = [&](const char* key) {
        const std::string at = p + "/" + key;
        if (o[key].is_number()) {
          const float g = number_at(o[key], at, key);
          if (!(g >= 0)) error(at, fmt::format("light {} must be >= 0", key));
          return Vec3(g);
        }
        return colour_at(o[key], at, key, 1e12f);
      };
      // Power (W, Blender's and Cycles' unit) or the radiometric quantity itself.
      const auto strength = [&](const char* direct) {
        if (o.contains("power") == o.contains(direct))
          error(p, fmt::format("give exactly one of \"power\" and \"{}\" for light '{}'", direct, name));
        return o.contains("power") ? std::pair{grey_or_rgb("power"), true} : std::pair{grey_or_rgb(direct), false};
      };
      PunctualLight l;
      l.name = name;
      if (type == "sun") {
        const SunLight sun = read_sun(o, p, true);
        l.type = LightType::kDirectional;
        l.direction = sun.direction;
        l.angle_deg = sun.angle_deg;
        l.intensity = sun.irradiance;
      } else if (type == "point" || type == "spot") {
        if (type == "point")
          check_keys(o, p, {"type", "name", "position", "power", "intensity", "radius"});
        else
          check_keys(o, p,
                     {"type", "name", "position", "direction", "power", "intensity", "spot_size_deg", "spot_blend",
                      "inner_cone_deg", "outer_cone_deg"});
        if (!o.contains("position")) error(p, fmt::format("light '{}' needs a \"position\"", name));
        l.position = vec3_at(o["position"], p + "/position", "light position");
        // Cycles' point and spot lamp of power P: intensity P / (4 pi) W/sr (a spot's cone does not
        // concentrate it).
        const auto [value, is_power] = strength("intensity");
        l.intensity = is_power ? value / (4 * kPi) : value;
        if (type == "spot") read_spot(o, p, &l);
        const float radius = o.contains("radius") ? number_at(o["radius"], p + "/radius", "light radius") : 0.f;
        if (!(radius >= 0)) error(p + "/radius", "light radius must be >= 0");
        if (radius > 0) {
          if (auto reason = check_light(l)) error(p, fmt::format("light '{}': {}", name, *reason));
          add_sphere_lamp(l, radius, scene);
          continue;
        }
      } else if (type == "area") {
        check_keys(o, p, {"type", "name", "corners", "power", "radiance"});
        add_area_lamp(o, p, name, strength("radiance"), scene);
        continue;
      } else {
        error(p + "/type", fmt::format("unknown light type {} (point, spot, sun, area)", quote_token(type)));
      }
      if (auto reason = check_light(l)) error(p, fmt::format("light '{}': {}", name, *reason));
      scene->lights.push_back(l);
    }
  }

  // A spot's cone: Blender's "spot_size_deg" (the full angle) and "spot_blend" (Cycles' falloff), or
  // glTF's half angles "inner_cone_deg" and "outer_cone_deg" (glTF's falloff).
  void read_spot(const nlohmann::json& o, const std::string& p, PunctualLight* l) {
    l->type = LightType::kSpot;
    if (!o.contains("direction")) error(p, fmt::format("spot '{}' needs a \"direction\" (the way it shines)", l->name));
    const Vec3 d = vec3_at(o["direction"], p + "/direction", "spot direction");
    if (!(length(d) > 0)) error(p + "/direction", "spot direction must not be 0");
    l->direction = normalize(d);
    const float rad = kPi / 180;
    if (o.contains("spot_size_deg")) {
      const float size = number_at(o["spot_size_deg"], p + "/spot_size_deg", "spot_size_deg");
      if (!(size > 0 && size <= 180)) error(p + "/spot_size_deg", "spot_size_deg must be in (0, 180]");
      const float blend = o.contains("spot_blend") ? number_at(o["spot_blend"], p + "/spot_blend", "spot_blend") : 0.f;
      if (!(blend >= 0 && blend <= 1)) error(p + "/spot_blend", "spot_blend must be in [0, 1]");
      l->falloff = SpotFalloff::kBlender;
      l->cos_outer = std::max(0.f, std::cos(0.5f * size * rad));
      l->cos_inner = l->cos_outer + (1 - l->cos_outer) * blend;
    } else if (o.contains("outer_cone_deg")) {
      const float outer = number_at(o["outer_cone_deg"], p + "/outer_cone_deg", "outer_cone_deg");
      const float inner =
          o.contains("inner_cone_deg") ? number_at(o["inner_cone_deg"], p + "/inner_cone_deg", "inner_cone_deg") : 0.f;
      if (!(inner >= 0 && inner < outer && outer <= 90))
        error(p, "spot cone angles must satisfy 0 <= inner_cone_deg < outer_cone_deg <= 90");
      l->cos_inner = std::cos(inner * rad);
      l->cos_outer = std::max(0.f, std::cos(outer * rad));
    } else {
      error(p, fmt::format("spot '{}' needs \"spot_size_deg\" (and \"spot_blend\") or \"outer_cone_deg\"", l->name));
    }
  }

  // A point lamp with a radius: an emitting sphere (an icosahedron subdivided twice, 320 triangles,
  // front side out) of the same power, radiance P / (pi A) with A the triangles' area (a convex
  // Lambertian emitter of power P). A spot with a radius stays a point (read_lights refuses none:
  // the add-on warns).
  void add_sphere_lamp(const PunctualLight& l, float radius, Scene* scene) {
    std::vector<std::array<Vec3, 3>> tris;
    const float t = (1 + std::sqrt(5.f)) / 2;
    const Vec3 v[12] = {{-1, t, 0},  {1, t, 0},  {-1, -t, 0}, {1, -t, 0}, {0, -1, t},  {0, 1, t},
                        {0, -1, -t}, {0, 1, -t}, {t, 0, -1},  {t, 0, 1},  {-t, 0, -1}, {-t, 0, 1}};
    const int f[20][3] = {{0, 11, 5},  {0, 5, 1},  {0, 1, 7},  {0, 7, 10}, {0, 10, 11}, {1, 5, 9}, {5, 11, 4},
                          {11, 10, 2}, {10, 7, 6}, {7, 1, 8},  {3, 9, 4},  {3, 4, 2},   {3, 2, 6}, {3, 6, 8},
                          {3, 8, 9},   {4, 9, 5},  {2, 4, 11}, {6, 2, 10}, {8, 6, 7},   {9, 8, 1}};
    for (const auto& c : f) tris.push_back({normalize(v[c[0]]), normalize(v[c[1]]), normalize(v[c[2]])});
    for (int level = 0; level < 2; ++level) {
      std::vector<std::array<Vec3, 3>> finer;
      for (const auto& [a, b, c] : tris) {
        const Vec3 ab = normalize(a + b), bc = normalize(b + c), ca = normalize(c + a);
        finer.push_back({a, ab, ca});
        finer.push_back({ab, b, bc});
        finer.push_back({ca, bc, c});
        finer.push_back({ab, bc, ca});
      }
      tris = std::move(finer);
    }
    double area = 0;
    for (auto& tri : tris) {
      for (Vec3& c : tri) c = l.position + c * radius;
      area += 0.5 * length(cross(tri[1] - tri[0], tri[2] - tri[0]));
    }
    add_lamp_triangles(l.name, l.intensity * float(4 * kPi / (kPi * area)), tris, scene);
  }

  // An area lamp: a planar convex polygon of "corners" (counter-clockwise seen from the side it lights,
  // its front; Blender's square, rectangle, disk and ellipse), one-sided, of radiance "radiance" or
  // power / (4 A): Cycles' area lamp (its kernel's 0.25 / area, measured with Blender 3.4; not
  // P / (pi A)), whose emitted flux is pi P / 4.
  void add_area_lamp(const nlohmann::json& o, const std::string& p, const std::string& name,
                     std::pair<Vec3, bool> strength, Scene* scene) {
    if (!o.contains("corners") || !o["corners"].is_array() || o["corners"].size() < 3 || o["corners"].size() > 256)
      error(p, fmt::format("area light '{}' needs \"corners\": 3 to 256 points of a convex polygon", name));
    std::vector<Vec3> c;
    for (size_t k = 0; k < o["corners"].size(); ++k)
      c.push_back(vec3_at(o["corners"][k], p + "/corners/" + std::to_string(k), "area light corner"));
    std::vector<std::array<Vec3, 3>> tris;
    double area = 0;
    for (size_t k = 1; k + 1 < c.size(); ++k) {
      tris.push_back({c[0], c[k], c[k + 1]});
      area += 0.5 * length(cross(c[k] - c[0], c[k + 1] - c[0]));
    }
    if (!(area > 0) || !std::isfinite(area)) error(p + "/corners", fmt::format("area light '{}' has no area", name));
    add_lamp_triangles(name, strength.second ? strength.first / float(4 * area) : strength.first, tris, scene);
  }

  void add_lamp_triangles(const std::string& name, Vec3 radiance, const std::vector<std::array<Vec3, 3>>& tris,
                          Scene* scene) {
    Material m;
    m.name = "lamp '" + name + "'";
    m.kd = Vec3(0.f);
    m.ke = radiance;
    m.emits_front_only = true;
    const uint32_t id = add_material(*scene, m);
    for (const auto& [a, b, c] : tris) add_triangle(*scene, a, b, c, id);
  }

  void apply_materials(const nlohmann::json& mats, const std::vector<GlossyDefaults>& glossy, Scene* scene) {
    if (!mats.is_object()) error("/materials", "\"materials\" must be an object");
    for (const auto& item : mats.items()) {
      const std::string& name = item.key();
      const nlohmann::json& o = item.value();
      const std::string p = "/materials/" + pointer_token(name);
      const auto named = [&](const Material& m) { return m.name == name; };
      if (std::none_of(scene->materials.begin(), scene->materials.end(), named)) {
        std::vector<std::string> names;
        for (const Material& m : scene->materials)
          if (names.size() < 20) names.push_back(m.name);
        error(p, fmt::format("no material named '{}' in the scene (it has: {})", name, fmt::join(names, ", ")));
      }
      if (!o.is_object()) error(p, fmt::format("material override '{}' must be an object", name));
      check_keys(o, p, {"kd", "ke", "emit", "type", "ks", "exponent"});
      if (o.contains("emit") && o["emit"] != "front" && o["emit"] != "both")
        error(p + "/emit", "emit must be \"front\" (Ke leaves the front side only) or \"both\"");
      for (size_t i = 0; i < scene->materials.size(); ++i) {
        Material& m = scene->materials[i];
        if (m.name != name) continue;
        if (o.contains("kd")) {
          m.kd = colour_at(o["kd"], p + "/kd", "kd", 1.f);
          m.kd_texture = -1;  // a constant kd replaces the texture
        }
        if (o.contains("ke")) m.ke = colour_at(o["ke"], p + "/ke", "ke", 1e6f);
        if (o.contains("emit")) m.emits_front_only = o["emit"] == "front";
        if (o.contains("type")) {
          const auto& t = o["type"];
          if (t == "glossy") {
            if (m.type != MaterialType::kGlossy) {  // start from the MTL's Ks and Ns
              m.type = MaterialType::kGlossy;
              m.ks = i < glossy.size() ? glossy[i].ks : Vec3(0.f);
              m.exponent = i < glossy.size() ? glossy[i].exponent : Material{}.exponent;
            }
          } else if (t == "diffuse") {  // also makes a glTF material Lambertian (and reprojectable)
            m.type = MaterialType::kDiffuse;
            m.ks = Vec3(0.f);
            m.metallic_roughness_texture = -1;
          } else {
            error(p + "/type", "material type must be \"diffuse\" or \"glossy\"");
          }
        }
        if (o.contains("ks") || o.contains("exponent")) {
          if (m.type != MaterialType::kGlossy)
            error(p + (o.contains("ks") ? "/ks" : "/exponent"),
                  fmt::format("material '{}' is not glossy: add \"type\": \"glossy\" to use ks and exponent", name));
          if (o.contains("ks")) m.ks = colour_at(o["ks"], p + "/ks", "ks", 1.f);
          if (o.contains("exponent")) {
            m.exponent = number_at(o["exponent"], p + "/exponent", "exponent");
            if (!(m.exponent > 0.f && m.exponent <= 1e6f)) error(p + "/exponent", "exponent must lie in (0, 1e6]");
          }
        }
        if (m.type == MaterialType::kGlossy && is_black(m.ks))
          warn(report_,
               fmt::format("{}:{}: glossy material '{}' has ks 0 and renders as diffuse", path_, line(p), name));
        if (m.type != MaterialType::kMicrofacet && max_component(m.kd + m.ks) > 1.f)
          warn(report_,
               fmt::format("{}:{}: material '{}' reflects more than it receives (kd + ks > 1)", path_, line(p), name));
      }
    }
  }

  std::string path_;
  const LoadOptions& opts_;
  LoadReport& report_;
  std::unique_ptr<JsonLines> lines_;
  CameraAnimation* animation_ = nullptr;
};

}  // namespace

Scene load_scene_json(const std::string& json_path, const LoadOptions& opts, LoadReport* report) {
  LoadReport local;
  return JsonSceneReader(json_path, opts, report ? *report : local).read();
}

CameraAnimation load_camera_animation(const std::string& spec, const LoadOptions& opts, CameraSpec* still) {
  CameraAnimation animation{spec, {}};
  std::string ext = fs::path(spec).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  if (spec.rfind("builtin:", 0) == 0 || ext != ".json") {  // OBJ files carry no camera (load_obj)
    if (still)
      *still = spec.rfind("builtin:", 0) == 0 || is_gltf_path(spec) ? load_scene(spec, opts).camera : CameraSpec{};
    return animation;
  }
  LoadReport report;
  const Scene scene = JsonSceneReader(spec, opts, report, &animation).read();
  if (still) *still = scene.camera;
  return animation;
}

}  // namespace epr
