#include "master/server/job_manager.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <set>

#include <fmt/format.h>
#include <tbb/task_group.h>

#include "common/image.h"
#include "common/log.h"
#include "common/scene_loader.h"
#include "common/thread_name.h"
#include "master/gl_context.h"
#include "master/server/checkpoint.h"
#include "worker/tile_renderer.h"

namespace epr {
namespace fs = std::filesystem;
namespace {

int64_t now_ms() {
  return std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::system_clock::now().time_since_epoch())
      .count();
}

}  // namespace

const char* to_string(JobState s) {
  switch (s) {
    case JobState::kQueued: return "queued";
    case JobState::kRunning: return "running";
    case JobState::kDone: return "done";
    case JobState::kFailed: return "failed";
    case JobState::kCancelled: return "cancelled";
  }
  return "?";
}

// ---- state ----------------------------------------------------------------------------------------

struct JobManager::Job {
  struct Slot {
    enum class State { kPending, kLeased, kCommitted, kIdle } state = State::kPending;
    std::set<uint64_t> leases;  // leases currently out for this tile
    int64_t deadline_ms = 0;
    bool re_leased = false;
    struct Hold {
      std::string worker;
      int64_t since_ms = 0, deadline_ms = 0;
      int64_t seen_ms = 0;  // leased or last extended by a heartbeat
    };
    std::map<uint64_t, Hold> holds;  // who holds each lease of `leases`, since and until when
    bool speculated = false;         // a speculative copy went out this round
    std::set<uint64_t> issued;       // every lease of the tile this round (results name one of them)
  };

  std::string id;
  uint64_t seq = 0;
  JobRequest request;
  JobState state = JobState::kQueued;
  std::string error;
  std::string scene_hash;
  std::shared_ptr<const SceneBundleData> bundle;
  uint64_t triangles = 0;
  Bounds3 codec_bounds;

  std::vector<TileRect> tiles;
  std::vector<Slot> slots;
  std::deque<uint32_t> pending;
  std::vector<std::vector<uint8_t>> tile_skip;      // this round's inputs, per tile
  std::vector<std::vector<uint32_t>> tile_first;    // this round's inputs, per tile
  uint32_t round = 0;
  uint32_t remaining = 0;  // tiles of the round not yet applied by the reprojection thread
  int paths_per_pixel = 1;
  bool round_open = false;
  int64_t round_opened_ms = 0;              // for the round duration histogram
  double reprojecting_at_round_open = 0;    // seconds_reprojecting when the round opened
  std::chrono::steady_clock::time_point last_commit_at;  // the round's latest committed result arrived
  double seconds_round_backlog = 0, seconds_round_closing = 0, seconds_writing_results = 0;  // JobSnapshot
  // Round checkpoints (MasterOptions::checkpoint_interval_s): when the last was taken (0: none yet
  // in this master's run) and what it cost, copy + write, seconds.
  int64_t last_checkpoint_ms = 0;
  double checkpoint_cost_s = 0;
  uint32_t round_checkpoints = 0;

  FrameProgress progress;
  ReprojectionCounts counts;
  uint64_t rays = 0, vertices_received = 0, non_finite = 0, worker_culled = 0;
  uint64_t tiles_leased = 0, tiles_committed = 0, tiles_re_leased = 0, tiles_dropped = 0;
  uint64_t tiles_speculative = 0, worker_failures = 0;
  std::map<std::string, int> failures_by_worker;  // worker id -> failed leases of this job
  std::set<std::string> blocked, scene_failed;    // worker ids: no more tiles; reported a scene failure
  std::string last_failure;
  // Lease-to-commit times (ms) of the tiles committed in round tile_ms_round: the current round once it
  // has a commit, else the last round that had one. Drives the speculative re-lease threshold.
  uint32_t tile_ms_round = 0;
  std::vector<int64_t> tile_ms;
  int64_t submitted_ms = 0, started_ms = 0, finished_ms = 0;
  double seconds_tracing = 0, seconds_reprojecting = 0;
  bool budget_exhausted = false;
  uint64_t version = 0;
  // Previews: a copy of the images taken at most once a second when a round closes (a running job)
  // and the PNGs encoded from it on demand, by whoever asks (never on the reprojection thread). A
  // finished job's previews come from its result files.
  std::shared_ptr<const FrameImages> preview_images;
  bool preview_reprojects = false;
  std::map<std::string, std::vector<unsigned char>> previews;  // layer -> PNG of preview_images
  int64_t last_preview_ms = 0;

  // Reprojection thread only.
  int64_t counts_ms = 0;  // when `counts` was last refreshed from the reprojector
  std::unique_ptr<Scene> scene;
  std::unique_ptr<Camera> camera;
  std::unique_ptr<FrameState> frame;
  // Set when the job was running when the master stopped: start_job continues from it.
  std::shared_ptr<const JobProgressRecord> resume;
};

struct JobManager::Worker {
  std::string id, name;
  uint32_t threads = 1;
  int64_t last_seen_ms = 0;
  std::set<uint64_t> leases;
  uint64_t tiles_committed = 0, paths = 0;
  double seconds_tracing = 0;
};

struct JobManager::Task {
  std::shared_ptr<Job> job;
  uint32_t round = 0, tile_index = 0;
  AssembledTile tile;
};

// ---- lifecycle ------------------------------------------------------------------------------------

JobManager::JobManager(MasterOptions options) : options_(std::move(options)) {
  // A temporary folder is this manager's alone (several masters may live in one process) and goes
  // with it.
  static std::atomic<uint32_t> temporary_folders{0};
  state_dir_ = options_.state_dir.empty()
                   ? (fs::temp_directory_path() / fmt::format("epr-master-{}-{}", ::getpid(), ++temporary_folders)).string()
                   : options_.state_dir;
  fs::create_directories(fs::path(state_dir_) / "jobs");
  store_ = std::make_unique<CheckpointStore>(state_dir_);
  checkpointing_ = options_.checkpoints && !options_.state_dir.empty();
  // Lease ids are never reused, not even across restarts: the run number is their top bits.
  epoch_ = store_->next_epoch();
  next_lease_ = (epoch_ << kLeaseEpochShift) + 1;
  load_state();
  reprojection_thread_ = std::thread([this] { reprojection_loop(); });
  reaper_thread_ = std::thread([this] { reaper_loop(); });
  if (checkpointing_) checkpoint_thread_ = std::thread([this] { checkpoint_loop(); });
}

JobManager::~JobManager() {
  shutdown();
  if (options_.state_dir.empty()) {
    std::error_code ec;
    fs::remove_all(state_dir_, ec);
  }
}

void JobManager::shutdown() {
  {
    std::lock_guard lock(mu_);
    if (stopping_) return;
    stopping_ = true;
    parking_stopped_ = true;
    wake_parked(/*all=*/true);
  }
  answer_due();
  work_cv_.notify_all();
  if (reprojection_thread_.joinable()) reprojection_thread_.join();
  if (reaper_thread_.joinable()) reaper_thread_.join();
  {
    std::lock_guard lock(checkpoint_mu_);  // the checkpoints still queued are written first
    checkpoint_stopping_ = true;
  }
  checkpoint_cv_.notify_all();
  if (checkpoint_thread_.joinable()) checkpoint_thread_.join();
}

bool JobManager::gl_ready() const {
  std::lock_guard lock(mu_);
  return gl_ready_;
}

DurationHistograms JobManager::histograms() const {
  std::lock_guard lock(mu_);
  return histograms_;
}

std::string JobManager::job_dir(const Job& job) const { return (fs::path(state_dir_) / "jobs" / job.id).string(); }

// ---- clients --------------------------------------------------------------------------------------

