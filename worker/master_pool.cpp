#include "worker/master_pool.h"

#include <fmt/format.h>

#include <algorithm>
#include <condition_variable>
#include <random>

#include "common/thread_name.h"
#include "wire/rpc/status.h"
#include "worker/backoff.h"

namespace epr {
namespace {

constexpr int kMinResolveGapMs = 1000;  // re-resolutions asked for by failing links: at most this often

}  // namespace

struct MasterPool::Link {
  explicit Link(MasterEndpoint e) : endpoint(std::move(e)) { status.name = endpoint.name; }

  const MasterEndpoint endpoint;
  std::atomic<bool> removed{false};    // gone from the resolution: leave the master
  std::atomic<bool> shutdown{false};   // the master answered a lease with Shutdown: end this session
  std::atomic<bool> refused{false};    // for good
  std::atomic<bool> duplicate{false};  // the same master as another link's (MasterInfo.instance): ended
  Mutex mu;
  std::condition_variable_any idle;                           // users dropped
  std::shared_ptr<MasterSession> session EPR_GUARDED_BY(mu);  // from before Register until its farewell
  int users EPR_GUARDED_BY(mu) = 0;                           // Uses of `session`
  MasterStatus status EPR_GUARDED_BY(mu);
  std::thread thread;
};

// ---- Use ------------------------------------------------------------------------------------------

MasterPool::Use::Use(std::shared_ptr<Link> link, std::shared_ptr<MasterSession> session)
    : link_(std::move(link)), session_(std::move(session)) {}

MasterPool::Use::~Use() {
  {
    MutexLock lock(link_->mu);
    --link_->users;
  }
  link_->idle.notify_all();
}

const std::string& MasterPool::Use::target() const { return link_->endpoint.target; }
const std::string& MasterPool::Use::name() const { return link_->endpoint.name; }

void MasterPool::Use::master_shutdown(const std::string& reason) const {
  link_->shutdown = true;
  session_->end("master shutdown: " + reason, /*lost=*/false);
}

// ---- the pool -------------------------------------------------------------------------------------

MasterPool::MasterPool(Options options, StopSignal& signal, NodeCounters& counters, std::shared_ptr<spdlog::logger> log)
    : opts_(std::move(options)),
      signal_(signal),
      counters_(counters),
      log_(std::move(log)),
      has_names_(std::any_of(opts_.targets.begin(), opts_.targets.end(),
                             [](const MasterTarget& t) { return !t.host.empty(); })) {}

MasterPool::~MasterPool() {
  std::vector<std::shared_ptr<Link>> all;
  {
    MutexLock lock(mu_);
    all = links_;
    all.insert(all.end(), retired_.begin(), retired_.end());
  }
  for (auto& l : all)
    if (l->thread.joinable()) l->thread.join();
}

void MasterPool::changed() {
  signal_.notify([&] { ++generation_; });
}

void MasterPool::resolve_soon() {
  if (!has_names_) return;
  signal_.notify([&] { resolve_requested_ = true; });
}

void MasterPool::set_state(Link& link, MasterState state, const std::string& detail) {
  {
    MutexLock lock(link.mu);
    link.status.state = state;
    link.status.detail = detail;
  }
  changed();
}

std::string MasterPool::summary() const {
  std::string out;
  for (const MasterStatus& m : status())
    out += fmt::format("{}{} {}", out.empty() ? "" : ", ", m.name, to_string(m.state));
  return out;
}

std::vector<std::string> MasterPool::connected() const {
  std::vector<std::shared_ptr<Link>> links;
  {
    MutexLock lock(mu_);
    links = links_;
  }
  std::vector<std::string> out;
  for (const auto& l : links) {
    MutexLock lock(l->mu);
    if (l->session && l->session->registered() && !l->session->ending()) out.push_back(l->endpoint.target);
  }
  return out;
}

std::shared_ptr<MasterPool::Use> MasterPool::use(const std::string& target) const {
  std::shared_ptr<Link> link;
  {
    MutexLock lock(mu_);
    for (const auto& l : links_)
      if (l->endpoint.target == target) link = l;
  }
  if (!link) return nullptr;
  std::shared_ptr<MasterSession> s;
  {
    MutexLock lock(link->mu);
    // Counted under the lock the link's farewell waits on: a session that is not ending yet cannot
    // say farewell before this Use is dropped.
    if (!link->session || !link->session->registered() || link->session->ending()) return nullptr;
    s = link->session;
    ++link->users;
  }
  return std::make_shared<Use>(link, s);
}

std::shared_ptr<MasterSession> MasterPool::session(const std::string& target) const {
  std::vector<std::shared_ptr<Link>> links;
  {
    MutexLock lock(mu_);
    links = links_;
    links.insert(links.end(), retired_.begin(), retired_.end());
  }
  for (const auto& l : links) {
    if (l->endpoint.target != target) continue;
    MutexLock lock(l->mu);
    if (l->session) return l->session;
  }
  return nullptr;
}

std::vector<MasterStatus> MasterPool::status() const {
  std::vector<std::shared_ptr<Link>> links;
  {
    MutexLock lock(mu_);
    links = links_;
  }
  std::vector<MasterStatus> out;
  for (const auto& l : links) {
    MutexLock lock(l->mu);
    out.push_back(l->status);
  }
  return out;
}

void MasterPool::end_sessions(const std::string& reason) {
  std::vector<std::shared_ptr<Link>> links;
  {
    MutexLock lock(mu_);
    links = links_;
    links.insert(links.end(), retired_.begin(), retired_.end());
  }
  for (const auto& l : links) {
    std::shared_ptr<MasterSession> s;
    {
      MutexLock lock(l->mu);
      s = l->session;
    }
    if (s) s->end(reason, /*lost=*/false);
  }
}

// Starts a link per new endpoint; with a complete resolution, leaves the masters no longer in it.
void MasterPool::sync(const std::vector<MasterEndpoint>& endpoints, bool complete) {
  std::vector<std::shared_ptr<Link>> started, gone;
  {
    MutexLock lock(mu_);
    std::vector<std::shared_ptr<Link>> next;
    for (const auto& e : endpoints) {
      auto it = std::find_if(links_.begin(), links_.end(),
                             [&](const std::shared_ptr<Link>& l) { return l->endpoint.target == e.target; });
      if (it != links_.end()) {
        next.push_back(*it);
        continue;
      }
      auto link = std::make_shared<Link>(e);
      next.push_back(link);
      started.push_back(link);
    }
    for (const auto& l : links_) {
      if (std::find(next.begin(), next.end(), l) != next.end()) continue;
      if (complete) {
        gone.push_back(l);
        retired_.push_back(l);
      } else {
        next.push_back(l);  // a name that did not resolve this time: keep its masters
      }
    }
    links_ = next;
    single_ = links_.size() == 1 && opts_.targets.size() == 1 && links_[0]->endpoint.target == opts_.targets[0].spec;
    for (const auto& l : started) l->thread = std::thread([this, l] { link_loop(l); });
  }
  for (const auto& l : started) log_->info("master {}: serving it", l->endpoint.name);
  for (const auto& l : gone) {
    log_->info("master {}: its address is no longer in the resolution; leaving it", l->endpoint.name);
    std::shared_ptr<MasterSession> s;
    signal_.notify([&] { l->removed = true; });
    {
      MutexLock lock(l->mu);
      s = l->session;
    }
    if (s) s->end("the master's address is gone", /*lost=*/false);
  }
  if (!started.empty() || !gone.empty()) changed();
}

std::optional<std::string> MasterPool::all_refused() const {
  MutexLock lock(mu_);
  if (links_.empty()) return std::nullopt;
  std::string reasons;
  for (const auto& l : links_) {
    if (!l->refused && !l->duplicate) return std::nullopt;
    MutexLock link_lock(l->mu);
    reasons += (reasons.empty() ? "" : "; ") + l->status.detail;
  }
  return reasons;
}

std::optional<std::string> MasterPool::run() {
  auto last_resolve = std::chrono::steady_clock::now();
  sync(resolve_masters(opts_.targets, opts_.resolver), /*complete=*/false);
  std::optional<std::string> refused;
  std::string logged;  // the last summary of the masters' states in the log
  while (!signal_.stopping()) {
    if ((refused = all_refused())) break;
    const uint64_t seen = generation_;
    if (!single_) {
      std::string now = summary();
      if (now != logged) log_->info("masters: {}", now);
      logged = std::move(now);
    }
    const int since = int(
        std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::steady_clock::now() - last_resolve).count());
    if (has_names_ && (since >= opts_.resolve_interval_ms || (resolve_requested_ && since >= kMinResolveGapMs))) {
      resolve_requested_ = false;
      last_resolve = std::chrono::steady_clock::now();
      bool complete = false;
      const auto endpoints = resolve_masters(opts_.targets, opts_.resolver, &complete);
      sync(endpoints, complete);
      continue;
    }
    int wait_ms = has_names_ ? std::max(10, opts_.resolve_interval_ms - since) : 60000;
    if (has_names_ && resolve_requested_) wait_ms = std::max(10, kMinResolveGapMs - since);
    signal_.wait_for(wait_ms, [&] { return generation_ != seen || resolve_requested_.load(); });
  }
  {
    std::vector<std::shared_ptr<Link>> all;
    {
      MutexLock lock(mu_);
      all = links_;
      all.insert(all.end(), retired_.begin(), retired_.end());
    }
    for (auto& l : all)
      if (l->thread.joinable()) l->thread.join();
  }
  return refused;
}

