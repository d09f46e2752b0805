#include "worker/bsdf_ggx.h"

#include <algorithm>
#include <cmath>

#include "common/sampling.h"
#include "worker/microfacet.h"

namespace epr {

MicrofacetBsdf::MicrofacetBsdf(const MicrofacetInputs& in, const Vec3& n, const Vec3& wo)
    : frame_(Frame::from_normal(n)),
      wo_(frame_.to_local(wo)),
      c_(in.base),
      metal_(std::clamp(in.metallic, 0.f, 1.f)),
      trans_(std::clamp(in.transmission, 0.f, 1.f)),
      alpha_(std::clamp(in.roughness, 0.f, 1.f) * std::clamp(in.roughness, 0.f, 1.f)),
      smooth_(alpha_ < ggx::kMinAlpha) {
  valid_ = wo_.z > 0;
  if (!valid_) return;
  // An opaque surface is entered from whichever side: only a transmissive one has an inside.
  eta_ = (in.front || trans_ == 0) ? in.ior : 1 / in.ior;
  f_o_ = ggx::fresnel_dielectric(wo_.z, eta_);
  // Blender's Principled BSDF v1 (Cycles 3.x): the diffuse base is not weighted by 1 - F, so it is
  // the same for every viewer; the specular layer adds on top (the sum can exceed 1 at grazing wo).
  diffuse_ = c_ * ((1 - metal_) * (1 - trans_) * kInvPi);
  const float lc = luminance(c_);
  const float e_spec = metal_ * luminance(ggx::fresnel_schlick(c_, wo_.z)) + (1 - metal_) * f_o_;
  const float e_trans = (1 - metal_) * trans_ * (1 - f_o_) * lc;
  const float e_diff = (1 - metal_) * (1 - trans_) * lc;
  const float total = e_spec + e_trans + e_diff;
  p_micro_ = total > 0 ? (e_spec + e_trans) / total : 1.f;
  if (e_diff == 0) p_micro_ = 1;
  const float mc = max_component(c_);
  albedo_ = std::min(1.f, metal_ * mc + (1 - metal_) * (f_o_ + (1 - trans_ * f_o_) * mc));
}

float MicrofacetBsdf::reflect_share(float cos_oh) const {
  const float f = ggx::fresnel_dielectric(cos_oh, eta_);
  const float r = metal_ * luminance(ggx::fresnel_schlick(c_, cos_oh)) + (1 - metal_) * f;
  const float t = (1 - metal_) * trans_ * (1 - f) * luminance(c_);
  return r + t > 0 ? r / (r + t) : 1.f;
}

Vec3 MicrofacetBsdf::refraction_half(const Vec3& wi) const {
  const Vec3 h = normalize(wo_ + wi * eta_);
  return h.z < 0 ? -h : h;
}

Vec3 MicrofacetBsdf::eval(const Vec3& wi) const { return valid_ ? eval_local(frame_.to_local(wi)) : Vec3(0.f); }
Vec3 MicrofacetBsdf::eval_diffuse(const Vec3& wi) const {
  return valid_ && frame_.to_local(wi).z > 0 ? diffuse_ : Vec3(0.f);
}
float MicrofacetBsdf::pdf(const Vec3& wi) const { return valid_ ? pdf_local(frame_.to_local(wi)) : 0.f; }

Vec3 MicrofacetBsdf::eval_local(const Vec3& wi) const {
  const float co = wo_.z, ci = wi.z;
  Vec3 f(0.f);
  if (ci > 0) {
    f += diffuse_;
    if (smooth_) return f;
    const Vec3 h = normalize(wo_ + wi);
    const float coh = dot(wo_, h);
    if (!(coh > 0)) return f;
    const float dg = ggx::D(h, alpha_) * ggx::G2(wo_, wi, alpha_) / (4 * co * ci);
    f += (ggx::fresnel_schlick(c_, coh) * metal_ + Vec3((1 - metal_) * ggx::fresnel_dielectric(coh, eta_))) * dg;
    return f;
  }
  if (!(ci < 0) || smooth_ || trans_ == 0 || metal_ >= 1) return f;
  const Vec3 h = refraction_half(wi);
  const float coh = dot(wo_, h), cih = dot(wi, h);
  if (!(coh > 0) || !(cih < 0)) return f;
  const float denom = cih + coh / eta_;
  const float ft = ggx::D(h, alpha_) * ggx::G2(wo_, wi, alpha_) * (1 - ggx::fresnel_dielectric(coh, eta_)) *
                   std::abs(cih * coh) / (-ci * co * denom * denom * eta_ * eta_);
  return c_ * ((1 - metal_) * trans_ * ft);
}

float MicrofacetBsdf::pdf_local(const Vec3& wi) const {
  const float ci = wi.z;
  if (ci > 0) {
    float p = (1 - p_micro_) * cosine_hemisphere_pdf(ci);
    if (smooth_) return p;
    const Vec3 h = normalize(wo_ + wi);
    const float coh = dot(wo_, h);
    if (coh > 0) p += p_micro_ * ggx::visible_pdf(wo_, h, alpha_) / (4 * coh) * reflect_share(coh);
    return p;
  }
  if (!(ci < 0) || smooth_ || trans_ == 0 || metal_ >= 1) return 0;
  const Vec3 h = refraction_half(wi);
  const float coh = dot(wo_, h), cih = dot(wi, h);
  if (!(coh > 0) || !(cih < 0)) return 0;
  const float denom = cih + coh / eta_;
  return p_micro_ * ggx::visible_pdf(wo_, h, alpha_) * -cih / (denom * denom) * (1 - reflect_share(coh));
}

BsdfSample MicrofacetBsdf::sample(float u_lobe, Vec2 u) const {
  BsdfSample s;
  if (!valid_) return s;
  Vec3 wi;
  if (u_lobe >= p_micro_) {
    wi = sample_cosine_hemisphere(u);
  } else {
    const float u_pick = u_lobe / p_micro_;  // rescaled to [0, 1): reflection or refraction
    const Vec3 h = smooth_ ? Vec3(0, 0, 1) : ggx::sample_visible(wo_, alpha_, u);
    const float coh = dot(wo_, h);
    const float r = reflect_share(coh);
    const bool reflected = u_pick < r;
    if (reflected) {
      wi = ggx::reflect(wo_, h);
      if (!(wi.z > 0)) return s;
    } else if (!ggx::refract(wo_, h, eta_, &wi) || !(wi.z < 0)) {
      return s;
    }
    if (smooth_) {
      // A delta lobe: f |cos| / pdf is its reflectance (or transmittance) over its probability.
      const float f = ggx::fresnel_dielectric(coh, eta_);
      const Vec3 w = reflected ? ggx::fresnel_schlick(c_, coh) * metal_ + Vec3((1 - metal_) * f)
                               : c_ * ((1 - metal_) * trans_ * (1 - f) / (eta_ * eta_));
      const float p = p_micro_ * (reflected ? r : 1 - r);
      s.wi = frame_.to_world(wi);
      s.weight = w / p;
      s.pdf = p;
      s.delta = true;
      s.valid = p > 0 && is_finite(s.weight);
      return s;
    }
  }
  const float p = pdf_local(wi);
  if (!(p > 0)) return s;
  s.wi = frame_.to_world(wi);
  s.weight = eval_local(wi) * (std::abs(wi.z) / p);
  s.pdf = p;
  s.valid = is_finite(s.weight);
  return s;
}

}  // namespace epr
