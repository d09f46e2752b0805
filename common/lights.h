// Lights that are not triangles of the scene (scenes/README.md, "Lamps"): point and spot lights
// (delta lights: a position, no area) and directional lights (suns at infinity), from a glTF's
// KHR_lights_punctual (common/scene_loader/gltf_lights.cpp) or a scene JSON's "lights". Their units
// are radiometric: a point or spot light's radiant intensity in W/sr per channel, a directional
// light's irradiance in W/m^2 on a surface facing it. Area lamps are emitting triangles
// (Material::ke), not entries here. The tracing side is worker/sky_light.h.
#pragma once

#include <optional>
#include <span>
#include <string>
#include <vector>

#include "common/lighting.h"
#include "common/math.h"

namespace epr {

enum class LightType : uint8_t { kPoint, kSpot, kDirectional };

/// How a spot light's intensity falls off between its inner and outer cone (cosines of the angle
/// between the spot's axis and the direction, c):
///   kGltf:    t = clamp((c - cos_outer) / (cos_inner - cos_outer), 0, 1), scale t^2 (glTF's
///             KHR_lights_punctual reference implementation);
///   kBlender: 0 outside the outer cone, else c x smoothstep(0, 1, (c - cos_outer) / (cos_inner - cos_outer))
///             with cos_inner = cos_outer + (1 - cos_outer) x blend (Cycles' spot lamp: its intensity
///             carries the cosine to the axis too).
enum class SpotFalloff : uint8_t { kGltf, kBlender };

struct PunctualLight {
  std::string name;  // for messages
  LightType type = LightType::kPoint;
  Vec3 position{0.f};                  // point and spot, world space
  Vec3 direction{0, -1, 0};            // spot: the way it shines; directional: towards the light; unit length
  Vec3 intensity{1.f};                 // point, spot: W/sr per channel; directional: irradiance W/m^2
  float cos_inner = 1, cos_outer = 0;  // spot: cosines of the cone half angles, cos_inner >= cos_outer
  SpotFalloff falloff = SpotFalloff::kGltf;
  float angle_deg = 0;  // directional: the disc's angular diameter (0: the smallest sun disc)

  /// Radiant intensity (W/sr) towards unit direction d leaving the light (point and spot).
  Vec3 intensity_towards(const Vec3& d) const;
  /// The spot's falloff factor for the cosine c to its axis (1 for a point light).
  float spot_scale(float c) const;
  /// A directional light as the sky's sun model (common/lighting.h), its angle at least
  /// limits::kMinSunAngleDeg.
  SunLight as_sun() const;
  /// An estimate of the light's power (luminance, W) for light selection: 4 pi I for a point light, the
  /// cone's solid angle x I for a spot; 0 for a directional light (the sky's estimate covers it).
  double power() const;
};

/// Checks one light's values; the reason (without the light's name) if unusable.
std::optional<std::string> check_light(const PunctualLight& l);

/// True if light comes from outside the scene: an environment or a sun that gives light, or a
/// directional light. `--rr auto` resolves by it (common/roulette.h), on the worker and in the master's
/// statistics alike.
bool lit_from_outside(const Lighting& lighting, std::span<const PunctualLight> lights);

}  // namespace epr
