#include "master/make_reprojector.h"

#include <fmt/format.h>

#include <stdexcept>

#include "master/cpu_reprojector.h"
#include "master/gl_reprojector.h"

namespace epr {

std::unique_ptr<Reprojector> make_reprojector(std::string_view backend, const Camera& camera,
                                              const DeepFramebuffer& dfb, const ReprojectorSettings& settings,
                                              GlContext* gl) {
  if (backend != "cpu" && backend != "gl")
    throw std::invalid_argument(fmt::format("unknown reprojector back-end '{}' (expected 'gl' or 'cpu')", backend));
  return make_reprojector(backend, camera, detail::plane_grid_for(camera, dfb, settings), settings, gl);
}

std::unique_ptr<Reprojector> make_reprojector(std::string_view backend, const Camera& camera, detail::PlaneGrid grid,
                                              const ReprojectorSettings& settings, GlContext* gl) {
  if (backend == "cpu") return std::make_unique<CpuReprojector>(camera, std::move(grid), settings);
  if (backend == "gl") {
    if (gl) return std::make_unique<GlReprojector>(*gl, camera, std::move(grid), settings);
    return std::make_unique<GlReprojector>(camera, std::move(grid), settings);
  }
  throw std::invalid_argument(fmt::format("unknown reprojector back-end '{}' (expected 'gl' or 'cpu')", backend));
}

}  // namespace epr
