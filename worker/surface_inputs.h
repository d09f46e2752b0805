// What a material looks like at a point of a triangle: its texture coordinates, the metallic-roughness
// inputs of worker/bsdf_ggx.h with their textures applied, and the emitted radiance with its
// emission texture.
#pragma once

#include <cstdint>

#include "common/image.h"
#include "common/scene.h"
#include "worker/bsdf_ggx.h"

namespace epr {

/// Texture coordinates of triangle `tri` at barycentrics (u, v) of corners 1 and 2; (0, 0) untextured.
inline Vec2 texcoord_at(const Scene& s, uint32_t tri, float u, float v) {
  if (s.uvs.empty()) return {0.f, 0.f};
  const auto& uv = s.uvs[tri];
  return {uv[0].x * (1 - u - v) + uv[1].x * u + uv[2].x * v, uv[0].y * (1 - u - v) + uv[1].y * u + uv[2].y * v};
}

/// The inputs of a kMicrofacet material at that point; `base` its base colour there, `front` true
/// if the path arrived at the triangle's front.
inline MicrofacetInputs microfacet_inputs(const Scene& s, const Material& m, Vec3 base, uint32_t tri, float u, float v,
                                          bool front) {
  MicrofacetInputs in{base, m.metallic, m.roughness, m.transmission, m.ior, front};
  if (m.metallic_roughness_texture >= 0 && !s.uvs.empty()) {
    const Vec3 t = s.textures[size_t(m.metallic_roughness_texture)].lookup(texcoord_at(s, tri, u, v));
    in.roughness = m.roughness * linear_to_srgb(t.y);
    in.metallic = m.metallic * linear_to_srgb(t.z);
  }
  return in;
}

/// Ke times the emission texture at that point (`ke`: the material's emitted(side)).
inline Vec3 emission_at(const Scene& s, const Material& m, Vec3 ke, uint32_t tri, float u, float v) {
  if (m.ke_texture < 0 || s.uvs.empty() || is_black(ke)) return ke;
  return ke * s.textures[size_t(m.ke_texture)].lookup(texcoord_at(s, tri, u, v));
}

/// Barycentrics (u, v) of corners 1 and 2 of triangle `tri` for a point p in its plane.
inline Vec2 barycentrics_of(const Scene& s, uint32_t tri, const Vec3& p) {
  const auto& t = s.triangles[tri];
  const Vec3 a = s.positions[t[0]], e1 = s.positions[t[1]] - a, e2 = s.positions[t[2]] - a, d = p - a;
  const float d11 = dot(e1, e1), d12 = dot(e1, e2), d22 = dot(e2, e2), dp1 = dot(d, e1), dp2 = dot(d, e2);
  const float det = d11 * d22 - d12 * d12;
  if (!(det > 0)) return {0.f, 0.f};
  return {(d22 * dp1 - d12 * dp2) / det, (d11 * dp2 - d12 * dp1) / det};
}

}  // namespace epr
