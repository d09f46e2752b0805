// The deep framebuffer: what the camera sees, per subpixel texel, for the reprojection visibility test.
//
// Grid: width = S * image width, height = S * image height texels (S = subpixels per axis, default 4).
// Texel (i, j) is sampled at its centre, raster position ((i + 0.5) / S, (j + 0.5) / S) of the image,
// y pointing DOWN (row 0 is the top), exactly the convention of Camera::generate_ray/project. Texel
// index = j * width + i, the same as the subpixel index used by the reprojectors and ExactSample.
//
// Per covered texel: the nearest triangle hit by the camera ray through the texel centre, the hit
// point (world space, metres), and that triangle's plane as (unit geometric normal N, offset d) with
// the plane = { x : dot(N, x) = d }. N is Scene::geometric_normal (right-hand rule on the corner
// order, NOT flipped towards the camera) and d = dot(N, first corner), both computed once per
// triangle on the CPU by plane_of(), so the GL and CPU builders store bit-identical planes: for an
// axis-aligned triangle N is exactly (0, 0, +-1) (or a permutation) and d exactly the coordinate,
// which is what makes the epsilon = 0 plane test exact for axis-aligned walls.
//
// Builders:
//  - build_deep_framebuffer_gl: rasterises with OpenGL (OSMesa/llvmpipe), reversed-Z float depth.
//  - build_deep_framebuffer_cpu: casts the texel-centre ray against every triangle whose screen
//    bounding box contains the texel (TBB over row bands). Fallback for machines without OSMesa.
//    A FrameState uses the GL builder for either reprojection back-end where OSMesa is available, so
//    that the back-ends decide alike (the builders differ as said next).
// Both agree on which triangle covers a texel except where a triangle edge passes (nearly) through
// the texel centre (GL uses the top-left fill rule, the CPU an inclusive barycentric test) and for
// geometry closer to the eye than the near plane (GL clips at kNearPlane * scene diagonal).
// GL only picks the triangle; the position is then computed on the CPU by both builders the same way
// (detail::ray_triangle on the texel-centre ray), so it is bit-identical wherever the triangles agree
// and does not depend on how the GL builder's bands place the texel in its framebuffer.
#pragma once

#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <vector>

#include "common/camera.h"
#include "common/math.h"
#include "common/scene.h"

namespace epr {

class GlContext;

struct DeepFramebuffer {
  static constexpr uint32_t kNoTriangle = std::numeric_limits<uint32_t>::max();

  int width = 0, height = 0;        // texels: S * image width, S * image height (of the band, for a band)
  int subpixels = 4;                // S
  int first_row = 0;                // grid row of row 0 (0 but for a band of a larger grid)
  std::vector<float> position;      // 3 per texel: hit point, world space, metres (0 if uncovered)
  std::vector<float> normal;        // 3 per texel: unit geometric face normal (0 if uncovered)
  std::vector<float> plane_offset;  // 1 per texel: d = dot(normal, first triangle corner)
  std::vector<uint8_t> covered;     // 1 per texel: 1 if a triangle covers the texel centre
  std::vector<uint32_t> triangle;   // 1 per texel: index into Scene::triangles, kNoTriangle if uncovered

