#include "common/lights.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

#include "common/limits.h"

namespace epr {

float PunctualLight::spot_scale(float c) const {
  if (type != LightType::kSpot) return 1;
  if (!(c > cos_outer)) return 0;
  const float width = cos_inner - cos_outer;
  const float t = width > 0 ? std::min((c - cos_outer) / width, 1.f) : 1.f;
  if (falloff == SpotFalloff::kGltf) return t * t;
  return c * t * t * (3 - 2 * t);
}

Vec3 PunctualLight::intensity_towards(const Vec3& d) const {
  return type == LightType::kSpot ? intensity * spot_scale(dot(d, direction)) : intensity;
}

SunLight PunctualLight::as_sun() const {
  SunLight s;
  s.direction = direction;
  s.angle_deg = std::max(angle_deg, limits::kMinSunAngleDeg);
  s.irradiance = intensity;
  return s;
}

double PunctualLight::power() const {
  const double i = luminance(intensity);
  if (type == LightType::kPoint) return 4 * kPi * i;
  if (type == LightType::kSpot) return 2 * kPi * (1 - double(cos_outer)) * i;
  return 0;
}

std::optional<std::string> check_light(const PunctualLight& l) {
  if (!is_finite(l.intensity) || !(l.intensity.x >= 0 && l.intensity.y >= 0 && l.intensity.z >= 0) ||
      max_component(l.intensity) > 1e12f)
    return fmt::format("{} must be finite and >= 0 (at most 1e12), got ({:g}, {:g}, {:g})",
                       l.type == LightType::kDirectional ? "irradiance" : "intensity", l.intensity.x, l.intensity.y,
                       l.intensity.z);
  if (l.type != LightType::kDirectional && !limits::within_coordinate_limit(l.position.x, l.position.y, l.position.z))
    return fmt::format("position ({:g}, {:g}, {:g}) is not finite or exceeds the coordinate limit", l.position.x,
                       l.position.y, l.position.z);
  if (l.type != LightType::kPoint && !(is_finite(l.direction) && std::abs(length(l.direction) - 1) < 1e-3f))
    return "direction must be a finite non-zero vector";
  if (l.type == LightType::kSpot &&
      !(l.cos_outer >= -1e-6f && l.cos_outer < 1 && l.cos_inner >= l.cos_outer && l.cos_inner <= 1))
    return "cone angles must satisfy 0 <= inner <= outer <= 90 degrees with outer > 0";
  if (l.type == LightType::kDirectional && !(l.angle_deg >= 0 && l.angle_deg <= 90))
    return fmt::format("angle_deg (angular diameter) must be in [0, 90], got {:g}", l.angle_deg);
  return std::nullopt;
}

bool lit_from_outside(const Lighting& lighting, std::span<const PunctualLight> lights) {
  return lighting.lights() || std::any_of(lights.begin(), lights.end(), [](const PunctualLight& l) {
           return l.type == LightType::kDirectional && luminance(l.intensity) > 0;
         });
}

}  // namespace epr