std::optional<std::string> JobManager::validate(const JobRequest& req) const {
  auto invalid = [](std::string why) { return std::optional<std::string>(std::move(why)); };
  if (auto err = req.options.validate()) return invalid(*err);
  if (auto err = req.camera.validate()) return invalid(*err);
  const SceneBundleData& b = req.bundle;
  if (b.builtin.empty()) {
    if (b.files.empty()) return invalid("the scene bundle is empty");
    if (b.total_bytes() > options_.max_scene_bytes)
      return invalid(fmt::format("the scene bundle has {} bytes, over the limit of {}", b.total_bytes(), options_.max_scene_bytes));
    bool has_entry = false;
    std::set<std::string> paths;
    for (const auto& [path, data] : b.files) {
      if (!is_safe_relative_path(path)) return invalid(fmt::format("scene file path '{}' is not a safe relative path", path));
      if (!paths.insert(path).second) return invalid(fmt::format("scene file path '{}' appears twice", path));
      has_entry |= path == b.entry_path;
    }
    if (!has_entry) return invalid(fmt::format("the scene's entry path '{}' is not among its files", b.entry_path));
  } else if (b.builtin.rfind("builtin:", 0) != 0) {
    return invalid("a built-in scene is named builtin:NAME");
  }
  if (req.options.width > options_.max_image_side || req.options.height > options_.max_image_side)
    return invalid(fmt::format("image sides are limited to {} pixels", options_.max_image_side));
  if (req.options.spp > options_.max_spp)
    return invalid(fmt::format("spp {} is over this master's limit of {}", req.options.spp, options_.max_spp));
  return std::nullopt;
}

JobManager::SubmitResult JobManager::submit(JobRequest req) {
  if (auto err = validate(req)) return {"", *err};
  const std::string hash = content_hash(req.bundle);
  try {
    if (checkpointing_) store_->save_scene(hash, req.bundle);
  } catch (const std::exception& e) {
    logger("master")->error("cannot store scene {}: {} (its jobs will not survive a restart)", hash, e.what());
  }

  std::shared_ptr<Job> job;
  JobSpecRecord spec;
  std::vector<std::string> forgotten;
  {
    std::lock_guard lock(mu_);
    if (!req.request_id.empty()) {
      if (auto it = request_ids_.find(req.request_id); it != request_ids_.end()) return {it->second, ""};
    }
    job = std::make_shared<Job>();
    job->seq = next_job_seq_++;
    job->id = fmt::format("j{:06d}-{:04x}", job->seq, uint32_t(now_ms()) & 0xffff);
    job->scene_hash = hash;
    auto& cached = scenes_[hash];
    if (!cached) cached = std::make_shared<const SceneBundleData>(std::move(req.bundle));
    job->bundle = cached;
    job->submitted_ms = now_ms();
    job->tiles = make_tiles(req.options);
    job->request = std::move(req);
    if (!job->request.request_id.empty()) request_ids_[job->request.request_id] = job->id;
    jobs_[job->id] = job;
    spec = {job->id,
            job->seq,
            job->submitted_ms,
            hash,
            job->request.options,
            job->request.camera,
            job->request.name,
            job->request.priority,
            job->request.time_budget_seconds,
            job->request.request_id};
    // Forget the oldest finished jobs beyond the limit.
    while (jobs_.size() > size_t(options_.max_jobs)) {
      auto oldest = std::find_if(jobs_.begin(), jobs_.end(), [](const auto& kv) {
        return kv.second->state != JobState::kQueued && kv.second->state != JobState::kRunning;
      });
      if (oldest == jobs_.end()) break;
      forgotten.push_back(oldest->first);
      jobs_.erase(oldest);
    }
  }
  for (const auto& id : forgotten) store_->remove_job(id);
  try {
    if (checkpointing_)
      store_->save_spec(spec);  // before the client learns the id: an acknowledged job survives a restart
  } catch (const std::exception& e) {
    logger("master")->error("job {}: cannot store its spec: {} (it will not survive a restart)", spec.id, e.what());
  }
  logger("master")->info("job {} submitted: {} {}x{} spp {} mode {}", job->id, job->scene_hash.substr(0, 12),
                         job->request.options.width, job->request.options.height, job->request.options.spp,
                         to_string(job->request.options.mode));
  work_cv_.notify_all();
  notify(job);
  return {job->id, ""};
}

JobSnapshot JobManager::snapshot(const Job& job) const {
  JobSnapshot s;
  s.id = job.id;
  s.name = job.request.name;
  s.error = job.error;
  s.state = job.state;
  s.priority = job.request.priority;
  s.options = job.request.options;
  s.camera = job.request.camera;
  s.scene_hash = job.scene_hash;
  s.scene_builtin = job.bundle->builtin;
  s.scene_bytes = job.bundle->total_bytes();
  s.triangles = job.triangles;
  s.progress = job.progress;
  s.counts = job.counts;
  const auto& o = job.request.options;
  s.rounds_planned = rounds_planned(o);
  s.rays_traced = job.rays;
  s.vertices_received = job.vertices_received;
  s.non_finite_dropped = job.non_finite;
  s.worker_culled = job.worker_culled;
  s.tiles_leased = job.tiles_leased;
  s.tiles_committed = job.tiles_committed;
  s.tiles_re_leased = job.tiles_re_leased;
  s.tiles_dropped = job.tiles_dropped;
  s.tiles_speculative = job.tiles_speculative;
  s.worker_failures = job.worker_failures;
  s.workers_blocked = uint32_t(job.blocked.size());
  std::set<std::string> active_workers;
  for (const auto& [wid, w] : workers_)
    if (!w->leases.empty() && active_.get() == &job) active_workers.insert(wid);
  s.workers_active = uint32_t(active_workers.size());
  s.submitted_ms = job.submitted_ms;
  s.started_ms = job.started_ms;
  s.finished_ms = job.finished_ms;
  const int64_t end = job.finished_ms ? job.finished_ms : now_ms();
  s.seconds_elapsed = job.started_ms ? double(end - job.started_ms) / 1000.0 : 0.0;
  if (job.state == JobState::kRunning && job.progress.round > 0 && job.progress.paths_traced > 0) {
    s.eta_seconds = eta_seconds(job.progress, o.spp, s.seconds_elapsed);
  } else if (job.state == JobState::kDone) {
    s.eta_seconds = 0;
  }
  s.seconds_tracing = job.seconds_tracing;
  s.seconds_reprojecting = job.seconds_reprojecting;
  s.seconds_round_backlog = job.seconds_round_backlog;
  s.seconds_round_closing = job.seconds_round_closing;
  s.seconds_writing_results = job.seconds_writing_results;
  s.round_checkpoints = job.round_checkpoints;
  s.budget_exhausted = job.budget_exhausted;
  s.version = job.version;
  return s;
}

std::optional<JobSnapshot> JobManager::get(const std::string& id) const {
  std::lock_guard lock(mu_);
  auto it = jobs_.find(id);
  if (it == jobs_.end()) return std::nullopt;
  return snapshot(*it->second);
}

std::vector<JobSnapshot> JobManager::list() const {
  std::lock_guard lock(mu_);
  std::vector<JobSnapshot> out;
  for (const auto& [id, job] : jobs_) out.push_back(snapshot(*job));
  return out;
}

bool JobManager::cancel(const std::string& id) {
  std::shared_ptr<Job> job;
  bool cancelled = false;
  {
    std::lock_guard lock(mu_);
    auto it = jobs_.find(id);
    if (it == jobs_.end()) return false;
    job = it->second;
    if (job->state == JobState::kQueued || job->state == JobState::kRunning) {
      cancelled = true;
      job->state = JobState::kCancelled;
      job->finished_ms = now_ms();
      job->round_open = false;
      ++job->version;
    }
  }
  work_cv_.notify_all();
  if (cancelled) save_final_checkpoint(job);
  notify(job);
  return true;
}

uint64_t JobManager::watch(const std::string& id, std::function<void(const JobSnapshot&)> listener) {
  std::lock_guard lock(mu_);
  if (!jobs_.count(id)) return 0;
  const uint64_t h = next_watch_++;
  watchers_[h] = {id, std::move(listener)};
  return h;
}

void JobManager::unwatch(uint64_t handle) {
  std::lock_guard lock(mu_);
  watchers_.erase(handle);
}

void JobManager::notify(const std::shared_ptr<Job>& job) {
  std::vector<std::function<void(const JobSnapshot&)>> listeners;
  JobSnapshot snap;
  {
    std::lock_guard lock(mu_);
    snap = snapshot(*job);
    for (const auto& [h, w] : watchers_)
      if (w.first == job->id) listeners.push_back(w.second);
  }
  for (auto& l : listeners) l(snap);
}

