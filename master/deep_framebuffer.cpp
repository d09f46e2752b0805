// CPU deep-framebuffer builder and shared helpers. See deep_framebuffer.h.
#include "master/deep_framebuffer.h"

#include <fmt/format.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <future>
#include <stdexcept>

#include "common/limits.h"
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
  first_row = 0;
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

std::vector<TrianglePlane> detail::triangle_planes(const Scene& scene) {
  std::vector<TrianglePlane> planes(scene.triangle_count());
  tbb::parallel_for(size_t(0), planes.size(), [&](size_t t) { planes[t] = plane_of(scene, t); });
  return planes;
}

void detail::check_deep_framebuffer_grid(const Camera& camera, int subpixels) {
  if (subpixels < 1 || subpixels > 16)
    throw std::invalid_argument(fmt::format("subpixels {} outside [1, 16]", subpixels));
  if (int64_t(camera.width()) * subpixels > limits::kMaxGridSide ||
      int64_t(camera.height()) * subpixels > limits::kMaxGridSide)
    throw std::invalid_argument(fmt::format("deep framebuffer {}x{} x S={} exceeds {} texels per axis", camera.width(),
                                            camera.height(), subpixels, limits::kMaxGridSide));
}

namespace detail {

std::vector<ScreenTriangle> screen_triangles(const Scene& scene, const Camera& camera, int S, float near) {
  // Per triangle: Moller-Trumbore data and a conservative texel bounding box of the full grid (whole
  // grid when a corner is at or behind the near plane: no clipping needed, the ray test is exact anyway).
  const int W = camera.width() * S, H = camera.height() * S;
  std::vector<ScreenTriangle> tris(scene.triangle_count());
  tbb::parallel_for(size_t(0), tris.size(), [&](size_t t) {
    const auto& idx = scene.triangles[t];
    const Vec3 a = scene.positions[idx[0]], b = scene.positions[idx[1]], c = scene.positions[idx[2]];
    ScreenTriangle& ct = tris[t];
    ct.v0 = a;
    ct.e1 = b - a;
    ct.e2 = c - a;
    float lo_x = INFINITY, lo_y = INFINITY, hi_x = -INFINITY, hi_y = -INFINITY;
    for (const Vec3& p : {a, b, c}) {
      float rx, ry;
      if (dot(p - camera.eye(), camera.forward()) <= near || !camera.project(p, &rx, &ry)) {
        ct.x0 = 0, ct.y0 = 0, ct.x1 = W - 1, ct.y1 = H - 1;
        return;
      }
      lo_x = std::min(lo_x, rx * float(S)), hi_x = std::max(hi_x, rx * float(S));
      lo_y = std::min(lo_y, ry * float(S)), hi_y = std::max(hi_y, ry * float(S));
    }
    // Texel centres i + 0.5 in [lo, hi], widened by one texel against rounding.
    auto clampi = [](double v, int lo, int hi) { return int(std::clamp(v, double(lo), double(hi))); };
    ct.x0 = clampi(std::floor(lo_x - 0.5) - 1, 0, W), ct.x1 = clampi(std::ceil(hi_x - 0.5) + 1, -1, W - 1);
    ct.y0 = clampi(std::floor(lo_y - 0.5) - 1, 0, H), ct.y1 = clampi(std::ceil(hi_y - 0.5) + 1, -1, H - 1);
  });
  return tris;
}

std::vector<uint8_t> cut_out_triangles(const Scene& scene) {
  if (!scene.has_cut_outs()) return {};
  std::vector<uint8_t> cut(scene.triangle_count());
  for (size_t t = 0; t < cut.size(); ++t) cut[t] = scene.materials[scene.material_of[t]].cut_out() ? 1 : 0;
  return cut;
}

CutoutResolver::CutoutResolver(const Scene& scene, const Camera& camera, int S, float near)
    : scene_(scene), camera_(camera), S_(S), near_(near) {
  tris_ = screen_triangles(scene, camera, S, near);
  cut_ = cut_out_triangles(scene);
  tiles_x_ = (camera.width() * S + kTile - 1) / kTile;
  tiles_y_ = (camera.height() * S + kTile - 1) / kTile;
  // Two passes over the bounding boxes: count per tile, then fill in triangle order.
  start_.assign(size_t(tiles_x_) * size_t(tiles_y_) + 1, 0);
  auto for_tiles = [&](const ScreenTriangle& st, auto&& f) {
    if (st.x0 > st.x1 || st.y0 > st.y1) return;
    for (int ty = st.y0 / kTile; ty <= st.y1 / kTile; ++ty)
      for (int tx = st.x0 / kTile; tx <= st.x1 / kTile; ++tx) f(size_t(ty) * size_t(tiles_x_) + size_t(tx));
  };
  for (const ScreenTriangle& st : tris_) for_tiles(st, [&](size_t tile) { ++start_[tile + 1]; });
  for (size_t i = 1; i < start_.size(); ++i) start_[i] += start_[i - 1];
  tile_tris_.resize(start_.back());
  std::vector<uint32_t> fill(start_.begin(), start_.end() - 1);
  for (uint32_t t = 0; t < uint32_t(tris_.size()); ++t)
    for_tiles(tris_[t], [&](size_t tile) { tile_tris_[fill[tile]++] = t; });
}

uint32_t CutoutResolver::nearest(int x, int y, Vec3* hit) const {
  const size_t tile = size_t(y / kTile) * size_t(tiles_x_) + size_t(x / kTile);
  const Ray r = camera_.generate_ray((float(x) + 0.5f) / float(S_), (float(y) + 0.5f) / float(S_));
  float best = INFINITY;
  uint32_t found = DeepFramebuffer::kNoTriangle;
  for (uint32_t i = start_[tile]; i < start_[tile + 1]; ++i) {
    const uint32_t t = tile_tris_[i];
    const ScreenTriangle& st = tris_[t];
    if (x < st.x0 || x > st.x1 || y < st.y0 || y > st.y1) continue;  // the CPU builder's candidates
    if (texel_hit(scene_, cut_, camera_.forward(), near_, st, t, r, &best)) found = t;
  }
  if (found != DeepFramebuffer::kNoTriangle) *hit = r.origin + r.dir * best;
  return found;
}

}  // namespace detail

