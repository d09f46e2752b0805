// Everything a render job is made of: scene, camera, image, sampling, method. Shared by the CLI's
// `render` (embedded default) and `submit` (cluster) so both take the same flags.
#pragma once

#include <cstdint>
#include <optional>
#include <string>

#include "common/camera.h"
#include "common/lighting.h"
#include "common/roulette.h"
#include "common/sampler.h"

namespace epr {

enum class RenderMode { kPathTrace, kReproject, kSkip };
enum class ReprojectMethod { kGl, kCpu, kExact };
// How a pixel's own path estimate and its reprojected estimate are combined, and when a pixel skips
// (master/combine_rule.h; DESIGN.md "Combining the two estimates"):
//   kFixed     a reprojected sample counts for W of a path: (sum + W M' L_rp) / (M + W M'), skip once
//              M + W M' >= P;
//   kVariance  inverse-variance weights from the pixel's measured second moments, skip once the
//              effective sample count N_eff >= P.
enum class CombineRule { kFixed, kVariance };

struct RenderOptions {
  std::string scene = "builtin:cornell";  // OBJ path, scene JSON path or builtin:NAME[?k=v&...]
  int width = 512, height = 512;          // pixels
  int spp = 16;                           // target samples per pixel P (path samples + reprojected)
  int paths_per_round = 1;                // k: paths per non-skipped pixel in the first rounds
  // Round schedule (round_paths()): later rounds trace more paths so that every round carries enough
  // work to amortise its fixed cost (barrier, reprojection close, M' readback). 0: k in every round.
  float round_growth = 0.25f;
  uint64_t seed = 1;
  std::string out = "render";  // output prefix
  RenderMode mode = RenderMode::kPathTrace;
  ReprojectMethod reproject = ReprojectMethod::kGl;
  int subpixels = 4;      // S: S x S subpixels per pixel in the deep framebuffer
  float epsilon = 3e-4f;  // plane-test tolerance as a fraction of the scene's bbox diagonal
  int min_paths = 1;      // a pixel is never skipped before it has this many real paths
  // W in (0, 1]: what one reprojected sample counts for against one of the pixel's own paths, in the
  // image and in the skip rule (master/reprojection_image.h; DESIGN.md "Combining the two estimates"
  // says why 0.5).
  float reprojected_weight = 0.5f;
  CombineRule combine = CombineRule::kFixed;
  // Skip mode, fixed rule: a pixel traces only the paths its counts say reach P this round
  // (FrameState::path_budget; BENCHMARKS.md 22: it does not pay with W = 0.5, so off).
  bool path_budget = false;
  bool reproject_glossy = false;  // failure-mode study only
  bool joint_test = true;         // the plane test's normal and crease tests (off: failure-mode study)
  // Edge pixels take no reprojected samples (master/edge_pixels.h). Off only for the failure-mode
  // study, which measures the deep framebuffer's discretisation at edges; not carried by the wire.
  bool edge_pixels = true;
  RussianRoulette rr = RussianRoulette::standard();
  // Eye paths' random numbers (common/sampler.h).
  SamplerKind sampler = SamplerKind::kSobolBurley;
  bool mis = true;                    // direct light by MIS of light and BSDF samples; false: NEE only
  int tile_size = 64;                 // pixels (`epr render` picks auto_tile_size() unless told)
  bool taper_tiles = false;           // the last quarter of the tile rows in half-size tiles (make_tiles)
  int threads = 0;                    // 0: all cores
  std::optional<Vec3> eye, look, up;  // camera overrides
  std::optional<float> fov;           // vertical, degrees
  // --env / --sun: each replaces the scene's own; an environment image is named relative to the
  // scene's folder (it travels in the scene bundle).
  Lighting lighting;
  // The client's side only, never sent: the folder `lighting`'s environment image is read from when
  // the scene is built in (the image's own folder; bundle_scene bundles it with a scene JSON naming
  // the built-in). Empty for file scenes, whose images lie in the scene's folder.
  std::string env_folder;

  /// Empty if the options are usable; otherwise the reason.
  std::optional<std::string> validate() const;
  /// The scene's camera with the overrides applied.
  CameraSpec camera_for(const CameraSpec& scene_camera) const;
};

/// The round schedule: paths every active pixel traces in the next round, given the paths each
/// active pixel has traced so far. A pure function of its arguments, so the master and the
/// single-process render follow the same schedule (and give the same image). With round_growth g > 0:
///   k_r = max(k, floor(g * paths_done)),
/// i.e. rounds grow geometrically (by a factor ~1 + g) once paths_done > k / g; a last round shorter
/// than half of k_r is merged into this one. Always in [0, spp - paths_done]. (Skip mode decides per
/// round which pixels stop, so late rounds must not grow much faster: a pixel that would have
/// stopped after a few more paths traces the whole round.)
int round_paths(const RenderOptions& o, int paths_done);
/// Rounds the schedule needs (skip mode may end earlier, when every pixel is skipped).
int rounds_planned(const RenderOptions& o);

/// The tile size `epr render` uses unless told: the largest of 128, 64, 32 and 16 pixels that gives
/// each of `threads` tracing threads at least kTilesPerThread tiles per round (16 if none does).
/// Larger tiles mean fewer lease and submission round trips, GL dispatches and hand-offs per path;
/// enough tiles per thread keep a round's tail (threads idle while the last tiles are traced)
/// short. A cluster job keeps its tiles while workers come and go, so a submitted job does not
/// guess: JobSpec.tile_size, default 64.
int auto_tile_size(int width, int height, int threads);
inline constexpr int kTilesPerThread = 8;

const char* to_string(RenderMode m);
const char* to_string(ReprojectMethod m);
const char* to_string(CombineRule c);

}  // namespace epr
