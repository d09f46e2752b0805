// The masters a worker serves (worker/master_targets.h) and its session with each: one link per
// master, each on a thread of its own that registers, heartbeats, and when its session ends says
// farewell (a stop) or salvages its leases (the session broke), then registers again after an
// exponential backoff of its own. A master that is down, or that refused the worker for good (a wrong
// token, limits), does not hold up the others. Masters share nothing: a lease, its tile's result and
// the scene it needs go to and come from the master that granted it.
//
// Names are resolved again every resolve_interval_ms, and soon after a link fails, so masters that
// join a headless Service are found; a master whose address is gone from a successful resolution is
// left (leases returned, unregistered).
//
// The tracing threads (worker/worker_node.cpp) ask connected() which masters they may lease from and
// take a Use of one for each lease: while any Use of a session lives, its link does not say farewell,
// so every tile's result can still be submitted to the master that leased it.
#pragma once

#include <spdlog/logger.h>

#include <atomic>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "common/check.h"
#include "worker/master_session.h"
#include "worker/master_targets.h"

namespace epr {

class MasterPool {
 public:
  struct Options {
    std::vector<MasterTarget> targets;
    MasterResolver resolver;  // empty: getaddrinfo (resolve_host)
    int resolve_interval_ms = 30000;
    MasterSession::Config session;  // master and tls_server_name come from each endpoint
    int threads = 1;                // for the log line of a registration
  };

  struct Link;

  /// A session in use by a tracing thread: its link waits for every Use to go before its farewell.
  class Use {
   public:
    Use(std::shared_ptr<Link> link, std::shared_ptr<MasterSession> session);
    ~Use();
    Use(const Use&) = delete;
    Use& operator=(const Use&) = delete;
    MasterSession& session() const { return *session_; }
    const std::string& target() const;  // the master's endpoint target
    const std::string& name() const;    // the master's endpoint name
    /// The master answered a lease with Shutdown: ends this session (leases given back); its link
    /// registers again after its backoff.
    void master_shutdown(const std::string& reason) const;

   private:
    std::shared_ptr<Link> link_;
    std::shared_ptr<MasterSession> session_;
  };

  MasterPool(Options options, StopSignal& signal, NodeCounters& counters, std::shared_ptr<spdlog::logger> log);
  ~MasterPool();  // stops the links (the node's StopSignal must be stopping) and joins them
  MasterPool(const MasterPool&) = delete;
  MasterPool& operator=(const MasterPool&) = delete;

  /// Runs the links until the StopSignal stops, or until every master refused the worker: then
  /// returns the reasons (every link has ended). Call once.
  std::optional<std::string> run() EPR_EXCLUDES(mu_);
  /// The targets of the masters whose session is registered and not ending, in a stable order.
  std::vector<std::string> connected() const EPR_EXCLUDES(mu_);
  /// A Use of `target`'s session; nullptr when it is not connected.
  std::shared_ptr<Use> use(const std::string& target) const EPR_EXCLUDES(mu_);
  /// The session of `target` (even one that is ending), or nullptr.
  std::shared_ptr<MasterSession> session(const std::string& target) const EPR_EXCLUDES(mu_);
  /// Changes whenever a session comes up or ends (read it, then wait on the StopSignal for a change).
  uint64_t generation() const { return generation_; }
  /// Exactly one master is configured and it is not a name resolving to several addresses: it
  /// behaves as the only master did before (its Shutdown stops the worker).
  bool single() const { return single_; }
  std::vector<MasterStatus> status() const EPR_EXCLUDES(mu_);
  /// "NAME STATE, ..." of every master.
  std::string summary() const EPR_EXCLUDES(mu_);
  /// Ends every session (not lost: the worker stops); cancels a Register in flight.
  void end_sessions(const std::string& reason) EPR_EXCLUDES(mu_);

 private:
  void sync(const std::vector<MasterEndpoint>& endpoints, bool complete) EPR_EXCLUDES(mu_);
  void link_loop(const std::shared_ptr<Link>& link);
  bool run_session(Link& link, const std::shared_ptr<MasterSession>& s);
  void set_state(Link& link, MasterState state, const std::string& detail);
  void changed();  // bumps the generation and wakes the waits
  void resolve_soon();
  std::optional<std::string> all_refused() const EPR_EXCLUDES(mu_);
  /// Takes MasterInfo.instance for `link` while its session runs; "" when it is the link's (or
  /// unknown), else the name of the link that serves that master already.
  std::string claim(const Link& link, const std::string& instance) EPR_EXCLUDES(mu_);
  void release(const Link& link, const std::string& instance) EPR_EXCLUDES(mu_);

  const Options opts_;
  StopSignal& signal_;
  NodeCounters& counters_;
  std::shared_ptr<spdlog::logger> log_;
  const bool has_names_;
  std::atomic<bool> single_{false};
  std::atomic<uint64_t> generation_{0};
  std::atomic<bool> resolve_requested_{false};

  mutable Mutex mu_;
  std::vector<std::shared_ptr<Link>> links_ EPR_GUARDED_BY(mu_);      // current endpoints, in list order
  std::vector<std::shared_ptr<Link>> retired_ EPR_GUARDED_BY(mu_);    // gone from the resolution, being left
  std::map<std::string, std::string> instances_ EPR_GUARDED_BY(mu_);  // master instance -> serving link's target
};

}  // namespace epr
