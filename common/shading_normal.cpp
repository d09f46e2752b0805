#include "common/shading_normal.h"

#include <algorithm>
#include <cmath>

#include "common/tangents.h"

namespace epr {

Vec3 interpolated_normal(const Scene& s, size_t tri, float u, float v) {
  if (s.normals.empty()) return s.geometric_normal(tri);
  const auto& c = s.normals[tri];
  const Vec3 n = c[0] * (1 - u - v) + c[1] * u + c[2] * v;
  const float l = length(n);
  return l > 0 && std::isfinite(l) ? n / l : s.geometric_normal(tri);
}

namespace {

Vec3 mapped_normal(const Scene& s, size_t tri, float u, float v, Vec3 n) {
  const Material& m = s.materials[s.material_of[tri]];
  if (m.normal_texture < 0 || s.tangents.empty() || s.uvs.empty()) return n;
  const float w = 1 - u - v;
  const auto& c = s.tangents[tri];
  const auto& uv = s.uvs[tri];
  const Tangent t{c[0].t * w + c[1].t * u + c[2].t * v, c[0].w};
  const Vec2 st{uv[0].x * w + uv[1].x * u + uv[2].x * v, uv[0].y * w + uv[1].y * u + uv[2].y * v};
  return apply_normal_map(n, t, s.textures[size_t(m.normal_texture)].lookup(st), m.normal_scale);
}

}  // namespace

Vec3 shading_normal(const Scene& s, size_t tri, float u, float v) {
  return mapped_normal(s, tri, u, v, interpolated_normal(s, tri, u, v));
}

Vec3 oriented_shading_normal(Vec3 n, Vec3 ng, Vec3 wo) {
  if (dot(n, ng) < 0) n = -n;
  const Vec3 r = n * (2 * dot(n, wo)) - wo;
  const float iz = dot(wo, ng);
  const float threshold = std::min(0.9f * iz, 0.01f);
  if (dot(ng, r) >= threshold) return n;
  // Cycles' construction: in the frame (X, ., ng) with n in the X-ng plane, the n' of that plane
  // whose reflection of wo has height exactly `threshold` over the geometric surface.
  Vec3 x = n - ng * dot(n, ng);
  const float xl = length(x);
  x = xl > 0 ? x / xl : n;
  const float ix = dot(wo, x);
  const float a = ix * ix + iz * iz;
  const float b = 2 * (a + iz * threshold);
  const float c = (threshold + iz) * (threshold + iz);
  const float root = std::sqrt(std::max(0.f, b * b - 4 * a * c));
  const float nz2 = ix < 0 ? 0.25f * (b + root) / a : 0.25f * (b - root) / a;
  const float nx = std::sqrt(std::max(0.f, 1 - nz2)), nz = std::sqrt(std::max(0.f, nz2));
  const Vec3 bent = x * nx + ng * nz;
  const float l = length(bent);
  return l > 0 && std::isfinite(l) ? bent / l : ng;
}

Vec3 shading_normal_towards(const Scene& s, size_t tri, float u, float v, Vec3 ng, Vec3 wo) {
  return hit_normals_towards(s, tri, u, v, ng, wo).shading;
}

HitNormals hit_normals_towards(const Scene& s, size_t tri, float u, float v, Vec3 ng, Vec3 wo) {
  if (s.normals.empty() && s.materials[s.material_of[tri]].normal_texture < 0) return {ng, ng};
  const Vec3 n = interpolated_normal(s, tri, u, v);
  return {dot(n, ng) < 0 ? -n : n, oriented_shading_normal(mapped_normal(s, tri, u, v, n), ng, wo)};
}

}  // namespace epr
