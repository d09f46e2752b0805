#include "common/spherical_triangle.h"

#include <algorithm>
#include <cmath>

namespace epr {
namespace {

float safe_sqrt(float x) { return std::sqrt(std::max(0.f, x)); }

// The part of v orthogonal to the unit vector w, normalised (zero if v is parallel to w).
Vec3 orthogonal_part(const Vec3& v, const Vec3& w) {
  const Vec3 o = v - w * dot(v, w);
  const float l2 = dot(o, o);
  return l2 > 0 ? o / std::sqrt(l2) : Vec3(0.f);
}

}  // namespace

float spherical_triangle_area(const Vec3& a, const Vec3& b, const Vec3& c) {
  const float num = std::abs(dot(a, cross(b, c)));
  const float den = 1 + dot(a, b) + dot(b, c) + dot(c, a);
  return 2 * std::atan2(num, den);  // den <= 0 gives an angle of at least pi/2, as it should
}

float triangle_solid_angle(const Vec3& p, const Vec3& v0, const Vec3& v1, const Vec3& v2) {
  return spherical_triangle_area(normalize(v0 - p), normalize(v1 - p), normalize(v2 - p));
}

SphericalTriangleSample sample_spherical_triangle(const Vec3& p, const Vec3& v0, const Vec3& v1, const Vec3& v2,
                                                  Vec2 u) {
  SphericalTriangleSample s;
  const Vec3 a = normalize(v0 - p), b = normalize(v1 - p), c = normalize(v2 - p);
  const float area = spherical_triangle_area(a, b, c);
  s.solid_angle = area;
  Vec3 n_ab = cross(a, b), n_ca = cross(c, a);
  const float l_ab = dot(n_ab, n_ab), l_ca = dot(n_ca, n_ca);
  if (!(area > 0) || !(l_ab > 0) || !(l_ca > 0) || !std::isfinite(area)) return s;
  n_ab = n_ab / std::sqrt(l_ab);
  n_ca = n_ca / std::sqrt(l_ca);
  // The spherical angle alpha at a, between the planes (a, b) and (a, c): its cosine and sine from
  // the planes' unit normals. The sampled sub-triangle (a, b, c') has area A' = u.x * area; with
  // ap_pi = A' + pi, sin(ap_pi) = -sin(A') and cos(ap_pi) = -cos(A').
  const float cos_alpha = -dot(n_ab, n_ca), sin_alpha = length(cross(n_ab, n_ca));
  const float sampled = u.x * area;
  const float sin_ap = -std::sin(sampled), cos_ap = -std::cos(sampled);
  const float sin_phi = sin_ap * cos_alpha - cos_ap * sin_alpha;
  const float cos_phi = cos_ap * cos_alpha + sin_ap * sin_alpha;
  const float k1 = cos_phi + cos_alpha;
  const float k2 = sin_phi - sin_alpha * dot(a, b);
  const float den = (k2 * sin_phi + k1 * cos_phi) * sin_alpha;
  float cos_bp = den != 0 ? (k2 + (k2 * cos_phi - k1 * sin_phi) * cos_alpha) / den : 1.f;
  if (!std::isfinite(cos_bp)) return s;
  cos_bp = std::clamp(cos_bp, -1.f, 1.f);
  // c' on the arc from a towards c, then a direction on the arc from b towards c'.
  const Vec3 cp = a * cos_bp + orthogonal_part(c, a) * safe_sqrt(1 - cos_bp * cos_bp);
  const float cos_t = 1 - u.y * (1 - dot(cp, b));
  const Vec3 w = b * cos_t + orthogonal_part(cp, b) * safe_sqrt(1 - cos_t * cos_t);
  if (!is_finite(w)) return s;
  s.dir = normalize(w);
  s.valid = true;
  return s;
}

}  // namespace epr
