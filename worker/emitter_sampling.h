// Next event estimation's point on an emitting triangle, and the solid-angle density with which it
// picks a direction: the one function both halves of multiple importance sampling evaluate.
//
// Two techniques, chosen per (shading point p, triangle) by a rule that depends on nothing else, so
// that a BSDF-sampled hit of the triangle from p finds the density light sampling would have used:
//   * uniform in solid angle (spherical triangle sampling, common/spherical_triangle.h) when the
//     triangle looks large from p: its longest edge is longer than p's distance to its plane (Cycles'
//     rule) and its solid angle lies in [3e-4, 6.22] sr, where Arvo's mapping is well conditioned in
//     float (pbrt-v4's bounds). Area sampling's 1/d^2 and cos at the light are then gone: no bright
//     outliers on walls and ceilings next to an emitter;
//   * uniform in area otherwise (Heitz's triangle mapping), density pdf_area d^2 / cos_y.
// Either way the triangle is first chosen with probability pmf = pdf_area x area.
#pragma once

#include <algorithm>
#include <cmath>

#include "common/check.h"
#include "common/sampling.h"
#include "common/spherical_triangle.h"
#include "worker/embree_scene.h"

namespace epr {

inline constexpr float kMinSphericalSampleArea = 3e-4f, kMaxSphericalSampleArea = 6.22f;

/// Cycles' first test: the triangle's longest edge is longer than p's distance to its plane.
inline bool emitter_looks_large(const Vec3& p, const Vec3& v0, const Vec3& v1, const Vec3& v2, const Vec3& n) {
  const Vec3 e0 = v1 - v0, e1 = v2 - v0, e2 = v2 - v1;
  const float longest2 = std::max({dot(e0, e0), dot(e1, e1), dot(e2, e2)});
  const float plane = dot(n, v0 - p);
  return longest2 > plane * plane;
}

inline bool solid_angle_in_range(float omega) {
  return omega >= kMinSphericalSampleArea && omega <= kMaxSphericalSampleArea;
}

/// The solid angle of the triangle seen from p if next event estimation samples it by solid angle
/// from p, else 0 (area sampling). `n` is the triangle's unit normal.
inline float emitter_solid_angle(const Vec3& p, const Vec3& v0, const Vec3& v1, const Vec3& v2, const Vec3& n) {
  if (!emitter_looks_large(p, v0, v1, v2, n)) return 0;
  const float omega = triangle_solid_angle(p, v0, v1, v2);
  return solid_angle_in_range(omega) ? omega : 0.f;
}

inline float triangle_area(const Vec3& v0, const Vec3& v1, const Vec3& v2) {
  return 0.5f * length(cross(v1 - v0, v2 - v0));
}

/// Solid-angle density (1/sr) with which next event estimation reaches a point at distance^2 `dist2`
/// and cosine `cos_y` (> 0) on the triangle (v0, v1, v2) from p; pdf_area = pmf / area.
inline float emitter_direction_pdf(const Vec3& p, const Vec3& v0, const Vec3& v1, const Vec3& v2, const Vec3& n,
                                   float pdf_area, float dist2, float cos_y) {
  EPR_DCHECK_GT(cos_y, 0.f);
  EPR_DCHECK_GT(pdf_area, 0.f);
  const float omega = emitter_solid_angle(p, v0, v1, v2, n);
  if (omega > 0) return pdf_area * triangle_area(v0, v1, v2) / omega;
  return pdf_area * dist2 / cos_y;
}

struct EmitterPoint {
  Vec3 pos;
  float solid_angle = 0;  // > 0: chosen uniformly in this solid angle; 0: uniformly in area
  bool valid = false;
};

/// A point on emitter `e` for the shading point p; u in [0,1)^2.
inline EmitterPoint sample_emitter_point(const Emitter& e, const Vec3& p, Vec2 u) {
  EmitterPoint s;
  if (emitter_looks_large(p, e.p0, e.p1, e.p2, e.normal)) {
    // The sample's solid angle is triangle_solid_angle(p, ...) bit for bit (the same operations), so
    // the range test below decides as emitter_solid_angle does.
    const SphericalTriangleSample d = sample_spherical_triangle(p, e.p0, e.p1, e.p2, u);
    if (solid_angle_in_range(d.solid_angle)) {
      const float cos_d = dot(e.normal, d.dir);
      if (!d.valid || cos_d == 0) return s;
      // Where the direction meets the triangle's plane.
      s.pos = p + d.dir * (dot(e.normal, e.p0 - p) / cos_d);
      s.solid_angle = d.solid_angle;
      s.valid = is_finite(s.pos);
      return s;
    }
  }
  const Vec2 b = sample_uniform_triangle(u);
  s.pos = e.p0 * b.x + e.p1 * b.y + e.p2 * (1 - b.x - b.y);
  s.valid = true;
  return s;
}

}  // namespace epr
