// The reprojection back-ends by name: the CPU reprojector (cpu_reprojector.h) or the OSMesa one
// (gl_reprojector.h).
#pragma once

#include <memory>
#include <string_view>

#include "master/reprojection_kernel.h"
#include "master/reprojector.h"

namespace epr {

/// `backend` = "cpu" or "gl". For "gl", `gl` is the context to use (must be current on the calling
/// thread and outlive the reprojector); if null, the reprojector creates and owns a context, current
/// on the calling thread. The deep framebuffer's grid defines S and the subpixel grid; `camera` must
/// be the one it was built with. Throws std::invalid_argument (bad backend name, epsilon < 0 or not
/// finite, grid mismatch) or GlUnavailable.
std::unique_ptr<Reprojector> make_reprojector(std::string_view backend, const Camera& camera,
                                              const DeepFramebuffer& dfb, const ReprojectorSettings& settings,
                                              GlContext* gl = nullptr);
/// The same from the compact deep framebuffer (detail::PlaneGrid, built for `settings`).
std::unique_ptr<Reprojector> make_reprojector(std::string_view backend, const Camera& camera, detail::PlaneGrid grid,
                                              const ReprojectorSettings& settings, GlContext* gl = nullptr);

}  // namespace epr