namespace {

class CpuBands final : public detail::DeepFramebufferBands {
 public:
  CpuBands(const Scene& scene, const Camera& camera, int subpixels)
      : scene_(scene), camera_(camera), S_(subpixels), W_(camera.width() * subpixels), H_(camera.height() * subpixels) {
    detail::check_deep_framebuffer_grid(camera, subpixels);
    near_ = kNearPlane * scene.bounds().diagonal_length();
    planes_ = detail::triangle_planes(scene);
    tris_ = detail::screen_triangles(scene, camera, S_, near_);
    cut_ = detail::cut_out_triangles(scene);
  }

  int max_rows() const override { return H_; }

  void build(int row0, int row1, DeepFramebuffer* out) override {
    if (row0 < 0 || row1 > H_ || row0 >= row1) throw std::invalid_argument("deep framebuffer band outside the grid");
    DeepFramebuffer& dfb = *out;
    dfb.resize(W_, row1 - row0, S_);
    dfb.first_row = row0;
    const Camera& camera = camera_;
    const int S = S_;
    const float near = near_;
    // Per texel, the nearest hit of the ray through its centre; chunks of kBand grid rows in parallel.
    constexpr int kBand = 16;
    depth_.assign(dfb.texel_count(), INFINITY);
    const int first_chunk = row0 / kBand, last_chunk = (row1 - 1) / kBand;
    tbb::parallel_for(first_chunk, last_chunk + 1, [&](int band) {
      const int ya = std::max(row0, band * kBand), yb = std::min(row1, band * kBand + kBand) - 1;
      for (size_t t = 0; t < tris_.size(); ++t) {
        const detail::ScreenTriangle& ct = tris_[t];
        if (ct.x0 > ct.x1 || ct.y1 < ya || ct.y0 > yb) continue;
        for (int y = std::max(ya, ct.y0); y <= std::min(yb, ct.y1); ++y)
          for (int x = ct.x0; x <= ct.x1; ++x) {
            const Ray r = camera.generate_ray((float(x) + 0.5f) / float(S), (float(y) + 0.5f) / float(S));
            const size_t k = dfb.index(x, y - row0);
            if (!detail::texel_hit(scene_, cut_, camera.forward(), near, ct, uint32_t(t), r, &depth_[k])) continue;
            dfb.triangle[k] = uint32_t(t);
            const Vec3 hit = r.origin + r.dir * depth_[k];
            dfb.position[3 * k] = hit.x, dfb.position[3 * k + 1] = hit.y, dfb.position[3 * k + 2] = hit.z;
          }
      }
    });

    // Planes from the triangle table (identical to the GL builder's).
    tbb::parallel_for(size_t(0), dfb.texel_count(), [&](size_t k) {
      if (dfb.triangle[k] == DeepFramebuffer::kNoTriangle) return;
      const TrianglePlane& pl = planes_[dfb.triangle[k]];
      dfb.covered[k] = 1;
      dfb.normal[3 * k] = pl.normal.x, dfb.normal[3 * k + 1] = pl.normal.y, dfb.normal[3 * k + 2] = pl.normal.z;
      dfb.plane_offset[k] = pl.offset;
    });
  }

 private:
  const Scene& scene_;
  const Camera& camera_;
  int S_, W_, H_;
  float near_ = 0;
  std::vector<detail::ScreenTriangle> tris_;
  std::vector<uint8_t> cut_;           // per triangle: a cut-out (empty if the scene has none)
  std::vector<TrianglePlane> planes_;  // per triangle
  std::vector<float> depth_;           // per texel of the current band
};

}  // namespace

std::unique_ptr<detail::DeepFramebufferBands> detail::cpu_deep_framebuffer_bands(const Scene& scene,
                                                                                 const Camera& camera, int subpixels) {
  return std::make_unique<CpuBands>(scene, camera, subpixels);
}

DeepFramebuffer build_deep_framebuffer_cpu(const Scene& scene, const Camera& camera, int subpixels) {
  CpuBands bands(scene, camera, subpixels);
  DeepFramebuffer dfb;
  bands.build(0, camera.height() * subpixels, &dfb);
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
