// The ranges of a job's settings, one table for the validation (RenderOptions::validate, the master's
// --max-* defaults) and its messages. The proto (proto/epr/v1/*.proto) documents the same ranges;
// tests/common/limits_test.cpp checks that every range below is written there.
#pragma once

#include <fmt/format.h>

#include <cstddef>
#include <optional>
#include <string>
#include <string_view>

namespace epr {

template <class T>
struct Range {
  std::string_view what;  // as a message names it: the flag of `epr render`
  T lo, hi;               // inclusive
  bool contains(T v) const { return v >= lo && v <= hi; }
  /// Nullopt if `v` is in range, else the message.
  std::optional<std::string> check(T v) const {
    if (contains(v)) return std::nullopt;
    return fmt::format("{} {} must be between {} and {}", what, v, lo, hi);
  }
};

namespace limits {
inline constexpr Range<int> kImageSide{"--width/--height", 1, 16384};
inline constexpr Range<int> kSpp{"--spp", 1, 1000000};
inline constexpr Range<int> kSubpixels{"--subpixels", 1, 8};
inline constexpr Range<int> kTileSize{"--tile", 4, 1024};
inline constexpr Range<int> kMaxDepth{"--max-depth", 1, 100000};
inline constexpr Range<double> kRoundGrowth{"--round-growth", 0, 16};
inline constexpr Range<double> kEpsilon{"--epsilon", 0, 1};
/// Frame windows (DESIGN.md "Frame windows"): K frames on each side, and the frames of one run (the
/// frames a master renders together, window_first..window_last).
inline constexpr Range<int> kFrameWindow{"--frame-window", 0, 16};
inline constexpr Range<int> kWindowRunFrames{"--window-run", 1, 64};
/// epr-master's: seconds a run waits for its frames before it starts with those there, and the share
/// of neighbouring frames' views below which they are cut apart (0: never).
inline constexpr Range<double> kWindowRunWaitSeconds{"--window-run-wait", 0, 86400};
inline constexpr Range<double> kWindowCutShare{"--window-cut-share", 0, 1};
/// Job, batch and worker names are at most this many bytes (UTF-8).
inline constexpr size_t kMaxNameBytes = 256;
/// The deep framebuffer's subpixels (width x height x S^2) at most, and its texels per axis
/// (width x S, height x S) at most: the largest GL viewport the deep framebuffer is rasterised into.
inline constexpr long long kMaxSubpixels = 1ll << 28;
inline constexpr int kMaxGridSide = 16384;
/// Scene coordinates (vertices after their transforms, the camera's eye and look-at point) are at most
/// this in magnitude, in metres: beyond it float edge lengths, areas and the scene's diagonal overflow.
inline constexpr double kMaxCoordinate = 1e8;
/// True if the point (x, y, z) is finite and within kMaxCoordinate in every coordinate.
inline bool within_coordinate_limit(double x, double y, double z) {
  const auto in = [](double v) { return v >= -kMaxCoordinate && v <= kMaxCoordinate; };
  return in(x) && in(y) && in(z);
}
/// Colour values (emission, environment colours and image texels) are capped at this.
inline constexpr float kMaxColour = 1e6f;
/// The sun's angular diameter is at least this, in degrees (its radiance grows as 1 / angle^2).
inline constexpr float kMinSunAngleDeg = 0.001f;
}  // namespace limits

}  // namespace epr
