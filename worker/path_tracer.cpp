#include "worker/path_tracer.h"

#include <cmath>
#include <cstdlib>
#include <limits>

#include "common/check.h"
#include "common/sampler.h"
#include "common/shading_normal.h"
#include "worker/bsdf.h"
#include "worker/emitter_sampling.h"
#include "worker/roulette.h"
#include "worker/surface_inputs.h"

namespace epr {
namespace {

// One traced vertex, kept until the path ends and radiance can be propagated back.
struct PathVertex {
  Vec3 position, normal;       // geometric normal oriented towards the previous vertex
  Vec3 shading;                // shading normal the BSDF uses (common/shading_normal.h), same side
  Vec3 le;                     // emitted radiance at the vertex
  Vec3 direct;                 // D_n, the direct-light estimate (MIS-weighted, or NEE only)
  Vec3 weight;                 // f cos / pdf / q for the continuation (0 if the path ended here)
  float continuation_pdf = 0;  // solid-angle pdf of the continuation direction (BSDF sampling), 1/sr;
                               // kOnlyBsdf where next event estimation cannot pick it
  bool diffuse = true;
  // A microfacet vertex with a diffuse base beside its glossy lobes: its record carries the diffuse
  // base's share of its reflected light, from direct_diffuse and weight_diffuse (the same estimates
  // through that lobe alone, Bsdf::eval_diffuse). Otherwise the whole is diffuse or nothing is.
  bool split = false;
  Vec3 direct_diffuse, weight_diffuse;
};

// The continuation_pdf of a direction next event estimation never picks: a delta lobe's, or one
// below the surface (transmission; light samples lie above it). BSDF sampling is then the only
// technique (MIS weight power_heuristic(inf, p) = 1, also with MIS off).
constexpr float kOnlyBsdf = std::numeric_limits<float>::infinity();

// Power heuristic (beta = 2) weight of the technique with density p_this against p_other, written
// as 1 / (1 + (p_other / p_this)^2) so that a huge density (a grazing emitter) cannot overflow to
// inf / inf. p_this > 0.
inline float power_heuristic(float p_this, float p_other) {
  EPR_DCHECK_GT(p_this, 0.f);
  const float r = p_other / p_this;
  return 1 / (1 + r * r);
}

// A test hook: with EPR_TEST_NONFINITE_EVERY=N (N > 0) in the environment, every Nth path sample of
// a pixel (samples N-1, 2N-1, ...) comes out NaN. No valid scene makes non-finite samples, so the
// tests of the warnings a render's end gives about them (tests/integration/cluster/
// nonfinite_warning_test.cpp) set it on the real programs. 0 (unset): off.
uint32_t test_nonfinite_every() {
  static const uint32_t every = [] {
    const char* e = std::getenv("EPR_TEST_NONFINITE_EVERY");
    return e ? uint32_t(std::strtoul(e, nullptr, 10)) : 0u;
  }();
  return every;
}

}  // namespace

PathTracer::PathTracer(const EmbreeScene& scene, const Camera& camera, uint64_t seed, RussianRoulette rr, bool mis,
                       SamplerKind sampler, const SkyLight* sky)
    : scene_(scene),
      camera_(camera),
      seed_(seed),
      rr_(rr.resolved(sky && sky->from_outside())),
      mis_(mis),
      sampler_(sampler) {
  if (sky && !sky->empty()) {
    sky_ = sky;
    triangle_share_ = sky->triangle_share();
  }
}

Vec3 PathTracer::albedo_at(const Material& m, uint32_t prim, float u, float v) const {
  const Scene& s = scene_.scene();
  if (m.kd_texture < 0 || s.uvs.empty()) return m.kd;
  return s.textures[size_t(m.kd_texture)].lookup(texcoord_at(s, prim, u, v));
}

Vec3 PathTracer::trace(int x, int y, uint32_t sample, std::vector<VertexRecord>* records, PathStats* stats,
                       Vec3* glossy) const {
  const size_t first_record = records ? records->size() : 0;
  const Vec3 pixel = trace_unfiltered(x, y, sample, records, stats, glossy);
  if (is_finite(pixel)) return pixel;
  // Never let a NaN reach the image; drop this path's sample and its vertices.
  if (stats) stats->nonfinite_dropped += 1;
  if (records) records->resize(first_record);
  if (glossy) *glossy = Vec3(0.f);
  return Vec3(0.f);
}

Vec3 PathTracer::trace_unfiltered(int x, int y, uint32_t sample, std::vector<VertexRecord>* records, PathStats* stats,
                                  Vec3* glossy) const {
  thread_local std::vector<PathVertex> path;
  path.clear();
  const Scene& s = scene_.scene();
  const float eps = scene_.ray_epsilon();
  PathSampler rng(sampler_, seed_, uint32_t(y) * uint32_t(camera_.width()) + uint32_t(x), sample);

  const Vec2 film = rng.film();
  Ray ray = camera_.generate_ray(float(x) + film.x, float(y) + film.y);
  uint64_t rays = 0;
  Vec3 background(0.f);  // the sky seen by a camera ray that escapes
  PathRoulette roulette(rr_, camera_);

  // ---- trace forwards: NEE and continuation at every vertex ----------------------------------------
  for (int depth = 1;; ++depth) {
    Hit hit;
    ++rays;
    if (!scene_.intersect(ray, 0.f, std::numeric_limits<float>::infinity(), &hit)) {
      // The ray escapes: a camera ray shows the sky; a continuation ray's sky radiance is light
      // reflected at x_{n-1}, MIS-weighted into D_{n-1} as an emitter hit is below.
      if (sky_ && path.empty()) background = sky_->radiance(ray.dir);
      if (sky_ && !path.empty() && (mis_ || path.back().continuation_pdf == kOnlyBsdf)) {
        PathVertex& prev = path.back();
        const Vec3 sky = sky_->escaped(ray.dir, prev.shading, prev.continuation_pdf);
        prev.direct += prev.weight * sky;
        if (prev.split) prev.direct_diffuse += prev.weight_diffuse * sky;
      }
      break;
    }
    const Material& mat = s.materials[scene_.material(hit.prim)];
    // MIS, BSDF-sampling half: the continuation ray of x_{n-1} found emission at x_n. It is light
    // reflected at x_{n-1}, so it belongs to D_{n-1}, weighted by w_bsdf and carried by x_{n-1}'s
    // continuation weight f cos / pdf / q. (Le(x_n) itself stays in the vertex below unweighted:
    // see the back-propagation.) |cos| at the light; a one-sided emitter's back emits nothing.
    const float side = -dot(hit.ng, ray.dir);  // > 0: the ray arrives at the front
    const Vec3 le = emission_at(s, mat, mat.emitted(side), hit.prim, hit.u, hit.v);
    if (!path.empty() && !is_black(le) && (mis_ || path.back().continuation_pdf == kOnlyBsdf)) {
      PathVertex& prev = path.back();
      float w_bsdf = 1;  // an emitter next event estimation cannot pick: BSDF sampling is the only technique
      const float pdf_area = scene_.emitter_pdf_area(mat) * triangle_share_;
      if (pdf_area > 0) {
        const float ng_len = length(hit.ng);
        const float cos_y = std::abs(dot(hit.ng, ray.dir)) / ng_len;  // ray.dir is unit length
        const auto& tri = s.triangles[hit.prim];
        // p_light as next event estimation from x_{n-1} would have chosen this point (area or solid
        // angle: worker/emitter_sampling.h). Edge-on (cos 0) the area density is infinite;
        // prev.continuation_pdf > 0 (a sampled direction).
        w_bsdf = cos_y > 0
                     ? power_heuristic(prev.continuation_pdf,
                                       emitter_direction_pdf(prev.position, s.positions[tri[0]], s.positions[tri[1]],
                                                             s.positions[tri[2]], hit.ng * (1 / ng_len), pdf_area,
                                                             hit.t * hit.t, cos_y))
                     : 0.f;
      }
      prev.direct += prev.weight * le * w_bsdf;
      if (prev.split) prev.direct_diffuse += prev.weight_diffuse * le * w_bsdf;
    }
    // Filled in place: building the vertex on the stack and copying it costs more than its shading.
    PathVertex& v = path.emplace_back();
    v.position = ray.origin + ray.dir * hit.t;
    const Vec3 ng = hit.ng * (1 / length(hit.ng));
    v.normal = dot(ng, ray.dir) < 0 ? ng : -ng;
    v.le = le;  // diffuse emitter
    const HitNormals normals = hit_normals_towards(s, hit.prim, hit.u, hit.v, v.normal, -ray.dir);
    v.shading = normals.shading;
    const Vec3 base = albedo_at(mat, hit.prim, hit.u, hit.v);
    const Bsdf bsdf = mat.type == MaterialType::kMicrofacet
                          ? Bsdf(microfacet_inputs(s, mat, base, hit.prim, hit.u, hit.v, side > 0), v.normal, v.shading,
                                 -ray.dir, normals.smooth)
                          : Bsdf(mat, base, v.normal, v.shading, -ray.dir, normals.smooth);
    v.split = mat.type == MaterialType::kMicrofacet && bsdf.has_diffuse();
    v.diffuse = mat.diffuse() || v.split;
    const Vec3 origin = v.position + v.normal * eps;

    // This vertex's random numbers, in the fixed dimension layout of common/sampler.h.
    const PathSampler::Bounce u = rng.bounce();
    const float u_light = u.light_select, u_rr = u.rr, u_lobe = u.lobe;
    const Vec2 u_point = u.light_point, u_dir = u.dir;

    // Russian roulette (q is the probability of continuing from this vertex) and the continuation,
    // chosen before the shadow ray is cast: the two dependency chains then overlap, and the next
    // ray is ready when the shadow query returns.
    const float q = roulette.survival(depth, bsdf.albedo(), v.position, v.normal, v.diffuse);
    EPR_DCHECK_LE(q, 1.f);
    if (u_rr < q) {
      const BsdfSample bs = bsdf.sample(u_lobe, u_dir);
      if (bs.valid && !is_black(bs.weight)) {
        v.weight = bs.weight / q;
        roulette.continued(v.weight);
        EPR_DCHECK_GT(bs.pdf, 0.f);
        if (v.split && !bs.delta) v.weight_diffuse = bsdf.eval_diffuse(bs.wi) * (bsdf.cosine(bs.wi) / bs.pdf / q);
        const bool below = dot(bs.wi, v.normal) <= 0;  // transmitted: leaves from the other side
        v.continuation_pdf = bs.delta || below ? kOnlyBsdf : bs.pdf;
        ray = {below ? v.position - v.normal * eps : origin, bs.wi};
      }
    }

    // Next event estimation: one shadow ray to a point on the emitters, cast only when the estimate
    // can be non-zero (the surface reflects, the point is in front of it and it faces the point).
    // The sky (when there is one) takes its share of the selection number first.
    const Emitter* light = nullptr;
    if (!bsdf.black() && !bsdf.delta_only()) {
      float u_pick = u_light;
      if (sky_ && sky_->picks_sky(u_light, &u_pick))
        v.direct = sky_next_event(*sky_, scene_, bsdf, v.shading, origin, u_pick, u_point, mis_ && q > 0, &rays,
                                  v.split ? &v.direct_diffuse : nullptr);
      else
        light = scene_.sample_emitter(u_pick);
    }
    const EmitterPoint lp = light ? sample_emitter_point(*light, v.position, u_point) : EmitterPoint{};
    if (lp.valid) {
      const Vec3& light_pos = lp.pos;
      // Geometry from the true surface point (an offset origin would give coplanar emitters a
      // spurious cosine with a 1/d^4 singularity); the offset is only for the shadow ray.
      Vec3 to_light = light_pos - v.position;
      const float dist2 = dot(to_light, to_light);
      const float dist = std::sqrt(dist2);
      if (dist > 4 * eps) {
        const float inv_dist = 1 / dist;
        to_light = to_light * inv_dist;
        const float cos_x = bsdf.cosine(to_light);  // 0 below the geometric surface
        const float cos_y = light->cos_towards(to_light);
        if (cos_x > 0 && cos_y > 0) {
          ++rays;
          // The segment from the offset origin to the light point, parametrised over [0, 1] (Embree
          // takes directions of any length); it stops about 2 eps short of the emitter.
          if (!scene_.occluded(origin, light_pos - origin, 0.f, 1 - 2 * eps * inv_dist)) {
            // MIS, light-sampling half: w_light against the BSDF's density for the same direction,
            // both in solid angle at x_n. With q = 0 (depth cap) no continuation can be traced, so
            // BSDF sampling is no technique here and next event estimation keeps weight 1.
            const float light_pdf_area = light->pdf_area * triangle_share_;
            const float pdf_light =
                lp.solid_angle > 0 ? light_pdf_area * triangle_area(light->p0, light->p1, light->p2) / lp.solid_angle
                                   : light_pdf_area * dist2 / cos_y;
            EPR_DCHECK_GT(pdf_light, 0.f);
            float w_light = 1;
            if (mis_ && q > 0) w_light = power_heuristic(pdf_light, bsdf.pdf(to_light));
            Vec3 le_light = light->le;  // Ke, times the emission texture at the point if it has one
            if (const Material& lm = s.materials[s.material_of[light->tri]]; lm.ke_texture >= 0) {
              const Vec2 b = barycentrics_of(s, light->tri, light_pos);
              le_light = emission_at(s, lm, light->le, light->tri, b.x, b.y);
            }
            v.direct = bsdf.eval(to_light) * le_light * (w_light * cos_x / pdf_light);
            if (v.split) v.direct_diffuse = bsdf.eval_diffuse(to_light) * le_light * (w_light * cos_x / pdf_light);
          }
        }
      }
    }
    if (is_black(v.weight)) break;
  }

  // ---- propagate radiance back: R_n = D_n + w_n R_{n+1} -----------------------------------------------
  // R_n estimates the radiance x_n reflects towards x_{n-1} (its own emission excluded), whatever
  // the direct-light estimator: with MIS, D_n = w_light NEE_n + w_n w_bsdf Le(x_{n+1}) has the
  // expectation of NEE_n alone (the two weights sum to 1 for every direction: standard MIS), and
  // w_n R_{n+1} estimates the rest of the reflected light as before. A record of x_n, n >= 2, is the
  // radiance leaving x_n towards x_{n-1}, Le(x_n) + R_n, with Le(x_n) unweighted: the MIS-weighted
  // share of Le(x_n) went into D_{n-1} (the estimate of x_{n-1}'s reflected light, part of its own
  // record) and is a different quantity. Reprojection then shows x_n with Le + R_n from any other
  // pixel, exactly as a path-traced sample of x_n would: Le(x_1) + R_1.
  // A split vertex's record holds Le + R_n^d instead, R_n^d = D_n^d + w_n^d R_{n+1} the light its
  // diffuse base reflects (the view-independent part), and the pixel's own sample is split the same
  // way at x_1: *glossy gets Le(x_1) + R_1 - (Le(x_1) + R_1^d), the part the master adds unchanged
  // rather than combining it with reprojected samples (DESIGN.md "Diffuse-share reprojection").
  Vec3 r(0.f), r_diffuse(0.f);
  const size_t first_record = records ? records->size() : 0;
  if (records && path.size() > 1) records->resize(first_record + path.size() - 1);
  for (size_t i = path.size(); i-- > 0;) {
    const PathVertex& v = path[i];
    if (v.split) r_diffuse = v.direct_diffuse + v.weight_diffuse * r;
    r = v.direct + v.weight * r;
    if (i >= 1 && records) {
      VertexRecord& rec = (*records)[first_record + i - 1];
      rec.position = v.position;
      rec.normal = v.normal;
      rec.radiance = v.le + (v.split ? r_diffuse : r);
      rec.flags = v.diffuse ? VertexRecord::kDiffuse : 0;
    }
  }
  Vec3 pixel = path.empty() ? background : path[0].le + r;
  Vec3 own_glossy(0.f);
  if (!path.empty() && path[0].split) own_glossy = max(pixel - (path[0].le + r_diffuse), Vec3(0.f));
  if (const uint32_t every = test_nonfinite_every(); every && (sample + 1) % every == 0)
    pixel = Vec3(std::numeric_limits<float>::quiet_NaN());

  if (stats) {
    stats->paths += 1;
    stats->vertices += path.size();
    stats->rays += rays;
  }
  if (glossy) *glossy = own_glossy;
  return pixel;
}

}  // namespace epr
