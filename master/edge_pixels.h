// Pixels whose footprint the deep framebuffer sees span more than one surface (DESIGN.md "Edge
// pixels"), and what their reprojected samples are worth.
//
// The plane test classifies a subpixel by the surface at its centre: a vertex that lands in the part
// of a subpixel covered by another surface (the Cornell light's panel, in a subpixel whose centre
// sees the ceiling 1 cm behind it) is refused, so averaging a pixel's subpixel means weighs its
// surfaces by how many subpixel centres see them, not by the area they cover. Where the surfaces'
// radiance differs that is a bias (the Cornell light's edge pixels were 2.5-4 % too dark). A pixel
// is an edge pixel when the texels of its footprint and the ring of texels around it (a surface
// boundary within half a texel outside the pixel's outer texel centres is seen by that ring) do not
// all see one surface -- another plane counts as the same surface only where the two texels' points
// (their centre rays on their planes) each lie within epsilon of the other's plane, as for the
// facets of a flat or gently curved mesh -- or some see none.
//
// Given the scene, an edge pixel is resolved by a supersampled visibility: k x k rays per texel
// (k = max(1, 16 / S): 256 rays per pixel at S = 4), traced as one coherent stream per pixel with an
// Embree BVH of the scene (common/embree_bvh.h, the workers' BVH: holes of cut-outs skipped by the
// same filter) from the deep framebuffer's near plane on, are assigned to the surface classes of the
// pixel's texel centres: to their own texel's class if the hit lies within epsilon of its plane
// (where the plane test accepts a vertex), else to the class of the pixel's texel whose plane is
// nearest, within epsilon. With every ray assigned the pixel is area-weighted (AreaWeights: each
// class's area is its share of the rays); if one class takes them all it is no edge pixel after all.
// A ray that hits nothing or a surface no centre sees, a texel that sees nothing, or an emitter
// beside another surface (the contrast magnifies what the weights leave: the strip of a surface
// inside subpixels whose centres see another is not sampled), leaves the pixel an edge pixel that
// takes no reprojected samples: M' = 0 and L_rp = 0, so it traces its own P paths and its value is
// the path tracer's. Without the scene every edge pixel is of that kind. Edge pixels' vertices
// still reproject into the other pixels.
//
// All of it is a function of the plane grid, the camera and the scene, which both back-ends share
// (FrameState builds one grid with one builder), so the GL and CPU back-ends, and a cluster and one
// process, agree on it. Held: one bit per pixel, and per area-weighted pixel its index (4 bytes) and
// 2 bytes per subpixel.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <span>
#include <vector>

#include "common/embree_bvh.h"
#include "common/scene.h"
#include "master/reprojection_image.h"
#include "master/reprojection_kernel.h"

namespace epr::detail {

/// Closest hits of camera rays, as EmbreeBvh::intersect_coherent gives them.
using CoherentRays = std::function<void(std::span<const Ray>, std::span<const float>, std::span<Hit>)>;

class EdgePixels {
 public:
  EdgePixels() = default;
  /// The edge pixels of `grid` (S x S texels per pixel) seen by `camera`, with the plane test's
  /// `epsilon` (metres); with `scene`, those it can resolve become area-weighted pixels.
  /// The rays are traced with `rays`, by default with an Embree BVH of `scene` built for the purpose.
  EdgePixels(const PlaneGrid& grid, const Camera& camera, float epsilon, const Scene* scene = nullptr,
             const CoherentRays& rays = {});
  /// The edge pixels that take no reprojected samples.
  bool empty() const { return count_ == 0; }
  size_t count() const { return count_; }
  bool operator[](size_t pixel) const { return (bits_[pixel >> 6] >> (pixel & 63)) & 1u; }
  /// The area-weighted pixels (for PixelReprojection::area_weights).
  const AreaWeights& weights() const { return weights_; }
  size_t weighted() const { return weights_.pixels.size(); }
  /// Wall seconds the set took to compute (the supersampled visibility's BVH and rays included).
  double seconds() const { return seconds_; }
  /// Gives the edge pixels no reprojected samples in `out` (a downsample's result, any of its parts
  /// present): M' and M'_eff 0, L_rp 0, v_rp -1 (undefined).
  void drop(PixelReprojection* out) const;

  /// Rays per texel axis of the supersampled visibility at S subpixels.
  static int rays_per_texel(int subpixels) { return subpixels >= 16 ? 1 : 16 / subpixels; }

 private:
  void resolve(const PlaneGrid& grid, const Camera& camera, float epsilon, const Scene& scene,
               const CoherentRays& rays);

  int width_ = 0, height_ = 0;
  size_t count_ = 0;
  double seconds_ = 0;
  std::vector<uint64_t> bits_;
  AreaWeights weights_;
};

}  // namespace epr::detail
