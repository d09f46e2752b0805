// CPU deep-framebuffer builder and shared helpers. See deep_framebuffer.h.
#include "master/deep_framebuffer.h"

#include <fmt/format.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <future>
#include <stdexcept>

#include "common/log.h"
#include "master/gl_context.h"

namespace epr {

size_t DeepFramebuffer::covered_count() const {
  size_t n = 0;
  for (uint8_t c : covered) n += c;
  return n;
}

void DeepFramebuffer::resize(int w, int h, int s) {
  width = w;
  height = h;
  subpixels = s;
  const size_t n = texel_count();
  position.assign(3 * n, 0.f);
  normal.assign(3 * n, 0.f);
  plane_offset.assign(n, 0.f);
  covered.assign(n, 0);
  triangle.assign(n, kNoTriangle);
}

TrianglePlane plane_of(const Scene& scene, size_t tri) {
  const Vec3 n = scene.geometric_normal(tri);
  return {n, dot(n, scene.positions[scene.triangles[tri][0]])};
}

void detail::check_deep_framebuffer_grid(const Camera& camera, int subpixels) {
  if (subpixels < 1 || subpixels > 16)
    throw std::invalid_argument(fmt::format("subpixels {} outside [1, 16]", subpixels));
  if (int64_t(camera.width()) * subpixels > 16384 || int64_t(camera.height()) * subpixels > 16384)
    throw std::invalid_argument(fmt::format("deep framebuffer {}x{} x S={} exceeds 16384 texels per axis",
                                            camera.width(), camera.height(), subpixels));
}

namespace {

struct CpuTriangle {
  Vec3 v0, e1, e2;
  int x0, x1, y0, y1;  // inclusive texel bounding box, empty if x0 > x1
};

}  // namespace

DeepFramebuffer build_deep_framebuffer_cpu(const Scene& scene, const Camera& camera, int subpixels) {
  detail::check_deep_framebuffer_grid(camera, subpixels);
  const int S = subpixels, W = camera.width() * S, H = camera.height() * S;
  DeepFramebuffer dfb;
  dfb.resize(W, H, S);
  const float near = kNearPlane * scene.bounds().diagonal_length();

  // Per triangle: Moller-Trumbore data and a conservative texel bounding box (whole grid when a
  // corner is at or behind the near plane: no clipping needed, the ray test is exact anyway).
  std::vector<CpuTriangle> tris(scene.triangle_count());
  tbb::parallel_for(size_t(0), tris.size(), [&](size_t t) {
    const auto& idx = scene.triangles[t];
    const Vec3 a = scene.positions[idx[0]], b = scene.positions[idx[1]], c = scene.positions[idx[2]];
    CpuTriangle& ct = tris[t];
    ct.v0 = a;
    ct.e1 = b - a;
    ct.e2 = c - a;
    float lo_x = INFINITY, lo_y = INFINITY, hi_x = -INFINITY, hi_y = -INFINITY;
    bool all_in_front = true;
    for (const Vec3& p : {a, b, c}) {
      float rx, ry;
      if (dot(p - camera.eye(), camera.forward()) <= near || !camera.project(p, &rx, &ry)) {
        all_in_front = false;
        break;
      }
      lo_x = std::min(lo_x, rx * float(S)), hi_x = std::max(hi_x, rx * float(S));
      lo_y = std::min(lo_y, ry * float(S)), hi_y = std::max(hi_y, ry * float(S));
    }
    if (!all_in_front) {
      ct.x0 = 0, ct.y0 = 0, ct.x1 = W - 1, ct.y1 = H - 1;
      return;
    }
    // Texel centres i + 0.5 in [lo, hi], widened by one texel against rounding.
    auto clampi = [](double v, int lo, int hi) { return int(std::clamp(v, double(lo), double(hi))); };
    ct.x0 = clampi(std::floor(lo_x - 0.5) - 1, 0, W), ct.x1 = clampi(std::ceil(hi_x - 0.5) + 1, -1, W - 1);
    ct.y0 = clampi(std::floor(lo_y - 0.5) - 1, 0, H), ct.y1 = clampi(std::ceil(hi_y - 0.5) + 1, -1, H - 1);
  });

  constexpr int kBand = 16;
  std::vector<float> depth(dfb.texel_count(), INFINITY);
  tbb::parallel_for(0, (H + kBand - 1) / kBand, [&](int band) {
    const int ya = band * kBand, yb = std::min(H, ya + kBand) - 1;
    for (size_t t = 0; t < tris.size(); ++t) {
      const CpuTriangle& ct = tris[t];
      if (ct.x0 > ct.x1 || ct.y1 < ya || ct.y0 > yb) continue;
      for (int y = std::max(ya, ct.y0); y <= std::min(yb, ct.y1); ++y)
        for (int x = ct.x0; x <= ct.x1; ++x) {
          const Ray r = camera.generate_ray((float(x) + 0.5f) / float(S), (float(y) + 0.5f) / float(S));
          // Moller-Trumbore, edges inclusive.
          const Vec3 p = cross(r.dir, ct.e2);
          const float det = dot(ct.e1, p);
          if (det == 0.f || !std::isfinite(det)) continue;
          const float inv = 1.f / det;
          const Vec3 s = r.origin - ct.v0;
          const float u = dot(s, p) * inv;
          if (!(u >= 0.f && u <= 1.f)) continue;
          const Vec3 q = cross(s, ct.e1);
          const float v = dot(r.dir, q) * inv;
          if (!(v >= 0.f && u + v <= 1.f)) continue;
          const float tt = dot(ct.e2, q) * inv;
          if (!(tt * dot(r.dir, camera.forward()) > near)) continue;
          const size_t k = dfb.index(x, y);
          if (!(tt < depth[k])) continue;  // ties keep the lower triangle index
          depth[k] = tt;
          dfb.triangle[k] = uint32_t(t);
          const Vec3 hit = r.origin + r.dir * tt;
          dfb.position[3 * k] = hit.x, dfb.position[3 * k + 1] = hit.y, dfb.position[3 * k + 2] = hit.z;
        }
    }
  });

  // Planes from the triangle table (identical to the GL builder's).
  tbb::parallel_for(size_t(0), dfb.texel_count(), [&](size_t k) {
    if (dfb.triangle[k] == DeepFramebuffer::kNoTriangle) return;
    const TrianglePlane pl = plane_of(scene, dfb.triangle[k]);
    dfb.covered[k] = 1;
    dfb.normal[3 * k] = pl.normal.x, dfb.normal[3 * k + 1] = pl.normal.y, dfb.normal[3 * k + 2] = pl.normal.z;
    dfb.plane_offset[k] = pl.offset;
  });
  return dfb;
}

DeepFramebuffer build_deep_framebuffer(const Scene& scene, const Camera& camera, int subpixels) {
  if (!gl_available()) return build_deep_framebuffer_cpu(scene, camera, subpixels);
  // A private context on a thread of its own, so that a context current on the caller is left alone.
  return std::async(std::launch::async,
                    [&] {
                      GlContext gl;
                      return build_deep_framebuffer_gl(gl, scene, camera, subpixels);
                    })
      .get();
}

}  // namespace epr
