// Light from outside as the path tracer samples it (DESIGN.md, "Sky and sun"): the environment
// (common/lighting.h) and the sun, each a technique of next event estimation combined with BSDF
// sampling by MIS, like the emitting triangles.
//
// Light selection: one uniform number picks emitting triangles with probability triangle_share(),
// else the sky; within the sky the environment and the sun share in proportion to the irradiance
// each gives a surface facing it (pi x the mean luminance of the environment, the luminance of the
// sun's irradiance). The triangles' share follows an estimate of each side's power reaching the
// scene (as pbrt's power light sampler does): the triangles' emitted power, 2 pi x the sum of area x
// luminance(Ke) (two-sided), against the sky's irradiance on a disc of the scene's bounding-sphere
// cross-section, (pi L_env + E_sun) x pi R^2 (R half the bounding box's diagonal); clamped to
// [kMinLightShare, 1 - kMinLightShare] so that neither technique starves where the estimate is wrong
// (an emitter or a sky hidden from most of the scene). 1 or 0 when only one side gives light. A pure
// function of the scene, so every worker picks alike. Each sky light's density in solid angle,
// selection included, is what both MIS halves use:
//   * environment image: a 2D piecewise-constant distribution over the image's texels, texel weight
//     luminance x sin(theta) (theta at the texel's centre), uniform within a texel in (u, t); in
//     solid angle pdf = p(u, t) / (2 pi^2 sin(theta)).
//   * constant environment: cosine-weighted about the shading vertex's normal, pdf = cos / pi.
//   * sun: uniform in its cone of half angle h, pdf = 1 / (2 pi (1 - cos h)).
// A BSDF-sampled ray that escapes gathers each sky light's radiance weighted by the power heuristic
// against that light's density (sky_escape); shadow rays towards the sky are unbounded.
#pragma once

#include <optional>
#include <vector>

#include "common/lighting.h"
#include "common/sampling.h"
#include "worker/bsdf.h"
#include "worker/embree_scene.h"

namespace epr {

/// The floor of either side's share of the light selection when both give light.
inline constexpr float kMinLightShare = 0.25f;

/// The triangles' share of the light selection for the two powers (W, luminance): their fraction
/// of the total, clamped to [kMinLightShare, 1 - kMinLightShare]; 0 without triangle power, 1
/// without sky power.
float triangle_share_for_power(double triangle_power, double sky_power);

class SkyLight {
 public:
  /// The scene's lighting with `scene`'s emitting triangles (EmbreeScene::emitted_power()) and
  /// bounding sphere.
  SkyLight(const Lighting& lighting, const EmbreeScene& scene);
  /// The same from the triangles' power and the scene's bounding-sphere radius; `fixed_share`, if
  /// given, replaces the power-based triangle share when both sides give light (benchmarks, tests).
  SkyLight(const Lighting& lighting, double triangle_power, float scene_radius,
           std::optional<float> fixed_share = std::nullopt);

  /// Half the diagonal of the scene's bounding box, metres.
  static float scene_radius(const Scene& scene);

  /// True if neither an environment nor a sun gives light.
  bool empty() const { return p_env_ == 0 && p_sun_ == 0; }
  /// Probability that next event estimation picks the emitting triangles.
  float triangle_share() const { return p_tri_; }
  /// The power estimates the share follows (luminance, W): see the file comment.
  double triangle_power() const { return triangle_power_; }
  double sky_power() const { return sky_power_; }

  /// Splits the selection number: true if it picks the sky, with `u` rescaled to [0, 1) for the next
  /// choice either way (the triangle table's, or sample()'s).
  bool picks_sky(float u_select, float* u) const;

  struct Sample {
    Vec3 wi;        // unit direction towards the light
    Vec3 radiance;  // of the chosen light along wi
    float pdf = 0;  // solid angle, selection included, 1/sr
  };
  /// A direction towards the environment or the sun (chosen by u); pdf 0 if none. `n` is the vertex's
  /// normal (the constant environment samples the cosine about it).
  Sample sample(float u, Vec2 u_dir, const Vec3& n) const;

  /// Radiance reaching a ray that leaves the scene along d, every sky light unweighted (a camera ray).
  Vec3 radiance(const Vec3& d) const;
  /// The same for a BSDF-sampled continuation from a vertex with normal n and density pdf_bsdf, each
  /// light's share weighted by the power heuristic against its own density (MIS).
  Vec3 escaped(const Vec3& d, const Vec3& n, float pdf_bsdf) const;

  /// Solid-angle densities (selection included) with which sample() returns d.
  float pdf_environment(const Vec3& d, const Vec3& n) const;
  float pdf_sun(const Vec3& d) const;

 private:
  Vec3 env_radiance(const Vec3& d) const;
  Vec3 sun_radiance(const Vec3& d) const;
  /// Unit direction d lies in the sun's disc: |d x n| <= sin h on the sun's side. The sine, not the
  /// cosine, which float rounds to 1 for half angles below ~3e-4 rad (the disc would look ~0.03 deg wide).
  bool in_sun(const Vec3& d) const;

  std::optional<EnvironmentLight> env_;
  std::optional<SunLight> sun_;
  float p_tri_ = 0, p_env_ = 0, p_sun_ = 0;
  double triangle_power_ = 0, sky_power_ = 0;
  float rotation_ = 0;  // radians
  // Environment image: texel weights (luminance x sin theta), their total, and the 2D distribution.
  int w_ = 0, h_ = 0;
  std::vector<float> weight_;
  double total_weight_ = 0;
  DiscreteDistribution rows_;
  std::vector<DiscreteDistribution> columns_;
  // Sun: frame about its direction, cone, radiance.
  Frame sun_frame_;
  float sun_sin2_ = 0, sun_one_minus_cos_ = 0;  // sin^2 h and 1 - cos h, h the half angle
  Vec3 sun_l_{0.f};
};

/// Next event estimation towards the sky from a vertex (position p, normal n, shadow-ray origin
/// `origin`): the light sample sky.sample(u, u_dir, n), an unbounded shadow ray, and f cos L / pdf,
/// weighted by the power heuristic against the BSDF's density when `mis`. Counts the ray in *rays.
Vec3 sky_next_event(const SkyLight& sky, const EmbreeScene& scene, const Bsdf& bsdf, const Vec3& n, const Vec3& origin,
                    float u, Vec2 u_dir, bool mis, uint64_t* rays);

}  // namespace epr
