// Unidirectional path tracer that records its eye-path vertices for reprojection (DESIGN.md section 1).
//
// Per vertex x_n: next event estimation (one shadow ray to a point on the emitters, chosen by area x
// luminance of Ke), then a BSDF-sampled continuation and Russian roulette. Radiance is propagated
// back once the path ends:
//     R_N = D_N,  R_n = D_n + (f_n cos_n / pdf_n / q_n) R_{n+1},  pixel sample = Le(x_1) + R_1
// D_n, the direct light reflected at x_n, is one of two estimators:
//   * MIS (default): multiple importance sampling with the power heuristic (beta 2) of the shadow
//     ray's light sample, weighted w_light = p_light^2 / (p_light^2 + p_bsdf^2), and the emission
//     Le(x_{n+1}) the continuation ray hits, weighted w_bsdf = p_bsdf^2 / (p_light^2 + p_bsdf^2)
//     and carried by f cos / pdf / q. Both densities in solid angle at x_n; p_light = emitter pmf /
//     area * dist^2 / |cos at the light|. Removes the 1/d^2 fireflies next to area lights.
//   * next event estimation only (DESIGN.md section 1; `mis` false): emission found by a
//     BSDF-sampled ray after the first vertex is not added (NEE counts it). Bit-identical to the
//     tracer before MIS.
// Either way every x_n with n >= 2 is recorded with radiance Le(x_n) + R_n (see trace()), except that
// a microfacet vertex with a diffuse base records only that base's share, Le(x_n) + R_n^d.
// Light from outside (worker/sky_light.h) is one more pair of techniques: next event estimation
// picks the sky or the triangles, and a continuation ray that escapes adds the sky's MIS-weighted
// radiance to D_n like an emitter it hits; a camera ray that escapes sees the sky (no record).
//
// Parameters: RussianRoulette (common/roulette.h, applied by worker/roulette.h); `mis`; the seed and the sampler of the
// path's random numbers (common/sampler.h: Sobol-Burley by default, or independent per dimension). Determinism: a path
// depends only on (seed, pixel, sample index): same inputs, same bits. Caveat: a hard depth cap (`max_depth`, default
// 1024) stops pathological paths; its bias is below float precision for albedos < 0.95 with the paper's roulette.
#pragma once

#include <cstdint>
#include <vector>

#include "common/camera.h"
#include "common/render_options.h"
#include "common/sampler.h"
#include "common/sampling.h"
#include "common/tile.h"
#include "common/vertex_record.h"
#include "worker/embree_scene.h"
#include "worker/sky_light.h"

namespace epr {

class PathTracer {
 public:
  /// `sky` (may be null: no light from outside) must outlive the tracer.
  PathTracer(const EmbreeScene& scene, const Camera& camera, uint64_t seed, RussianRoulette rr, bool mis = true,
             SamplerKind sampler = SamplerKind::kSobolBurley, const SkyLight* sky = nullptr);

  /// Traces path number `sample` of pixel (x, y); returns the pixel sample Le(x_1) + R_1. When
  /// `vertices` is not null, appends one record per vertex x_n, n >= 2.
  /// With `glossy` (may be null), also the part of the sample the master must not combine with
  /// reprojected samples: at a first vertex with glossy lobes beside a diffuse base, what the glossy
  /// lobes reflect (the sample minus Le(x_1) + R_1^d, clamped to >= 0 against rounding); else 0.
  /// A sample that comes out NaN or infinite is dropped: counted in stats->nonfinite_dropped, its
  /// records removed, 0 returned (and 0 in *glossy).
  Vec3 trace(int x, int y, uint32_t sample, std::vector<VertexRecord>* vertices, PathStats* stats,
             Vec3* glossy = nullptr) const;
  /// trace() keeping a NaN or infinite sample as it came out, with its records and not counted as
  /// dropped: the replay of a dropped sample (`epr render --single-process --trace-path`).
  Vec3 trace_unfiltered(int x, int y, uint32_t sample, std::vector<VertexRecord>* vertices, PathStats* stats,
                        Vec3* glossy = nullptr) const;

  const Camera& camera() const { return camera_; }
  uint64_t seed() const { return seed_; }
  const EmbreeScene& scene() const { return scene_; }
  bool mis() const { return mis_; }
  SamplerKind sampler() const { return sampler_; }

 private:
  Vec3 albedo_at(const Material& m, uint32_t prim, float u, float v) const;

  const EmbreeScene& scene_;
  Camera camera_;
  uint64_t seed_;
  RussianRoulette rr_;
  bool mis_ = true;
  SamplerKind sampler_ = SamplerKind::kSobolBurley;
  const SkyLight* sky_ = nullptr;  // null or empty: no light from outside
  float triangle_share_ = 1;       // probability that light selection picks the emitting triangles
};

}  // namespace epr
