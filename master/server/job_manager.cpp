#include "master/server/job_manager.h"

#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <filesystem>
#include <limits>
#include <set>

#include "common/camera_animation.h"
#include "common/log.h"
#include "common/scene_loader.h"
#include "common/thread_name.h"
#include "master/server/checkpoint.h"
#include "master/server/checkpointer.h"
#include "master/server/window_run.h"

namespace epr {
namespace fs = std::filesystem;
// ---- lifecycle ------------------------------------------------------------------------------------

JobManager::JobManager(MasterOptions options, MillisClock clock)
    : options_(std::move(options)), clock_(std::move(clock)) {
  // A temporary folder is this manager's alone (several masters may live in one process) and goes
  // with it.
  static std::atomic<uint32_t> temporary_folders{0};
  state_dir_ =
      options_.state_dir.empty()
          ? (fs::temp_directory_path() / fmt::format("epr-master-{}-{}", ::getpid(), ++temporary_folders)).string()
          : options_.state_dir;
  fs::create_directories(fs::path(state_dir_) / "jobs");
  store_ = std::make_unique<CheckpointStore>(state_dir_);
  // Lease ids are never reused, not even across restarts: the run number is their top bits.
  epoch_ = store_->next_epoch();
  {
    JobLock lock(mu_);
    next_lease_ = (epoch_ << kLeaseEpochShift) + 1;
  }
  load_state();
  if (options_.checkpoints && !options_.state_dir.empty())
    checkpointer_ = std::make_unique<Checkpointer>(*store_, [this](const std::string& id, double write_s) {
      JobLock lock(mu_);
      if (auto job = jobs_.find(id)) job->checkpoint_cost_s += write_s;
    });
  start_threads();
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
    JobLock lock(mu_);
    if (stopping_) return;
    stopping_ = true;
    parking_.stop();
  }
  answer_due();
  work_cv_.notify_all();
  if (reprojection_thread_.joinable()) reprojection_thread_.join();
  if (reaper_thread_.joinable()) reaper_thread_.join();
  if (checkpointer_) checkpointer_->stop();  // the checkpoints still queued are written first
}

bool JobManager::gl_ready() const {
  JobLock lock(mu_);
  return gl_ready_;
}

DurationHistograms JobManager::histograms() const {
  JobLock lock(mu_);
  return histograms_;
}

std::string JobManager::job_dir(const Job& job) const { return store_->job_dir(job.id).string(); }
std::string JobManager::cache_dir() const { return (fs::path(state_dir_) / "cache").string(); }

// ---- clients --------------------------------------------------------------------------------------

