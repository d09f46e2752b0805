// Shared views of two cameras: view_overlap.h.
#include "master/view_overlap.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <span>

#include "master/deep_framebuffer.h"

namespace epr {

ViewProbe view_probe(const SceneBvh& scene, const CameraSpec& spec, int width, int height) {
  const double aspect = double(std::max(width, 1)) / double(std::max(height, 1));
  int w = kViewProbeSide, h = kViewProbeSide;
  if (aspect >= 1)
    h = std::clamp(int(std::lround(kViewProbeSide / aspect)), 1, kViewProbeSide);
  else
    w = std::clamp(int(std::lround(kViewProbeSide * aspect)), 1, kViewProbeSide);
  ViewProbe p{Camera(spec, w, h), kNearPlane * scene.scene().bounds().diagonal_length(), {}, {}};
  const EmbreeBvh& bvh = scene.bvh();
  // One coherent stream per row of texels.
  const size_t n = size_t(w) * size_t(h);
  std::vector<Ray> rays(n);
  std::vector<float> tnear(n);
  std::vector<Hit> hits(n);
  tbb::parallel_for(0, h, [&](int y) {
    const size_t row = size_t(y) * size_t(w);
    for (int x = 0; x < w; ++x) {
      rays[row + size_t(x)] = p.camera.generate_ray(float(x) + 0.5f, float(y) + 0.5f);
      tnear[row + size_t(x)] = p.near / dot(rays[row + size_t(x)].dir, p.camera.forward());
    }
    bvh.intersect_coherent(std::span<const Ray>(rays).subspan(row, size_t(w)),
                           std::span<const float>(tnear).subspan(row, size_t(w)),
                           std::span<Hit>(hits).subspan(row, size_t(w)));
  });
  for (size_t i = 0; i < n; ++i) {
    if (hits[i].prim == EmbreeBvh::kMissed) continue;
    p.points.push_back(rays[i].origin + rays[i].dir * hits[i].t);
    p.normals.push_back(normalize(hits[i].ng));
  }
  return p;
}

double view_share(const ViewProbe& a, const ViewProbe& b, const SceneBvh& scene) {
  if (a.points.empty()) return 1.0;
  const EmbreeBvh& bvh = scene.bvh();
  const Vec3 eye_a = a.camera.eye(), eye_b = b.camera.eye(), forward_b = b.camera.forward();
  const float w = float(b.camera.width()), h = float(b.camera.height());
  const size_t shared = tbb::parallel_reduce(
      tbb::blocked_range<size_t>(0, a.points.size(), 256), size_t(0),
      [&](const tbb::blocked_range<size_t>& range, size_t count) {
        for (size_t i = range.begin(); i != range.end(); ++i) {
          const Vec3 p = a.points[i];
          float rx, ry;
          if (!b.camera.project(p, &rx, &ry) || !(rx >= 0 && ry >= 0 && rx < w && ry < h)) continue;
          const Vec3 d = p - eye_b;
          const float depth = dot(d, forward_b);
          if (!(depth > b.near)) continue;
          // The side of the surface a sees must face b too.
          const Vec3 n = a.normals[i];
          if (dot(n, eye_a - p) * dot(n, -d) <= 0) continue;
          // Nothing between b's near plane and the point (its last kViewProbeTolerance of the way left out).
          if (!bvh.occluded(eye_b, d, b.near / depth, 1.f - kViewProbeTolerance)) ++count;
        }
        return count;
      },
      std::plus<size_t>());
  return double(shared) / double(a.points.size());
}

double mutual_view_share(const ViewProbe& a, const ViewProbe& b, const SceneBvh& scene) {
  return std::min(view_share(a, b, scene), view_share(b, a, scene));
}

}  // namespace epr
