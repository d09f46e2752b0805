#include "worker/path_tracer.h"

#include <cmath>

#include "common/rng.h"
#include "worker/bsdf.h"

namespace epr {
namespace {

// One traced vertex, kept until the path ends and radiance can be propagated back.
struct PathVertex {
  Vec3 position, normal;  // normal oriented towards the previous vertex
  Vec3 le;                // emitted radiance at the vertex
  Vec3 direct;            // D_n, the next event estimate
  Vec3 weight;            // f cos / pdf / q for the continuation (0 if the path ended here)
  bool diffuse = true;
};

}  // namespace

PathTracer::PathTracer(const EmbreeScene& scene, const Camera& camera, uint64_t seed, RussianRoulette rr)
    : scene_(scene), camera_(camera), seed_(seed), rr_(rr) {
  const Scene& s = scene.scene();
  std::vector<float> weights;
  for (size_t i = 0; i < s.triangles.size(); ++i) {
    const Material& m = s.materials[s.material_of[i]];
    if (!m.emissive()) continue;
    const float w = s.area(i) * luminance(m.ke);
    if (!(w > 0)) continue;
    emitters_.push_back(uint32_t(i));
    weights.push_back(w);
  }
  emitter_distribution_ = DiscreteDistribution(weights);
}

bool PathTracer::sample_light(float u_select, Vec2 u, LightSample* out) const {
  if (emitters_.empty()) return false;
  float pmf = 0;
  const size_t k = emitter_distribution_.sample(u_select, &pmf);
  const uint32_t tri = emitters_[k];
  const Scene& s = scene_.scene();
  const auto& t = s.triangles[tri];
  const Vec2 b = sample_uniform_triangle(u);
  out->position = s.positions[t[0]] * b.x + s.positions[t[1]] * b.y + s.positions[t[2]] * (1 - b.x - b.y);
  out->normal = s.geometric_normal(tri);
  out->le = s.materials[s.material_of[tri]].ke;
  out->pdf_area = pmf / s.area(tri);
  return out->pdf_area > 0;
}

Vec3 PathTracer::albedo_at(const Material& m, uint32_t prim, float u, float v) const {
  const Scene& s = scene_.scene();
  if (m.kd_texture < 0 || s.uvs.empty()) return m.kd;
  const auto& uv = s.uvs[prim];
  const Vec2 st{uv[0].x * (1 - u - v) + uv[1].x * u + uv[2].x * v, uv[0].y * (1 - u - v) + uv[1].y * u + uv[2].y * v};
  return s.textures[size_t(m.kd_texture)].lookup(st);
}

Vec3 PathTracer::trace(int x, int y, uint32_t sample, std::vector<VertexRecord>* records, PathStats* stats) const {
  thread_local std::vector<PathVertex> path;
  path.clear();
  const Scene& s = scene_.scene();
  const float eps = scene_.ray_epsilon();
  SampleStream rng(seed_, uint32_t(y) * uint32_t(camera_.width()) + uint32_t(x), sample);

  const Vec2 film = rng.next2();
  Ray ray = camera_.generate_ray(float(x) + film.x, float(y) + film.y);
  uint64_t rays = 0;

  // ---- trace forwards: NEE and continuation at every vertex ----------------------------------------
  for (int depth = 1;; ++depth) {
    Hit hit;
    ++rays;
    if (!scene_.intersect(ray, 0.f, std::numeric_limits<float>::infinity(), &hit)) break;
    const Material& mat = s.materials[s.material_of[hit.prim]];
    PathVertex v;
    v.position = ray.origin + ray.dir * hit.t;
    const Vec3 ng = s.geometric_normal(hit.prim);
    v.normal = dot(ng, ray.dir) < 0 ? ng : -ng;
    v.le = mat.ke;  // two-sided diffuse emitter
    v.diffuse = mat.diffuse();
    const Vec3 wo = -ray.dir;
    const Bsdf bsdf(mat, albedo_at(mat, hit.prim, hit.u, hit.v), v.normal, wo);
    const Vec3 origin = v.position + v.normal * eps;

    // Next event estimation: one shadow ray to a point on the emitters.
    const float u_light = rng.next();
    const Vec2 u_point = rng.next2();
    LightSample ls;
    if (sample_light(u_light, u_point, &ls)) {
      // Geometry from the true surface point (an offset origin would give coplanar emitters a
      // spurious cosine with a 1/d^4 singularity); the offset is only for the shadow ray.
      Vec3 to_light = ls.position - v.position;
      const float dist2 = dot(to_light, to_light);
      const float dist = std::sqrt(dist2);
      if (dist > 4 * eps) {
        to_light = to_light / dist;
        const float cos_x = dot(v.normal, to_light);
        const float cos_y = std::abs(dot(ls.normal, to_light));
        if (cos_x > 0 && cos_y > 0) {
          ++rays;
          const Vec3 shadow = ls.position - origin;
          const float shadow_len = length(shadow);
          if (!scene_.occluded(origin, shadow / shadow_len, 0.f, shadow_len - 2 * eps))
            v.direct = bsdf.eval(to_light) * ls.le * (cos_x * cos_y / (dist2 * ls.pdf_area));
        }
      }
    }

    // Russian roulette: q is the probability of continuing from this vertex.
    float q = 1;
    if (depth >= rr_.max_depth) {
      q = 0;
    } else if (rr_.mode == RussianRoulette::Mode::kPaper && depth > rr_.start_depth) {
      q = 1 - rr_.termination;
    } else if (rr_.mode == RussianRoulette::Mode::kAlbedo && depth > rr_.start_depth) {
      q = std::clamp(bsdf.albedo(), 0.05f, 1.f);
    }
    const float u_rr = rng.next();
    const float u_lobe = rng.next();
    const Vec2 u_dir = rng.next2();
    if (u_rr < q) {
      const BsdfSample bs = bsdf.sample(u_lobe, u_dir);
      if (bs.valid && !is_black(bs.weight)) {
        v.weight = bs.weight / q;
        ray = {origin, bs.wi};
      }
    }
    path.push_back(v);
    if (is_black(v.weight)) break;
  }

  // ---- propagate radiance back: R_n = D_n + w_n R_{n+1} -----------------------------------------------
  Vec3 r(0.f);
  const size_t first_record = records ? records->size() : 0;
  if (records && path.size() > 1) records->resize(first_record + path.size() - 1);
  for (size_t i = path.size(); i-- > 0;) {
    const PathVertex& v = path[i];
    r = v.direct + v.weight * r;
    if (i >= 1 && records) {
      VertexRecord& rec = (*records)[first_record + i - 1];
      rec.position = v.position;
      rec.normal = v.normal;
      rec.radiance = v.le + r;
      rec.flags = v.diffuse ? VertexRecord::kDiffuse : 0;
    }
  }
  Vec3 pixel = path.empty() ? Vec3(0.f) : path[0].le + r;

  if (stats) {
    stats->paths += 1;
    stats->vertices += path.size();
    stats->rays += rays;
  }
  if (!is_finite(pixel)) {
    // Never let a NaN reach the image; drop this path's sample and its vertices.
    if (stats) stats->nonfinite_dropped += 1;
    if (records) records->resize(first_record);
    pixel = Vec3(0.f);
  }
  return pixel;
}

}  // namespace epr
