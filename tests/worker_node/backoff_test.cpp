// Reconnect backoff: exponential growth up to the cap, jitter within [cap/2, cap], reset after a
// success, and no two workers in lockstep.
#include "worker/backoff.h"

#include <gtest/gtest.h>

#include <set>

namespace epr {
namespace {

TEST(Backoff, GrowsExponentiallyUpToTheCap) {
  EXPECT_EQ(backoff_delay_ms(0, 100, 5000, 1.0), 100);
  EXPECT_EQ(backoff_delay_ms(0, 100, 5000, 0.0), 50);
  EXPECT_EQ(backoff_delay_ms(1, 100, 5000, 1.0), 200);
  EXPECT_EQ(backoff_delay_ms(5, 100, 5000, 1.0), 3200);
  EXPECT_EQ(backoff_delay_ms(6, 100, 5000, 1.0), 5000);
  EXPECT_EQ(backoff_delay_ms(1000, 100, 5000, 1.0), 5000);  // no overflow for huge attempt numbers
  EXPECT_EQ(backoff_delay_ms(1000, 100, 5000, 0.0), 2500);
  // Degenerate inputs still give a positive delay.
  EXPECT_GE(backoff_delay_ms(0, 0, 0, 0.0), 1);
  EXPECT_GE(backoff_delay_ms(-3, 10, 5, 0.0), 1);
}

TEST(Backoff, JitterStaysInsideTheWindowAndResets) {
  Backoff b(100, 5000, 1);
  for (int n = 0; n < 20; ++n) {
    const int cap = std::min(5000, 100 << std::min(n, 20));
    const int d = b.next_ms();
    EXPECT_GE(d, cap / 2) << n;
    EXPECT_LE(d, cap) << n;
  }
  EXPECT_EQ(b.attempts(), 20);
  b.reset();
  EXPECT_LE(b.next_ms(), 100);
}

TEST(Backoff, WorkersDoNotReconnectInLockstep) {
  std::set<int> first_delays_at_cap;
  for (uint64_t seed = 0; seed < 20; ++seed) {
    Backoff b(100, 5000, seed);
    int d = 0;
    for (int n = 0; n < 10; ++n) d = b.next_ms();
    first_delays_at_cap.insert(d);
  }
  EXPECT_GT(first_delays_at_cap.size(), 10u);
}

}  // namespace
}  // namespace epr
