// Light from outside as the path tracer samples it (DESIGN.md, "Sky and sun"): the environment
// (common/lighting.h) and the sun, each a technique of next event estimation combined with BSDF
// sampling by MIS, like the emitting triangles.
//
// Light selection: one uniform number picks emitting triangles with probability triangle_share()
// (1/2 when the scene also has a sky, else 1 or 0), else the sky; within the sky the environment and
// the sun share in proportion to the irradiance each gives a surface facing it (pi x the mean
// luminance of the environment, the luminance of the sun's irradiance). Each sky light's density in
// solid angle, selection included, is what both MIS halves use:
//   * environment image: a 2D piecewise-constant distribution over the image's texels, texel weight
//     luminance x sin(theta) (theta at the texel's centre), uniform within a texel in (u, t); in
//     solid angle pdf = p(u, t) / (2 pi^2 sin(theta)).
//   * constant environment: cosine-weighted about the shading vertex's normal, pdf = cos / pi.
//   * sun: uniform in its cone of half angle h, pdf = 1 / (2 pi (1 - cos h)).
// A BSDF-sampled ray that escapes gathers each sky light's radiance weighted by the power heuristic
// against that light's density (sky_escape); shadow rays towards the sky are unbounded.
#pragma once

#include <vector>

#include "common/lighting.h"
#include "common/sampling.h"
#include "worker/bsdf.h"
#include "worker/embree_scene.h"

namespace epr {

class SkyLight {
 public:
  /// `triangle_emitters`: whether the scene has emitting triangles to share the light selection with.
  SkyLight(const Lighting& lighting, bool triangle_emitters);

  /// True if neither an environment nor a sun gives light.
  bool empty() const { return p_env_ == 0 && p_sun_ == 0; }
  /// Probability that next event estimation picks the emitting triangles.
  float triangle_share() const { return p_tri_; }

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

  std::optional<EnvironmentLight> env_;
  std::optional<SunLight> sun_;
  float p_tri_ = 0, p_env_ = 0, p_sun_ = 0;
  float rotation_ = 0;  // radians
  // Environment image: texel weights (luminance x sin theta), their total, and the 2D distribution.
  int w_ = 0, h_ = 0;
  std::vector<float> weight_;
  double total_weight_ = 0;
  DiscreteDistribution rows_;
  std::vector<DiscreteDistribution> columns_;
  // Sun: frame about its direction, cone, radiance.
  Frame sun_frame_;
  float sun_cos_ = 1, sun_one_minus_cos_ = 0;
  Vec3 sun_l_{0.f};
};

/// Next event estimation towards the sky from a vertex (position p, normal n, shadow-ray origin
/// `origin`): the light sample sky.sample(u, u_dir, n), an unbounded shadow ray, and f cos L / pdf,
/// weighted by the power heuristic against the BSDF's density when `mis`. Counts the ray in *rays.
Vec3 sky_next_event(const SkyLight& sky, const EmbreeScene& scene, const Bsdf& bsdf, const Vec3& n, const Vec3& origin,
                    float u, Vec2 u_dir, bool mis, uint64_t* rays);

}  // namespace epr
