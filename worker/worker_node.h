// A worker of the farm: registers with one or several epr-masters' WorkerService, leases tiles,
// traces them and streams the results back (proto/epr/v1/worker_service.proto; DESIGN.md section 2,
// "A round, end to end", and section 4).
//
//   run():   per master: Register ─▶ { heartbeat thread }        (worker/master_pool.h)
//            T tracing threads: { LeaseTile (the masters in turn) ─▶ trace ─▶ SubmitTile (to the same master) }*
//
// Several masters (options.master a list, or a name resolving to several addresses: worker/master_targets.h):
// masters share nothing, so each has a session of its own (registration, worker id, heartbeat, leases,
// backoff) and a tile's result goes back to the master that leased it. The tracing threads ask the
// connected masters in turn, one lease each, starting after the master asked last; a master with no
// tile answers at once and the next one is asked, so a master without work, or one that is down,
// never keeps the threads from the others. Jobs are cached per master and job id; scenes on disk are
// shared by content hash.
//
// Parallelism: T tracing threads (options.threads, default all cores), each holding at most one
// lease and tracing its tile single-threaded with TileRenderer. Tiles are the unit of work the master
// balances across workers, so one tile per thread keeps every core busy without a second scheduler,
// overlaps one thread's network I/O with the others' tracing, and gives deterministic results (each
// tile's bits depend only on the lease). A round's last tiles may leave cores idle for up to one
// tile's time; the master hands out a round's tiles longest first, so that tail is short. Each
// thread submits its finished tile and asks for its next lease in the background (a courier thread
// each) while it traces; the master holds a lease call it cannot serve yet (a round closing) and
// answers it the moment the next round opens (LeaseRequest.max_wait_ms).
//
// Scenes: built-ins are generated locally from SceneRef.builtin; file scenes are fetched with
// FetchScene once and cached on disk by content hash, up to cache_max_bytes (worker/scene_fetch.h). Per-job state
// (scene, BVH, camera, path tracer) is kept for the last few jobs (worker/job_cache.h).
//
// Failure handling: every RPC has a deadline. When a master is unreachable or answers an RPC with
// an error (UNAVAILABLE, NOT_FOUND for an unknown worker id after a master restart, ...), the worker
// abandons that session: it gives its leases back if it still can, waits with exponential backoff and
// jitter (capped at max_backoff_ms) and registers again; the other masters' sessions go on. A master
// that refuses Register with a permanent error (rpc::is_transient: a name or thread count over the
// master's limits, a wrong token, another protocol), which registering again cannot mend, is given up
// (logged); the worker ends when every master refused it. With one master, its Shutdown ends the
// worker; with several, a Shutdown ends that master's session only (it registers again later). A lease the
// heartbeat reports invalid is abandoned between two strips of rows. A job whose scene cannot be loaded (or a tile
// whose lease is unusable or whose tracing throws) gets its lease returned as failed (ReturnLeaseRequest.failure) and
// the thread waits (with backoff) before leasing again, so a broken job cannot make the worker spin; the master stops
// leasing the job's tiles to a worker that keeps failing them.
//
// Files: worker_node.cpp runs the node (the tracing threads); master_pool.h runs a link per master
// (sessions one after another); master_session.h makes every call to a master; courier.h runs a thread's submissions
// and early lease calls in the background; time_accounting.h splits the threads' time by activity.
//
// In-process use: no globals and no signal handling; any number of WorkerNodes may run in one
// process (the embedded `epr render` runs a master and N nodes over loopback gRPC). epr-worker's main
// installs the signal handling and calls stop().
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "wire/scene_bundle.h"
#include "worker/master_targets.h"
#include "worker/time_accounting.h"

namespace grpc {
class Channel;
class ChannelArguments;
}  // namespace grpc