std::optional<std::string> JobManager::result_path(const std::string& id, const std::string& kind) const {
  std::string dir;
  {
    std::lock_guard lock(mu_);
    auto it = jobs_.find(id);
    if (it == jobs_.end() || it->second->state != JobState::kDone) return std::nullopt;
    dir = job_dir(*it->second);
  }
  static const std::map<std::string, std::string> files = {
      {"exr", "combined.exr"},      {"png", "combined.png"},
      {"samples.png", "samples.png"}, {"json", "stats.json"},
      {"pathtrace.exr", "pathtrace.exr"}, {"reprojection.exr", "reprojection.exr"}, {"counts.exr", "counts.exr"}};
  auto f = files.find(kind);
  if (f == files.end()) return std::nullopt;
  const fs::path p = fs::path(dir) / f->second;
  if (!fs::exists(p)) return std::nullopt;
  return p.string();
}

std::optional<std::vector<unsigned char>> JobManager::preview_png(const std::string& id, const std::string& layer) const {
  std::shared_ptr<const FrameImages> images;
  bool reprojects = false, done = false;
  std::string dir;
  {
    std::lock_guard lock(mu_);
    auto it = jobs_.find(id);
    if (it == jobs_.end()) return std::nullopt;
    const Job& job = *it->second;
    if (auto p = job.previews.find(layer); p != job.previews.end()) return p->second;
    images = job.preview_images;
    reprojects = job.preview_reprojects;
    done = job.state == JobState::kDone;
    dir = job_dir(job);
  }
  // Encoded here, on the caller's thread, without the mutex: the rounds go on meanwhile.
  auto png = images ? encode_preview(*images, reprojects, layer) : done ? result_preview(dir, layer) : std::nullopt;
  if (!png) return std::nullopt;
  std::lock_guard lock(mu_);
  auto it = jobs_.find(id);
  if (it != jobs_.end() && it->second->preview_images == images && (images || it->second->state == JobState::kDone))
    it->second->previews[layer] = *png;
  return png;
}

// ---- workers --------------------------------------------------------------------------------------

std::string JobManager::register_worker(const std::string& name, uint32_t threads) {
  std::lock_guard lock(mu_);
  auto w = std::make_unique<Worker>();
  w->id = fmt::format("w{}-{:04x}", next_worker_++, uint32_t(now_ms()) & 0xffff);
  w->name = name;
  w->threads = std::max(1u, threads);
  w->last_seen_ms = now_ms();
  const std::string id = w->id;
  workers_[id] = std::move(w);
  logger("master")->info("worker {} ({}, {} threads) registered", id, name, threads);
  return id;
}

void JobManager::unregister_worker(const std::string& worker) {
  std::lock_guard lock(mu_);
  workers_.erase(worker);
}

std::optional<std::vector<std::pair<bool, int64_t>>> JobManager::heartbeat(const std::string& worker,
                                                                         const std::vector<uint64_t>& leases) {
  std::lock_guard lock(mu_);
  auto wit = workers_.find(worker);
  if (wit == workers_.end()) return std::nullopt;
  wit->second->last_seen_ms = now_ms();
  std::vector<std::pair<bool, int64_t>> out;
  const int64_t deadline = now_ms() + options_.lease_timeout_ms;
  for (uint64_t lease : leases) {
    bool valid = false;
    if (active_ && active_->state == JobState::kRunning) {
      for (auto& slot : active_->slots)
        if (slot.state == Job::Slot::State::kLeased && slot.leases.count(lease)) {
          slot.deadline_ms = std::max(slot.deadline_ms, deadline);
          if (auto h = slot.holds.find(lease); h != slot.holds.end()) {
            h->second.deadline_ms = deadline;
            h->second.seen_ms = now_ms();
          }
          valid = true;
          break;
        }
    }
    out.emplace_back(valid, valid ? deadline : 0);
    if (!valid) wit->second->leases.erase(lease);
  }
  return out;
}

LeaseDecision JobManager::lease_tile(const std::string& worker) {
  std::lock_guard lock(mu_);
  bool parkable = false;
  return lease_tile_locked(worker, &parkable);
}

std::optional<LeaseDecision> JobManager::lease_tile_or_park(const std::string& worker, int max_wait_ms,
                                                            std::function<void(LeaseDecision)> answer,
                                                            uint64_t* handle) {
  std::lock_guard lock(mu_);
  bool parkable = false;
  LeaseDecision d = lease_tile_locked(worker, &parkable);
  if (!parkable || max_wait_ms <= 0 || parking_stopped_) return d;
  *handle = next_parked_++;
  parked_[*handle] = {worker, now_ms() + std::min(max_wait_ms, kMaxParkMs), std::move(answer)};
  return std::nullopt;
}

bool JobManager::cancel_parked(uint64_t handle) {
  std::lock_guard lock(mu_);
  return parked_.erase(handle) > 0;
}

size_t JobManager::parked_requests() const {
  std::lock_guard lock(mu_);
  return parked_.size();
}

void JobManager::stop_parking() {
  {
    std::lock_guard lock(mu_);
    parking_stopped_ = true;
    // The server is going away: no tile is handed out now that its result could not come back.
    for (auto& [handle, p] : parked_) due_.emplace_back(std::move(p.answer), LeaseWait{1000});
    parked_.clear();
  }
  answer_due();
}

void JobManager::wake_parked(bool all) {
  const int64_t now = now_ms();
  for (auto it = parked_.begin(); it != parked_.end();) {
    bool parkable = false;
    LeaseDecision d = lease_tile_locked(it->second.worker, &parkable);
    if (parkable && !all && now < it->second.deadline_ms) {
      ++it;
      continue;
    }
    // Out of time: ask again at once (a job may start any moment).
    if (parkable) d = LeaseWait{1};
    due_.emplace_back(std::move(it->second.answer), std::move(d));
    it = parked_.erase(it);
  }
}

void JobManager::answer_due() {
  std::vector<std::pair<std::function<void(LeaseDecision)>, LeaseDecision>> due;
  {
    std::lock_guard lock(mu_);
    due.swap(due_);
  }
  for (auto& [answer, decision] : due) answer(std::move(decision));
}

// *parkable: the answer is a short Wait that a tile may end soon (see lease_tile_or_park).
LeaseDecision JobManager::lease_tile_locked(const std::string& worker, bool* parkable) {
  *parkable = false;
  auto wit = workers_.find(worker);
  if (wit == workers_.end()) return UnknownWorker{};
  Worker& w = *wit->second;
  w.last_seen_ms = now_ms();
  if (stopping_) return LeaseWait{1000};
  // Back-pressure: the reprojection thread is behind.
  if (queued_vertices_ > options_.max_queued_vertices) return LeaseWait{20};
  Job* job = active_.get();
  // No job: poll slowly. A running job between rounds (its last tiles are out or being reprojected):
  // the next round opens within milliseconds, so ask again soon; a long wait here idles every core
  // at every round barrier.
  if (!job || job->state != JobState::kRunning) {
    *parkable = true;
    return LeaseWait{job ? 20u : 200u};
  }
  // A worker that failed too many of this job's tiles waits for the next job.
  if (job->blocked.count(worker)) return LeaseWait{500};
  *parkable = true;
  if (!job->round_open) return LeaseWait{5};
  const int64_t now = now_ms();
  // Every tile is out: maybe a copy of one whose lease runs long (the first complete result wins).
  std::optional<uint32_t> speculative;
  if (job->pending.empty() && !(speculative = speculative_tile(*job, worker, now))) return LeaseWait{5};
  *parkable = false;
  const uint32_t t = speculative ? *speculative : job->pending.front();
  if (!speculative) job->pending.pop_front();
  Job::Slot& slot = job->slots[t];
  TileLeaseInfo info;
  info.lease_id = next_lease_++;
  slot.state = Job::Slot::State::kLeased;
  slot.leases.insert(info.lease_id);
  slot.issued.insert(info.lease_id);
  slot.holds[info.lease_id] = {worker, now, now + options_.lease_timeout_ms, now};
  slot.deadline_ms = std::max(slot.deadline_ms, now + options_.lease_timeout_ms);
  w.leases.insert(info.lease_id);
  ++job->tiles_leased;
  if (slot.re_leased && !speculative) ++job->tiles_re_leased;
  if (speculative) {
    slot.speculated = true;
    ++job->tiles_speculative;
    logger("master")->info("job {} round {} tile {}: lease runs long, speculative copy to worker {}", job->id,
                           job->round, t, worker);
  }
  ++job->version;

  info.job_id = job->id;
  info.round = job->round;
  info.tile_index = t;
  info.rect = job->tiles[t];
  info.skip = job->tile_skip[t];
  info.first_sample = job->tile_first[t];
  info.paths_per_pixel = uint32_t(job->paths_per_pixel);
  info.seed = job->request.options.seed;
  info.options = job->request.options;
  info.camera = job->request.camera;
  info.codec_bounds = job->codec_bounds;
  info.scene_hash = job->scene_hash;
  info.scene_builtin = job->bundle->builtin;
  info.scene_bytes = job->bundle->total_bytes();
  info.triangles = job->triangles;
  info.deadline_ms = now + options_.lease_timeout_ms;
  return info;
}

