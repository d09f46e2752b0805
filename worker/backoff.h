// Exponential backoff with jitter for reconnecting to the master (and for jobs whose scene fails to
// load): attempt n waits a random time in [cap_n / 2, cap_n], cap_n = min(max, initial * 2^n)
// ("equal jitter"), so a farm of workers that lost the same master does not reconnect in lockstep,
// and no attempt follows the previous one sooner than initial / 2.
#pragma once

#include <cstdint>
#include <random>

namespace epr {

/// The delay of attempt `attempt` (0-based), milliseconds, for u in [0, 1): pure. At least 1.
int backoff_delay_ms(int attempt, int initial_ms, int max_ms, double u);

class Backoff {
 public:
  /// `seed` keys the jitter (per instance: no hidden global randomness).
  Backoff(int initial_ms, int max_ms, uint64_t seed);

  /// The delay before the next attempt; each call counts one attempt.
  int next_ms();
  /// After a success: the next delay starts from initial_ms again.
  void reset() { attempt_ = 0; }
  int attempts() const { return attempt_; }

 private:
  int initial_ms_, max_ms_;
  int attempt_ = 0;
  std::mt19937_64 rng_;
};

}  // namespace epr
