#include "master/server/checkpointer.h"

#include <algorithm>
#include <chrono>

#include "common/log.h"
#include "common/thread_name.h"

namespace epr {

Checkpointer::Checkpointer(CheckpointStore& store, std::function<void(const std::string&, double)> written)
    : store_(store), written_(std::move(written)), thread_([this] { loop(); }) {}

Checkpointer::~Checkpointer() { stop(); }

void Checkpointer::stop() {
  {
    MutexLock lock(mu_);
    stopping_ = true;
  }
  cv_.notify_all();
  if (thread_.joinable()) thread_.join();
}

void Checkpointer::push(const std::string& job_id, Item item) {
  auto it = std::find_if(queue_.begin(), queue_.end(), [&](const auto& q) { return q.first == job_id; });
  if (it != queue_.end()) {
    // Not written yet: the newer state replaces it.
    if (!it->second.written.empty()) {
      std::error_code ec;
      std::filesystem::remove(it->second.written, ec);
    }
    it->second = std::move(item);
  } else {
    queue_.emplace_back(job_id, std::move(item));
  }
  cv_.notify_all();
}

void Checkpointer::queue(const std::string& job_id, const std::function<std::optional<JobProgressRecord>()>& make) {
  MutexLock lock(mu_);
  std::optional<JobProgressRecord> record = make();
  if (!record) return;
  push(job_id, {std::make_shared<const JobProgressRecord>(std::move(*record)), {}});
}

void Checkpointer::queue_and_wait(const std::string& job_id,
                                  const std::function<std::optional<JobProgressRecord>()>& make) {
  MutexLock lock(mu_);
  std::optional<JobProgressRecord> record = make();
  if (!record) return;
  push(job_id, {std::make_shared<const JobProgressRecord>(std::move(*record)), {}});
  cv_.wait(lock, [&]() EPR_REQUIRES(mu_) {  // with mu_ held
    if (stopped_) return true;
    if (writing_ == job_id) return false;
    return std::none_of(queue_.begin(), queue_.end(), [&](const auto& q) { return q.first == job_id; });
  });
}

void Checkpointer::queue_written(const std::string& job_id, std::filesystem::path written,
                                 const std::function<bool()>& accept) {
  MutexLock lock(mu_);
  if (!accept()) {
    std::error_code ec;
    std::filesystem::remove(written, ec);
    return;
  }
  push(job_id, {nullptr, std::move(written)});
}

void Checkpointer::loop() {
  set_thread_name("epr-checkpoint");
  MutexLock lock(mu_);
  for (;;) {
    cv_.wait(lock, [&]() EPR_REQUIRES(mu_) { return stopping_ || !queue_.empty(); });  // with mu_ held
    if (queue_.empty()) {                                                              // stopping, everything written
      stopped_ = true;
      cv_.notify_all();
      return;
    }
    auto [job_id, item] = std::move(queue_.front());
    queue_.pop_front();
    writing_ = job_id;
    lock.unlock();
    const auto start = std::chrono::steady_clock::now();
    try {
      if (item.record) {
        store_.save_progress(job_id, *item.record);
        const double write_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
        logger("master")->debug("job {}: checkpoint ({} after round {}) written in {:.1f} ms", job_id,
                                to_string(item.record->state), item.record->progress.round, 1e3 * write_s);
        if (item.record->frame) written_(job_id, write_s);
      } else {
        store_.commit_progress(job_id, item.written);
        const double commit_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
        logger("master")->debug("job {}: round checkpoint synced and put in place in {:.1f} ms", job_id,
                                1e3 * commit_s);
        written_(job_id, commit_s);
      }
    } catch (const std::exception& e) {
      logger("master")->error("job {}: cannot write its checkpoint: {}", job_id, e.what());
      if (!item.written.empty()) {
        std::error_code ec;
        std::filesystem::remove(item.written, ec);
      }
    }
    item = {};  // frees a frame copy before waiting
    lock.lock();
    writing_.clear();
    cv_.notify_all();  // queue_and_wait
  }
}

}  // namespace epr
