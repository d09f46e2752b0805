// A worker's session with the master (proto/epr/v1/worker_service.proto): one registration, its
// worker id and limits, the leases it holds, and every call it makes -- Register, Heartbeat,
// LeaseTile, FetchScene, SubmitTile, ReturnLease, Unregister -- each with a deadline, cancelled when
// the session ends. worker/worker_node.cpp runs the tracing threads on top of it.
//
// A session ends in one of two ways: the worker stops (calls that wait on the master are cancelled,
// submissions in flight may finish; farewell() then gives the leases back and unregisters), or the
// session is lost (a call failed: everything in flight is cancelled; salvage() then tries to give the
// leases back, and the node registers again). StopSignal is the node's stop flag and the condition
// every wait of the node and its sessions uses, so a stop or a session's end wakes them all.
#pragma once

#include <grpcpp/grpcpp.h>
#include <spdlog/logger.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "common/check.h"
#include "common/math.h"
#include "epr/v1/job_service.grpc.pb.h"
#include "epr/v1/worker_service.grpc.pb.h"
#include "wire/rpc/channel.h"
#include "wire/tile_result_stream.h"

namespace epr {

struct TileResult;

/// The node's stop flag and the condition its waits use.
class StopSignal {
 public:
  bool stopping() const { return stopping_; }
  /// Sets the flag (the first reason is kept) and wakes every wait.
  void stop(const std::string& reason) EPR_EXCLUDES(mu_);
  std::string reason() const EPR_EXCLUDES(mu_);
  /// Waits up to `ms`; true when woken early by a stop or by `until` (read under the lock).
  bool wait_for(int ms, const std::function<bool()>& until = nullptr) EPR_EXCLUDES(mu_);
  /// Waits until a stop or `until`.
  void wait(const std::function<bool()>& until) EPR_EXCLUDES(mu_);
  /// Runs `change` under the lock, then wakes every wait: how a change their `until` reads is made.
  void notify(const std::function<void()>& change) EPR_EXCLUDES(mu_);

 private:
  mutable Mutex mu_;
  std::condition_variable_any cv_;
  std::atomic<bool> stopping_{false};  // read without the lock; changed under it, so no wait misses it
  std::string reason_ EPR_GUARDED_BY(mu_);
};

/// What the node counts (WorkerNodeStats).
struct NodeCounters {
  std::atomic<uint64_t> registrations{0}, reconnects{0}, tiles_leased{0}, tiles_committed{0}, tiles_duplicate{0},
      tiles_stale{0}, tiles_refused{0}, tiles_abandoned{0}, tiles_returned{0}, paths_traced{0}, vertices_sent{0},
      exact_samples_sent{0}, scenes_fetched{0}, scene_bytes_fetched{0};
  std::atomic<uint64_t> micros_tracing{0};
};

class MasterSession {
 public:
  struct Config {
    std::string master;           // the channel's target (HOST:PORT, ipv4:ADDRESS:PORT, ...)
    std::string tls_server_name;  // with TLS: the name the certificate is checked against (empty: the target's)
    rpc::ClientTls tls;
    std::string token;      // bearer token; empty: none
    std::string name;       // WorkerInfo.name
    int threads = 1;        // WorkerInfo.threads
    std::string cache_dir;  // WorkerInfo.cached_scenes comes from here; FetchScene writes here
    int min_backoff_ms = 100, max_backoff_ms = 5000;  // the channel's own reconnection follows these
    // A master in this process (the embedded set-up): its in-process channel, made with the session's
    // channel arguments, instead of a connection to `master` (which still names it).
    std::function<std::shared_ptr<grpc::Channel>(const grpc::ChannelArguments&)> in_process;
  };

  /// A lease held from the moment the master grants it until the master has answered for its tile
  /// or it is given back: heartbeats report it, a stop returns it.
  struct Hold {
    uint64_t lease_id = 0;
    std::atomic<bool> abandoned{false};  // heartbeat said invalid: drop it without returning it
  };

  struct LeaseCall {
    grpc::Status status;
    v1::Lease lease;
  };

  /// A channel to config.master; no call yet.
  MasterSession(Config config, StopSignal& signal, NodeCounters& counters, std::shared_ptr<spdlog::logger> log);
  ~MasterSession();
  MasterSession(const MasterSession&) = delete;
  MasterSession& operator=(const MasterSession&) = delete;

  // ---- registration ----
  /// Register: OK once the master accepted the worker, else its answer (rpc::is_transient tells
  /// whether registering again may help).
  grpc::Status register_worker();
  const std::string& worker_id() const { return worker_id_; }
  /// MasterInfo.instance of the master registered with (asked right after Register): the same for
  /// one master under two addresses. Empty when the master did not tell.
  const std::string& master_instance() const { return master_instance_; }
  bool registered() const { return registered_; }
  uint32_t heartbeat_ms() const { return heartbeat_ms_; }

