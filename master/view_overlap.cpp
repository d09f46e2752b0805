// Shared views of two cameras: view_overlap.h.
#include "master/view_overlap.h"

#include <algorithm>
#include <cmath>

namespace epr {

ViewProbe view_probe(const Scene& scene, const CameraSpec& spec, int width, int height, GlContext* gl) {
  const double aspect = double(std::max(width, 1)) / double(std::max(height, 1));
  int w = kViewProbeSide, h = kViewProbeSide;
  if (aspect >= 1)
    h = std::clamp(int(std::lround(kViewProbeSide / aspect)), 1, kViewProbeSide);
  else
    w = std::clamp(int(std::lround(kViewProbeSide * aspect)), 1, kViewProbeSide);
  ViewProbe p{Camera(spec, w, h), {}};
  p.view = gl ? build_deep_framebuffer_gl(*gl, scene, p.camera, 1) : build_deep_framebuffer_cpu(scene, p.camera, 1);
  return p;
}

double view_share(const ViewProbe& a, const ViewProbe& b) {
  const DeepFramebuffer& va = a.view;
  const DeepFramebuffer& vb = b.view;
  const Vec3 eye_a = a.camera.eye(), eye_b = b.camera.eye();
  size_t covered = 0, shared = 0;
  for (size_t t = 0; t < va.texel_count(); ++t) {
    if (!va.covered[t]) continue;
    ++covered;
    const Vec3 p = va.position_at(t);
    float rx, ry;
    if (!b.camera.project(p, &rx, &ry)) continue;
    if (!(rx >= 0 && ry >= 0 && rx < float(vb.width) && ry < float(vb.height))) continue;
    const size_t u = vb.index(int(rx), int(ry));
    if (!vb.covered[u]) continue;
    // The side of the surface a sees must face b too.
    const Vec3 n = va.normal_at(t);
    if (dot(n, eye_a - p) * dot(n, eye_b - p) <= 0) continue;
    // On the plane b sees there (not behind it, not in front of it).
    const float off = std::fabs(dot(vb.normal_at(u), p) - vb.plane_offset[u]);
    if (off <= kViewProbeTolerance * length(p - eye_b)) ++shared;
  }
  return covered ? double(shared) / double(covered) : 1.0;
}

double mutual_view_share(const ViewProbe& a, const ViewProbe& b) {
  return std::min(view_share(a, b), view_share(b, a));
}

}  // namespace epr
