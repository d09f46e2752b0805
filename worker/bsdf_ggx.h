// glTF's metallic-roughness material (its specification's appendix B) on a GGX microfacet model
// (worker/microfacet.h), with KHR_materials_transmission and KHR_materials_ior:
//   f = metallic       * conductor:  D G2 F_schlick(c, wo.h) / (4 cos_o cos_i)         (F0 = base colour c)
//     + (1 - metallic) * dielectric: D G2 F(wo.h) / (4 cos_o cos_i)                    (specular layer)
//                                    + (1 - t) c / pi                                  (diffuse base)
//                                    + t c (1 - F(wo.h)) D G2 |wi.h wo.h| / (cos_i cos_o (wi.h + wo.h / eta)^2 eta^2)
// F the exact dielectric Fresnel for eta = ior (or 1 / ior leaving a transmissive surface from its
// back), t the transmission; the transmission lobe refracts (Walter et al. 2007; solid glass, not
// glTF's thin-walled default) and carries radiance (the 1 / eta^2). alpha = roughness^2; below
// ggx::kMinAlpha the microfacet lobes are Dirac deltas. The diffuse base is not weighted by 1 - F, as
// in Blender's Principled BSDF v1 (Cycles 3.x, the reference renderer): it is view-independent, and
// with the specular layer on top a white base reflects more than 1 at grazing wo. Single scattering
// only: rough surfaces lose the energy that multiple scattering between microfacets would return (no
// compensation). Sampling: the microfacet lobes (a visible normal, then reflection or refraction in
// proportion to their Fresnel-weighted albedos at that normal) or the diffuse base (cosine), chosen
// in proportion to estimates of their albedos seen from wo. pdf() is the density of that whole
// mixture; it leaves out delta lobes, which eval() leaves out too.
#pragma once

#include "common/math.h"
#include "worker/bsdf_sample.h"

namespace epr {

/// A metallic-roughness surface point (textures already applied).
struct MicrofacetInputs {
  Vec3 base{0.8f};  // base colour, linear RGB in [0, 1]
  float metallic = 0, roughness = 1, transmission = 0, ior = 1.5f;
  bool front = true;  // the path arrived at the front side (decides the direction of refraction)
};

class MicrofacetBsdf {
 public:
  MicrofacetBsdf() = default;
  /// n: the unit normal on the side wo lies on; wo: unit, back along the incoming ray.
  MicrofacetBsdf(const MicrofacetInputs& in, const Vec3& n, const Vec3& wo);

  Vec3 eval(const Vec3& wi) const;
  /// The diffuse base's share of eval(wi): (1 - metallic) (1 - t) c / pi above the surface, 0 below
  /// (the view-independent lobe, DESIGN.md "Diffuse-share reprojection").
  Vec3 eval_diffuse(const Vec3& wi) const;
  /// The diffuse base reflects something.
  bool has_diffuse() const { return valid_ && !is_black(diffuse_); }
  float pdf(const Vec3& wi) const;
  /// u_lobe picks the lobe, u the direction inside it.
  BsdfSample sample(float u_lobe, Vec2 u) const;

  /// Every lobe is a delta (a smooth metal or smooth glass): next event estimation finds nothing.
  bool delta_only() const { return smooth_ && p_micro_ >= 1; }
  /// An estimate of the total reflectance and transmittance seen from wo, at most 1.
  float albedo() const { return albedo_; }

 private:
  Vec3 eval_local(const Vec3& wi) const;
  float pdf_local(const Vec3& wi) const;
  /// Probability of reflecting (against refracting) at a microfacet seen at cosine cos_oh from wo.
  float reflect_share(float cos_oh) const;
  /// The generalised half vector of a refraction wo -> wi (wi.z < 0), facing +z.
  Vec3 refraction_half(const Vec3& wi) const;

  Frame frame_{};
  Vec3 wo_{0.f};  // local
  Vec3 c_{0.f};
  Vec3 diffuse_{0.f};  // the diffuse base's f, c (1 - metallic) (1 - t) / pi
  float metal_ = 0, trans_ = 0, alpha_ = 1, eta_ = 1.5f;
  float f_o_ = 0;      // dielectric Fresnel at cos_o
  float p_micro_ = 1;  // probability of sampling the microfacet lobes (else the diffuse base)
  float albedo_ = 0;
  bool smooth_ = false;  // alpha below ggx::kMinAlpha
  bool valid_ = false;   // wo lies above the surface
};

}  // namespace epr
