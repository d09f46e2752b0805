// The reflection models a scene may use (common/scene.h): Lambertian, Lambertian plus a normalised
// Phong lobe (the glossy material, only there to exercise the method's failure mode), and glTF's
// metallic-roughness material on GGX (worker/bsdf_ggx.h), to which this class hands over.
// Directions are in world space and unit length; `wo` points back along the incoming ray. `n` is the
// shading normal (common/shading_normal.h: oriented_shading_normal) and `ng` the geometric normal,
// both turned to the side the path arrived from: the lobes and cosines follow n, and no direction
// on the other side of the geometric surface than of the shading one is scattered into (f, pdf and
// samples there are zero: no light leaks through a smooth-shaded surface). Where n differs from the
// smooth (interpolated) normal, the diffuse lobes' values and sampled weights carry Cycles' bump
// shadowing term (worker/bump_shadowing.h); densities do not. For the radiance a camera path carries
// nothing else corrects for shading normals (pbrt's CorrectShadingNormal is for importance transport,
// light paths).
#pragma once

#include "common/check.h"
#include "common/math.h"
#include "common/sampling.h"
#include "common/scene.h"
#include "worker/bsdf_ggx.h"
#include "worker/bsdf_sample.h"
#include "worker/bump_shadowing.h"

namespace epr {

class Bsdf {
 public:
  Bsdf(const Material& m, Vec3 kd, Vec3 n, Vec3 wo) : Bsdf(m, kd, n, n, wo) {}
  Bsdf(const Material& m, Vec3 kd, Vec3 ng, Vec3 n, Vec3 wo) : Bsdf(m, kd, ng, n, wo, n) {}
  /// `smooth`: the interpolated normal n was tilted from (common/shading_normal.h: HitNormals).
  Bsdf(const Material& m, Vec3 kd, Vec3 ng, Vec3 n, Vec3 wo, Vec3 smooth)
      : kd_(kd),
        ks_(m.type == MaterialType::kGlossy ? m.ks : Vec3(0.f)),
        exponent_(m.exponent),
        n_(n),
        ng_(ng),
        wo_(wo),
        smooth_(smooth),
        bumped_(!(smooth == n)) {
    if (m.type == MaterialType::kGlossy) {
      const float ld = luminance(kd_), ls = luminance(ks_);
      p_glossy_ = (ld + ls) > 0 ? ls / (ld + ls) : 0.f;
      EPR_DCHECK(p_glossy_ >= 0 && p_glossy_ <= 1);
    }
  }

  /// A metallic-roughness (MaterialType::kMicrofacet) surface point.
  Bsdf(const MicrofacetInputs& in, Vec3 ng, Vec3 n, Vec3 wo) : Bsdf(in, ng, n, wo, n) {}
  Bsdf(const MicrofacetInputs& in, Vec3 ng, Vec3 n, Vec3 wo, Vec3 smooth)
      : n_(n), ng_(ng), wo_(wo), smooth_(smooth), bumped_(!(smooth == n)), ggx_(in, n, wo), microfacet_(true) {}

  /// The cosine a reflection towards wi is weighted with: dot(n, wi), 0 below either surface.
  float cosine(const Vec3& wi) const { return dot(wi, ng_) > 0 ? std::max(0.f, dot(wi, n_)) : 0.f; }

  /// f(wo, wi), 1/sr.
  Vec3 eval(const Vec3& wi) const {
    if (microfacet_) {
      if (!same_side(wi)) return Vec3(0.f);
      const float b = bump(wi);
      return b < 1 ? ggx_.eval(wi) - ggx_.eval_diffuse(wi) * (1 - b) : ggx_.eval(wi);
    }
    if (dot(wi, n_) <= 0 || dot(wi, ng_) <= 0) return Vec3(0.f);
    Vec3 f = kd_ * (kInvPi * bump(wi));
    if (p_glossy_ > 0) {
      const float c = dot(reflect(wo_), wi);
      if (c > 0) f += ks_ * ((exponent_ + 2) * 0.5f * kInvPi * std::pow(c, exponent_));
    }
    return f;
  }

