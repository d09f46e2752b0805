// Screen triangles and the search behind cut-out holes. See deep_framebuffer_cutouts.h.
#include "master/deep_framebuffer_cutouts.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>

namespace epr::detail {

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

}  // namespace epr::detail