  // ---- state ----
  bool ending() const { return ending_; }    // threads wind down (stop, or the session broke)
  bool lost() const { return lost_; }        // it broke: finished tiles are not submitted any more
  bool healthy() const { return healthy_; }  // some call after Register succeeded
  std::string end_reason() const EPR_EXCLUDES(mu_);
  /// Ends the session: lost (it broke: every call in flight is cancelled) or not (the worker stops:
  /// the calls that wait on the master are cancelled). Wakes every wait.
  void end(const std::string& reason, bool lost) EPR_EXCLUDES(mu_);
  /// Waits up to `ms`; true when woken early by a stop or the end of the session.
  bool wait(int ms);

  // ---- leases held ----
  std::shared_ptr<Hold> hold(uint64_t lease_id) EPR_EXCLUDES(mu_);
  void release(uint64_t lease_id) EPR_EXCLUDES(mu_);
  std::vector<uint64_t> held_ids(bool include_abandoned) const EPR_EXCLUDES(mu_);

  // ---- calls ----
  /// Heartbeats every heartbeat_ms() until the session ends; a lease reported invalid is marked
  /// abandoned. A failed heartbeat loses the session.
  void heartbeat_loop() EPR_EXCLUDES(mu_);
  /// One LeaseTile call; a tile it grants is held at once. The caller ends the session on an error.
  /// max_wait_ms: how long the master may hold the call when it has no tile yet (LeaseRequest).
  LeaseCall lease_tile(uint32_t max_wait_ms);
  /// Submits a traced tile (SubmitTile, retried on UNAVAILABLE / DEADLINE_EXCEEDED). True once the
  /// master has answered for the tile (committed, dropped or refused: the hold can go); false if the
  /// result did not get through (the lease stays held and is returned on the way out).
  bool submit(const v1::TileLease& lease, const Bounds3& codec_bounds, const TileResult& result, const Hold& hold);
  /// Gives leases back as `failure` (the master counts it against this worker for the job and stops
  /// leasing it the job's tiles after a few) and drops their holds. A failed call loses the session.
  bool return_leases(const std::vector<uint64_t>& ids, const std::string& reason, v1::LeaseFailure failure);
  /// Fetches a file scene into the cache; returns its entry file. Throws std::runtime_error.
  /// Into `cache_root` (empty: Config::cache_dir). A failure to write there throws CacheWriteError.
  std::string fetch_scene(const v1::SceneRef& ref, const std::string& cache_root = "");
  /// After a stop: gives back the leases still held, with `reason`, and unregisters.
  void farewell(const std::string& reason);
  /// After the session was lost: tries to give back the leases still held (the master may be there).
  void salvage();
  /// Handles a failed call: the session is lost unless it is already ending.
  void call_failed(const char* what, const grpc::Status& status);

 private:
  class CallScope;
  // CallScope's halves, here rather than in its constructor and destructor, which clang's lock
  // analysis does not look into.
  void track(grpc::ClientContext& ctx, bool cancel_on_stop) EPR_EXCLUDES(mu_);
  void untrack(grpc::ClientContext& ctx) EPR_EXCLUDES(mu_);
  /// The one ReturnLease request; counts the leases returned when the master takes them. tracked:
  /// cancelled if the session is lost (false after the session ended: farewell and salvage).
  grpc::Status send_return(const std::vector<uint64_t>& ids, const std::string& reason, v1::LeaseFailure failure,
                           std::chrono::milliseconds deadline, bool tracked);
  void prepare(grpc::ClientContext& ctx, std::chrono::milliseconds deadline) const;

  const Config config_;
  StopSignal& signal_;
  NodeCounters& counters_;
  std::shared_ptr<spdlog::logger> log_;
  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<v1::WorkerService::Stub> stub_;

  // Set by register_worker, before any other call.
  std::string worker_id_;
  std::string master_instance_;
  uint32_t heartbeat_ms_ = 1000;
  TileResultLimits limits_;

  std::atomic<bool> registered_{false}, ending_{false}, lost_{false}, healthy_{false};
  mutable Mutex mu_;
  std::string end_reason_ EPR_GUARDED_BY(mu_);
  std::map<uint64_t, std::shared_ptr<Hold>> held_ EPR_GUARDED_BY(mu_);
  std::map<grpc::ClientContext*, bool> calls_ EPR_GUARDED_BY(mu_);  // in flight -> cancelled when the worker stops
};

}  // namespace epr
