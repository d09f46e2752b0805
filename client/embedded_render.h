// The embedded default (DESIGN.md section 2): `epr render` starts a master in this process on a
// loopback port, plus local workers calling it over real gRPC through the server's in-process channel
// (no socket), submits the job over the port with the same client a cluster user has, watches it and
// fetches the outputs. Same code paths as a cluster.
//
// The master's state folder is private unless given: TMPDIR/epr-render-PID-XXXXXX, locked while the
// render runs (master/server/state_dir_lock.h) and removed when it ends, however it ends short of
// SIGKILL; remove_stale_state_dirs() clears what killed renders left.
#pragma once

#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "client/job_client.h"
#include "common/render_options.h"
#include "master/server/job_manager.h"
#include "master/server/state_dir_lock.h"
#include "worker/worker_node.h"

namespace epr {

struct EmbeddedOptions {
  int workers = 1;         // worker nodes in this process
  int worker_threads = 0;  // tracing threads per worker; 0: all cores / workers
  // The master's state folder, locked while the render runs (StateDirLocked if another master holds
  // it); empty: a private temporary one (PrivateStateDir).
  std::string state_dir;
  bool checkpoints = true;            // with an explicit state_dir: checkpoint rounds (a temporary folder never does)
  double checkpoint_interval_s = -1;  // MasterOptions::checkpoint_interval_s (< 0: automatic)
  std::string http_listen = "127.0.0.1:0";  // the master's monitoring endpoint (dashboard); empty: none
  double timeout_seconds = 0;               // the whole render (upload, rounds, results); 0: no limit
  uint64_t memory_budget_bytes = 0;         // the master's MasterOptions::memory_budget_bytes (0: no limit)
  // cancel() from another thread (a signal) ends the render: render_embedded throws RpcError CANCELLED.
  CallCanceller* canceller = nullptr;
  UploadProgressCallback upload_progress = print_upload_progress;
};

/// A private state folder for one embedded master: TMPDIR/epr-render-PID-XXXXXX, created and locked
/// by the constructor (std::runtime_error if it cannot be), removed by remove() or the destructor.
class PrivateStateDir {
 public:
  PrivateStateDir();
  ~PrivateStateDir() { remove(); }
  PrivateStateDir(const PrivateStateDir&) = delete;
  PrivateStateDir& operator=(const PrivateStateDir&) = delete;
  const std::string& path() const { return path_; }
  /// Removes the folder now (idempotent). Not async-signal-safe.
  void remove();

 private:
  std::string path_;
  std::unique_ptr<StateDirLock> lock_;
};

/// Removes the temporary folders of processes that are gone: TMPDIR/epr-render-PID-*,
/// TMPDIR/epr-master-PID-N and TMPDIR/epr-worker-cache-PID-* of this user whose PID is not running
/// and whose lock is not held. Returns the folders removed.
std::vector<std::string> remove_stale_state_dirs();

struct EmbeddedResult {
  v1::JobStatus status;            // the final status
  std::vector<FetchedFile> files;  // what was written under the output prefix
  std::string master_target;       // the loopback address the master listened on
  std::string dashboard_url;       // "http://127.0.0.1:PORT/" while the render runs; empty if disabled
  /// Each worker node's statistics when the job ended; their time splits cover the job only (from
  /// the first update showing it running to the one showing it done).
  std::vector<WorkerNodeStats> workers;
  /// The master's view of the job when it ended (its round timings, ...).
  std::optional<JobSnapshot> master_view;
};

/// Tracing threads of each local worker node (EmbeddedOptions::worker_threads, else opts.threads,
/// else the cores shared out among the nodes).
int embedded_threads_per_worker(const RenderOptions& opts, const EmbeddedOptions& embedded);

/// Renders `opts` to completion and writes the outputs under opts.out. `on_status` is called with
/// every progress update (from the watch stream); `on_started` once the master is up (with its gRPC
/// target and the dashboard URL, empty if disabled). Throws std::runtime_error with the master's
/// reason when it refuses a local worker for good, or when timeout_seconds runs out; RpcError
/// CANCELLED when embedded.canceller fires.
EmbeddedResult render_embedded(
    const RenderOptions& opts, const EmbeddedOptions& embedded,
    const std::function<void(const v1::JobStatus&)>& on_status = {},
    const std::function<void(const std::string& master_target, const std::string& dashboard_url)>& on_started = {});

}  // namespace epr
