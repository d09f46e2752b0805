// A Lambertian floor at y = 0, the square |x|, |z| <= half_size, with a camera: the worker tests that
// check a render against the light a flat floor receives build it.
#pragma once

#include "common/scene.h"

namespace epr {

inline Scene diffuse_floor(const char* name, float half_size, float albedo, const CameraSpec& camera) {
  Scene s;
  s.name = name;
  Material m;
  m.name = "floor";
  m.kd = Vec3(albedo);
  const uint32_t id = add_material(s, m);
  const float h = half_size;
  add_quad(s, {-h, 0, -h}, {-h, 0, h}, {h, 0, h}, {h, 0, -h}, id);
  s.camera = camera;
  return s;
}

}  // namespace epr
