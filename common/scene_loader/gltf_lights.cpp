// Units. KHR_lights_punctual gives a point or spot light's luminous intensity in candela (lm/sr) and a
// directional light's illuminance in lux (lm/m^2). The scene's lights are radiometric (W/sr, W/m^2,
// common/lights.h). Following the extension's own note (a watt is 683 lumens at 555 nm) and Blender's
// glTF importer (io_scene_gltf2, PBR_WATTS_TO_LUMENS = 683 in its default "Standard" lighting mode: a
// point lamp of 4 pi cd / 683 W, a sun of lux / 683 W/m^2), so that Cycles renders an imported file as
// the farm does (Cycles' point lamp of power P has intensity P / (4 pi) W/sr):
//     intensity (W/sr) = candela / 683 x color,   irradiance (W/m^2) = lux / 683 x color.
// The spot's cone uses glTF's smooth falloff (SpotFalloff::kGltf).
#include "common/scene_loader/gltf_lights.h"

#include <fmt/format.h>

#include <cmath>

#include "common/scene_loader/text.h"

namespace epr::loader {
namespace {

constexpr double kLumensPerWatt = 683;
constexpr const char* kExtension = "KHR_lights_punctual";

}  // namespace

std::vector<PunctualLight> read_gltf_lights(const tinygltf::Model& model, const std::string& display,
                                            std::vector<std::string>* notes) {
  std::vector<PunctualLight> out;
  for (size_t i = 0; i < model.lights.size(); ++i) {
    const tinygltf::Light& g = model.lights[i];
    const std::string where = g.name.empty() ? fmt::format("{}.lights[{}]", kExtension, i)
                                             : fmt::format("{}.lights[{}] ('{}')", kExtension, i, g.name);
    const auto bad = [&](const std::string& reason) { fail_file(display, fmt::format("{}: {}", where, reason)); };
    PunctualLight l;
    l.name = g.name.empty() ? fmt::format("light {}", i) : g.name;
    if (g.type == "point")
      l.type = LightType::kPoint;
    else if (g.type == "spot")
      l.type = LightType::kSpot;
    else if (g.type == "directional")
      l.type = LightType::kDirectional;
    else
      bad(fmt::format("unknown type {} (point, spot, directional)", quote_token(g.type)));
    Vec3 color(1.f);
    if (!g.color.empty()) {
      if (g.color.size() != 3) bad("color must have 3 numbers");
      for (int k = 0; k < 3; ++k) {
        const double c = g.color[size_t(k)];
        if (!(std::isfinite(c) && c >= 0 && c <= 1e6)) bad(fmt::format("color[{}] must be >= 0, got {:g}", k, c));
        color[k] = float(c);
      }
    }
    if (!(std::isfinite(g.intensity) && g.intensity >= 0 && g.intensity <= 1e15))
      bad(fmt::format("intensity must be >= 0 ({}), got {:g}", l.type == LightType::kDirectional ? "lux" : "candela",
                      g.intensity));
    l.intensity = color * float(g.intensity / kLumensPerWatt);
    if (l.type == LightType::kSpot) {
      const double inner = g.spot.innerConeAngle, outer = g.spot.outerConeAngle;
      if (!(std::isfinite(inner) && std::isfinite(outer) && inner >= 0 && inner < outer && outer <= kPi / 2 + 1e-6))
        bad(
            fmt::format("spot cone angles must satisfy 0 <= innerConeAngle < outerConeAngle <= pi/2, got "
                        "innerConeAngle {:g}, outerConeAngle {:g}",
                        inner, outer));
      l.cos_inner = float(std::cos(inner));
      l.cos_outer = float(std::cos(std::min(outer, double(kPi) / 2)));
    }
    if (g.range != 0) {
      if (!(std::isfinite(g.range) && g.range > 0)) bad(fmt::format("range must be > 0, got {:g}", g.range));
      if (l.type != LightType::kDirectional)
        notes->push_back(fmt::format("{}: range ignored (the light falls off as 1/d^2 without a cut-off)", where));
    }
    l.direction = l.type == LightType::kDirectional ? Vec3(0, 0, 1) : Vec3(0, 0, -1);
    out.push_back(l);
  }
  return out;
}

void place_gltf_light(const tinygltf::Node& node, int n, const std::array<double, 16>& world,
                      const std::vector<PunctualLight>& lights, const std::string& display,
                      std::vector<PunctualLight>* out) {
  const auto ext = node.extensions.find(kExtension);
  if (ext == node.extensions.end()) return;
  const tinygltf::Value& v = ext->second;
  if (!v.IsObject() || !v.Has("light") || !v.Get("light").IsNumber())
    fail_file(display, fmt::format("nodes[{}]: {} must be an object like {{\"light\": 0}}", n, kExtension));
  const double index = v.Get("light").GetNumberAsDouble();
  if (!(index >= 0 && index < double(lights.size()) && index == std::floor(index)))
    fail_file(display, fmt::format("nodes[{}]: light {:g} does not exist ({} lights in {})", n, index, lights.size(),
                                   kExtension));
  PunctualLight l = lights[size_t(index)];
  const auto& m = world;
  // Lights sit at the node's origin; a spot shines along its local -Z, a directional light too (so the
  // direction towards it is +Z).
  const Vec3 origin{float(m[12]), float(m[13]), float(m[14])};
  const Vec3 z{float(m[8]), float(m[9]), float(m[10])};
  if (l.type != LightType::kDirectional) l.position = origin;
  if (l.type != LightType::kPoint) {
    const float len = length(z);
    if (!(len > 0) || !std::isfinite(len))
      fail_file(display, fmt::format("nodes[{}]: light '{}' has a degenerate orientation (its Z axis has length {:g})",
                                     n, l.name, len));
    l.direction = l.type == LightType::kDirectional ? z / len : -z / len;
  }
  if (auto reason = check_light(l)) fail_file(display, fmt::format("nodes[{}]: light '{}': {}", n, l.name, *reason));
  out->push_back(l);
}

}  // namespace epr::loader
