#include "worker/courier.h"

#include "common/thread_name.h"

namespace epr {

Courier::Courier(std::string name) : name_(std::move(name)), thread_([this] { loop(); }) {}

Courier::~Courier() {
  {
    MutexLock lock(mu_);
    stopping_ = true;
  }
  cv_.notify_one();
  thread_.join();
}

void Courier::loop() {
  set_thread_name(name_);
  MutexLock lock(mu_);
  for (;;) {
    cv_.wait(lock, [&]() EPR_NO_THREAD_SAFETY_ANALYSIS { return stopping_ || !tasks_.empty(); });  // with mu_ held
    if (tasks_.empty()) return;
    auto task = std::move(tasks_.front());
    tasks_.pop_front();
    lock.unlock();
    task();
    lock.lock();
  }
}

}  // namespace epr
