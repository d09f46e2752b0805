// JobManager's results (job_manager.h): a finished job's files, the partial results of a running,
// cancelled or failed job (its preview copy, taken when asked for), and the preview PNGs of the
// monitoring endpoint.
#include <fmt/format.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "common/log.h"
#include "master/result_files.h"
#include "master/server/job_manager.h"
#include "master/server/previews.h"

namespace epr {
namespace fs = std::filesystem;
namespace {

std::string read_bytes(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// The round a cancelled or failed job's stored copy reflects, from its statistics file (for a job
// loaded from the state directory, which does not remember its copy's round otherwise).
int stored_round(const fs::path& dir) {
  try {
    const auto stats = nlohmann::json::parse(read_bytes(dir / result_kind(ResultKind::kJson).stored_as));
    return stats.value("rounds", 0);
  } catch (const std::exception&) {
    return 0;
  }
}

// The copy asked for is there, or will not come.
bool copy_settled(const Job& job) EPR_REQUIRES(job_fields) {
  return job.preview.images || job.preview.copy == PreviewState::Copy::kIdle || job.state != JobState::kRunning;
}

}  // namespace

bool JobManager::ask_for_copy(Job& job) const {
  if (job.state != JobState::kRunning) return false;
  job.preview.asked_ms = clock_();
  if (job.preview.copy == PreviewState::Copy::kTaking) return true;
  if (job.preview.images || job.progress.round == 0) return false;
  job.preview.copy = PreviewState::Copy::kRequested;
  work_cv_.notify_all();
  return true;
}

size_t JobManager::preview_copy_bytes() const {
  JobLock lock(mu_);
  size_t bytes = 0;
  for (const auto& job : running_)
    if (const auto& c = job->preview.images)
      for (const Image* i : {&c->combined, &c->pathtrace, &c->path_sum, &c->glossy_sum, &c->reprojection,
                             &c->path_count, &c->reprojected})
        bytes += i->data.size() * sizeof(float);
  return bytes;
}

std::optional<std::string> JobManager::result_path(const std::string& id, ResultKind kind) const {
  std::string dir;
  {
    JobLock lock(mu_);
    auto job = jobs_.find(id);
    if (!job || job->state != JobState::kDone) return std::nullopt;
    dir = job_dir(*job);
  }
  const fs::path p = fs::path(dir) / result_kind(kind).stored_as;
  if (!fs::exists(p)) return std::nullopt;
  return p.string();
}

std::optional<std::vector<unsigned char>> JobManager::preview_png(const std::string& id,
                                                                  const std::string& layer) const {
  std::shared_ptr<const FrameImages> images;
  bool reprojects = false, done = false;
  std::string dir;
  {
    JobLock lock(mu_);
    auto job = jobs_.find(id);
    if (!job) return std::nullopt;
    if (ask_for_copy(*job))
      copy_cv_.wait_for(lock, std::chrono::milliseconds(kPreviewWaitMs),
                        [&]() EPR_REQUIRES(job_fields) { return copy_settled(*job); });
    if (auto p = job->preview.pngs.find(layer); p != job->preview.pngs.end()) return p->second;
    images = job->preview.images;
    reprojects = job->preview.reprojects;
    done = job->state == JobState::kDone;
    dir = job_dir(*job);
  }
  // Encoded here, on the caller's thread, without the mutex: the rounds go on meanwhile.
  auto png = images ? encode_preview(*images, reprojects, layer) : done ? result_preview(dir, layer) : std::nullopt;
  if (!png) return std::nullopt;
  JobLock lock(mu_);
  auto job = jobs_.find(id);
  if (job && job->preview.images == images && (images || job->state == JobState::kDone))
    job->preview.pngs[layer] = *png;
  return png;
}

JobManager::ResultFile JobManager::result_file(const std::string& id, ResultKind kind, bool allow_partial) const {
  using Error = ResultFile::Error;
  const ResultKindInfo& k = result_kind(kind);
  ResultFile out;
  auto fail = [&](Error e, std::string why) {
    out.error = e;
    out.why = std::move(why);
    return out;
  };
  JobState state;
  int round, rounds_done;
  std::shared_ptr<const FrameImages> images;
  std::shared_ptr<const nlohmann::json> stats;
  bool reprojects, copying;
  fs::path dir;
  {
    JobLock lock(mu_);
    auto job = jobs_.find(id);
    if (!job) return fail(Error::kNoJob, fmt::format("no job '{}'", id));
    // A running job's copy is taken on this ask; a cancelled or failed one's is being stored.
    if (allow_partial && ask_for_copy(*job))
      copy_cv_.wait_for(lock, std::chrono::milliseconds(kPartialWaitMs),
                        [&]() EPR_REQUIRES(job_fields) { return copy_settled(*job); });
    if (job->preview.partial_pending)
      copy_cv_.wait_for(lock, std::chrono::milliseconds(kPartialWaitMs),
                        [&]() EPR_REQUIRES(job_fields) { return !job->preview.partial_pending; });
    state = job->state;
    copying = job->preview.copy == PreviewState::Copy::kTaking;
    rounds_done = job->progress.round;
    round = state == JobState::kDone ? rounds_done : job->preview.round;
    images = job->preview.images;
    stats = job->preview.stats;
    reprojects = job->preview.reprojects;
    dir = job_dir(*job);
  }
  out.partial = state != JobState::kDone;
  out.round = round;
  if (state == JobState::kQueued) return fail(Error::kNotReady, fmt::format("job {} is queued: no results yet", id));
  if (state == JobState::kRunning && !allow_partial)
    return fail(Error::kNotReady,
                fmt::format("job {} is running (round {}): its results exist once it ends; allow_partial serves "
                            "its latest committed round",
                            id, rounds_done));
  // A done job's files, or the copy a cancelled or failed job stored.
  const fs::path stored = dir / k.stored_as;
  if (state != JobState::kRunning && fs::exists(stored)) {
    out.bytes = read_bytes(stored);
    if (out.partial && out.round == 0) out.round = stored_round(dir);
    return out;
  }
  const bool has_copy =
      images || (state != JobState::kRunning && fs::exists(dir / result_kind(ResultKind::kExr).stored_as));
  if (state == JobState::kDone || (has_copy && k.needs_reprojection && !reprojects) || (has_copy && !images))
    return fail(Error::kNotProduced, fmt::format("job {} has no {} result (not produced in this mode)", id, k.name));
  if (!images && copying && state == JobState::kRunning)
    return fail(Error::kNotReady, fmt::format("job {} is taking the copy of its round {} (or its final results); ask "
                                              "again in a moment",
                                              id, rounds_done));
  if (!images)
    return fail(Error::kNotReady, fmt::format("job {} is {} and has no committed round{}", id, to_string(state),
                                              state == JobState::kRunning ? " yet" : ": it has no results"));
  // Encoded from the copy on the calling thread; the reprojection thread goes on meanwhile.
  nlohmann::json partial_stats = stats ? *stats : nlohmann::json::object();
  partial_stats.update({{"partial", true}, {"state", to_string(state)}});
  static std::atomic<uint64_t> scratch{0};
  try {
    fs::create_directories(dir);
    out.bytes = encode_result(k, *images, partial_stats,
                              (dir / fmt::format(".tmp-partial-{}-{}", ++scratch, k.stored_as)).string());
  } catch (const std::exception& e) {
    logger("master")->error("job {}: cannot encode its partial {} result: {}", id, k.name, e.what());
    return fail(Error::kFailed, fmt::format("job {}: the partial {} result could not be encoded", id, k.name));
  }
  return out;
}

}  // namespace epr
