// speed_accuracy's error curves: one sample per round, a curve read at a given number of paths per
// pixel, and the CPU (or wall) time at which a curve reaches a target error.
#pragma once

#include <cmath>
#include <optional>
#include <vector>

#include "bench_reference.h"

namespace epr::bench {

struct Sample {
  int round = 0;
  double wall = 0, cpu = 0, eye_paths = 0, reprojected = 0, mean_spp = 0;
  double spp = 0;                // paths per pixel the round schedule has reached (traced + skipped; = pt's M)
  ErrorMeans raw, err;           // err = raw - floor
  std::optional<ErrorMeans> cy;  // against the Cycles reference, its floor subtracted
};

// The error column a table uses: trimmed or full relative MSE (reference noise subtracted).
inline double metric(const Sample& s, bool trimmed) { return trimmed ? s.err.trimmed : s.err.full; }

// A curve's state at exactly t paths per pixel: the round that ends there, or a log-log interpolation
// between the two rounds around it (the growing round schedule need not end a round at t).
inline std::optional<Sample> at_spp(const std::vector<Sample>& s, double t) {
  for (size_t i = 0; i < s.size(); ++i) {
    if (s[i].spp == t) return s[i];
    if (s[i].spp < t) continue;
    if (i == 0 || !(s[i - 1].spp > 0)) return std::nullopt;
    const Sample &a = s[i - 1], &b = s[i];
    const double f = (std::log(t) - std::log(a.spp)) / (std::log(b.spp) - std::log(a.spp));
    const auto lerp = [f](double x, double y) {
      return x > 0 && y > 0 ? std::exp(std::log(x) + f * (std::log(y) - std::log(x))) : x + f * (y - x);
    };
    Sample r = b;
    r.spp = t;
    r.wall = lerp(a.wall, b.wall);
    r.cpu = lerp(a.cpu, b.cpu);
    r.err = {lerp(a.err.full, b.err.full), lerp(a.err.trimmed, b.err.trimmed), lerp(a.err.mse, b.err.mse)};
    return r;
  }
  return std::nullopt;
}

// log(time) at which log(error) crosses `target` on the segment between rounds a and b.
inline double crossing(const Sample& a, const Sample& b, double target, bool use_cpu, bool trimmed) {
  const double t0 = use_cpu ? a.cpu : a.wall, t1 = use_cpu ? b.cpu : b.wall;
  const double e0 = metric(a, trimmed), e1 = metric(b, trimmed);
  if (!(e0 > 0) || !(e1 > 0) || !(t0 > 0) || e0 == e1) return t1;
  const double f = (std::log(target) - std::log(e0)) / (std::log(e1) - std::log(e0));
  return std::exp(std::log(t0) + f * (std::log(t1) - std::log(t0)));
}

// When a curve reaches `target`, read two ways because the curves are noisy (a firefly raises the
// full metric for a while): `first`, the first round at or below it (optimistic), and `stays`, the
// round from which on every later round stays at or below it (pessimistic); both interpolated
// log-log between rounds, nullopt if not reached.
struct Reach {
  std::optional<double> first, stays;
};

inline Reach time_to(const std::vector<Sample>& s, double target, bool use_cpu, bool trimmed) {
  Reach r;
  if (!(target > 0) || s.empty()) return r;
  for (size_t i = 0; i < s.size() && !r.first; ++i)
    if (metric(s[i], trimmed) <= target)
      r.first = i == 0 ? (use_cpu ? s[0].cpu : s[0].wall) : crossing(s[i - 1], s[i], target, use_cpu, trimmed);
  if (!(metric(s.back(), trimmed) <= target)) return r;
  size_t i = s.size() - 1;
  while (i > 0 && metric(s[i - 1], trimmed) <= target) --i;
  r.stays = i == 0 ? (use_cpu ? s[0].cpu : s[0].wall) : crossing(s[i - 1], s[i], target, use_cpu, trimmed);
  return r;
}
}  // namespace epr::bench
