// What both deep-framebuffer builders share so that cut-outs come out the same in each: the
// triangles' texel bounding boxes (the CPU builder's candidates) and, for the GL builder, the
// search for the surface behind a hole. Internal to master/deep_framebuffer*.cpp.
//
// A texel whose texel-centre ray first meets a hole of a cut-out (Scene::cut_out_at at the ray's
// barycentrics) sees what the ray sees next: the nearest hit that is not a hole, as the tracer's
// Embree filters make the rays see it. The CPU builder skips holes in its own search; the GL builder
// rasterises triangles whole and, where its triangle is a hole at the texel centre, asks
// CutoutResolver, which repeats the CPU builder's search for that one texel (same candidates, same
// arithmetic, same order), so both builders store the same triangle and point there.
#pragma once

#include <cstdint>
#include <vector>

#include "common/camera.h"
#include "common/math.h"
#include "common/scene.h"
#include "master/deep_framebuffer.h"

namespace epr::detail {

struct ScreenTriangle {
  Vec3 v0, e1, e2;     // Moller-Trumbore data: corner 0 and the edges to corners 1 and 2
  int x0, x1, y0, y1;  // inclusive texel bounding box of the full grid, empty if x0 > x1
};

/// Per triangle of `scene`: its ScreenTriangle for a grid of S x S texels per pixel of `camera`
/// (the whole grid when a corner is at or behind the near plane at distance `near`).
std::vector<ScreenTriangle> screen_triangles(const Scene& scene, const Camera& camera, int S, float near);

/// Per triangle: 1 if its material is a cut-out. Empty if the scene has none.
std::vector<uint8_t> cut_out_triangles(const Scene& scene);

/// Whether the ray `r` through a texel centre hits triangle `t` (given as `st`) as the CPU builder
/// tests it: inside (edges inclusive), beyond `near` along `forward`, nearer than *best_t (ties keep
/// the lower triangle index) and not in a hole; if so *best_t becomes its ray parameter.
inline bool texel_hit(const Scene& scene, const std::vector<uint8_t>& cut, const Vec3& forward, float near,
                      const ScreenTriangle& st, uint32_t t, const Ray& r, float* best_t) {
  float u, v, tt;
  if (!ray_triangle(r, st.v0, st.e1, st.e2, &u, &v, &tt)) return false;
  if (!(u >= 0.f && u <= 1.f) || !(v >= 0.f && u + v <= 1.f)) return false;
  if (!(tt * dot(r.dir, forward) > near)) return false;
  if (!(tt < *best_t)) return false;
  if (!cut.empty() && cut[t] && scene.cut_out_at(t, u, v)) return false;
  *best_t = tt;
  return true;
}

/// The search behind holes, for one texel at a time: the triangles binned by 16 x 16 texel tiles.
class CutoutResolver {
 public:
  CutoutResolver(const Scene& scene, const Camera& camera, int S, float near);
  /// The nearest non-hole triangle on the ray through texel (x, y) of the full grid and its hit
  /// point; DeepFramebuffer::kNoTriangle if there is none.
  uint32_t nearest(int x, int y, Vec3* hit) const;

 private:
  static constexpr int kTile = 16;
  const Scene& scene_;
  const Camera& camera_;
  int S_, tiles_x_ = 0, tiles_y_ = 0;
  float near_;
  std::vector<ScreenTriangle> tris_;
  std::vector<uint8_t> cut_;
  std::vector<uint32_t> start_;  // per tile (and one past the last): its range in tile_tris_
  std::vector<uint32_t> tile_tris_;
};

}  // namespace epr::detail
