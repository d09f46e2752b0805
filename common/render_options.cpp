#include "common/render_options.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <utility>

#include "common/limits.h"

namespace epr {

std::optional<std::string> RenderOptions::validate() const {
  if (!limits::kImageSide.contains(width) || !limits::kImageSide.contains(height))
    return fmt::format("image size {}x{} must be between 1x1 and {}x{}", width, height, limits::kImageSide.hi,
                       limits::kImageSide.hi);
  if (auto err = limits::kSpp.check(spp)) return err;
  if (paths_per_round <= 0 || paths_per_round > spp)
    return fmt::format("--paths-per-round {} must be between 1 and --spp ({})", paths_per_round, spp);
  if (auto err = limits::kSubpixels.check(subpixels)) return err;
  if (!std::isfinite(epsilon) || !limits::kEpsilon.contains(epsilon))
    return fmt::format("--epsilon {} must be a fraction of the scene diagonal in [0, 1]", epsilon);
  if (min_paths < 1 || min_paths > spp) return fmt::format("--min-paths {} must be between 1 and --spp", min_paths);
  if (!(reprojected_weight > 0 && reprojected_weight <= 1))
    return fmt::format("--reprojected-weight {} must be in (0, 1]: a reprojected sample counts for at most one path",
                       reprojected_weight);
  if (!std::isfinite(round_growth)) return fmt::format("--round-growth {} must be finite", round_growth);
  if (auto err = limits::kRoundGrowth.check(round_growth)) return err;
  if (auto err = limits::kTileSize.check(tile_size)) return err;
  if (threads < 0) return "--threads must be 0 (all cores) or positive";
  if (auto err = limits::kMaxDepth.check(rr.max_depth)) return err;
  if (mode != RenderMode::kPathTrace) {
    const auto fits = [&](int s) {
      return static_cast<long long>(width) * s * height * s <= limits::kMaxSubpixels &&
             static_cast<long long>(std::max(width, height)) * s <= limits::kMaxGridSide;
    };
    if (!fits(subpixels)) {
      int largest = subpixels;
      while (largest > 0 && !fits(largest)) --largest;
      return fmt::format(
          "a {}x{} frame at --subpixels {} needs a {}x{} deep framebuffer, over its limits of {} texels per axis "
          "and 2^28 texels; {}",
          width, height, subpixels, static_cast<long long>(width) * subpixels,
          static_cast<long long>(height) * subpixels, limits::kMaxGridSide,
          largest > 0 ? fmt::format("--subpixels {} fits", largest) : std::string("use --mode pt"));
    }
  }
  for (const auto& [flag, v] : {std::pair{"--eye", eye}, std::pair{"--look", look}, std::pair{"--up", up}})
    if (v && !limits::within_coordinate_limit(v->x, v->y, v->z))
      return fmt::format("{} {:g},{:g},{:g} exceeds the magnitude limit {:g} (metres)", flag, v->x, v->y, v->z,
                         limits::kMaxCoordinate);
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
    case RenderMode::kPathTrace:
      return "pt";
    case RenderMode::kReproject:
      return "rp";
    case RenderMode::kSkip:
      return "skip";
  }
  return "?";
}

const char* to_string(CombineRule c) { return c == CombineRule::kVariance ? "variance" : "fixed"; }

const char* to_string(ReprojectMethod m) {
  switch (m) {
    case ReprojectMethod::kGl:
      return "gl";
    case ReprojectMethod::kCpu:
      return "cpu";
    case ReprojectMethod::kExact:
      return "exact";
  }
  return "?";
}

}  // namespace epr
