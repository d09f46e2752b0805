#include "common/render_options.h"

#include <algorithm>
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
  if (!std::isfinite(round_growth) || round_growth < 0 || round_growth > 16)
    return fmt::format("--round-growth {} must be between 0 and 16", round_growth);
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

int round_paths(const RenderOptions& o, int paths_done) {
  const int left = o.spp - paths_done;
  if (left <= 0) return 0;
  int k = o.paths_per_round;
  if (o.round_growth > 0) {
    // In double: the products stay exact for every valid spp (< 2^20) and the result does not
    // depend on the compiler's float evaluation.
    k = std::max(k, int(std::floor(double(o.round_growth) * double(paths_done))));
    if (left - k < (k + 1) / 2) k = left;  // no sliver of a round at the end
  }
  return std::min(k, left);
}

int auto_tile_size(int width, int height, int threads) {
  const long long wanted = static_cast<long long>(kTilesPerThread) * std::max(1, threads);
  for (int t : {128, 64, 32}) {
    const long long tiles = static_cast<long long>((width + t - 1) / t) * ((height + t - 1) / t);
    if (tiles >= wanted) return t;
  }
  return 16;
}

int rounds_planned(const RenderOptions& o) {
  int rounds = 0;
  for (int done = 0; done < o.spp; ++rounds) done += std::max(1, round_paths(o, done));
  return rounds;
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
