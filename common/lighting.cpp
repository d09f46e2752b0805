#include "common/lighting.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <vector>

#include "common/limits.h"

namespace epr {
namespace {

constexpr float kDegrees = kPi / 180;

// Comma-separated finite numbers; empty if `s` is anything else.
std::vector<float> parse_numbers(const std::string& s) {
  std::vector<float> out;
  size_t at = 0;
  while (at <= s.size()) {
    const size_t comma = std::min(s.find(',', at), s.size());
    const std::string part = s.substr(at, comma - at);
    float v;
    char extra;
    if (part.empty() || std::sscanf(part.c_str(), "%f%c", &v, &extra) != 1 || !std::isfinite(v)) return {};
    out.push_back(v);
    at = comma + 1;
  }
  return out;
}

}  // namespace

Vec3 EnvironmentLight::radiance(const Vec3& d) const {
  if (!pixels) return color * strength;
  const Vec2 ut = direction_to_equirect(d, rotation_deg * kDegrees);
  const int x = std::clamp(int(ut.x * float(pixels->width)), 0, pixels->width - 1);
  const int y = std::clamp(int(ut.y * float(pixels->height)), 0, pixels->height - 1);
  return pixels->rgb(x, y) * strength;
}

Vec3 SunLight::radiance() const {
  const float s = std::sin(0.5f * angle_deg * kDegrees);
  return irradiance / (kPi * s * s);
}

float SunLight::cos_half_angle() const { return std::cos(0.5f * angle_deg * kDegrees); }

bool Lighting::lights() const {
  const bool env = environment && environment->strength > 0 && (environment->pixels || !is_black(environment->color));
  const bool sun_lights = sun && !is_black(sun->irradiance);
  return env || sun_lights;
}

Vec2 direction_to_equirect(const Vec3& d, float rotation) {
  float u = 0.5f + (std::atan2(d.z, d.x) - rotation) * (0.5f * kInvPi);
  u -= std::floor(u);
  const float t = std::acos(std::clamp(d.y, -1.f, 1.f)) * kInvPi;
  return {u, t};
}

Vec3 equirect_to_direction(Vec2 ut, float rotation) {
  const float phi = 2 * kPi * (ut.x - 0.5f) + rotation, theta = kPi * ut.y;
  const float s = std::sin(theta);
  return {s * std::cos(phi), std::cos(theta), s * std::sin(phi)};
}

EnvironmentLight parse_env_flag(const std::string& value, std::string* file) {
  EnvironmentLight e;
  file->clear();
  if (value.empty()) throw std::invalid_argument("--env: expects an image file (.hdr, .exr) or a colour R,G,B");
  const std::vector<float> n = parse_numbers(value);
  const bool numeric = value.find_first_not_of("0123456789+-.,eE ") == std::string::npos;
  if (numeric) {
    if (n.size() == 1)
      e.color = Vec3(n[0]);
    else if (n.size() == 3)
      e.color = {n[0], n[1], n[2]};
    else
      throw std::invalid_argument(fmt::format(
          "--env '{}': a colour is one number (a grey) or three, R,G,B, finite and >= 0, e.g. --env 1,1,1", value));
    if (auto err = check_environment(e)) throw std::invalid_argument("--env: " + *err);
    return e;
  }
  *file = value;
  e.image = value;
  return e;
}

SunLight parse_sun_flag(const std::string& value) {
  const std::vector<float> n = parse_numbers(value);
  if (n.size() != 3 && n.size() != 4 && n.size() != 5 && n.size() != 7)
    throw std::invalid_argument(fmt::format(
        "--sun '{}': expects DX,DY,DZ[,ANGLE_DEG[,E or ,R,G,B]]: the direction towards the sun, its angular "
        "diameter in degrees (default 0.53) and its irradiance in W/m^2 (default 1), e.g. --sun 1,2,0.5,0.53,3",
        value));
  SunLight s;
  s.direction = {n[0], n[1], n[2]};
  if (n.size() >= 4) s.angle_deg = n[3];
  if (n.size() == 5) s.irradiance = Vec3(n[4]);
  if (n.size() == 7) s.irradiance = {n[4], n[5], n[6]};
  if (auto err = check_sun(s)) throw std::invalid_argument("--sun: " + *err);
  s.direction = normalize(s.direction);
  return s;
}

std::optional<std::string> check_environment(const EnvironmentLight& e) {
  if (!is_finite(e.color) || e.color.x < 0 || e.color.y < 0 || e.color.z < 0 ||
      max_component(e.color) > limits::kMaxColour)
    return "environment colour values must be finite and in [0, 1e6]";
  if (!std::isfinite(e.strength) || e.strength < 0 || e.strength > 1e6f)
    return "environment strength must be finite and in [0, 1e6]";
  if (!std::isfinite(e.rotation_deg) || std::abs(e.rotation_deg) > 1e6f) return "environment rotation must be finite";
  return std::nullopt;
}

std::optional<std::string> check_sun(const SunLight& s) {
  if (!is_finite(s.direction) || !(length(s.direction) > 1e-20f))
    return "sun direction must be a finite non-zero vector (towards the sun)";
  if (!std::isfinite(s.angle_deg) || !(s.angle_deg >= limits::kMinSunAngleDeg) || s.angle_deg > 90)
    return fmt::format("sun angle (angular diameter, degrees) must be in [{:g}, 90], got {:g}", limits::kMinSunAngleDeg,
                       s.angle_deg);
  if (!is_finite(s.irradiance) || s.irradiance.x < 0 || s.irradiance.y < 0 || s.irradiance.z < 0 ||
      max_component(s.irradiance) > 1e9f)
    return "sun irradiance must be finite and in [0, 1e9] W/m^2";
  return std::nullopt;
}

}  // namespace epr
