// A test scene for the worker's tests: a closed box (-1..1 on each axis) of Lambertian walls (albedo
// 0.5) emitting radiance 1, around a floor (y = -1) of a given material; the caller sets the camera.
#pragma once

#include <string>

#include "common/scene.h"

namespace epr::test {

inline Scene glowing_box(const Material& floor, const std::string& name) {
  Scene s;
  s.name = name;
  Material wall;
  wall.kd = Vec3(0.5f);
  wall.ke = Vec3(1.f);
  const uint32_t w = add_material(s, wall);
  const uint32_t f = add_material(s, floor);
  const Vec3 p[8] = {{-1, -1, -1}, {1, -1, -1}, {1, 1, -1}, {-1, 1, -1},
                     {-1, -1, 1},  {1, -1, 1},  {1, 1, 1},  {-1, 1, 1}};
  add_quad(s, p[0], p[1], p[2], p[3], w);
  add_quad(s, p[5], p[4], p[7], p[6], w);
  add_quad(s, p[4], p[0], p[3], p[7], w);
  add_quad(s, p[1], p[5], p[6], p[2], w);
  add_quad(s, p[4], p[5], p[1], p[0], f);  // floor
  add_quad(s, p[3], p[2], p[6], p[7], w);
  return s;
}

}  // namespace epr::test
