// Russian roulette's policies and their names: one table for `epr render --rr`, the wire
// (RussianRouletteMode, whose names the Python client reads from the generated code), the benchmarks
// and the logs. The survival probability itself is worker/roulette.h's.
#pragma once

#include <optional>
#include <span>
#include <string>
#include <string_view>

namespace epr {

// Russian roulette: the probability q that a path continues from a vertex (worker/roulette.h; the
// named policies and the default: common/roulette.h; DESIGN.md "Russian roulette").
struct RussianRoulette {
  enum class Mode {
    kPaper,       // survive with 1 - termination once depth > start_depth (paper: 8 and 0.1)
    kAlbedo,      // survive with the surface's largest albedo (clamped to [0.05, 1]) once depth > start_depth
    kOff,         // no roulette: every path stops at max_depth (biased: reprojected samples get darker)
    kThroughput,  // survive with the path's throughput x albedo (clamped to [0.05, 1]) once depth > start_depth
    kReuse,       // kThroughput, the throughput counted from the latest vertex reprojection can show
    kAuto,        // kReuse in a scene lit from outside (a sky or a sun), kAlbedo otherwise: resolved()
  };
  Mode mode = Mode::kPaper;
  int start_depth = 8;       // vertices traced before roulette starts (kAuto: -1, the resolved mode's own)
  float termination = 0.1f;  // kPaper's termination probability
  int max_depth = 1024;      // hard cap on path vertices

  static RussianRoulette paper() { return {}; }
  static RussianRoulette albedo() { return {Mode::kAlbedo, 3, 0.f, 1024}; }
  static RussianRoulette off(int max_depth) { return {Mode::kOff, 0, 0.f, max_depth}; }
  static RussianRoulette throughput() { return {Mode::kThroughput, 2, 0.f, 1024}; }
  static RussianRoulette reuse() { return {Mode::kReuse, 2, 0.f, 1024}; }
  static RussianRoulette automatic() { return {Mode::kAuto, -1, 0.f, 1024}; }
  /// The default of `epr render`, `epr submit`, the Python client and the add-on (a job that names
  /// no roulette: RUSSIAN_ROULETTE_MODE_UNSPECIFIED).
  static RussianRoulette standard() { return automatic(); }
  /// The policy a path follows: kAuto becomes reuse() where light comes from outside the scene (an
  /// environment or a sun) and albedo() where it does not (DESIGN.md "Russian roulette" says why),
  /// with this one's max_depth and, if set (>= 0), start_depth; every other mode is itself.
  RussianRoulette resolved(bool light_from_outside) const;
  bool operator==(const RussianRoulette&) const = default;
};

struct NamedRoulette {
  std::string_view name;  // --rr NAME; the proto's RUSSIAN_ROULETTE_MODE_NAME in lower case
  RussianRoulette rr;
};

/// Every policy by name, in the proto's order: paper, albedo, off, throughput, reuse.
std::span<const NamedRoulette> named_roulettes();
/// The policy called `name` (case-insensitive), nullopt if none is.
std::optional<RussianRoulette> roulette_named(std::string_view name);
/// The name of `mode` ("paper", ...).
std::string_view roulette_name(RussianRoulette::Mode mode);
/// "paper, albedo, off, throughput, reuse": for messages.
std::string roulette_names();

}  // namespace epr
