// A cut-out test scene, shared by the worker's and the master's tests: a square screen in the plane
// z = 0 (x, y in [-0.5, 0.5]) cut out by an N x N checker mask in front of a wall at z = -1, lit by
// an emitter up and to the left so that the screen's shadow on the wall is seen beside it. The same
// scene with the holes modelled as geometry (only the opaque cells, as quads) is its reference.
#pragma once

#include <array>
#include <cstdint>

#include "common/scene.h"

namespace epr::test {

/// Appends the quad a-b-c-d as two triangles with uvs a = (0, 0), b = (1, 0), c = (1, 1), d = (0, 1)
/// mapped onto [u0, u1] x [v0, v1].
inline void add_uv_quad(Scene& s, Vec3 a, Vec3 b, Vec3 c, Vec3 d, uint32_t mat, float u0 = 0, float u1 = 1,
                        float v0 = 0, float v1 = 1) {
  s.uvs.resize(s.triangles.size());
  const uint32_t base = uint32_t(s.positions.size());
  s.positions.insert(s.positions.end(), {a, b, c, d});
  s.triangles.push_back({base, base + 1, base + 2});
  s.triangles.push_back({base, base + 2, base + 3});
  s.material_of.insert(s.material_of.end(), {mat, mat});
  s.uvs.push_back({Vec2{u0, v0}, Vec2{u1, v0}, Vec2{u1, v1}});
  s.uvs.push_back({Vec2{u0, v0}, Vec2{u1, v1}, Vec2{u0, v1}});
}

/// Cell (i, r) of the checker (column i from the left, row r from the top) is opaque iff i + r is even.
inline bool checker_opaque(int i, int r) { return (i + r) % 2 == 0; }

/// The scene; `modelled`: holes as geometry instead of a mask; `opaque`: no holes at all.
inline Scene cutout_screen_scene(int n = 4, bool modelled = false, bool opaque = false) {
  Scene s;
  s.name = modelled ? "test-cutout-modelled" : "test-cutout";
  Material wall;
  wall.name = "wall";
  wall.kd = Vec3(0.8f);
  Material screen;
  screen.name = "screen";
  screen.kd = {0.2f, 0.3f, 0.9f};
  Material light;
  light.name = "light";
  light.kd = Vec3(0.f);
  light.ke = Vec3(10.f);
  const uint32_t mw = add_material(s, wall), ml = add_material(s, light);
  if (!modelled && !opaque) {
    Texture mask;
    mask.path = "checker";
    mask.width = mask.height = n;
    mask.alpha.resize(size_t(n) * size_t(n));
    for (int r = 0; r < n; ++r)
      for (int i = 0; i < n; ++i) mask.alpha[size_t(r) * size_t(n) + size_t(i)] = checker_opaque(i, r) ? 1.f : 0.f;
    s.textures.push_back(mask);
    screen.alpha_texture = 0;
  }
  const uint32_t ms = add_material(s, screen);
  add_uv_quad(s, {-3, -3, -1}, {3, -3, -1}, {3, 3, -1}, {-3, 3, -1}, mw);
  // The emitter (two-sided) up, left and in front of the screen.
  add_uv_quad(s, {-1.2f, 0.8f, 1.2f}, {-0.8f, 0.8f, 1.2f}, {-0.8f, 1.2f, 0.8f}, {-1.2f, 1.2f, 0.8f}, ml);
  if (!modelled) {
    add_uv_quad(s, {-0.5f, -0.5f, 0}, {0.5f, -0.5f, 0}, {0.5f, 0.5f, 0}, {-0.5f, 0.5f, 0}, ms);
  } else {
    const float c = 1.f / float(n);
    for (int r = 0; r < n; ++r)
      for (int i = 0; i < n; ++i) {
        if (!checker_opaque(i, r)) continue;
        const float x0 = -0.5f + float(i) * c, y1 = 0.5f - float(r) * c;
        add_uv_quad(s, {x0, y1 - c, 0}, {x0 + c, y1 - c, 0}, {x0 + c, y1, 0}, {x0, y1, 0}, ms);
      }
  }
  s.camera = {Vec3(0.3f, -0.2f, 2.5f), Vec3(0.f, -0.3f, -1.f), Vec3(0, 1, 0), 60.f};
  return s;
}

}  // namespace epr::test