namespace epr {

struct WorkerNodeOptions {
  /// epr-master's gRPC endpoint, HOST:PORT; or several, comma-separated, and names that resolve to
  /// several addresses, one master each (worker/master_targets.h). std::invalid_argument if malformed.
  std::string master = "localhost:50051";
  int resolve_interval_ms = 30000;  // names are resolved again this often (and soon after a failure)
  MasterResolver resolver;          // tests: a name's addresses; empty: getaddrinfo
  int threads = 0;                  // tracing threads; 0: std::thread::hardware_concurrency()
  std::string name;                 // shown on dashboards; empty: "HOSTNAME-PID"
  // Scene cache root (scenes/HASH/...); when it cannot be written, a private temporary folder removed
  // with the node (worker/scene_fetch.h CacheRoot).
  std::string cache_dir = default_cache_root();
  uint64_t cache_max_bytes = uint64_t(2048) << 20;  // scenes beyond this go, least recently used first
  /// Bearer token file (the rule of wire/rpc/token.h). Empty: the EPR_TOKEN environment variable if
  /// set, else no token. Sent as "authorization: Bearer <token>" on every call.
  std::string token_file;
  /// TLS to the master (plaintext when false). ca_file: PEM roots (empty: the system's); cert and key:
  /// a client certificate for masters that require one.
  bool tls = false;
  std::string ca_file, cert_file, key_file;
  /// A master in this process (the embedded set-up; `master` is its address): calls go over its
  /// in-process channel (MasterServer::in_process_channel), without sockets. Empty: connect to `master`.
  std::function<std::shared_ptr<grpc::Channel>(const grpc::ChannelArguments&)> in_process;
  int max_backoff_ms = 5000;  // cap of the reconnect backoff
  int min_backoff_ms = 100;   // first reconnect delay (halved or kept, by the jitter)
  int max_cached_jobs = 3;    // per-job tracing state kept (scenes and BVHs of older jobs are dropped)
  // Take a scene that another user in this process holds (wire/scene_shelf.h: the embedded render's
  // client and master) rather than fetch and load it, and shelve the ones this node loads; a shelved
  // scene's BVH is built once for all of them.
  bool shared_scenes = false;
  // Split the tracing threads' CPU seconds by activity (WorkerNodeStats::cpu). A diagnostic: reading a
  // thread's CPU clock at every change of activity lets the kernel preempt it at the tiles' hand-offs
  // (worker/time_accounting.h), so it is off unless asked for.
  bool cpu_split = false;
};

struct WorkerNodeStats {
  std::string worker_id;              // as assigned by the first connected master; empty if none
  bool registered = false;            // a session with some master is up
  std::vector<MasterStatus> masters;  // each master's state
  uint64_t registrations = 0;         // successful Register calls
  uint64_t reconnects = 0;            // sessions lost (master unreachable, restarted, ...), all masters
  uint64_t tiles_leased = 0;
  uint64_t tiles_committed = 0;  // SubmitAck COMMITTED
  uint64_t tiles_duplicate = 0;  // SubmitAck DUPLICATE
  uint64_t tiles_stale = 0;      // SubmitAck STALE
  uint64_t tiles_refused = 0;    // SubmitTile failed with an error status (INVALID_ARGUMENT, ...)
  uint64_t tiles_abandoned = 0;  // heartbeat said the lease is no longer valid, or the session ended
  uint64_t tiles_returned = 0;   // given back with ReturnLease (bad lease, scene failure, stop)
  uint64_t paths_traced = 0;
  uint64_t vertices_sent = 0;
  uint64_t exact_samples_sent = 0;
  uint64_t scenes_fetched = 0;
  uint64_t scene_bytes_fetched = 0;
  double seconds_tracing = 0;
  // The tracing threads' wall time since run() began (up to the call of stats()), by activity. A
  // tracing thread that is not tracing while another one is (time_others_tracing minus its tracing)
  // idles at a round's tail; when none traces (time_none_tracing), the node waits for the master
  // (the round barrier) or has no work. With T threads, time_none_tracing.total() - its tracing is
  // T x the wall time during which the node traced nothing.
  WorkerTimeSplit time_others_tracing;
  WorkerTimeSplit time_none_tracing;
  WorkerTimeSplit cpu;  // the tracing threads' own CPU seconds by activity (up to their last change;
                        // zero unless options.cpu_split)
};

class WorkerNode {
 public:
  /// Throws std::runtime_error (rpc::TokenError) if the token file or $EPR_TOKEN breaks the token rule,
  /// or if no scene cache folder can be made (CacheRoot).
  explicit WorkerNode(WorkerNodeOptions options);
  ~WorkerNode();  // stops and waits for run() if it is still running in another thread
  WorkerNode(const WorkerNode&) = delete;
  WorkerNode& operator=(const WorkerNode&) = delete;

  /// Works until stop() or the (only) master's Shutdown; then gives back the leases it holds
  /// (ReturnLease), unregisters and returns nullopt. Returns the masters' reasons instead when every
  /// master refused the registration for good (a permanent error, see the file comment). Call once.
  std::optional<std::string> run();
  /// Thread-safe and non-blocking (safe to call from any thread, not from a signal handler): makes
  /// run() wind down — tracing is abandoned between strips, waits are interrupted — and return.
  void stop();
  WorkerNodeStats stats() const;
  /// Tracing threads (options.threads, or the cores when 0).
  int threads() const;

  struct Impl;

 private:
  std::unique_ptr<Impl> impl_;
};

}  // namespace epr