// ---- a link ---------------------------------------------------------------------------------------

void MasterPool::link_loop(const std::shared_ptr<Link>& link) {
  set_thread_name("epr-master");
  const MasterEndpoint& e = link->endpoint;
  Backoff backoff(opts_.session.min_backoff_ms, opts_.session.max_backoff_ms, std::random_device{}());
  while (!signal_.stopping() && !link->removed) {
    MasterSession::Config config = opts_.session;
    config.master = e.target;
    config.tls_server_name = e.tls_server_name;
    auto s = std::make_shared<MasterSession>(config, signal_, counters_, log_);
    {
      // Published before Register, so that a stop cancels the call.
      MutexLock lock(link->mu);
      if (signal_.stopping() || link->removed) break;
      link->session = s;
      // A master being retried stays "backing off" in the status until it answers.
      if (link->status.state != MasterState::kBackingOff) link->status.state = MasterState::kConnecting;
    }
    const grpc::Status status = s->register_worker();
    if (!status.ok()) {
      {
        MutexLock lock(link->mu);
        link->session.reset();
      }
      if (signal_.stopping() || link->removed) break;
      const std::string why = rpc::describe(status);
      if (!rpc::is_transient(status.error_code())) {
        // Registering again would be refused the same way.
        const std::string reason =
            fmt::format("the master at {} refused worker '{}': {}", e.name, opts_.session.name, why);
        set_state(*link, MasterState::kRefused, reason);
        log_->error("{}; not retrying", reason);
        signal_.notify([&] { link->refused = true; });
        changed();
        break;
      }
      const int delay = backoff.next_ms();
      set_state(*link, MasterState::kBackingOff, why);
      // Warn on attempts 1, 2, 4, 8, ...: a master that stays away does not flood the log.
      const int attempt = backoff.attempts();
      log_->log((attempt & (attempt - 1)) == 0 ? spdlog::level::warn : spdlog::level::debug,
                "cannot register with {}: {}; retrying in {} ms", e.name, why, delay);
      resolve_soon();
      signal_.wait_for(delay, [&] { return link->removed.load(); });
      continue;
    }
    if (const std::string other = claim(*link, s->master_instance()); !other.empty()) {
      // One master under two addresses: it is served once, on the link that registered first.
      const std::string reason = fmt::format("the same master as {}; served once", other);
      log_->warn("master {}: {}", e.name, reason);
      s->farewell(reason);
      {
        MutexLock lock(link->mu);
        link->session.reset();
      }
      set_state(*link, MasterState::kLeaving, reason);
      link->duplicate = true;
      changed();
      break;
    }
    const bool ended = run_session(*link, s);
    release(*link, s->master_instance());
    if (ended) break;
    const bool shutdown = link->shutdown.exchange(false);
    if (s->healthy() && !shutdown) backoff.reset();
    ++counters_.reconnects;
    const int delay = backoff.next_ms();
    set_state(*link, MasterState::kBackingOff, s->end_reason());
    log_->warn("lost the session with {} ({}); registering again in {} ms", e.name, s->end_reason(), delay);
    resolve_soon();
    signal_.wait_for(delay, [&] { return link->removed.load(); });
  }
  {
    MutexLock lock(link->mu);
    if (link->status.state != MasterState::kRefused) link->status.state = MasterState::kLeaving;
  }
  changed();
}

