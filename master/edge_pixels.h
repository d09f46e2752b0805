// Pixels that take no reprojected samples: those whose footprint the deep framebuffer sees span more
// than one surface (DESIGN.md "Edge pixels").
//
// The plane test classifies a subpixel by the surface at its centre: a vertex that lands in the part
// of a subpixel covered by another surface (the Cornell light's panel, in a subpixel whose centre
// sees the ceiling 1 cm behind it) is refused, so the pixel's reprojected estimate L_rp weighs its
// surfaces by how many subpixel centres see them, not by the area they cover. Where the surfaces'
// radiance differs that is a bias (the Cornell light's edge pixels were 2.5-4 % too dark). A pixel
// is an edge pixel when the texels of its footprint and the ring of texels around it (a surface
// boundary within half a texel outside the pixel's outer texel centres is seen by that ring) do not
// all see one surface -- another plane counts as the same surface only where the two texels' points
// (their centre rays on their planes) each lie within epsilon of the other's plane, as for the
// facets of a flat or gently curved mesh -- or some see none; an edge pixel keeps M' = 0 and L_rp = 0,
// so it traces its own P paths and its value is the path tracer's. Its vertices still reproject
// into the other pixels.
//
// The set is a function of the plane grid only, which both back-ends share (FrameState builds one
// grid with one builder), so the GL and CPU back-ends, and a cluster and one process, agree on it.
// It is held as one bit per pixel.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "master/reprojection_image.h"
#include "master/reprojection_kernel.h"

namespace epr::detail {

class EdgePixels {
 public:
  EdgePixels() = default;
  /// The edge pixels of `grid` (S x S texels per pixel) seen by `camera`, with the plane test's
  /// `epsilon` (metres).
  EdgePixels(const PlaneGrid& grid, const Camera& camera, float epsilon);
  bool empty() const { return count_ == 0; }
  size_t count() const { return count_; }
  bool operator[](size_t pixel) const { return (bits_[pixel >> 6] >> (pixel & 63)) & 1u; }
  /// Gives the edge pixels no reprojected samples in `out` (a downsample's result, any of its parts
  /// present): M' and M'_eff 0, L_rp 0, v_rp -1 (undefined).
  void drop(PixelReprojection* out) const;

 private:
  int width_ = 0, height_ = 0;
  size_t count_ = 0;
  std::vector<uint64_t> bits_;
};

}  // namespace epr::detail