  /// The diffuse lobe's share of eval(wi): Kd / pi for the Lambertian and glossy materials, the
  /// diffuse base for the microfacet one; 0 where eval() is 0.
  Vec3 eval_diffuse(const Vec3& wi) const {
    if (microfacet_) return same_side(wi) ? ggx_.eval_diffuse(wi) * bump(wi) : Vec3(0.f);
    if (dot(wi, n_) <= 0 || dot(wi, ng_) <= 0) return Vec3(0.f);
    return kd_ * (kInvPi * bump(wi));
  }

  float pdf(const Vec3& wi) const {
    if (microfacet_) return same_side(wi) ? ggx_.pdf(wi) : 0.f;
    const float cos_n = dot(wi, n_);
    if (cos_n <= 0 || dot(wi, ng_) <= 0) return 0;
    float p = (1 - p_glossy_) * cosine_hemisphere_pdf(cos_n);
    if (p_glossy_ > 0) p += p_glossy_ * phong_lobe_pdf(dot(reflect(wo_), wi), exponent_);
    return p;
  }

  /// u_lobe picks the lobe, u the direction inside it.
  BsdfSample sample(float u_lobe, Vec2 u) const {
    if (microfacet_) {
      BsdfSample s = ggx_.sample(u_lobe, u);
      if (s.valid && !same_side(s.wi)) s.valid = false;
      if (s.valid && !s.delta) {  // the weight is eval() cos / pdf: take the term out of its diffuse share
        const float b = bump(s.wi);
        if (b < 1) s.weight = s.weight - ggx_.eval_diffuse(s.wi) * ((1 - b) * dot(s.wi, n_) / s.pdf);
      }
      return s;
    }
    BsdfSample s;
    if (p_glossy_ == 0) {
      // Pure Lambertian: f cos / pdf = kd exactly (times the bump shadowing term).
      s.wi = Frame::from_normal(n_).to_world(sample_cosine_hemisphere(u));
      s.weight = bumped_ ? kd_ * bump(s.wi) : kd_;
      s.pdf = cosine_hemisphere_pdf(dot(s.wi, n_));
      s.valid = s.pdf > 0 && dot(s.wi, ng_) > 0;
      return s;
    }
    if (u_lobe < p_glossy_)
      s.wi = Frame::from_normal(reflect(wo_)).to_world(sample_phong_lobe(u, exponent_));
    else
      s.wi = Frame::from_normal(n_).to_world(sample_cosine_hemisphere(u));
    const float p = pdf(s.wi);
    if (!(p > 0)) return s;
    s.weight = eval(s.wi) * (dot(s.wi, n_) / p);
    s.pdf = p;
    s.valid = true;
    return s;
  }

  bool glossy() const { return microfacet_ || p_glossy_ > 0; }
  /// Has a diffuse lobe that reflects something (eval_diffuse() is not 0 everywhere).
  bool has_diffuse() const { return microfacet_ ? ggx_.has_diffuse() : !is_black(kd_); }
  /// Reflects nothing (f = 0 everywhere): no estimate at this vertex can be non-zero.
  bool black() const { return !microfacet_ && is_black(kd_) && is_black(ks_); }  // Fresnel reflects at grazing
  /// Only delta lobes: next event estimation cannot find a direction the BSDF reflects.
  bool delta_only() const { return microfacet_ && ggx_.delta_only(); }
  /// Largest total reflectance, the albedo-based Russian roulette's survival probability.
  float albedo() const { return microfacet_ ? ggx_.albedo() : max_component(kd_ + ks_); }

 private:
  Vec3 reflect(const Vec3& w) const { return n_ * (2 * dot(w, n_)) - w; }
  /// The diffuse lobes' bump shadowing term towards wi (1 where n is the smooth normal).
  float bump(const Vec3& wi) const { return bumped_ ? bump_shadowing_term(smooth_, n_, wi) : 1.f; }
  /// wi lies on the same side of the geometric surface as of the shading one (reflected above
  /// both, or transmitted below both).
  bool same_side(const Vec3& wi) const { return (dot(wi, n_) > 0) == (dot(wi, ng_) > 0); }

  Vec3 kd_{0.f}, ks_{0.f};
  float exponent_ = 1;
  Vec3 n_, ng_, wo_;
  Vec3 smooth_;          // the interpolated normal n was tilted from
  bool bumped_ = false;  // n differs from smooth_: the diffuse lobes take the bump shadowing term
  float p_glossy_ = 0;
  MicrofacetBsdf ggx_;
  bool microfacet_ = false;
};

}  // namespace epr
