#include "worker/backoff.h"

#include <algorithm>
#include <cmath>

namespace epr {

int backoff_delay_ms(int attempt, int initial_ms, int max_ms, double u) {
  const double initial = std::max(1, initial_ms);
  const double cap_max = std::max<double>(initial, max_ms);
  // 2^attempt saturates long before double does; clamp the exponent to keep it finite.
  const double cap = std::min(cap_max, initial * std::ldexp(1.0, std::clamp(attempt, 0, 62)));
  const double uu = std::clamp(u, 0.0, 1.0);
  return std::max(1, int(cap * (0.5 + 0.5 * uu)));
}

Backoff::Backoff(int initial_ms, int max_ms, uint64_t seed) : initial_ms_(initial_ms), max_ms_(max_ms), rng_(seed) {}

int Backoff::next_ms() {
  const double u = std::uniform_real_distribution<double>(0.0, 1.0)(rng_);
  const int delay = backoff_delay_ms(attempt_, initial_ms_, max_ms_, u);
  if (attempt_ < (1 << 30)) ++attempt_;
  return delay;
}

}  // namespace epr
