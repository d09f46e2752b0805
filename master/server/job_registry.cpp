#include "master/server/job_registry.h"

#include <algorithm>

namespace epr {

std::vector<std::string> JobRegistry::add(std::shared_ptr<Job> job, size_t max_jobs) {
  next_seq_ = std::max(next_seq_, job->seq + 1);
  if (!job->request.request_id.empty()) request_ids_[job->request.request_id] = job->id;
  jobs_[job->id] = std::move(job);
  std::vector<std::string> forgotten;
  while (jobs_.size() > max_jobs) {
    auto oldest = std::find_if(jobs_.begin(), jobs_.end(),
                               [](const auto& kv) EPR_REQUIRES(job_fields) { return is_terminal(kv.second->state); });
    if (oldest == jobs_.end()) break;
    forgotten.push_back(oldest->first);
    jobs_.erase(oldest);
  }
  return forgotten;
}

std::shared_ptr<Job> JobRegistry::find(const std::string& id) const {
  auto it = jobs_.find(id);
  return it == jobs_.end() ? nullptr : it->second;
}

std::shared_ptr<Job> JobRegistry::find_request(const std::string& request_id) const {
  if (request_id.empty()) return nullptr;
  auto it = request_ids_.find(request_id);
  return it == request_ids_.end() ? nullptr : find(it->second);
}

std::shared_ptr<Job> JobRegistry::next_queued(const std::vector<std::shared_ptr<Job>>& starting) const {
  std::shared_ptr<Job> best;
  for (const auto& [id, job] : jobs_) {
    if (job->state != JobState::kQueued) continue;
    if (std::find(starting.begin(), starting.end(), job) != starting.end()) continue;
    if (job->resume) return job;
    if (!best || job->request.priority > best->request.priority ||
        (job->request.priority == best->request.priority && job->seq < best->seq))
      best = job;
  }
  return best;
}

uint64_t JobRegistry::watch(const std::string& id, Listener listener) {
  if (!jobs_.count(id)) return 0;
  const uint64_t h = next_watch_++;
  watchers_[h] = {id, std::move(listener)};
  return h;
}

std::vector<JobRegistry::Listener> JobRegistry::listeners(const std::string& id) const {
  std::vector<Listener> out;
  for (const auto& [h, w] : watchers_)
    if (w.first == id) out.push_back(w.second);
  return out;
}

}  // namespace epr
