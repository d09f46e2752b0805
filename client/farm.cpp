#include "client/farm.h"

#include <fmt/format.h>

#include <algorithm>
#include <cstdio>
#include <thread>

namespace epr {

std::string FarmMaster::label() const {
  if (info && !info->name().empty()) return fmt::format("{} ({})", info->name(), endpoint.name);
  return endpoint.name;
}

std::string job_id_master(const std::string& job_id) {
  const size_t dot = job_id.find('.');
  return dot == std::string::npos ? "" : job_id.substr(0, dot);
}

Farm::Farm(const std::string& list, const JobClientOptions& options, const MasterResolver& resolver) {
  for (const MasterEndpoint& e : resolve_masters(parse_master_list(list), resolver)) {
    FarmMaster m;
    m.endpoint = e;
    JobClientOptions o = options;
    o.tls_server_name = e.tls_server_name;
    m.client = std::make_unique<JobClient>(e.target, o);
    masters_.push_back(std::move(m));
  }
}

void Farm::for_each(const std::function<void(FarmMaster&)>& fn) {
  auto run = [&](FarmMaster& m) {
    try {
      fn(m);
    } catch (const RpcError& e) {
      m.error = e;
    } catch (const std::exception& e) {  // nothing may leave a thread
      m.error = RpcError(grpc::Status(grpc::StatusCode::UNKNOWN, e.what()), e.what());
    }
  };
  if (masters_.size() == 1) return run(masters_[0]);
  std::vector<std::thread> threads;
  for (FarmMaster& m : masters_) threads.emplace_back([&run, &m] { run(m); });
  for (auto& t : threads) t.join();
}

void Farm::probe() {
  for (FarmMaster& m : masters_) {
    m.info.reset();
    m.error.reset();
  }
  for_each([](FarmMaster& m) { m.info = m.client->master_info(); });
  // One master under two addresses answers with one instance: it is used once (the first address).
  // Two masters with one name answer with two: their job ids cannot tell them apart.
  for (size_t i = 0; i < masters_.size(); ++i) {
    const FarmMaster& a = masters_[i];
    if (!a.info || a.info->instance().empty()) continue;
    for (size_t j = i + 1; j < masters_.size();) {
      const FarmMaster& b = masters_[j];
      if (b.info && b.info->instance() == a.info->instance()) {
        std::fprintf(stderr, "epr: %s and %s are the same master%s; using it once\n", a.endpoint.name.c_str(),
                     b.endpoint.name.c_str(), a.info->name().empty() ? "" : (" (" + a.info->name() + ")").c_str());
        masters_.erase(masters_.begin() + std::ptrdiff_t(j));
        continue;
      }
      if (b.info && !a.info->name().empty() && b.info->name() == a.info->name() &&
          warned_clashes_.insert(a.info->name()).second)
        std::fprintf(stderr,
                     "epr: %s and %s are two masters with the same name '%s': their job ids look alike (a job is "
                     "looked for on both); give each master its own --name\n",
                     a.endpoint.name.c_str(), b.endpoint.name.c_str(), a.info->name().c_str());
      ++j;
    }
  }
}

std::vector<const FarmMaster*> Farm::failed() const {
  std::vector<const FarmMaster*> out;
  for (const FarmMaster& m : masters_)
    if (m.error) out.push_back(&m);
  return out;
}

FarmMaster& Farm::least_loaded() {
  if (!several()) return masters_[0];
  probe();
  FarmMaster* best = nullptr;
  for (FarmMaster& m : masters_) {
    if (!m.info) continue;
    const auto key = [](const v1::MasterInfo& i) {
      return std::make_pair(i.samples_left(), i.jobs_queued() + i.jobs_running());
    };
    if (!best || key(*m.info) < key(*best->info)) best = &m;
  }
  if (!best) throw *masters_[0].error;
  return *best;
}

FarmMaster& Farm::locate(const std::string& job_id) {
  if (!several()) return masters_[0];
  probe();
  const std::string name = job_id_master(job_id);
  if (!name.empty()) {  // the master of that name, unless several answer to it (then asked below)
    FarmMaster* named = nullptr;
    size_t count = 0;
    for (FarmMaster& m : masters_)
      if (m.info && m.info->name() == name) {
        named = &m;
        ++count;
      }
    if (count == 1) return *named;
  }
  // No master answers to the id's name (it has none, or its master is down or renamed): ask them all.
  std::vector<bool> has(masters_.size(), false);
  for_each([&](FarmMaster& m) {
    if (m.error) return;  // down at the probe
    try {
      m.client->get(job_id);
      has[size_t(&m - masters_.data())] = true;
    } catch (const RpcError& e) {
      if (e.code() != grpc::StatusCode::NOT_FOUND) throw;
    }
  });
  for (size_t i = 0; i < masters_.size(); ++i)
    if (has[i]) return masters_[i];
  std::string asked, away;
  const FarmMaster* first_away = nullptr;
  for (const FarmMaster& m : masters_) {
    std::string& names = m.error ? away : asked;
    names += (names.empty() ? "" : ", ") + m.label();
    if (m.error && !first_away) first_away = &m;
  }
  if (!first_away)
    throw RpcError(grpc::Status(grpc::StatusCode::NOT_FOUND, "unknown job"),
                   fmt::format("no master knows job {} (asked {})", job_id, asked));
  throw RpcError(first_away->error->status(),
                 fmt::format("job {} is not on {}; it may be on {}, which did not answer ({})", job_id,
                             asked.empty() ? "any master" : asked, away, first_away->error->what()));
}

std::vector<FarmJob> Farm::list(const std::vector<v1::JobState>& states, size_t limit, const std::string& batch_id) {
  std::vector<std::vector<v1::JobStatus>> per(masters_.size());
  if (several()) {
    probe();  // the names, for the messages
  } else {
    masters_[0].error.reset();
  }
  for_each([&](FarmMaster& m) {
    if (!m.error) per[size_t(&m - masters_.data())] = m.client->list(states, limit, batch_id);
  });
  if (!several() && masters_[0].error) throw *masters_[0].error;
  std::vector<FarmJob> out;
  for (size_t i = 0; i < masters_.size(); ++i)
    for (auto& s : per[i])
      if (batch_id.empty() || s.batch_id() == batch_id) out.push_back({&masters_[i], std::move(s)});
  std::stable_sort(out.begin(), out.end(), [](const FarmJob& a, const FarmJob& b) {
    return a.status.submitted_unix_ms() > b.status.submitted_unix_ms();
  });
  if (limit && out.size() > limit) out.resize(limit);
  return out;
}

void print_failed(const Farm& farm, const std::string& cmd, const std::string& what) {
  for (const FarmMaster* m : farm.failed())
    std::fprintf(stderr, "epr %s: master %s %s (%s); %s\n", cmd.c_str(), m->label().c_str(),
                 m->error->unreachable() ? "did not answer" : "refused", m->error->what(), what.c_str());
}

}  // namespace epr
