#include "client/embedded_render.h"

#include <filesystem>
#include <thread>

#include "master/server/master_server.h"

namespace epr {

int embedded_threads_per_worker(const RenderOptions& opts, const EmbeddedOptions& embedded) {
  const int n = std::max(1, embedded.workers);
  const int cores = int(std::max(1u, std::thread::hardware_concurrency()));
  return embedded.worker_threads > 0 ? embedded.worker_threads
         : opts.threads > 0          ? opts.threads
                                     : std::max(1, cores / n);
}

EmbeddedResult render_embedded(const RenderOptions& opts, const EmbeddedOptions& embedded,
                               const std::function<void(const v1::JobStatus&)>& on_status,
                               const std::function<void(const std::string&, const std::string&)>& on_started) {
  MasterServerOptions mo;
  mo.listen = "127.0.0.1:0";
  mo.jobs.state_dir = embedded.state_dir;
  mo.jobs.checkpoints = embedded.checkpoints;
  mo.jobs.checkpoint_interval_s = embedded.checkpoint_interval_s;
  mo.http_listen = embedded.http_listen;
  MasterServer master(mo);
  EmbeddedResult result;
  result.master_target = master.local_target();
  result.dashboard_url = master.dashboard_url();
  if (on_started) on_started(result.master_target, result.dashboard_url);

  const int n = std::max(1, embedded.workers);
  const int threads = embedded_threads_per_worker(opts, embedded);
  std::vector<std::unique_ptr<WorkerNode>> nodes;
  std::vector<std::thread> runners;
  for (int i = 0; i < n; ++i) {
    WorkerNodeOptions wo;
    wo.master = result.master_target;
    wo.threads = threads;
    wo.name = "local-" + std::to_string(i);
    nodes.push_back(std::make_unique<WorkerNode>(wo));
    runners.emplace_back([node = nodes.back().get()] { node->run(); });
  }
  auto stop_workers = [&] {
    for (auto& node : nodes) node->stop();
    for (auto& t : runners)
      if (t.joinable()) t.join();
  };

  try {
    JobClient client(result.master_target);
    const std::string id = client.submit(opts);
    std::vector<WorkerNodeStats> at_start;
    result.status = client.watch(id, [&](const v1::JobStatus& s) {
      if (at_start.empty() && s.state() != v1::JOB_STATE_QUEUED)
        for (auto& node : nodes) at_start.push_back(node->stats());
      if (s.state() == v1::JOB_STATE_DONE && result.workers.empty())
        for (size_t i = 0; i < nodes.size(); ++i) {
          WorkerNodeStats w = nodes[i]->stats();
          if (i < at_start.size()) {
            w.time_others_tracing -= at_start[i].time_others_tracing;
            w.time_none_tracing -= at_start[i].time_none_tracing;
            w.cpu -= at_start[i].cpu;
          }
          result.workers.push_back(std::move(w));
        }
      if (on_status) on_status(s);
      return true;
    });
    result.master_view = master.jobs().get(id);
    if (result.status.state() == v1::JOB_STATE_DONE) result.files = client.fetch_all(id, opts.out);
  } catch (...) {
    stop_workers();
    master.shutdown();
    throw;
  }
  stop_workers();
  master.shutdown();
  return result;
}

}  // namespace epr