std::optional<uint32_t> JobManager::speculative_tile(Job& job, const std::string& worker, int64_t now) {
  // Nothing to compare with before the first commit (of this round or the previous one).
  if (options_.speculative_factor <= 0 || job.tile_ms.empty()) return std::nullopt;
  // The longest-running tile not yet copied and not held by this worker, whose holder is alive (its
  // heartbeat extended the lease lately): a dead worker's tile comes back when its lease expires.
  const int64_t alive_ms = int64_t(options_.heartbeat_interval_ms) * 3 / 2;
  std::optional<uint32_t> best;
  int64_t best_age = -1;
  for (uint32_t t = 0; t < job.slots.size(); ++t) {
    const Job::Slot& slot = job.slots[t];
    if (slot.state != Job::Slot::State::kLeased || slot.speculated || slot.holds.empty()) continue;
    int64_t since = now;
    bool own = false, alive = false;
    for (const auto& [id, h] : slot.holds) {
      since = std::min(since, h.since_ms);
      own |= h.worker == worker;
      alive |= now - h.seen_ms <= alive_ms;
    }
    if (!own && alive && now - since > best_age) {
      best = t;
      best_age = now - since;
    }
  }
  if (!best || best_age <= options_.speculative_floor_ms) return std::nullopt;
  std::vector<int64_t> times = job.tile_ms;
  std::nth_element(times.begin(), times.begin() + ptrdiff_t(times.size() / 2), times.end());
  const double median = double(times[times.size() / 2]);
  if (double(best_age) <= options_.speculative_factor * median) return std::nullopt;
  return best;
}

void JobManager::release_lease(Job& job, uint32_t t, uint64_t lease) {
  auto& slot = job.slots[t];
  slot.holds.erase(lease);
  if (slot.state == Job::Slot::State::kLeased && slot.leases.erase(lease) && slot.leases.empty()) {
    slot.state = Job::Slot::State::kPending;
    slot.re_leased = true;
    job.pending.push_front(t);
    ++job.version;
  }
}

void JobManager::return_leases(const std::string& worker, const std::vector<uint64_t>& leases) {
  fail_leases(worker, leases, LeaseFailure::kNone, "");
}

void JobManager::fail_leases(const std::string& worker, const std::vector<uint64_t>& leases, LeaseFailure failure,
                             const std::string& reason) {
  std::vector<std::shared_ptr<Job>> failed;
  {
    std::lock_guard lock(mu_);
    auto wit = workers_.find(worker);
    for (uint64_t lease : leases) {
      if (wit != workers_.end()) wit->second->leases.erase(lease);
      if (!active_) continue;
      for (uint32_t t = 0; t < active_->slots.size(); ++t) {
        auto& slot = active_->slots[t];
        if (!slot.leases.count(lease)) continue;
        auto h = slot.holds.find(lease);
        // Counted against the worker only if the lease is its own and still live.
        const bool counts = failure != LeaseFailure::kNone && slot.state == Job::Slot::State::kLeased &&
                            h != slot.holds.end() && h->second.worker == worker;
        release_lease(*active_, t, lease);
        if (counts) count_failure(active_, worker, failure, reason, &failed);
        break;
      }
    }
    wake_parked(/*all=*/false);  // the tiles given back
  }
  answer_due();
  if (!failed.empty()) work_cv_.notify_all();
  for (const auto& job : failed) notify(job);
}

void JobManager::count_failure(const std::shared_ptr<Job>& job, const std::string& worker, LeaseFailure failure,
                               const std::string& reason, std::vector<std::shared_ptr<Job>>* failed) {
  const int n = ++job->failures_by_worker[worker];
  ++job->worker_failures;
  if (failure == LeaseFailure::kScene) job->scene_failed.insert(worker);
  job->last_failure = reason;
  ++job->version;
  auto log = logger("master");
  log->warn("job {}: worker {} failed a tile ({} so far): {}", job->id, worker, n, reason);
  if (options_.max_worker_failures > 0 && n >= options_.max_worker_failures && job->blocked.insert(worker).second)
    log->warn("job {}: worker {} failed {} tiles and gets no more tiles of this job", job->id, worker, n);
  fail_if_all_blocked(job, failed);
}

void JobManager::fail_if_all_blocked(const std::shared_ptr<Job>& job, std::vector<std::shared_ptr<Job>>* failed) {
  if (job->state != JobState::kRunning || job->blocked.empty() || workers_.empty()) return;
  bool all_scene = true;
  for (const auto& [id, w] : workers_) {
    if (!job->blocked.count(id)) return;
    all_scene &= job->scene_failed.count(id) > 0;
  }
  const int limit = options_.max_worker_failures;
  job->error = all_scene ? fmt::format("no worker could load the job's scene ({} worker(s) tried {} times each); last error: {}",
                                       workers_.size(), limit, job->last_failure)
                         : fmt::format("every registered worker ({}) failed {} tiles of the job and is blocked for it; "
                                       "last failure: {}",
                                       workers_.size(), limit, job->last_failure);
  logger("master")->error("job {} failed: {}", job->id, job->error);
  job->state = JobState::kFailed;
  job->finished_ms = now_ms();
  job->round_open = false;
  ++job->version;
  failed->push_back(job);
}

std::vector<WorkerSnapshot> JobManager::workers() const {
  std::lock_guard lock(mu_);
  std::vector<WorkerSnapshot> out;
  const int64_t now = now_ms();
  for (const auto& [id, w] : workers_) {
    WorkerSnapshot s;
    s.id = id;
    s.name = w->name;
    s.threads = w->threads;
    s.heartbeat_age_seconds = double(now - w->last_seen_ms) / 1000.0;
    s.tiles_committed = w->tiles_committed;
    s.paths_traced = w->paths;
    s.paths_per_second = w->seconds_tracing > 0 ? double(w->paths) / w->seconds_tracing : 0.0;
    s.leases_held = w->leases.size();
    out.push_back(s);
  }
  return out;
}

std::string JobManager::add_scene(SceneBundleData bundle) {
  const std::string hash = content_hash(bundle);
  std::lock_guard lock(mu_);
  auto& slot = scenes_[hash];
  if (!slot) slot = std::make_shared<const SceneBundleData>(std::move(bundle));
  return hash;
}

std::optional<std::string> JobManager::check_scene(const SceneBundleData& bundle) const {
  const std::string cache = (fs::path(state_dir_) / "cache").string();
  try {
    const Scene s = load_bundle(bundle, cache);
    if (s.triangle_count() == 0) return "the scene has no triangles";
  } catch (const std::exception& e) {
    // Name files as the client knows them, not by their place in the master's cache.
    std::string msg = e.what();
    const std::string prefix = (fs::path(cache) / "scenes" / content_hash(bundle)).string() + "/";
    for (size_t p; (p = msg.find(prefix)) != std::string::npos;) msg.erase(p, prefix.size());
    return msg;
  }
  return std::nullopt;
}

std::shared_ptr<const SceneBundleData> JobManager::scene(const std::string& hash) const {
  std::lock_guard lock(mu_);
  auto it = scenes_.find(hash);
  return it == scenes_.end() ? nullptr : it->second;
}

