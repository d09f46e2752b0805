// Courier: runs the calls a tracing thread hands it (the submissions of its tiles, or the leases it
// asks for ahead) on a long-lived thread of its own, in order, while the tracing thread traces; a
// thread started per call (std::async) would cost a thread creation twice per tile. A hand-over
// wakes the courier only if it sleeps. The destructor runs what is queued and joins: every call ends
// before its tracing thread does.
#pragma once

#include <condition_variable>
#include <deque>
#include <functional>
#include <future>
#include <memory>
#include <mutex>
#include <string>
#include <thread>

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
    bool idle;
    {
      std::lock_guard<std::mutex> lock(mu_);
      tasks_.emplace_back([task] { (*task)(); });
      idle = waiting_;
    }
    if (idle) cv_.notify_one();  // a courier at work finds the task when it looks for the next one
    return result;
  }

 private:
  void loop();

  // A std::condition_variable on a plain std::mutex: condition_variable_any holds a mutex of its own
  // while it signals, which the woken courier then waits for (a second wake-up per hand-over).
  std::mutex mu_;
  std::condition_variable cv_;
  std::deque<std::function<void()>> tasks_;  // guarded by mu_
  bool stopping_ = false;                    // guarded by mu_
  bool waiting_ = false;                     // guarded by mu_: the courier sleeps on cv_
  const std::string name_;
  std::thread thread_;  // last: started once the members above exist
};

}  // namespace epr
