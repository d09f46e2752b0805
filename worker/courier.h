// Courier: runs the calls a tracing thread hands it (the submissions of its tiles, or the leases it
// asks for ahead) on a long-lived thread of its own, in order, while the tracing thread traces; a
// thread started per call (std::async) would cost a thread creation twice per tile. The destructor
// runs what is queued and joins: every call ends before its tracing thread does.
#pragma once

#include <condition_variable>
#include <deque>
#include <functional>
#include <future>
#include <memory>
#include <string>
#include <thread>

#include "common/check.h"

namespace epr {

class Courier {
 public:
  /// `name`: the thread's name (top -H, perf).
  explicit Courier(std::string name);
  ~Courier();
  Courier(const Courier&) = delete;
  Courier& operator=(const Courier&) = delete;

  /// Queues `f`; its result (or exception) arrives through the future.
  template <typename F>
  auto run(F f) -> std::future<decltype(f())> {
    auto task = std::make_shared<std::packaged_task<decltype(f())()>>(std::move(f));
    auto result = task->get_future();
    {
      MutexLock lock(mu_);
      tasks_.emplace_back([task] { (*task)(); });
    }
    cv_.notify_one();
    return result;
  }

 private:
  void loop() EPR_EXCLUDES(mu_);

  Mutex mu_;
  std::condition_variable_any cv_;
  std::deque<std::function<void()>> tasks_ EPR_GUARDED_BY(mu_);
  bool stopping_ EPR_GUARDED_BY(mu_) = false;
  const std::string name_;
  std::thread thread_;  // last: started once the members above exist
};

}  // namespace epr
