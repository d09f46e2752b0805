// The GGX (Trowbridge-Reitz) microfacet distribution and its helpers, in a local frame whose z axis is
// the macro-surface normal: the isotropic distribution D, Smith's height-correlated masking-shadowing
// G2 = 1 / (1 + Lambda(wo) + Lambda(wi)), sampling of the visible normals (Heitz 2018, "Sampling the
// GGX Distribution of Visible Normals"), and the Fresnel factors (exact dielectric, Schlick for
// conductors). alpha is glTF's roughness squared.
#pragma once

#include <algorithm>
#include <cmath>

#include "common/math.h"

namespace epr::ggx {

/// Below this alpha a surface is perfectly smooth: its lobes are Dirac deltas (float would
/// overflow D long before alpha reached 0).
inline constexpr float kMinAlpha = 1e-3f;

inline float D(const Vec3& h, float alpha) {
  if (h.z <= 0) return 0;
  const float a2 = alpha * alpha;
  const float c2 = h.z * h.z;
  const float d = c2 * (a2 - 1) + 1;
  return a2 / (kPi * d * d);
}

/// Smith's Lambda for GGX along w (either hemisphere).
inline float lambda(const Vec3& w, float alpha) {
  const float c2 = w.z * w.z;
  if (!(c2 > 0)) return 0;
  const float tan2 = std::max(0.f, 1 - c2) / c2;
  return 0.5f * (std::sqrt(1 + alpha * alpha * tan2) - 1);
}

inline float G1(const Vec3& w, float alpha) { return 1 / (1 + lambda(w, alpha)); }
/// Height-correlated masking-shadowing.
inline float G2(const Vec3& wo, const Vec3& wi, float alpha) { return 1 / (1 + lambda(wo, alpha) + lambda(wi, alpha)); }

/// Density of the visible normal h seen from wo (wo.z > 0): G1(wo) max(0, wo.h) D(h) / wo.z.
inline float visible_pdf(const Vec3& wo, const Vec3& h, float alpha) {
  const float c = dot(wo, h);
  if (!(c > 0) || !(wo.z > 0)) return 0;
  return G1(wo, alpha) * c * D(h, alpha) / wo.z;
}

/// A visible normal seen from wo (wo.z > 0) for u in [0, 1)^2 (Heitz 2018, listing 1).
inline Vec3 sample_visible(const Vec3& wo, float alpha, Vec2 u) {
  const Vec3 vh = normalize(Vec3(alpha * wo.x, alpha * wo.y, wo.z));
  const float lensq = vh.x * vh.x + vh.y * vh.y;
  const Vec3 t1 = lensq > 0 ? Vec3(-vh.y, vh.x, 0) * (1 / std::sqrt(lensq)) : Vec3(1, 0, 0);
  const Vec3 t2 = cross(vh, t1);
  const float r = std::sqrt(u.x), phi = 2 * kPi * u.y;
  const float p1 = r * std::cos(phi);
  float p2 = r * std::sin(phi);
  const float s = 0.5f * (1 + vh.z);
  p2 = (1 - s) * std::sqrt(std::max(0.f, 1 - p1 * p1)) + s * p2;
  const Vec3 nh = t1 * p1 + t2 * p2 + vh * std::sqrt(std::max(0.f, 1 - p1 * p1 - p2 * p2));
  return normalize(Vec3(alpha * nh.x, alpha * nh.y, std::max(1e-6f, nh.z)));
}

/// Unpolarised Fresnel reflectance of a dielectric interface for the cosine cos_i of the incident
/// direction with the normal on its side and eta = n_transmitted / n_incident; 1 under total
/// internal reflection.
inline float fresnel_dielectric(float cos_i, float eta) {
  cos_i = std::clamp(cos_i, 0.f, 1.f);
  const float sin2_t = (1 - cos_i * cos_i) / (eta * eta);
  if (sin2_t >= 1) return 1;
  const float cos_t = std::sqrt(1 - sin2_t);
  const float r_par = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
  const float r_perp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
  return 0.5f * (r_par * r_par + r_perp * r_perp);
}

/// Schlick's approximation with reflectance f0 at normal incidence (glTF's conductor Fresnel).
inline Vec3 fresnel_schlick(const Vec3& f0, float cos_i) {
  const float m = std::clamp(1 - cos_i, 0.f, 1.f);
  const float m5 = (m * m) * (m * m) * m;
  return f0 + (Vec3(1.f) - f0) * m5;
}

/// Mirror of w about h.
inline Vec3 reflect(const Vec3& w, const Vec3& h) { return h * (2 * dot(w, h)) - w; }

/// The direction refracted from w (on h's side, dot(w, h) > 0) through a microfacet h with eta =
/// n_transmitted / n_incident; false under total internal reflection.
inline bool refract(const Vec3& w, const Vec3& h, float eta, Vec3* out) {
  const float cos_i = dot(w, h);
  const float sin2_t = std::max(0.f, 1 - cos_i * cos_i) / (eta * eta);
  if (sin2_t >= 1) return false;
  const float cos_t = std::sqrt(1 - sin2_t);
  *out = normalize(-w * (1 / eta) + h * (cos_i / eta - cos_t));
  return true;
}

}  // namespace epr::ggx
