#include "client/embedded_render.h"

#include <fmt/format.h>
#include <signal.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <regex>
#include <thread>

#include "client/render_flags.h"
#include "common/log.h"
#include "common/result_kinds.h"
#include "master/server/master_server.h"
#include "wire/convert.h"
#include "wire/scene_shelf.h"

namespace epr {
namespace fs = std::filesystem;

int embedded_threads_per_worker(const RenderOptions& opts, const EmbeddedOptions& embedded) {
  const int n = std::max(1, embedded.workers);
  const int cores = int(std::max(1u, std::thread::hardware_concurrency()));
  return embedded.worker_threads > 0 ? embedded.worker_threads
         : opts.threads > 0          ? opts.threads
                                     : std::max(1, cores / n);
}

// ---- private state folders ----------------------------------------------------------------------

PrivateStateDir::PrivateStateDir() {
  std::string tmpl = (fs::temp_directory_path() / fmt::format("epr-render-{}-XXXXXX", ::getpid())).string();
  if (!::mkdtemp(tmpl.data()))
    throw std::runtime_error(fmt::format("cannot create a state folder like {}: {}", tmpl, std::strerror(errno)));
  path_ = tmpl;
  try {
    lock_ = std::make_unique<StateDirLock>(path_);
  } catch (...) {
    remove();
    throw;
  }
}

void PrivateStateDir::remove() {
  if (path_.empty()) return;
  std::error_code ec;
  fs::remove_all(path_, ec);
  lock_.reset();
  path_.clear();
}

std::vector<std::string> remove_stale_state_dirs() {
  // epr-render-PID-XXXXXX (PrivateStateDir), epr-master-PID-N (a master's own temporary folder) and
  // epr-worker-cache-PID-XXXXXX (a worker's fallback scene cache, worker/scene_fetch.h CacheRoot).
  static const std::regex kName(R"(epr-(render|master|worker-cache)-(\d+)-[A-Za-z0-9]+)");
  std::vector<std::string> removed;
  std::error_code ec;
  const fs::path tmp = fs::temp_directory_path(ec);
  if (ec) return removed;
  for (fs::directory_iterator it(tmp, ec), end; !ec && it != end; it.increment(ec)) {
    std::smatch m;
    const std::string name = it->path().filename().string();
    if (!std::regex_match(name, m, kName)) continue;
    struct stat st {};
    if (::lstat(it->path().c_str(), &st) != 0 || !S_ISDIR(st.st_mode) || st.st_uid != ::geteuid()) continue;
    const long pid = std::strtol(m[2].str().c_str(), nullptr, 10);
    if (pid <= 0 || pid == ::getpid()) continue;
    // kill(pid, 0) fails with ESRCH only when no such process exists (EPERM: it exists, not ours).
    if (!(::kill(pid_t(pid), 0) != 0 && errno == ESRCH)) continue;
    if (StateDirLock::holder(it->path().string())) continue;  // a process in another pid namespace
    std::error_code rm;
    fs::remove_all(it->path(), rm);
    if (!rm) removed.push_back(it->path().string());
  }
  return removed;
}

// ---- the render ---------------------------------------------------------------------------------

namespace {

// A done job's files from an in-process master's state folder to PREFIX.*: each moved (`keep`
// false: the folder goes with the render) or copied into a temp name beside its place, then renamed.
std::vector<FetchedFile> take_local_results(const JobManager& jobs, const std::string& id, const std::string& prefix,
                                            bool keep, uint32_t round) {
  std::vector<FetchedFile> files;
  for (const ResultKindInfo& k : result_kinds()) {
    const std::optional<std::string> from = jobs.result_path(id, k.kind);
    if (!from) {
      if (k.kind == ResultKind::kExr) throw std::runtime_error(fmt::format("job {} has no {} result", id, k.name));
      continue;
    }
    const fs::path to(prefix + std::string(k.suffix));
    if (!to.parent_path().empty()) fs::create_directories(to.parent_path());
    const fs::path tmp = to.parent_path() / (".tmp-" + to.filename().string());
    std::error_code ec;
    if (!keep) fs::rename(*from, tmp, ec);  // another file system: EXDEV, copied instead
    if (keep || ec) fs::copy_file(*from, tmp, fs::copy_options::overwrite_existing);
    fs::rename(tmp, to);
    files.push_back({to_proto(k.kind), to.string(), uint64_t(fs::file_size(to)), round, false});
  }
  return files;
}

}  // namespace

EmbeddedResult render_embedded(const RenderOptions& opts, const EmbeddedOptions& embedded,
                               const std::function<void(const v1::JobStatus&)>& on_status,
                               const std::function<void(const std::string&, const std::string&)>& on_started) {
  const auto started = std::chrono::steady_clock::now();
  auto since_start = [&] { return std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count(); };
  // The scene first: a file that cannot be read or a scene without light is refused before a master
  // and workers start.
  SceneBundleData bundle = bundle_scene(opts.scene, opts.lighting, opts.env_folder);
  if (!opts.out.empty())
    if (auto err = output_replaces_input(opts.out, bundle.sources)) throw OutputError("--out " + *err);
  logger("client")->info("scene bundled: {:.2f} s", since_start());
  // The state folder: the caller's (locked: one master per folder), else a private one that goes
  // with this function (declared first: removed after the master is gone).
  std::unique_ptr<PrivateStateDir> private_dir;
  std::unique_ptr<StateDirLock> lock;
  MasterServerOptions mo;
  mo.listen = "127.0.0.1:0";
  if (embedded.state_dir.empty()) {
    private_dir = std::make_unique<PrivateStateDir>();
    mo.jobs.state_dir = private_dir->path();
    mo.jobs.checkpoints = false;
  } else {
    lock = std::make_unique<StateDirLock>(embedded.state_dir);
    mo.jobs.state_dir = embedded.state_dir;
    mo.jobs.checkpoints = embedded.checkpoints;
  }
  mo.jobs.checkpoint_interval_s = embedded.checkpoint_interval_s;
  mo.jobs.memory_budget_bytes = embedded.memory_budget_bytes;
  // A benchmark knob (epr-master --reproject-batch-records): 0 applies every tile in its own call.
  if (const char* batch = std::getenv("EPR_REPROJECT_BATCH_RECORDS"))
    mo.jobs.reproject_batch_records = std::strtoull(batch, nullptr, 10);
  mo.http_listen = embedded.http_listen;
  MasterServer master(mo);
  logger("client")->info("master started: {:.2f} s", since_start());
  EmbeddedResult result;
  result.master_target = master.local_target();
  result.dashboard_url = master.dashboard_url();
  if (on_started) on_started(result.master_target, result.dashboard_url);

  CallCanceller own_canceller;
  CallCanceller* canceller = embedded.canceller ? embedded.canceller : &own_canceller;
  struct Refusal {  // a worker the master refused for good: the render cannot go on
    Mutex mu;
    std::string why EPR_GUARDED_BY(mu);
  } refusal;

  const int n = std::max(1, embedded.workers);
  const int threads = embedded_threads_per_worker(opts, embedded);
  std::vector<std::unique_ptr<WorkerNode>> nodes;
  std::vector<std::thread> runners;
  for (int i = 0; i < n; ++i) {
    WorkerNodeOptions wo;
    wo.master = result.master_target;
    wo.in_process = [&master](const grpc::ChannelArguments& args) { return master.in_process_channel(args); };
    wo.threads = threads;
    wo.name = "local-" + std::to_string(i);
    wo.shared_scenes = true;  // the scene this function loaded (store_scene below)
    nodes.push_back(std::make_unique<WorkerNode>(wo));
    runners.emplace_back([&, node = nodes.back().get()] {
      if (auto why = node->run()) {
        {
          MutexLock l(refusal.mu);
          if (refusal.why.empty()) refusal.why = *why;
        }
        canceller->cancel();
      }
    });
  }
  auto stop_workers = [&] {
    for (auto& node : nodes) node->stop();
    for (auto& t : runners)
      if (t.joinable()) t.join();
  };

  JobClientOptions co;
  co.upload_progress = embedded.upload_progress;
  // The master is in this process: it takes the bundle as it is (no upload), and the scene loaded
  // above goes on the shelf (wire/scene_shelf.h) under its hash, so that the master and the workers
  // use it rather than load it again; held here until the render ends.
  std::shared_ptr<const Scene> shared_scene;
  co.store_scene = [&](SceneBundleData b) {
    std::shared_ptr<const Scene> loaded = std::move(b.loaded);
    const std::string hash = master.jobs().add_scene(std::move(b));
    if (loaded) shared_scene = shelve_scene(hash, std::move(loaded));
    return hash;
  };
  if (embedded.timeout_seconds > 0)
    co.end_by = std::chrono::system_clock::now() +
                std::chrono::milliseconds(int64_t(std::min(embedded.timeout_seconds, 1e9) * 1000));
  try {
    JobClient client(result.master_target, co);
    const std::string id = client.submit(client.make_job_spec(opts, std::move(bundle)));
    std::vector<WorkerNodeStats> at_start;
    bool first_round_logged = false;
    result.status = client.watch(
        id,
        [&](const v1::JobStatus& s) {
          // The progress line (and the dashboard's preview) of the first committed round.
          if (s.round() >= 1 && !first_round_logged) {
            first_round_logged = true;
            logger("client")->info("first round on screen: {:.2f} s since the render began", since_start());
          }
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
        },
        0, canceller);
    result.master_view = master.jobs().get(id);
    logger("client")->info("job {} watched to its end: {:.2f} s since the render began", id, since_start());
    if (result.status.state() == v1::JOB_STATE_DONE) {
      // The master is in this process: its files are taken from its state folder (moved out of a
      // private one, copied from the caller's), not streamed through gRPC.
      result.files =
          take_local_results(master.jobs(), id, opts.out, !embedded.state_dir.empty(), uint32_t(result.status.round()));
      logger("client")->info("results in place: {:.2f} s", since_start());
    }
  } catch (const RpcError& e) {
    stop_workers();
    master.shutdown();
    {
      MutexLock l(refusal.mu);
      if (!refusal.why.empty()) throw std::runtime_error(refusal.why);
    }
    if (co.end_by && std::chrono::system_clock::now() >= *co.end_by)
      throw std::runtime_error(fmt::format("the render did not finish within its time limit of {:g} s ({})",
                                           embedded.timeout_seconds, e.what()));
    throw;
  } catch (...) {
    stop_workers();
    master.shutdown();
    throw;
  }
  stop_workers();
  master.shutdown();
  logger("client")->info("workers and master stopped: {:.2f} s", since_start());
  return result;
}

}  // namespace epr
