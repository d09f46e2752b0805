// Light from outside and the lamps as the path tracer samples them (DESIGN.md, "Sky and sun";
// scenes/README.md, "Lamps"): the environment (common/lighting.h), the suns (the job's or scene's sun
// and the scene's directional lights, common/lights.h), each a technique of next event estimation
// combined with BSDF sampling by MIS like the emitting triangles, and the scene's point and spot
// lights, delta lights that only next event estimation reaches (weight 1: BSDF sampling cannot hit
// them).
//
// Light selection: one uniform number picks emitting triangles with probability triangle_share(),
// else one of the other lights, each in proportion to an estimate of its power reaching the scene:
// the environment's and each sun's irradiance on a surface facing it (pi x the mean luminance of the
// environment, the luminance of the sun's irradiance) times the cross-section of the scene's
// bounding sphere, pi R^2 (R half the bounding box's diagonal); a point light's 4 pi x luminance(I),
// a spot's cone solid angle x luminance(I). The triangles' share follows the same estimate (as pbrt's
// power light sampler does): their emitted power, 2 pi x the sum of area x luminance(Ke) (two-sided),
// against the other lights' total; clamped to [kMinLightShare, 1 - kMinLightShare] so that neither
// side starves where the estimate is wrong (an emitter or a sky hidden from most of the scene). 1 or
// 0 when only one side gives light. A pure function of the scene, so every worker picks alike. Each
// sky light's density in solid angle, selection included, is what both MIS halves use:
//   * environment image: a 2D piecewise-constant distribution over the image's texels, texel weight
//     luminance x sin(theta) (theta at the texel's centre), uniform within a texel in (u, t); in
//     solid angle pdf = p(u, t) / (2 pi^2 sin(theta)).
//   * constant environment: cosine-weighted about the shading vertex's normal, pdf = cos / pi.
//   * sun: uniform in its cone of half angle h, pdf = 1 / (2 pi (1 - cos h)).
// A BSDF-sampled ray that escapes gathers each sky light's radiance weighted by the power heuristic
// against that light's density (sky_escape); shadow rays towards the sky are unbounded, towards a
// point or spot light they end at it.
#pragma once

#include <limits>
#include <optional>
#include <span>
#include <vector>

#include "common/lighting.h"
#include "common/lights.h"
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
  /// The scene's lighting with `scene`'s emitting triangles (EmbreeScene::emitted_power()), lights
  /// (Scene::lights) and bounding sphere.
  SkyLight(const Lighting& lighting, const EmbreeScene& scene);
  /// The same from the triangles' power, the scene's bounding-sphere radius and its lights;
  /// `fixed_share`, if given, replaces the power-based triangle share when both sides give light
  /// (benchmarks, tests).
  SkyLight(const Lighting& lighting, double triangle_power, float scene_radius,
           std::optional<float> fixed_share = std::nullopt, std::span<const PunctualLight> lights = {});

  /// Half the diagonal of the scene's bounding box, metres.
  static float scene_radius(const Scene& scene);

  /// True if no environment, sun, point or spot light gives light.
  bool empty() const { return p_env_ == 0 && p_sun_ == 0 && p_punctual_ == 0; }
  /// True if light comes from outside the scene (common/lights.h lit_from_outside: an environment, a
  /// sun or a directional light that gives light; lamps are inside).
  bool from_outside() const { return from_outside_; }
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
    Vec3 radiance;  // of the chosen light along wi; a delta light: its irradiance I / d^2 facing it
    float pdf = 0;  // solid angle, selection included, 1/sr; a delta light: its selection probability
    float distance = std::numeric_limits<float>::infinity();  // to a point or spot light
    bool delta = false;                                       // a point or spot light
  };
  /// A direction towards the environment, a sun or a point or spot light (chosen by u) from point p;
  /// pdf 0 if none. `n` is the vertex's normal (the constant environment samples the cosine about it).
  Sample sample(float u, Vec2 u_dir, const Vec3& n, const Vec3& p = Vec3(0.f)) const;

  /// Radiance reaching a ray that leaves the scene along d, every sky light unweighted (a camera ray).
  Vec3 radiance(const Vec3& d) const;
  /// The same for a BSDF-sampled continuation from a vertex with normal n and density pdf_bsdf, each
  /// light's share weighted by the power heuristic against its own density (MIS).
  Vec3 escaped(const Vec3& d, const Vec3& n, float pdf_bsdf) const;

  /// Solid-angle densities (selection included) with which sample() returns d (pdf_sun: the suns'
  /// densities summed).
  float pdf_environment(const Vec3& d, const Vec3& n) const;
  float pdf_sun(const Vec3& d) const;
  /// The number of suns (the job's or scene's sun and the scene's directional lights) and of point
  /// and spot lights that give light.
  size_t sun_count() const { return suns_.size(); }
  size_t punctual_count() const { return punctual_.size(); }

 private:
  // One sun: a frame about its direction, its cone (sin^2 h and 1 - cos h, h the half angle), its
  // radiance and its probability of selection.
  struct Sun {
    Frame frame;
    float sin2 = 0, one_minus_cos = 0;
    Vec3 l{0.f};
    float p = 0;
    /// Unit direction d lies in the disc: |d x n| <= sin h on the sun's side. The sine, not the
    /// cosine, which float rounds to 1 for half angles below ~3e-4 rad (the disc would look ~0.03
    /// deg wide).
    bool contains(const Vec3& d) const;
    float pdf() const { return p / (2 * kPi * one_minus_cos); }
  };

  Vec3 env_radiance(const Vec3& d) const;
  Vec3 sun_radiance(const Vec3& d) const;

  std::optional<EnvironmentLight> env_;
  std::vector<Sun> suns_;
  std::vector<PunctualLight> punctual_;  // point and spot lights
  std::vector<float> p_punctual_each_;   // selection probability of each
  float p_tri_ = 0, p_env_ = 0, p_sun_ = 0, p_punctual_ = 0;
  bool from_outside_ = false;
  double triangle_power_ = 0, sky_power_ = 0;
  float rotation_ = 0;  // radians
  // Environment image: texel weights (luminance x sin theta), their total, and the 2D distribution.
  int w_ = 0, h_ = 0;
  std::vector<float> weight_;
  double total_weight_ = 0;
  DiscreteDistribution rows_;
  std::vector<DiscreteDistribution> columns_;
};

/// Next event estimation towards the sky and the point and spot lights from a vertex (normal n,
/// shadow-ray origin `origin`): the light sample sky.sample(u, u_dir, n, origin), a shadow ray
/// (unbounded towards the sky, ending at a point light), and f cos L / pdf, weighted by the power
/// heuristic against the BSDF's density when `mis` and the light is not a delta light. Counts the
/// ray in *rays. With `diffuse` (may be null) also the same estimate through the BSDF's diffuse lobe
/// alone (Bsdf::eval_diffuse).
Vec3 sky_next_event(const SkyLight& sky, const EmbreeScene& scene, const Bsdf& bsdf, const Vec3& n, const Vec3& origin,
                    float u, Vec2 u_dir, bool mis, uint64_t* rays, Vec3* diffuse = nullptr);

}  // namespace epr
