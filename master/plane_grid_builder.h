// The reprojectors' compact deep framebuffer (detail::PlaneGrid) built band of rows by band of rows:
// each band of the deep framebuffer (with a one-row halo above and below, the crease neighbours) is
// built, turned into its rows of the plane grid and dropped, so no full-frame DeepFramebuffer (33
// bytes per subpixel) is ever held. The result equals make_plane_grid of the full-frame builder of the
// same kind (build_deep_framebuffer_gl or _cpu) bit for bit.
#pragma once

#include "common/camera.h"
#include "common/scene.h"
#include "master/reprojection_kernel.h"

namespace epr {

class GlContext;

namespace detail {

/// Bytes of band buffers the automatic band height aims at.
inline constexpr size_t kPlaneGridBandBytes = size_t(64) << 20;

/// Rows per band for a grid `width` texels wide: as many as keep the band's buffers (deep framebuffer
/// band, GL textures and read-back with `gl`) near kPlaneGridBandBytes, at least 8.
int automatic_band_rows(int width, int height, bool gl);

/// With `gl` (current on the calling thread) the GL builder rasterises the bands, else the CPU builder
/// casts rays. `band_rows` = grid rows per band (0: automatic_band_rows). Throws std::invalid_argument
/// for a grid check_deep_framebuffer_grid refuses, std::runtime_error for what the GL cannot do.
PlaneGrid build_plane_grid(const Scene& scene, const Camera& camera, int subpixels, float crease_tolerance,
                           bool creases, GlContext* gl, int band_rows = 0);

/// build_deep_framebuffer's rule for plane grids: the GL builder on a private context (on a thread of
/// its own, so a context current on the caller is left alone) if OSMesa is available, else the CPU one.
PlaneGrid build_plane_grid_any(const Scene& scene, const Camera& camera, int subpixels, float crease_tolerance,
                               bool creases, int band_rows = 0);

}  // namespace detail
}  // namespace epr
