#include "worker/courier.h"

#include "common/thread_name.h"

namespace epr {

Courier::Courier(std::string name) : name_(std::move(name)), thread_([this] { loop(); }) {}

Courier::~Courier() {
  {
    std::lock_guard<std::mutex> lock(mu_);
    stopping_ = true;
  }
  cv_.notify_one();
  thread_.join();
}

void Courier::loop() {
  set_thread_name(name_);
  std::unique_lock<std::mutex> lock(mu_);
  for (;;) {
    waiting_ = true;
    cv_.wait(lock, [&] { return stopping_ || !tasks_.empty(); });
    waiting_ = false;
    if (tasks_.empty()) return;
    auto task = std::move(tasks_.front());
    tasks_.pop_front();
    lock.unlock();
    task();
    lock.lock();
  }
}

}  // namespace epr