std::optional<std::string> JobManager::validate(const JobRequest& req) const {
  auto invalid = [](std::string why) { return std::optional<std::string>(std::move(why)); };
  if (auto err = req.options.validate()) return invalid(*err);
  if (auto err = req.camera.validate()) return invalid(*err);
  const SceneBundleData& b = req.bundle;
  if (b.builtin.empty()) {
    if (b.files.empty()) return invalid("the scene bundle is empty");
    if (b.total_bytes() > options_.max_scene_bytes)
      return invalid(fmt::format("the scene bundle has {} bytes, over the limit of {}", b.total_bytes(),
                                 options_.max_scene_bytes));
    bool has_entry = false;
    std::set<std::string> paths;
    for (const auto& [path, data] : b.files) {
      if (!is_safe_relative_path(path))
        return invalid(fmt::format("scene file path '{}' is not a safe relative path", path));
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
  return window_error(req);
}

JobManager::SubmitResult JobManager::submit(JobRequest req) {
  const std::string hash = content_hash(req.bundle);
  if (auto err = validate(req)) return {"", *err, hash};
  // The scene and the spec are stored before the client learns the id (what a restart needs); a
  // job the state folder cannot take is refused.
  auto unstored = [&](const std::string& what, const std::string& id, const std::exception& e) {
    logger("master")->error("job {}refused: cannot store {}: {}", id.empty() ? "" : id + " ", what, e.what());
    return SubmitResult{"", fmt::format("this master cannot store {}: {}", what, e.what()), hash, true};
  };
  try {
    if (checkpointer_) store_->save_scene(hash, req.bundle);
  } catch (const std::exception& e) {
    return unstored("the job's scene", "", e);
  }
  uint64_t seq = 0;
  int64_t submitted_ms = 0;
  std::shared_ptr<const SceneBundleData> bundle;
  {
    JobLock lock(mu_);
    if (auto earlier = jobs_.find_request(req.request_id)) return {earlier->id, "", hash};
    // A window job joins the run of the frames of it already here: they must agree.
    if (windowed(req.batch))
      for (const auto& [id, other] : jobs_.all())
        if (!is_terminal(other->state) && same_run(other->request.batch, req.batch))
          if (auto err = run_mismatch(req, hash, *other)) return {"", *err, hash};
    seq = jobs_.next_seq();
    submitted_ms = clock_();
    if (auto cached = scenes_.find(hash); cached != scenes_.end()) bundle = cached->second;
  }
  // Out of the request in any case: the job keeps one copy of the bytes, the shared one.
  SceneBundleData sent = std::move(req.bundle);
  if (!bundle) bundle = std::make_shared<const SceneBundleData>(std::move(sent));
  std::string id = fmt::format("{}{}j{:06d}-{:04x}", options_.name, options_.name.empty() ? "" : ".", seq,
                               uint32_t(submitted_ms) & 0xffff);
  auto job = std::make_shared<Job>(std::move(id), seq, std::move(req), hash, std::move(bundle), submitted_ms);
  try {
    if (checkpointer_) store_->save_spec(spec_record(*job));
  } catch (const std::exception& e) {
    store_->remove_job(job->id);
    return unstored("the job's spec", job->id, e);
  }
  std::vector<std::string> forgotten;
  std::string earlier_id;
  {
    JobLock lock(mu_);
    if (auto earlier = jobs_.find_request(job->request.request_id)) earlier_id = earlier->id;  // submitted meanwhile
    auto& cached = scenes_[hash];
    if (!cached) cached = job->bundle;
    if (earlier_id.empty()) forgotten = jobs_.add(job, size_t(options_.max_jobs));
  }
  if (!earlier_id.empty()) {
    store_->remove_job(job->id);
    return {earlier_id, "", hash};
  }
  for (const auto& id : forgotten) store_->remove_job(id);
  const RenderOptions& o = job->request.options;
  logger("master")->info("job {} submitted: {} {}x{} spp {} mode {}", job->id, job->scene_hash.substr(0, 12), o.width,
                         o.height, o.spp, to_string(o.mode));
  work_cv_.notify_all();
  notify(job);
  return {job->id, "", hash};
}

JobSnapshot JobManager::snapshot(const Job& job) const {
  JobSnapshot s = job.snapshot(clock_());
  s.workers_active = job.state == JobState::kRunning && job.leases ? uint32_t(job.leases->holders()) : 0;
  return s;
}

std::optional<JobSnapshot> JobManager::get(const std::string& id) const {
  JobLock lock(mu_);
  auto job = jobs_.find(id);
  if (!job) return std::nullopt;
  return snapshot(*job);
}

std::vector<JobSnapshot> JobManager::list() const {
  JobLock lock(mu_);
  std::vector<JobSnapshot> out;
  for (const auto& [id, job] : jobs_.all()) out.push_back(snapshot(*job));
  return out;
}

bool JobManager::cancel(const std::string& id) {
  std::shared_ptr<Job> job;
  bool cancelled = false;
  {
    JobLock lock(mu_);
    job = jobs_.find(id);
    if (!job) return false;
    cancelled = job->end(JobState::kCancelled, "", clock_());
  }
  work_cv_.notify_all();
  if (cancelled) save_final_checkpoint(job);
  notify(job);
  return true;
}

uint64_t JobManager::watch(const std::string& id, std::function<void(const JobSnapshot&)> listener) {
  JobLock lock(mu_);
  return jobs_.watch(id, std::move(listener));
}

void JobManager::unwatch(uint64_t handle) {
  JobLock lock(mu_);
  jobs_.unwatch(handle);
}

void JobManager::notify(const std::shared_ptr<Job>& job) {
  std::vector<JobRegistry::Listener> listeners;
  JobSnapshot snap;
  {
    JobLock lock(mu_);
    snap = snapshot(*job);
    listeners = jobs_.listeners(job->id);
  }
  for (auto& l : listeners) l(snap);
}

std::string JobManager::add_scene(SceneBundleData bundle) {
  const std::string hash = content_hash(bundle);
  JobLock lock(mu_);
  auto& slot = scenes_[hash];
  if (!slot) slot = std::make_shared<const SceneBundleData>(std::move(bundle));
  return hash;
}

std::optional<std::string> JobManager::check_scene(const SceneBundleData& bundle, CameraSpec* scene_camera,
                                                   CameraAnimation* animation, const Lighting& lighting) const {
  const std::string cache = cache_dir();
  const std::string hash = content_hash(bundle);
  {
    JobLock lock(mu_);
    ++scene_checks_[hash];  // discard_checked_scene() leaves the cached files alone meanwhile
  }
  std::optional<std::string> error;
  try {
    // The shared copy: in the embedded render, the one the client loaded.
    std::shared_ptr<const Scene> s = share_bundle_scene(bundle, hash, cache, lighting);
    if (s->triangle_count() == 0) error = "the scene has no triangles";
    if (!error) {
      // Kept for the job's start (release_checked_scene); the one kept before goes, outside the lock.
      std::pair<std::string, std::shared_ptr<const Scene>> earlier(hash, s);
      JobLock lock(mu_);
      std::swap(checked_scene_, earlier);
    }
    if (scene_camera) *scene_camera = s->camera;
    if (animation && bundle.builtin.empty()) {
      *animation = load_camera_animation(write_bundle_files(bundle, hash, cache));
      animation->file = bundle.entry_path;
    }
  } catch (const std::exception& e) {
    // Name files as the client knows them, not by their place in the master's cache.
    std::string msg = e.what();
    const std::string prefix = (fs::path(cache) / "scenes" / hash).string() + "/";
    for (size_t p; (p = msg.find(prefix)) != std::string::npos;) msg.erase(p, prefix.size());
    error = std::move(msg);
  }
  JobLock lock(mu_);
  if (--scene_checks_[hash] == 0) scene_checks_.erase(hash);
  return error;
}

void JobManager::release_checked_scene(const std::string& hash) {
  std::shared_ptr<const Scene> released;  // freed outside the lock
  JobLock lock(mu_);
  if (checked_scene_.first != hash) return;
  for (const auto& [id, job] : jobs_.all())  // a job being started is in running_, still kQueued
    if (job->scene_hash == hash && job->state == JobState::kQueued &&
        std::find(running_.begin(), running_.end(), job) == running_.end())
      return;
  released = std::move(checked_scene_.second);
  checked_scene_.first.clear();
}

void JobManager::discard_checked_scene(const std::string& hash) {
  if (hash.empty()) return;
  std::shared_ptr<const Scene> released;  // freed outside the lock
  // Under the mutex: a job that is added later loads the scene (and caches it again) only after this.
  JobLock lock(mu_);
  if (scene_checks_.count(hash)) return;
  for (const auto& [id, job] : jobs_.all())
    if (job->scene_hash == hash) return;
  if (checked_scene_.first == hash) {
    released = std::move(checked_scene_.second);
    checked_scene_.first.clear();
  }
  const fs::path scenes = fs::path(cache_dir()) / "scenes";
  std::error_code ec;
  fs::remove_all(scenes / hash, ec);
  // A copy whose writing failed half-way (load_bundle writes into .tmp-HASH-PID first).
  for (fs::directory_iterator it(scenes, ec), end; !ec && it != end; it.increment(ec))
    if (it->path().filename().string().rfind(".tmp-" + hash + "-", 0) == 0) fs::remove_all(it->path(), ec);
}

std::shared_ptr<const SceneBundleData> JobManager::scene(const std::string& hash) const {
  JobLock lock(mu_);
  auto it = scenes_.find(hash);
  return it == scenes_.end() ? nullptr : it->second;
}

// ---- workers --------------------------------------------------------------------------------------

std::string JobManager::register_worker(const std::string& name, uint32_t threads,
                                        std::vector<std::string> cached_scenes) {
  JobLock lock(mu_);
  return workers_.add(name, threads, {cached_scenes.begin(), cached_scenes.end()}, clock_());
}

void JobManager::unregister_worker(const std::string& worker) {
  // Leases it still holds go back at once: one granted to a LeaseTile call that the worker cancelled
  // as it stopped, after this master had answered, is held here but unknown to the worker.
  std::vector<uint64_t> held;
  {
    JobLock lock(mu_);
    if (const WorkerRegistry::Worker* w = workers_.find(worker)) held.assign(w->leases.begin(), w->leases.end());
  }
  if (!held.empty()) return_leases(worker, held);
  JobLock lock(mu_);
  workers_.remove(worker);
}

std::vector<WorkerSnapshot> JobManager::workers() const {
  JobLock lock(mu_);
  return workers_.snapshot(clock_());
}

std::optional<std::vector<std::pair<bool, int64_t>>> JobManager::heartbeat(const std::string& worker,
                                                                           const std::vector<uint64_t>& leases) {
  JobLock lock(mu_);
  WorkerRegistry::Worker* w = workers_.touch(worker, clock_());
  if (!w) return std::nullopt;
  std::vector<std::pair<bool, int64_t>> out;
  for (uint64_t lease : leases) {
    std::optional<int64_t> deadline;
    for (const auto& job : running_)
      if (job->state == JobState::kRunning && job->leases && (deadline = job->leases->extend(lease))) break;
    out.emplace_back(deadline.has_value(), deadline.value_or(0));
    if (!deadline) w->leases.erase(lease);
  }
  return out;
}

LeaseDecision JobManager::lease_tile(const std::string& worker) {
  JobLock lock(mu_);
  bool parkable = false;
  return decide_lease(worker, &parkable);
}

std::optional<LeaseDecision> JobManager::lease_tile_or_park(const std::string& worker, int max_wait_ms,
                                                            std::function<void(LeaseDecision)> answer,
                                                            uint64_t* handle) {
  JobLock lock(mu_);
  bool parkable = false;
  LeaseDecision d = decide_lease(worker, &parkable);
  if (!parkable || max_wait_ms <= 0 || parking_.stopped()) return d;
  *handle = parking_.park(worker, clock_() + std::min(max_wait_ms, kMaxParkMs), std::move(answer));
  return std::nullopt;
}

bool JobManager::cancel_parked(uint64_t handle) {
  JobLock lock(mu_);
  return parking_.cancel(handle);
}

size_t JobManager::parked_requests() const {
  JobLock lock(mu_);
  return parking_.size();
}

void JobManager::stop_parking() {
  {
    JobLock lock(mu_);
    parking_.stop();
  }
  answer_due();
}

void JobManager::answer_due() {
  std::vector<std::pair<LeaseParking::Answer, LeaseDecision>> due;
  {
    JobLock lock(mu_);
    due = parking_.take_due();
  }
  for (auto& [answer, decision] : due) answer(std::move(decision));
}

TileLeaseInfo JobManager::grant(Job& job, const std::string& worker, const LeaseTable::Grant& g, uint64_t lease) {
  ++job.version;
  TileLeaseInfo info;
  info.lease_id = lease;
  info.job_id = job.id;
  info.round = job.round;
  info.tile_index = g.tile;
  info.rect = job.tiles[g.tile];
  info.skip = job.plan.skip[g.tile];
  info.first_sample = job.plan.first_sample[g.tile];
  info.paths_per_pixel = uint32_t(job.plan.paths_per_pixel);
  info.paths = job.plan.paths[g.tile];
  info.seed = job.request.options.seed;
  info.options = job.request.options;
  info.camera = job.request.camera;
  // Every frame of the run within K, whatever its state: which of them have started or ended when a
  // lease goes out is a matter of timing (a run's frames start one after another, a round's frames
  // close one after another), and what the worker culls must not be, or M' would be too.
  if (job.run)
    for (const auto& g : job.run->neighbours(job.request.batch.frame.value_or(0)))
      info.window_cameras.push_back(g->request.camera);
  info.codec_bounds = job.codec_bounds;
  info.scene_hash = job.scene_hash;
  info.scene_builtin = job.bundle->builtin;
  info.scene_bytes = job.bundle->total_bytes();
  info.triangles = job.triangles;
  info.deadline_ms = g.deadline_ms;
  return info;
}

void JobManager::return_leases(const std::string& worker, const std::vector<uint64_t>& leases) {
  fail_leases(worker, leases, LeaseFailure::kNone, "");
}

void JobManager::fail_leases(const std::string& worker, const std::vector<uint64_t>& leases, LeaseFailure failure,
                             const std::string& reason) {
  std::vector<std::shared_ptr<Job>> failed;
  {
    JobLock lock(mu_);
    WorkerRegistry::Worker* w = workers_.find(worker);
    for (uint64_t lease : leases) {
      if (w) w->leases.erase(lease);
      for (const auto& job : running_) {
        if (!job->leases || !job->leases->release(lease, worker, failure, reason)) continue;
        ++job->version;
        if (failure != LeaseFailure::kNone) fail_if_stuck(job, &failed);
        break;
      }
    }
    wake_parked(/*all=*/false);  // the tiles given back
  }
  answer_due();
  if (!failed.empty()) work_cv_.notify_all();
  for (const auto& job : failed) {
    save_final_checkpoint(job);  // a restart must not run it again
    notify(job);
  }
}

void JobManager::fail_if_stuck(const std::shared_ptr<Job>& job, std::vector<std::shared_ptr<Job>>* failed) {
  if (job->state != JobState::kRunning || !job->leases) return;
  std::optional<std::string> why;
  if (const auto lost = job->leases->lost_tile()) {
    const TileRect& r = job->tiles.at(lost->tile);
    why = fmt::format(
        "tile {} (pixels x {}-{}, y {}-{}) lost its worker {} times: every worker that took it vanished (crashed, "
        "killed or cut off) before returning it, so it is not handed out again",
        lost->tile, r.x0, r.x1 - 1, r.y0, r.y1 - 1, lost->losses);
  } else {
    why = job->leases->all_blocked(workers_.ids());
  }
  if (!why) return;
  logger("master")->error("job {} failed: {}", job->id, *why);
  if (job->end(JobState::kFailed, *why, clock_())) failed->push_back(job);
}

// ---- results --------------------------------------------------------------------------------------

TileCheck JobManager::expect(const TileResultIdentity& h) const {
  auto verdict = [](TileVerdict v, std::string why) { return TileCheck{v, {}, std::move(why)}; };
  JobLock lock(mu_);
  if (h.lease_id == 0 || h.lease_id >= next_lease_) return verdict(TileVerdict::kInvalid, "unknown lease id");
  if ((h.lease_id >> kLeaseEpochShift) != epoch_)
    return verdict(TileVerdict::kEarlierEpoch, "the lease is from before the master restarted");
  auto found = jobs_.find(h.job_id);
  if (!found) return verdict(TileVerdict::kUnknownJob, "no such job (finished and forgotten, or never existed)");
  const Job& job = *found;
  if (job.state != JobState::kRunning || h.round != job.round || !job.round_open)
    return verdict(TileVerdict::kStaleRound, fmt::format("job {} is {} in round {}, the result is for round {}", job.id,
                                                         to_string(job.state), job.round, h.round));
  if (h.tile_index >= job.tiles.size())
    return verdict(TileVerdict::kInvalid,
                   fmt::format("tile index {} is outside the job's {} tiles", h.tile_index, job.tiles.size()));
  if (!job.leases->issued(h.tile_index, h.lease_id))
    return verdict(TileVerdict::kInvalid, fmt::format("lease {} was not issued for tile {} of job {} round {}",
                                                      h.lease_id, h.tile_index, job.id, job.round));
  const TileRect& r = job.tiles[h.tile_index];
  const RenderOptions& o = job.request.options;
  TileCheck check{TileVerdict::kExpected, {}, {}};
  TileExpectation& e = check.expectation;
  e.job_id = job.id;
  e.round = job.round;
  e.tile_index = h.tile_index;
  e.x0 = uint32_t(r.x0);
  e.y0 = uint32_t(r.y0);
  e.x1 = uint32_t(r.x1);
  e.y1 = uint32_t(r.y1);
  e.image_width = uint32_t(o.width);
  e.image_height = uint32_t(o.height);
  e.subpixels = uint32_t(o.subpixels);
  e.codec_bounds = job.codec_bounds;
  e.payload = o.mode == RenderMode::kPathTrace         ? TileExpectation::Payload::kPathsOnly
              : o.reproject == ReprojectMethod::kExact ? TileExpectation::Payload::kExactSamples
                                                       : TileExpectation::Payload::kVertices;
  e.paths_per_pixel = uint32_t(job.plan.paths_per_pixel);
  e.skip = job.plan.skip[h.tile_index];
  e.paths = job.plan.paths[h.tile_index];
  e.max_vertices_per_tile = std::max<uint64_t>(options_.max_queued_vertices, 1u << 20);
  e.keep_packed = true;  // decoded by the reprojector, in place
  return check;
}

void JobManager::count_dropped(const std::string& job_id, DropReason reason) {
  JobLock lock(mu_);
  if (auto job = jobs_.find(job_id)) {
    ++job->counters.tiles_dropped;
    ++job->drops[reason];
    ++job->version;
  }
}

CommitOutcome JobManager::commit(const std::string& job_id, uint32_t round, uint32_t tile_index, AssembledTile tile) {
  {
    JobLock lock(mu_);
    auto job = jobs_.find(job_id);
    WorkerRegistry::Worker* w = workers_.find(tile.worker_id);
    if (w) w->leases.erase(tile.lease_id);
    if (!job || job->state != JobState::kRunning || job->round != round || tile_index >= job->tiles.size()) {
      if (job) {
        ++job->counters.tiles_dropped;
        ++job->drops[DropReason::kStaleRound];
      }
      return CommitOutcome::kStale;
    }
    std::vector<uint64_t> losers;
    if (job->leases->commit(tile_index, tile.lease_id, &losers) == LeaseTable::CommitOutcome::kDuplicate) {
      ++job->counters.tiles_dropped;
      ++job->drops[DropReason::kDuplicate];
      return CommitOutcome::kDuplicate;
    }
    // The other leases of the tile lost: their heartbeat now answers "not wanted", and a result they
    // still send is dropped as a duplicate.
    for (uint64_t l : losers) workers_.drop_lease(l);
    const auto& st = tile.worker_stats;
    JobCounters& c = job->counters;
    ++c.tiles_committed;
    c.rays += st.rays_traced();
    c.non_finite += st.non_finite_dropped() + tile.dropped_pixel_sums + tile.dropped_exact_samples;
    c.worker_culled += st.culled_frustum() + st.culled_facing() + st.culled_not_diffuse() + st.exact_occluded();
    c.vertices_received += tile.vertex_count() + tile.exact_samples.size();
    c.seconds_tracing += st.seconds_tracing();
    ++job->version;
    workers_.credit(tile.worker_id, st.paths_traced(), st.seconds_tracing());
    if (w) w->cached_scenes.insert(job->scene_hash);
    queued_vertices_ += tile.vertex_count() + tile.exact_samples.size();
    job->last_commit_at = std::chrono::steady_clock::now();
    tasks_.push_back(std::make_unique<Task>(Task{job, round, tile_index, std::move(tile)}));
  }
  work_cv_.notify_all();
  return CommitOutcome::kCommitted;
}

// ---- the state directory -------------------------------------------------------------------------------

void JobManager::load_state() {
  auto log = logger("master");
  std::vector<std::string> problems;
  std::vector<CheckpointStore::LoadedJob> loaded = store_->load_jobs(&problems);
  for (const auto& p : problems) log->warn("state directory: {}", p);
  size_t resumed = 0, restarted = 0;
  JobLock lock(mu_);
  for (auto& l : loaded) {
    const JobSpecRecord& spec = l.spec;
    for (const auto& p : l.problems) log->warn("job {}: checkpoint rejected: {}", spec.id, p);
    auto& cached = scenes_[spec.scene_hash];
    if (!cached) {
      try {
        cached = std::make_shared<const SceneBundleData>(store_->load_scene(spec.scene_hash));
      } catch (const CheckpointError& e) {
        log->error("job {}: its scene is lost: {}", spec.id, e.what());
      }
    }
    const bool lost = !cached;
    const std::shared_ptr<const SceneBundleData> bundle = lost ? std::make_shared<const SceneBundleData>() : cached;
    if (lost) scenes_.erase(spec.scene_hash);
    auto job = std::make_shared<Job>(spec.id, spec.seq,
                                     JobRequest{spec.options,
                                                spec.camera,
                                                {},
                                                spec.name,
                                                spec.priority,
                                                spec.time_budget_seconds,
                                                spec.request_id,
                                                spec.batch},
                                     spec.scene_hash, bundle, spec.submitted_ms);
    if (lost) {
      job->state = JobState::kFailed;
      job->error = "the scene was lost from the master's state directory";
    }
    if (l.progress && job->state == JobState::kQueued) {
      JobProgressRecord& r = *l.progress;
      job->triangles = r.triangles;
      job->progress = r.progress;
      job->counts = r.counts;
      job->counters = r.counters;
      job->started_ms = r.started_ms;
      job->round = uint32_t(std::max(0, r.progress.round));
      if (!is_terminal(r.state)) {
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
        job->preview.pngs = std::move(r.previews);
      }
    } else if (job->state == JobState::kQueued) {
      ++restarted;
    }
    jobs_.add(job, std::numeric_limits<size_t>::max());
  }
  log->info("state directory {}: run {}, {} jobs loaded, {} resume from their checkpoint, {} start from round 0",
            state_dir_, epoch_, loaded.size(), resumed, restarted);
}

}  // namespace epr