std::variant<TileExpectation, std::string> JobManager::expect(const v1::TileResultHeader& h, bool* stale) const {
  *stale = false;
  std::lock_guard lock(mu_);
  if (h.lease_id() == 0 || h.lease_id() >= next_lease_) return std::string("unknown lease id");
  if ((h.lease_id() >> kLeaseEpochShift) != epoch_) {
    *stale = true;  // leased by an earlier run of the master: its round is traced again
    return std::string("the lease is from before the master restarted");
  }
  auto it = jobs_.find(h.job_id());
  if (it == jobs_.end()) {
    *stale = true;
    return std::string("no such job (finished and forgotten, or never existed)");
  }
  const Job& job = *it->second;
  if (job.state != JobState::kRunning || h.round() != job.round || !job.round_open) {
    *stale = true;
    return fmt::format("job {} is {} in round {}, the result is for round {}", job.id, to_string(job.state), job.round, h.round());
  }
  if (h.tile_index() >= job.tiles.size())
    return fmt::format("tile index {} is outside the job's {} tiles", h.tile_index(), job.tiles.size());
  if (h.tile_index() < job.slots.size() && !job.slots[h.tile_index()].issued.count(h.lease_id()))
    return fmt::format("lease {} was not issued for tile {} of job {} round {}", h.lease_id(), h.tile_index(), job.id,
                       job.round);
  const TileRect& r = job.tiles[h.tile_index()];
  TileExpectation e;
  e.job_id = job.id;
  e.round = job.round;
  e.tile_index = h.tile_index();
  e.x0 = uint32_t(r.x0);
  e.y0 = uint32_t(r.y0);
  e.x1 = uint32_t(r.x1);
  e.y1 = uint32_t(r.y1);
  const RenderOptions& o = job.request.options;
  e.image_width = uint32_t(o.width);
  e.image_height = uint32_t(o.height);
  e.subpixels = uint32_t(o.subpixels);
  e.codec_bounds = job.codec_bounds;
  e.payload = o.mode == RenderMode::kPathTrace       ? TileExpectation::Payload::kPathsOnly
              : o.reproject == ReprojectMethod::kExact ? TileExpectation::Payload::kExactSamples
                                                       : TileExpectation::Payload::kVertices;
  e.paths_per_pixel = uint32_t(job.paths_per_pixel);
  e.skip = job.tile_skip[h.tile_index()];
  e.max_vertices_per_tile = std::max<uint64_t>(options_.max_queued_vertices, 1u << 20);
  e.keep_packed = true;  // decoded by the reprojector, in place
  return e;
}

void JobManager::count_stale(const std::string& job_id) {
  std::lock_guard lock(mu_);
  if (auto it = jobs_.find(job_id); it != jobs_.end()) {
    ++it->second->tiles_dropped;
    ++it->second->version;
  }
}

CommitOutcome JobManager::commit(const std::string& job_id, uint32_t round, uint32_t tile_index, AssembledTile tile) {
  {
    std::lock_guard lock(mu_);
    auto it = jobs_.find(job_id);
    auto wit = workers_.find(tile.worker_id);
    if (wit != workers_.end()) wit->second->leases.erase(tile.lease_id);
    if (it == jobs_.end() || it->second->state != JobState::kRunning || it->second->round != round ||
        tile_index >= it->second->slots.size()) {
      if (it != jobs_.end()) ++it->second->tiles_dropped;
      return CommitOutcome::kStale;
    }
    Job& job = *it->second;
    Job::Slot& slot = job.slots[tile_index];
    if (slot.state == Job::Slot::State::kCommitted || slot.state == Job::Slot::State::kIdle) {
      ++job.tiles_dropped;
      return CommitOutcome::kDuplicate;
    }
    if (slot.state == Job::Slot::State::kPending) {
      // Its lease had expired and the tile went back to the queue: this result still wins.
      job.pending.erase(std::remove(job.pending.begin(), job.pending.end(), tile_index), job.pending.end());
    }
    if (auto h = slot.holds.find(tile.lease_id); h != slot.holds.end()) {
      if (job.tile_ms_round != round) job.tile_ms.clear();
      job.tile_ms_round = round;
      job.tile_ms.push_back(now_ms() - h->second.since_ms);
    }
    // Any other lease of the tile (a speculative copy, or the slow original) lost: its heartbeat now
    // answers "not wanted", and a result it still sends is dropped as a duplicate.
    for (uint64_t l : slot.leases)
      for (auto& [wid, w] : workers_) w->leases.erase(l);
    slot.leases.clear();
    slot.holds.clear();
    slot.state = Job::Slot::State::kCommitted;
    ++job.tiles_committed;
    const auto& st = tile.worker_stats;
    job.rays += st.rays_traced();
    job.non_finite += st.non_finite_dropped() + tile.dropped_pixel_sums + tile.dropped_exact_samples;
    job.worker_culled += st.culled_frustum() + st.culled_facing() + st.culled_not_diffuse() + st.exact_occluded();
    job.vertices_received += tile.vertex_count() + tile.exact_samples.size();
    job.seconds_tracing += st.seconds_tracing();
    ++job.version;
    if (wit != workers_.end()) {
      ++wit->second->tiles_committed;
      wit->second->paths += st.paths_traced();
      wit->second->seconds_tracing += st.seconds_tracing();
    }
    auto task = std::make_unique<Task>();
    task->job = it->second;
    task->round = round;
    task->tile_index = tile_index;
    queued_vertices_ += tile.vertex_count() + tile.exact_samples.size();
    job.last_commit_at = std::chrono::steady_clock::now();
    task->tile = std::move(tile);
    tasks_.push_back(std::move(task));
  }
  work_cv_.notify_all();
  return CommitOutcome::kCommitted;
}

// ---- the reprojection thread ----------------------------------------------------------------------

std::shared_ptr<JobManager::Job> JobManager::next_job() const {
  std::shared_ptr<Job> best;
  for (const auto& [id, job] : jobs_) {
    if (job->state != JobState::kQueued) continue;
    if (job->resume) return job;  // it was running when the master stopped: it goes on first
    if (!best || job->request.priority > best->request.priority ||
        (job->request.priority == best->request.priority && job->seq < best->seq))
      best = job;
  }
  return best;
}

void JobManager::reprojection_loop() {
  set_thread_name("epr-reproject");
  auto log = logger("master");
  std::unique_ptr<GlContext> gl;
  if (options_.reproject_backend_override != "cpu") {
    try {
      gl = std::make_unique<GlContext>();
      log->info("reprojection context: {} / {}", gl->renderer(), gl->version());
    } catch (const std::exception& e) {
      log->warn("no OSMesa context ({}); jobs asking for GL reprojection will use the CPU reprojector", e.what());
    }
  }
  {
    std::lock_guard lock(mu_);
    gl_ready_ = gl != nullptr;
  }
  for (;;) {
    std::unique_ptr<Task> task;
    std::shared_ptr<Job> to_start;
    std::shared_ptr<Job> to_drop;
    {
      std::unique_lock lock(mu_);
      work_cv_.wait(lock, [&] {
        if (stopping_ || !tasks_.empty()) return true;
        if (active_ && active_->state != JobState::kRunning && active_->state != JobState::kQueued) return true;
        return !active_ && next_job() != nullptr;
      });
      if (stopping_) break;
      if (active_ && (active_->state == JobState::kCancelled || active_->state == JobState::kFailed)) {
        to_drop = active_;
        active_.reset();
      } else if (!tasks_.empty()) {
        task = std::move(tasks_.front());
        tasks_.pop_front();
        queued_vertices_ -= task->tile.vertex_count() + task->tile.exact_samples.size();
      } else if (!active_) {
        active_ = next_job();
        to_start = active_;
      }
    }
    if (to_drop) {
      // Cancelled or failed: its last previews stay available as PNGs, the image copy goes.
      std::shared_ptr<const FrameImages> images;
      {
        std::lock_guard lock(mu_);
        images = std::move(to_drop->preview_images);
      }
      if (images) {
        std::map<std::string, std::vector<unsigned char>> pngs;
        for (const char* layer : {"combined", "pathtrace", "reprojection", "samples"})
          if (auto png = encode_preview(*images, to_drop->preview_reprojects, layer)) pngs[layer] = std::move(*png);
        std::lock_guard lock(mu_);
        to_drop->previews = std::move(pngs);
      }
      to_drop->frame.reset();
      to_drop->scene.reset();
      notify(to_drop);
      continue;
    }
    if (to_start) {
      try {
        to_start->frame.reset();
        start_job(to_start, gl.get());
      } catch (const std::exception& e) {
        log->error("job {} failed to start: {}", to_start->id, e.what());
        {
          std::lock_guard lock(mu_);
          to_start->state = JobState::kFailed;
          to_start->error = e.what();
          to_start->finished_ms = now_ms();
          ++to_start->version;
          active_.reset();
        }
        save_final_checkpoint(to_start);
        notify(to_start);
      }
      continue;
    }
    if (task) {
      try {
        apply_commit(*task);
      } catch (const std::exception& e) {
        log->error("job {}: commit failed: {}", task->job->id, e.what());
        {
          std::lock_guard lock(mu_);
          task->job->state = JobState::kFailed;
          task->job->error = e.what();
          task->job->finished_ms = now_ms();
          ++task->job->version;
        }
        work_cv_.notify_all();
        save_final_checkpoint(task->job);
        notify(task->job);
      }
    }
  }
  std::lock_guard lock(mu_);
  for (auto& [id, job] : jobs_) job->frame.reset();
}

