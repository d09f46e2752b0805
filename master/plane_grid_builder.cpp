// Banded plane-grid construction. See plane_grid_builder.h.
#include "master/plane_grid_builder.h"

#include <algorithm>
#include <future>

#include "master/deep_framebuffer.h"
#include "master/gl_context.h"

namespace epr::detail {

int automatic_band_rows(int width, int height, bool gl) {
  // Per texel of a band: the DeepFramebuffer (33 B) and the builder's plain-entry array (4 B); the CPU
  // builder's depth (4 B); the GL textures (triangle 4 B, depth 4 B) and the triangles' read-back (4 B).
  const size_t per_texel = gl ? 33 + 4 + 12 : 33 + 4 + 4;
  const size_t rows = kPlaneGridBandBytes / (std::max<size_t>(size_t(width), 1) * per_texel);
  return int(std::clamp<size_t>(rows, 8, size_t(std::max(height, 1))));
}

PlaneGrid build_plane_grid(const Scene& scene, const Camera& camera, int subpixels, float crease_tolerance,
                           bool creases, GlContext* gl, int band_rows) {
  check_deep_framebuffer_grid(camera, subpixels);
  const int W = camera.width() * subpixels, H = camera.height() * subpixels;
  const int rows = std::min(H, band_rows > 0 ? band_rows : automatic_band_rows(W, H, gl != nullptr));
  // Each band's deep framebuffer holds its rows and one more above and below (when they exist).
  const int halo_rows = std::min(H, rows + 2);
  const std::unique_ptr<DeepFramebufferBands> bands =
      gl ? gl_deep_framebuffer_bands(*gl, scene, camera, subpixels, halo_rows)
         : cpu_deep_framebuffer_bands(scene, camera, subpixels);
  PlaneGridBuilder builder(W, H, subpixels, camera.eye(), crease_tolerance, creases);
  DeepFramebuffer band;
  for (int row0 = 0; row0 < H; row0 += rows) {
    const int row1 = std::min(H, row0 + rows);
    bands->build(std::max(0, row0 - 1), std::min(H, row1 + 1), &band);
    builder.add_band(band, row0, row1);
  }
  return builder.finish();
}

PlaneGrid build_plane_grid_any(const Scene& scene, const Camera& camera, int subpixels, float crease_tolerance,
                               bool creases, int band_rows) {
  if (!gl_available()) return build_plane_grid(scene, camera, subpixels, crease_tolerance, creases, nullptr, band_rows);
  return std::async(std::launch::async,
                    [&] {
                      GlContext gl;
                      return build_plane_grid(scene, camera, subpixels, crease_tolerance, creases, &gl, band_rows);
                    })
      .get();
}

}  // namespace epr::detail
