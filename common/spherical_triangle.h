// Uniform sampling of the directions a triangle subtends: the spherical triangle its corners project
// to on the unit sphere around a point (J. Arvo, "Stratified Sampling of Spherical Triangles",
// SIGGRAPH 1995; pbrt-v4's SampleSphericalTriangle). The density is 1 / solid angle over the
// spherical triangle; the solid angle comes from one function for the sampler and for whoever
// evaluates the density, so that both agree bit for bit.
#pragma once

#include "common/math.h"

namespace epr {

/// Solid angle (sr) of the spherical triangle with unit-length corners a, b, c (A. van Oosterom and
/// J. Strackee, IEEE Trans. Biomed. Eng. 30(2), 1983): well conditioned for small triangles too.
float spherical_triangle_area(const Vec3& a, const Vec3& b, const Vec3& c);

/// Solid angle (sr) of the triangle (v0, v1, v2) seen from p.
float triangle_solid_angle(const Vec3& p, const Vec3& v0, const Vec3& v1, const Vec3& v2);

struct SphericalTriangleSample {
  Vec3 dir;               // unit direction from p into the triangle
  float solid_angle = 0;  // triangle_solid_angle(p, v0, v1, v2) bit for bit (set even when !valid);
                          // the density of dir is 1 / solid_angle
  bool valid = false;     // false for a degenerate spherical triangle (p in the triangle's plane)
};

/// A direction from p, uniform over the solid angle of the triangle (v0, v1, v2); u in [0,1)^2.
/// Arvo's mapping is area preserving and continuous in u, so stratified u stay stratified.
SphericalTriangleSample sample_spherical_triangle(const Vec3& p, const Vec3& v0, const Vec3& v1, const Vec3& v2,
                                                  Vec2 u);

}  // namespace epr