void JobManager::start_job(const std::shared_ptr<Job>& job, GlContext* gl) {
  RenderOptions opts = job->request.options;
  if (options_.reproject_backend_override == "cpu" || !gl)
    if (opts.reproject == ReprojectMethod::kGl) opts.reproject = ReprojectMethod::kCpu;
  job->scene = std::make_unique<Scene>(load_bundle(*job->bundle, (fs::path(state_dir_) / "cache").string()));
  job->camera = std::make_unique<Camera>(job->request.camera, opts.width, opts.height);
  job->frame = std::make_unique<FrameState>(opts, *job->camera, *job->scene, gl);
  std::shared_ptr<const JobProgressRecord> resume;
  {
    std::lock_guard lock(mu_);
    resume = std::move(job->resume);
  }
  const bool had_checkpoint = resume != nullptr;
  if (resume) {
    try {
      job->frame->restore(*resume->frame);
    } catch (const std::exception& e) {
      logger("master")->error("job {}: its checkpoint does not fit ({}); starting it again from round 0", job->id,
                              e.what());
      resume.reset();
    }
  }
  {
    std::lock_guard lock(mu_);
    job->triangles = job->scene->triangle_count();
    job->codec_bounds = job->scene->bounds();
    if (job->state != JobState::kQueued) return;  // cancelled meanwhile
    job->state = JobState::kRunning;
    job->started_ms = now_ms();
    if (had_checkpoint) {
      JobProgressRecord counters = resume ? *resume : JobProgressRecord{};
      if (!resume) counters.started_ms = job->started_ms;
      job->progress = job->frame->progress();
      job->counts = job->frame->counts();
      job->round = uint32_t(job->frame->round());
      job->started_ms = counters.started_ms;
      job->rays = counters.rays;
      job->vertices_received = counters.vertices_received;
      job->non_finite = counters.non_finite;
      job->worker_culled = counters.worker_culled;
      job->tiles_leased = counters.tiles_leased;
      job->tiles_committed = counters.tiles_committed;
      job->tiles_re_leased = counters.tiles_re_leased;
      job->tiles_dropped = counters.tiles_dropped;
      job->seconds_tracing = counters.seconds_tracing;
      job->seconds_reprojecting = job->frame->seconds_reprojecting();
    }
    job->slots.assign(job->tiles.size(), {});
    open_round(*job);
    wake_parked(/*all=*/false);
  }
  answer_due();
  logger("master")->info("job {} running: {} triangles, {} tiles", job->id, job->triangles, job->tiles.size());
  notify(job);
}

void JobManager::open_round(Job& job) {
  job.paths_per_pixel = job.frame->next_paths_per_pixel();
  job.pending.clear();
  job.tile_skip.resize(job.tiles.size());
  job.tile_first.resize(job.tiles.size());
  job.remaining = 0;
  for (uint32_t t = 0; t < job.tiles.size(); ++t) {
    const TileRect& r = job.tiles[t];
    auto& slot = job.slots[t];
    slot = {};
    if (job.frame->tile_idle(r.x0, r.y0, r.x1, r.y1)) {
      slot.state = Job::Slot::State::kIdle;
      job.tile_skip[t].clear();
      job.tile_first[t].clear();
      continue;
    }
    job.frame->tile_inputs(r.x0, r.y0, r.x1, r.y1, &job.tile_skip[t], &job.tile_first[t]);
    job.pending.push_back(t);
    ++job.remaining;
  }
  // Longest first (every pixel of a round traces the same number of paths, so a tile's cost is about
  // its active pixels): the round ends on small tiles, and its tail -- cores idle while the last tile
  // is traced -- is short. The results do not depend on the order: commits of a round touch disjoint
  // pixels and each pixel's samples are keyed by (pixel, sample index).
  std::vector<size_t> active(job.tile_skip.size(), 0);  // counted once, not in every comparison
  for (uint32_t t : job.pending) active[t] = size_t(std::count(job.tile_skip[t].begin(), job.tile_skip[t].end(), uint8_t(0)));
  std::stable_sort(job.pending.begin(), job.pending.end(), [&](uint32_t a, uint32_t b) { return active[a] > active[b]; });
  job.round_open = true;
  job.round_opened_ms = now_ms();
  job.reprojecting_at_round_open = job.frame->seconds_reprojecting();  // not the deep framebuffer build
  ++job.version;
}

void JobManager::apply_commit(Task& task) {
  Job& job = *task.job;
  {
    std::lock_guard lock(mu_);
    if (job.state != JobState::kRunning || job.round != task.round) return;
  }
  AssembledTile& t = task.tile;
  job.frame->add_paths(int(t.x0), int(t.y0), int(t.x1), int(t.y1), t.path_sum, t.path_count);
  job.frame->reproject(t.vertices);
  job.frame->reproject_packed(t.packed_vertices);
  if (!t.exact_samples.empty()) {
    std::vector<ExactSample> exact(t.exact_samples.size());
    for (size_t i = 0; i < exact.size(); ++i) exact[i] = {t.exact_samples[i].first, t.exact_samples[i].second};
    job.frame->add_exact(exact);
  }
  // The counts at most every 100 ms (and at the round's close): GL's counters are read back, which
  // waits for the dispatches in flight.
  const int64_t now = now_ms();
  const bool refresh = now - job.counts_ms >= 100;
  ReprojectionCounts counts;
  if (refresh) {
    counts = job.frame->counts();
    job.counts_ms = now;
  }
  bool round_done;
  {
    std::lock_guard lock(mu_);
    if (refresh) job.counts = counts;
    job.seconds_reprojecting = job.frame->seconds_reprojecting();
    round_done = --job.remaining == 0;
  }
  if (round_done) close_round(task.job);
}

void JobManager::close_round(const std::shared_ptr<Job>& job) {
  const auto closing = std::chrono::steady_clock::now();
  const bool more = job->frame->finish_round();
  bool budget_over = false;
  bool want_preview;
  {
    std::lock_guard lock(mu_);
    job->seconds_round_backlog += std::chrono::duration<double>(closing - job->last_commit_at).count();
    job->progress = job->frame->progress();
    job->counts = job->frame->counts();
    job->seconds_reprojecting = job->frame->seconds_reprojecting();
    job->round_open = false;
    histograms_.round.observe(double(now_ms() - job->round_opened_ms) / 1000.0);
    histograms_.reprojection.observe(job->seconds_reprojecting - job->reprojecting_at_round_open);
    if (job->request.time_budget_seconds)
      budget_over = double(now_ms() - job->started_ms) / 1000.0 >= *job->request.time_budget_seconds;
    want_preview = now_ms() - job->last_preview_ms >= 1000;
  }
  JobProgressRecord checkpoint;
  {
    std::lock_guard lock(mu_);
    checkpoint = progress_record(*job);  // the counters as of the round's end
  }
  if (!more || budget_over) {
    finish_job(job, budget_over && more);
    return;
  }
  {
    std::lock_guard lock(mu_);
    if (job->state != JobState::kRunning) return;
    ++job->round;
    open_round(*job);
    job->seconds_round_closing += std::chrono::duration<double>(std::chrono::steady_clock::now() - closing).count();
    wake_parked(/*all=*/false);
  }
  answer_due();
  // The preview copy after the next round opened (workers trace meanwhile): the frame still holds the
  // closed round's state, since only this thread applies the next round's results.
  if (want_preview) {
    auto images = std::make_shared<const FrameImages>(job->frame->images(/*preview=*/true));
    std::lock_guard lock(mu_);
    job->preview_images = std::move(images);
    job->preview_reprojects = job->frame->reprojects();
    job->previews.clear();
    job->last_preview_ms = now_ms();
  }
  notify(job);
  save_round_checkpoint(job, std::move(checkpoint));  // the next round's tiles are being traced meanwhile
}

