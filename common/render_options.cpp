#include "common/render_options.h"

#include <cmath>

#include <fmt/format.h>

namespace epr {

std::optional<std::string> RenderOptions::validate() const {
  constexpr int kMaxSide = 16384;
  if (width <= 0 || height <= 0 || width > kMaxSide || height > kMaxSide)
    return fmt::format("image size {}x{} must be between 1x1 and {}x{}", width, height, kMaxSide, kMaxSide);
  if (spp <= 0 || spp > 1'000'000) return fmt::format("--spp {} must be between 1 and 1000000", spp);
  if (paths_per_round <= 0 || paths_per_round > spp)
    return fmt::format("--paths-per-round {} must be between 1 and --spp ({})", paths_per_round, spp);
  if (subpixels < 1 || subpixels > 8) return fmt::format("--subpixels {} must be between 1 and 8", subpixels);
  if (!std::isfinite(epsilon) || epsilon < 0 || epsilon > 1)
    return fmt::format("--epsilon {} must be a fraction of the scene diagonal in [0, 1]", epsilon);
  if (min_paths < 1 || min_paths > spp) return fmt::format("--min-paths {} must be between 1 and --spp", min_paths);
  if (tile_size < 4 || tile_size > 1024) return fmt::format("--tile {} must be between 4 and 1024", tile_size);
  if (threads < 0) return "--threads must be 0 (all cores) or positive";
  if (rr.max_depth < 1 || rr.max_depth > 100000) return "--max-depth must be between 1 and 100000";
  if (mode != RenderMode::kPathTrace && static_cast<long long>(width) * subpixels * height * subpixels > (1ll << 28))
    return "the deep framebuffer (width x height x subpixels^2) would exceed 2^28 texels";
  CameraSpec probe = camera_for(CameraSpec{});
  if (auto err = probe.validate()) return *err;
  return std::nullopt;
}

CameraSpec RenderOptions::camera_for(const CameraSpec& scene_camera) const {
  CameraSpec c = scene_camera;
  if (eye) c.eye = *eye;
  if (look) c.look = *look;
  if (up) c.up = *up;
  if (fov) c.fov_y_degrees = *fov;
  return c;
}

const char* to_string(RenderMode m) {
  switch (m) {
    case RenderMode::kPathTrace: return "pt";
    case RenderMode::kReproject: return "rp";
    case RenderMode::kSkip: return "skip";
  }
  return "?";
}

const char* to_string(ReprojectMethod m) {
  switch (m) {
    case ReprojectMethod::kGl: return "gl";
    case ReprojectMethod::kCpu: return "cpu";
    case ReprojectMethod::kExact: return "exact";
  }
  return "?";
}

}  // namespace epr