std::string MasterPool::claim(const Link& link, const std::string& instance) {
  if (instance.empty()) return "";
  MutexLock lock(mu_);
  const auto [it, added] = instances_.emplace(instance, link.endpoint.target);
  if (added || it->second == link.endpoint.target) return "";
  for (const auto& l : links_)
    if (l->endpoint.target == it->second) return l->endpoint.name;
  return it->second;
}

void MasterPool::release(const Link& link, const std::string& instance) {
  MutexLock lock(mu_);
  if (auto it = instances_.find(instance); it != instances_.end() && it->second == link.endpoint.target)
    instances_.erase(it);
}

// Runs one registered session until it ends and nothing uses it any more; then says farewell (a
// stop, a Shutdown, the address gone) or salvages its leases (it broke). True: the link ends.
bool MasterPool::run_session(Link& link, const std::shared_ptr<MasterSession>& s) {
  const MasterEndpoint& e = link.endpoint;
  {
    MutexLock lock(link.mu);
    link.status.worker_id = s->worker_id();
    link.status.state = MasterState::kConnected;
    link.status.detail.clear();
  }
  ++counters_.registrations;
  log_->info("registered with {} as {} ({} tracing threads, heartbeat every {} ms)", e.name, s->worker_id(),
             opts_.threads, s->heartbeat_ms());
  changed();
  std::thread heartbeat([&] { s->heartbeat_loop(); });
  signal_.wait([&] { return s->ending() || link.removed.load(); });
  if (signal_.stopping()) s->end("stopping", /*lost=*/false);
  if (link.removed) s->end("the master's address is gone", /*lost=*/false);
  heartbeat.join();
  changed();  // no longer connected: the tracing threads pick again
  {
    // The tracing threads finish with it: the tiles they trace are abandoned, their submissions end.
    MutexLock lock(link.mu);
    link.idle.wait(lock, [&]() EPR_NO_THREAD_SAFETY_ANALYSIS { return link.users == 0; });  // with mu held
    link.session.reset();
  }
  const bool leaving = signal_.stopping() || link.removed;
  if (!s->lost() && (leaving || link.shutdown)) {
    set_state(link, MasterState::kLeaving, s->end_reason());
    const std::string reason = leaving && signal_.stopping() ? signal_.reason() : s->end_reason();
    s->farewell(reason.empty() ? "worker stopping" : reason);
    return leaving;
  }
  s->salvage();
  return leaving;
}

}  // namespace epr
