// Waiting in tests for something another thread or process does: poll a condition until it holds.
// The deadline only keeps a broken build from hanging the suite; it is generous and never what a test
// asserts. Prefer a condition variable or a future where the code under test offers one; this is for
// state that can only be read (a child process, a counter in a stats snapshot, a page in a browser).
#pragma once

#include <chrono>
#include <thread>

namespace epr::test {

/// Calls `done` until it returns true (then true) or `timeout` has passed (then false), `poll` apart.
template <typename Done>
bool wait_until(Done&& done, std::chrono::steady_clock::duration timeout = std::chrono::seconds(60),
                std::chrono::steady_clock::duration poll = std::chrono::milliseconds(5)) {
  const auto until = std::chrono::steady_clock::now() + timeout;
  for (;;) {
    if (done()) return true;
    if (std::chrono::steady_clock::now() >= until) return false;
    std::this_thread::sleep_for(poll);
  }
}

}  // namespace epr::test