std::optional<std::vector<unsigned char>> JobManager::encode_preview(const FrameImages& img, bool reprojects,
                                                                      const std::string& layer) {
  if (layer == "combined") return encode_png_srgb(img.combined);
  if (layer == "pathtrace") return encode_png_srgb(img.pathtrace);
  if (!reprojects) return std::nullopt;
  if (layer == "reprojection") return encode_png_srgb(img.reprojection);
  if (layer == "samples") {
    float max_m = 0;
    for (float v : img.reprojected.data) max_m = std::max(max_m, v);
    return encode_png_srgb(heat_map(img.reprojected, max_m));
  }
  return std::nullopt;
}

std::optional<std::vector<unsigned char>> JobManager::result_preview(const std::string& dir, const std::string& layer) {
  auto bytes = [](const fs::path& p) -> std::optional<std::vector<unsigned char>> {
    std::ifstream in(p, std::ios::binary);
    if (!in) return std::nullopt;
    return std::vector<unsigned char>(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  };
  try {
    if (layer == "combined") return bytes(fs::path(dir) / "combined.png");
    if (layer == "samples") return bytes(fs::path(dir) / "samples.png");
    if (layer == "pathtrace" || layer == "reprojection") {
      const fs::path exr = fs::path(dir) / (layer + ".exr");
      if (!fs::exists(exr)) return std::nullopt;
      return encode_png_srgb(read_image(exr.string()));
    }
  } catch (const std::exception& e) {
    logger("master")->warn("preview {} from {}: {}", layer, dir, e.what());
  }
  return std::nullopt;
}

void JobManager::finish_job(const std::shared_ptr<Job>& job, bool budget_exhausted) {
  const auto start = std::chrono::steady_clock::now();
  const std::string dir = job_dir(*job);
  fs::create_directories(dir);
  const FrameImages img = job->frame->images();
  auto write = [&](const std::string& name, auto fn) {
    const std::string tmp = dir + "/.tmp-" + name;  // keeps the extension OpenImageIO picks the format by
    fn(tmp);
    fs::rename(tmp, dir + "/" + name);
  };
  // The files are encoded side by side: the workers are idle until the job is done (one after the
  // other, this took ~0.5 s of a 512 x 512 job's ~8 s on two cores).
  tbb::task_group files;
  files.run([&] { write("combined.exr", [&](const std::string& p) { write_exr(p, img.combined); }); });
  files.run([&] { write("combined.png", [&](const std::string& p) { write_png_srgb(p, img.combined); }); });
  files.run([&] { write("pathtrace.exr", [&](const std::string& p) { write_exr(p, img.pathtrace); }); });
  files.run([&] { write("counts.exr", [&](const std::string& p) { write_exr(p, counts_image(img)); }); });
  if (job->frame->reprojects()) {
    files.run([&] { write("reprojection.exr", [&](const std::string& p) { write_exr(p, img.reprojection); }); });
    files.run([&] {
      float max_m = 0;
      for (float v : img.reprojected.data) max_m = std::max(max_m, v);
      write("samples.png", [&](const std::string& p) { write_png_srgb(p, heat_map(img.reprojected, max_m)); });
    });
  }
  files.wait();  // rethrows what a write threw
  nlohmann::json stats = job->frame->statistics(job->request.options);
  {
    std::lock_guard lock(mu_);
    job->preview_images.reset();  // from now on the previews come from the result files
    job->previews.clear();
    job->progress = job->frame->progress();
    job->counts = job->frame->counts();
    job->seconds_reprojecting = job->frame->seconds_reprojecting();
    job->budget_exhausted = budget_exhausted;
    job->seconds_writing_results = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    job->finished_ms = now_ms();
    job->state = JobState::kDone;
    job->round_open = false;
    ++job->version;
    const JobSnapshot s = snapshot(*job);
    stats.update({{"job", job->id},
                  {"scene_hash", job->scene_hash},
                  {"triangles", job->triangles},
                  {"width", job->request.options.width},
                  {"height", job->request.options.height},
                  {"spp", job->request.options.spp},
                  {"seed", job->request.options.seed},
                  {"rays", s.rays_traced},
                  {"vertices_received", s.vertices_received},
                  {"culled_worker", s.worker_culled},
                  {"nonfinite_dropped", s.non_finite_dropped},
                  {"tiles_leased", s.tiles_leased},
                  {"tiles_committed", s.tiles_committed},
                  {"tiles_re_leased", s.tiles_re_leased},
                  {"tiles_dropped", s.tiles_dropped},
                  {"seconds", s.seconds_elapsed},
                  {"seconds_tracing", s.seconds_tracing},
                  {"budget_exhausted", budget_exhausted}});
    active_.reset();
  }
  write("stats.json", [&](const std::string& p) { std::ofstream(p) << stats.dump(2) << "\n"; });
  save_final_checkpoint(job);  // after the results: a finished job's checkpoint promises them
  job->frame.reset();
  job->scene.reset();
  logger("master")->info("job {} done", job->id);
  work_cv_.notify_all();
  notify(job);
}

// ---- checkpoints -----------------------------------------------------------------------------------

void JobManager::load_state() {
  auto log = logger("master");
  std::vector<std::string> problems;
  std::vector<CheckpointStore::LoadedJob> loaded = store_->load_jobs(&problems);
  for (const auto& p : problems) log->warn("state directory: {}", p);
  size_t resumed = 0, restarted = 0;
  std::lock_guard lock(mu_);
  for (auto& l : loaded) {
    const JobSpecRecord& spec = l.spec;
    for (const auto& p : l.problems) log->warn("job {}: checkpoint rejected: {}", spec.id, p);
    auto job = std::make_shared<Job>();
    job->id = spec.id;
    job->seq = spec.seq;
    job->submitted_ms = spec.submitted_ms;
    job->scene_hash = spec.scene_hash;
    job->request.options = spec.options;
    job->request.camera = spec.camera;
    job->request.name = spec.name;
    job->request.priority = spec.priority;
    job->request.time_budget_seconds = spec.time_budget_seconds;
    job->request.request_id = spec.request_id;
    job->tiles = make_tiles(spec.options);
    auto& cached = scenes_[spec.scene_hash];
    if (!cached) {
      try {
        cached = std::make_shared<const SceneBundleData>(store_->load_scene(spec.scene_hash));
      } catch (const CheckpointError& e) {
        log->error("job {}: its scene is lost: {}", spec.id, e.what());
      }
    }
    if (cached) {
      job->bundle = cached;
    } else {
      scenes_.erase(spec.scene_hash);
      job->bundle = std::make_shared<const SceneBundleData>();
      job->state = JobState::kFailed;
      job->error = "the scene was lost from the master's state directory";
    }
    if (l.progress && job->state == JobState::kQueued) {
      JobProgressRecord& r = *l.progress;
      job->triangles = r.triangles;
      job->progress = r.progress;
      job->counts = r.counts;
      job->rays = r.rays;
      job->vertices_received = r.vertices_received;
      job->non_finite = r.non_finite;
      job->worker_culled = r.worker_culled;
      job->tiles_leased = r.tiles_leased;
      job->tiles_committed = r.tiles_committed;
      job->tiles_re_leased = r.tiles_re_leased;
      job->tiles_dropped = r.tiles_dropped;
      job->started_ms = r.started_ms;
      job->seconds_tracing = r.seconds_tracing;
      job->seconds_reprojecting = r.seconds_reprojecting;
      job->round = uint32_t(std::max(0, r.progress.round));
      if (r.state == JobState::kRunning || r.state == JobState::kQueued) {
        if (r.frame) {
          job->resume = std::make_shared<const JobProgressRecord>(std::move(r));  // stays queued until started
          ++resumed;
        } else {
          ++restarted;
        }
      } else {
        job->state = r.state;
        job->error = r.error;
        job->finished_ms = r.finished_ms;
        job->budget_exhausted = r.budget_exhausted;
        job->previews = std::move(r.previews);
      }
    } else if (job->state == JobState::kQueued) {
      ++restarted;
    }
    next_job_seq_ = std::max(next_job_seq_, spec.seq + 1);
    if (!spec.request_id.empty()) request_ids_[spec.request_id] = job->id;
    jobs_[job->id] = job;
  }
  log->info("state directory {}: run {}, {} jobs loaded, {} resume from their checkpoint, {} start from round 0",
            state_dir_, epoch_, loaded.size(), resumed, restarted);
}

JobProgressRecord JobManager::progress_record(const Job& job) const {
  JobProgressRecord r;
  r.state = job.state;
  r.error = job.error;
  r.triangles = job.triangles;
  r.progress = job.progress;
  r.counts = job.counts;
  r.rays = job.rays;
  r.vertices_received = job.vertices_received;
  r.non_finite = job.non_finite;
  r.worker_culled = job.worker_culled;
  r.tiles_leased = job.tiles_leased;
  r.tiles_committed = job.tiles_committed;
  r.tiles_re_leased = job.tiles_re_leased;
  r.tiles_dropped = job.tiles_dropped;
  r.started_ms = job.started_ms;
  r.finished_ms = job.finished_ms;
  r.seconds_tracing = job.seconds_tracing;
  r.seconds_reprojecting = job.seconds_reprojecting;
  r.budget_exhausted = job.budget_exhausted;
  if (job.state == JobState::kDone) r.previews = job.previews;
  return r;
}

void JobManager::save_round_checkpoint(const std::shared_ptr<Job>& job, JobProgressRecord record) {
  if (!checkpointing_) return;
  {
    // Not every round: a 512 x 512 frame is ~80 MB to copy and write (see checkpoint_interval_s).
    std::lock_guard lock(mu_);
    const double gap = options_.checkpoint_interval_s >= 0 ? options_.checkpoint_interval_s
                                                           : MasterOptions::kAutoCheckpointFactor * job->checkpoint_cost_s;
    if (job->last_checkpoint_ms && double(now_ms() - job->last_checkpoint_ms) < 1000 * gap) return;
    job->last_checkpoint_ms = now_ms();
  }
  const auto start = std::chrono::steady_clock::now();
  record.frame = job->frame->save();  // the state after the closed round: nothing of the next is applied yet
  const double copy_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  logger("master")->debug("job {}: frame after round {} copied for its checkpoint in {:.1f} ms", job->id,
                          record.progress.round, 1e3 * copy_s);
  std::lock_guard checkpoint_lock(checkpoint_mu_);
  {
    std::lock_guard lock(mu_);
    if (job->state != JobState::kRunning) return;  // cancelled meanwhile: its final record is queued instead
    job->checkpoint_cost_s = copy_s;  // the write's time is added when it is written
    ++job->round_checkpoints;
  }
  enqueue_checkpoint(job->id, std::move(record));
}

void JobManager::save_final_checkpoint(const std::shared_ptr<Job>& job) {
  if (!checkpointing_) return;
  std::lock_guard checkpoint_lock(checkpoint_mu_);
  JobProgressRecord record;
  {
    std::lock_guard lock(mu_);
    record = progress_record(*job);
  }
  enqueue_checkpoint(job->id, std::move(record));
}

void JobManager::enqueue_checkpoint(const std::string& job_id, JobProgressRecord record) {
  auto r = std::make_shared<const JobProgressRecord>(std::move(record));
  auto it = std::find_if(checkpoint_queue_.begin(), checkpoint_queue_.end(),
                         [&](const auto& q) { return q.first == job_id; });
  if (it != checkpoint_queue_.end())
    it->second = std::move(r);  // not written yet: the newer state replaces it
  else
    checkpoint_queue_.emplace_back(job_id, std::move(r));
  checkpoint_cv_.notify_all();
}

void JobManager::checkpoint_loop() {
  set_thread_name("epr-checkpoint");
  std::unique_lock lock(checkpoint_mu_);
  for (;;) {
    checkpoint_cv_.wait(lock, [&] { return checkpoint_stopping_ || !checkpoint_queue_.empty(); });
    if (checkpoint_queue_.empty()) return;  // stopping, everything written
    auto [job_id, record] = std::move(checkpoint_queue_.front());
    checkpoint_queue_.pop_front();
    lock.unlock();
    const auto start = std::chrono::steady_clock::now();
    try {
      store_->save_progress(job_id, *record);
      const double write_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      logger("master")->debug("job {}: checkpoint ({} after round {}) written in {:.1f} ms", job_id,
                              to_string(record->state), record->progress.round, 1e3 * write_s);
      if (record->frame) {
        std::lock_guard jobs_lock(mu_);
        if (auto it = jobs_.find(job_id); it != jobs_.end()) it->second->checkpoint_cost_s += write_s;
      }
    } catch (const std::exception& e) {
      logger("master")->error("job {}: cannot write its checkpoint: {}", job_id, e.what());
    }
    record.reset();  // frees the frame copy before waiting
    lock.lock();
  }
}

// ---- the reaper -----------------------------------------------------------------------------------

void JobManager::reaper_loop() {
  set_thread_name("epr-reaper");
  std::unique_lock lock(mu_);
  while (!stopping_) {
    work_cv_.wait_for(lock, std::chrono::milliseconds(200));
    if (stopping_) break;
    const int64_t now = now_ms();
    std::vector<std::shared_ptr<Job>> failed;
    if (active_ && active_->state == JobState::kRunning) {
      const std::shared_ptr<Job> job = active_;
      for (uint32_t t = 0; t < job->slots.size() && job->state == JobState::kRunning; ++t) {
        auto& slot = job->slots[t];
        if (slot.state != Job::Slot::State::kLeased) continue;
        if (slot.holds.empty()) {
          if (slot.deadline_ms >= now) continue;
          logger("master")->warn("job {} tile {}: lease expired, re-queued", job->id, t);
          slot.state = Job::Slot::State::kPending;
          slot.leases.clear();
          slot.re_leased = true;
          job->pending.push_front(t);
          ++job->version;
          continue;
        }
        // Each lease on its own deadline: a dead holder expires even while a speculative copy lives.
        std::vector<std::pair<uint64_t, std::string>> expired;
        for (const auto& [id, h] : slot.holds)
          if (h.deadline_ms < now) expired.emplace_back(id, h.worker);
        for (const auto& [id, worker] : expired) {
          if (slot.leases.size() == 1)
            logger("master")->warn("job {} tile {}: lease expired, re-queued (lease {}, worker {})", job->id, t, id, worker);
          else
            logger("master")->warn("job {} tile {}: lease {} of worker {} expired; another lease of the tile is still out",
                                   job->id, t, id, worker);
          if (auto wit = workers_.find(worker); wit != workers_.end()) wit->second->leases.erase(id);
          release_lease(*job, t, id);
          count_failure(job, worker, LeaseFailure::kExpired,
                        fmt::format("lease of tile {} expired without a result", t), &failed);
        }
      }
    }
    for (auto it = workers_.begin(); it != workers_.end();) {
      if (now - it->second->last_seen_ms > options_.worker_timeout_ms) {
        logger("master")->warn("worker {} silent for {} ms: forgotten", it->first, now - it->second->last_seen_ms);
        it = workers_.erase(it);
      } else {
        ++it;
      }
    }
    // The workers that were not blocked may have left.
    if (active_) fail_if_all_blocked(active_, &failed);
    // Parked lease requests: tiles that came back, speculative copies, and the ones out of time.
    wake_parked(/*all=*/false);
    if (!failed.empty() || !due_.empty()) {
      lock.unlock();
      answer_due();
      work_cv_.notify_all();
      for (const auto& job : failed) notify(job);
      lock.lock();
    }
  }
}

}  // namespace epr