  size_t texel_count() const { return size_t(width) * size_t(height); }
  size_t index(int x, int y) const { return size_t(y) * size_t(width) + size_t(x); }
  Vec3 position_at(size_t t) const { return {position[3 * t], position[3 * t + 1], position[3 * t + 2]}; }
  Vec3 normal_at(size_t t) const { return {normal[3 * t], normal[3 * t + 1], normal[3 * t + 2]}; }
  size_t covered_count() const;
  /// Allocates all arrays for a width x height grid (first_row 0), everything uncovered.
  void resize(int w, int h, int s);
};

/// A triangle's plane as stored in the deep framebuffer: unit normal and offset d = dot(n, corner 0).
struct TrianglePlane {
  Vec3 normal;
  float offset = 0;
};
TrianglePlane plane_of(const Scene& scene, size_t triangle);
namespace detail {
/// plane_of of every triangle (both builders look the planes of their texels up here).
std::vector<TrianglePlane> triangle_planes(const Scene& scene);
}  // namespace detail

/// Near clipping distance of the GL builder, as a fraction of the scene's bounding-box diagonal.
inline constexpr float kNearPlane = 1e-5f;

/// Rasterises `scene` (positions only) seen by `camera` at S x S texels per pixel with OpenGL.
/// Must be called on the thread `gl` is current on. Throws GlUnavailable / std::runtime_error.
DeepFramebuffer build_deep_framebuffer_gl(GlContext& gl, const Scene& scene, const Camera& camera, int subpixels = 4);

/// The CPU equivalent (see the file comment for where it may differ from the GL one).
DeepFramebuffer build_deep_framebuffer_cpu(const Scene& scene, const Camera& camera, int subpixels = 4);

namespace detail {
/// Moller-Trumbore of ray `r` against the triangle (v0, v0 + e1, v0 + e2): barycentrics u, v and the
/// ray parameter t; false if the determinant is 0 or not finite. Both builders' positions come from it.
inline bool ray_triangle(const Ray& r, const Vec3& v0, const Vec3& e1, const Vec3& e2, float* u, float* v, float* t) {
  const Vec3 p = cross(r.dir, e2);
  const float det = dot(e1, p);
  if (det == 0.f || !std::isfinite(det)) return false;
  const float inv = 1.f / det;
  const Vec3 s = r.origin - v0;
  *u = dot(s, p) * inv;
  const Vec3 q = cross(s, e1);
  *v = dot(r.dir, q) * inv;
  *t = dot(e2, q) * inv;
  return true;
}

/// Throws std::invalid_argument unless 1 <= S <= 16 and the grid fits 16384 texels per axis.
void check_deep_framebuffer_grid(const Camera& camera, int subpixels);

/// A deep-framebuffer builder that produces the grid band by band: build(r0, r1, band) fills `band`
/// with rows [r0, r1) of the full grid (band->first_row = r0), each texel exactly as the full-frame
/// builder of the same kind computes it. Bands may come in any order and overlap.
class DeepFramebufferBands {
 public:
  virtual ~DeepFramebufferBands() = default;
  virtual void build(int row0, int row1, DeepFramebuffer* band) = 0;
  virtual int max_rows() const = 0;  // the most rows one build() call takes
};

/// The CPU builder's bands (any height).
std::unique_ptr<DeepFramebufferBands> cpu_deep_framebuffer_bands(const Scene& scene, const Camera& camera,
                                                                 int subpixels);
/// The GL builder's bands of at most `max_rows` rows: each band is rasterised into a framebuffer of
/// that height with the full grid's viewport shifted up by the band's first row (the triangle of a
/// texel is the full frame's: the shift is a whole number of rows; see the file comment for positions). Refuses (throws
/// std::runtime_error naming the limit) what this GL cannot do: band textures over
/// GL_MAX_TEXTURE_SIZE, a grid over GL_MAX_VIEWPORT_DIMS or a shift beyond GL_VIEWPORT_BOUNDS_RANGE.
/// `gl` must be current on the calling thread and outlive the result.
std::unique_ptr<DeepFramebufferBands> gl_deep_framebuffer_bands(GlContext& gl, const Scene& scene, const Camera& camera,
                                                                int subpixels, int max_rows);
}  // namespace detail

// Cut-outs. What both builders share so that cut-outs come out the same in each: the
// triangles' texel bounding boxes (the CPU builder's candidates) and, for the GL builder, the
// search for the surface behind a hole.
//
// A texel whose texel-centre ray first meets a hole of a cut-out (Scene::cut_out_at at the ray's
// barycentrics) sees what the ray sees next: the nearest hit that is not a hole, as the tracer's
// Embree filters make the rays see it. The CPU builder skips holes in its own search; the GL builder
// rasterises triangles whole and, where its triangle is a hole at the texel centre, asks
// CutoutResolver, which repeats the CPU builder's search for that one texel (same candidates, same
// arithmetic, same order), so both builders store the same triangle and point there.
namespace detail {

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

/// The search behind holes, for one texel at a time: the triangles binned by 32 x 32 texel tiles (the
/// binning is serial and the searches parallel: on Sponza at 640 x 360 texels, 32 builds the plane
/// grid about 15 % faster than 16, 8 slower; any size finds the same triangle, the candidates of a
/// texel being taken in triangle order).
class CutoutResolver {
 public:
  CutoutResolver(const Scene& scene, const Camera& camera, int S, float near);
  /// The nearest non-hole triangle on the ray through texel (x, y) of the full grid and its hit
  /// point; DeepFramebuffer::kNoTriangle if there is none.
  uint32_t nearest(int x, int y, Vec3* hit) const;

 private:
  static constexpr int kTile = 32;
  const Scene& scene_;
  const Camera& camera_;
  int S_, tiles_x_ = 0, tiles_y_ = 0;
  float near_;
  std::vector<ScreenTriangle> tris_;
  std::vector<uint8_t> cut_;
  std::vector<uint32_t> start_;  // per tile (and one past the last): its range in tile_tris_
  std::vector<uint32_t> tile_tris_;
};

}  // namespace detail

/// "gl" if an OSMesa context can be created (then uses a private one), else "cpu".
DeepFramebuffer build_deep_framebuffer(const Scene& scene, const Camera& camera, int subpixels = 4);

}  // namespace epr
