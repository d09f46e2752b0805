// Light from outside the scene (scenes/README.md, "Sky and sun"): an environment at infinity, a
// constant colour or an equirectangular image, and a sun, a disc of uniform radiance of a given
// angular diameter. Both are set by a scene JSON ("environment", "sun") or by a job (`--env`,
// `--sun`), the job's replacing the scene's. The tracing side (importance sampling, MIS) is in
// worker/sky_light.h.
//
// Equirectangular mapping (world is Y-up, right-handed; the same as Blender's Environment Texture
// for a scene imported from glTF, where Blender's (x, y, z) = ours (x, -z, y)): a unit direction
// d = (sin(theta) cos(phi), cos(theta), sin(theta) sin(phi)), theta in [0, pi] from +Y and
// phi = atan2(d.z, d.x), reads the image at
//     u = 0.5 + (phi - rotation) / (2 pi)   (from the left edge, wrapping),
//     t = theta / pi                        (from the top row),
// so the image's centre column looks along +X, its top row is straight up, and `rotation_deg` turns
// the sky as the Z rotation of a Mapping node (type Point) in front of Blender's Environment Texture.
#pragma once

#include <memory>
#include <optional>
#include <string>

#include "common/image.h"
#include "common/math.h"

namespace epr {

struct EnvironmentLight {
  Vec3 color{1.f};         // constant radiance, W / (m^2 sr) per channel, when `image` is empty
  std::string image;       // equirectangular .hdr / .exr, path relative to the scene's folder; empty: colour
  float strength = 1.f;    // multiplies the colour or the image
  float rotation_deg = 0;  // about +Y (see the file comment)
  std::shared_ptr<const Image> pixels;  // `image` decoded (linear RGB, row 0 at the top)

  /// Radiance arriving from unit direction d, strength applied (nearest texel of the image).
  Vec3 radiance(const Vec3& d) const;
};

struct SunLight {
  Vec3 direction{0, 1, 0};  // towards the sun, world space, unit length
  float angle_deg = 0.53f;  // angular diameter of the disc, degrees, in [limits::kMinSunAngleDeg, 90]
  Vec3 irradiance{1.f};     // W / m^2 per channel on a surface facing the sun (Blender's sun strength)

  /// The disc's uniform radiance: irradiance / (pi sin^2(angle / 2)), the irradiance a disc of half
  /// angle h and radiance L gives a surface facing it being L pi sin^2(h).
  Vec3 radiance() const;
  /// cos of the half angle: a direction d is inside the disc when dot(d, direction) >= this.
  float cos_half_angle() const;
};

struct Lighting {
  std::optional<EnvironmentLight> environment;
  std::optional<SunLight> sun;

  /// True if the environment or the sun gives any light.
  bool lights() const;
};

/// Equirectangular image coordinates (u across from the left, t down from the top, both in [0, 1])
/// of unit direction d, and back (the file comment's mapping, rotation in radians).
Vec2 direction_to_equirect(const Vec3& d, float rotation);
Vec3 equirect_to_direction(Vec2 ut, float rotation);

/// Parses `--env`: "R,G,B" (or one number, a grey) as a constant colour, else a file name, returned
/// as given in `file`. Throws std::invalid_argument naming the flag.
EnvironmentLight parse_env_flag(const std::string& value, std::string* file);
/// Parses `--sun DX,DY,DZ[,ANGLE_DEG[,E | ,R,G,B]]`: the direction towards the sun, the angular
/// diameter (default 0.53) and the irradiance (one number or three; default 1). Throws
/// std::invalid_argument naming the flag.
SunLight parse_sun_flag(const std::string& value);

/// Checks an environment or a sun given by any source; the reason if unusable.
std::optional<std::string> check_environment(const EnvironmentLight& e);
std::optional<std::string> check_sun(const SunLight& s);

}  // namespace epr
