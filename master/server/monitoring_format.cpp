#include "master/server/monitoring_format.h"

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <initializer_list>
#include <set>
#include <utility>

#include "master/reprojection_outcomes.h"

namespace epr {
namespace {

using json = nlohmann::json;

double progress_fraction(const JobSnapshot& s) {
  if (s.state == JobState::kDone) return 1.0;
  return std::clamp(s.progress.mean_spp / std::max(1, s.options.spp), 0.0, 1.0);
}

// Reprojection decisions by outcome (ReprojectionOutcomes: culled includes what the workers culled,
// accepted the exact samples).
std::array<std::pair<const char*, uint64_t>, 5> outcomes(const ReprojectionCounts& c, const JobCounters& n) {
  const ReprojectionOutcomes o = ReprojectionOutcomes::of(c, n.worker_culled);
  return {{{"accepted", o.accepted},
           {"occluded", o.occluded},
           {"culled", o.culled},
           {"not_diffuse", o.not_diffuse},
           {"invalid", o.invalid}}};
}

json dropped_by_reason(const TileDrops& d) {
  json out = json::object();
  for (const auto& [reason, name] : kDropReasons) out[name] = d.at(reason);
  return out;
}

}  // namespace

// ---- JSON -----------------------------------------------------------------------------------------

json to_json(const JobSnapshot& s) {
  const auto& o = s.options;
  const auto& p = s.progress;
  const auto& c = s.counts;
  const JobCounters& n = s.counters;
  const ReprojectionOutcomes r = ReprojectionOutcomes::of(c, n.worker_culled);
  const uint64_t pixels = uint64_t(o.width) * uint64_t(o.height);
  const double busy = n.seconds_tracing + n.seconds_reprojecting;
  return json{
      {"id", s.id},
      {"name", s.name},
      {"state", to_string(s.state)},
      {"error", s.error},
      {"priority", s.priority},
      {"batch", s.batch.id.empty() ? json(nullptr)
                                   : json{{"id", s.batch.id},
                                          {"name", s.batch.name},
                                          {"frame", s.batch.frame ? json(*s.batch.frame) : json(nullptr)},
                                          {"frames", s.batch.frames},
                                          {"frame_window", s.batch.window},
                                          {"window_first", s.batch.window_first},
                                          {"window_last", s.batch.window_last},
                                          {"fed_by_first", s.fed_by_first},
                                          {"fed_by_last", s.fed_by_last}}},
      {"scene",
       {{"builtin", s.scene_builtin}, {"hash", s.scene_hash}, {"bytes", s.scene_bytes}, {"triangles", s.triangles}}},
      {"settings",
       {{"width", o.width},
        {"height", o.height},
        {"spp", o.spp},
        {"paths_per_round", o.paths_per_round},
        {"mode", to_string(o.mode)},
        {"reproject", to_string(o.reproject)},
        {"subpixels", o.subpixels},
        {"epsilon", o.epsilon},
        {"tile_size", o.tile_size},
        {"taper_tiles", o.taper_tiles},
        {"seed", o.seed},
        {"sampler", to_string(o.sampler)}}},
      {"round", p.round},
      {"rounds_planned", s.rounds_planned},
      {"progress", progress_fraction(s)},
      {"elapsed_seconds", s.seconds_elapsed},
      {"eta_seconds", s.eta_seconds >= 0 ? json(s.eta_seconds) : json(nullptr)},
      {"submitted_unix_ms", s.submitted_ms},
      {"started_unix_ms", s.started_ms},
      {"finished_unix_ms", s.finished_ms},
      {"budget_exhausted", s.budget_exhausted},
      {"spp",
       {{"min", p.min_spp},
        {"mean", p.mean_spp},
        {"target", o.spp},
        {"paths_mean", p.mean_paths},
        {"reprojected_mean", p.mean_reprojected}}},
      {"pixels", {{"total", pixels}, {"active", p.pixels_active}, {"skipped", p.pixels_skipped}}},
      {"eye_paths", {{"traced", p.paths_traced}, {"skipped", p.paths_skipped}}},
      {"rays_traced", n.rays},
      {"vertices_received", n.vertices_received},
      {"reprojection",
       {{"considered", r.considered},
        {"accepted", r.accepted},
        {"occluded", r.occluded},
        {"backfacing", c.backfacing},
        {"culled", r.culled},
        {"culled_by_workers", r.culled_by_workers},
        {"not_diffuse", r.not_diffuse},
        {"invalid", r.invalid},
        {"accepted_percent", r.accepted_percent()},
        {"occluded_percent", r.occluded_percent()},
        {"culled_percent", r.culled_percent()}}},
      {"non_finite_dropped", n.non_finite + c.invalid},
      {"time",
       {{"tracing_seconds", n.seconds_tracing},
        {"reprojecting_seconds", n.seconds_reprojecting},
        {"tracing_percent", busy > 0 ? 100.0 * n.seconds_tracing / busy : 0.0}}},
      {"tiles",
       {{"leased", n.tiles_leased},
        {"committed", n.tiles_committed},
        {"re_leased", n.tiles_re_leased},
        {"dropped", n.tiles_dropped},
        {"dropped_by_reason", dropped_by_reason(s.drops)},
        {"speculative", n.tiles_speculative}}},
      {"workers_active", s.workers_active},
      {"worker_failures", n.worker_failures},
      {"workers_blocked", s.workers_blocked},
      {"version", s.version},
  };
}

json to_json(const WorkerSnapshot& w) {
  return json{{"id", w.id},
              {"name", w.name},
              {"threads", w.threads},
              {"heartbeat_age_seconds", w.heartbeat_age_seconds},
              {"paths_per_second", w.paths_per_second},
              {"paths_traced", w.paths_traced},
              {"tiles_committed", w.tiles_committed},
              {"leases_held", w.leases_held}};
}

// ---- farm totals ----------------------------------------------------------------------------------

FarmTotals FarmTotals::of(const JobSnapshot& s) {
  FarmTotals t;
  t.jobs = 1;
  t.rounds = uint64_t(std::max(0, s.progress.round));
  t.paths_traced = s.progress.paths_traced;
  t.paths_skipped = s.progress.paths_skipped;
  t.counters = s.counters;
  t.drops = s.drops;
  t.counts = s.counts;
  return t;
}

FarmTotals& FarmTotals::operator+=(const FarmTotals& o) {
  jobs += o.jobs;
  rounds += o.rounds;
  paths_traced += o.paths_traced;
  paths_skipped += o.paths_skipped;
  counters += o.counters;
  drops += o.drops;
  counts += o.counts;
  return *this;
}

FarmTotals FarmTotalsTracker::update(const std::vector<JobSnapshot>& jobs) {
  std::map<std::string, FarmTotals> now;
  for (const auto& s : jobs) now[s.id] = FarmTotals::of(s);
  MutexLock lock(mu_);
  for (const auto& [id, t] : live_)
    if (!now.count(id)) retired_ += t;
  live_ = std::move(now);
  FarmTotals sum = retired_;
  for (const auto& [id, t] : live_) sum += t;
  return sum;
}

// ---- Prometheus text format -----------------------------------------------------------------------

namespace {

using Labels = std::vector<std::pair<std::string, std::string>>;

std::string escape_label(const std::string& v) {
  std::string out;
  out.reserve(v.size());
  for (char ch : v) {
    if (ch == '\\')
      out += "\\\\";
    else if (ch == '"')
      out += "\\\"";
    else if (ch == '\n')
      out += "\\n";
    else
      out += ch;
  }
  return out;
}

std::string format_value(double v) {
  if (std::isnan(v)) return "NaN";
  if (std::isinf(v)) return v > 0 ? "+Inf" : "-Inf";
  return fmt::format("{}", v);
}

class Exposition {
 public:
  void family(const std::string& name, const char* type, const char* help) {
    out_ += fmt::format("# HELP {} {}\n# TYPE {} {}\n", name, help, name, type);
  }
  void sample(const std::string& name, const Labels& labels, const std::string& value) {
    out_ += name;
    if (!labels.empty()) {
      out_ += '{';
      for (size_t i = 0; i < labels.size(); ++i)
        out_ += fmt::format("{}{}=\"{}\"", i ? "," : "", labels[i].first, escape_label(labels[i].second));
      out_ += '}';
    }
    out_ += ' ';
    out_ += value;
    out_ += '\n';
  }
  void sample(const std::string& name, const Labels& labels, double v) { sample(name, labels, format_value(v)); }
  void sample(const std::string& name, const Labels& labels, uint64_t v) { sample(name, labels, std::to_string(v)); }

  // A family with one unlabelled sample.
  template <typename T>
  void single(const std::string& name, const char* type, const char* help, T v) {
    family(name, type, help);
    sample(name, {}, v);
  }

  void histogram(const std::string& name, const char* help, const DurationHistogram& h) {
    family(name, "histogram", help);
    uint64_t cumulative = 0;
    for (size_t i = 0; i < h.kBounds.size(); ++i) {
      cumulative += h.buckets[i];
      sample(name + "_bucket", {{"le", format_value(h.kBounds[i])}}, cumulative);
    }
    sample(name + "_bucket", {{"le", "+Inf"}}, h.count);
    sample(name + "_sum", {}, h.sum);
    sample(name + "_count", {}, h.count);
  }

  std::string take() { return std::move(out_); }

 private:
  std::string out_;
};

// The jobs that get per-job series: every unfinished job and the most recently finished few.
std::vector<const JobSnapshot*> labelled_jobs(const std::vector<JobSnapshot>& jobs) {
  std::vector<const JobSnapshot*> finished, out;
  for (const auto& s : jobs) {
    if (s.state == JobState::kQueued || s.state == JobState::kRunning)
      out.push_back(&s);
    else
      finished.push_back(&s);
  }
  std::sort(finished.begin(), finished.end(), [](auto* a, auto* b) { return a->finished_ms > b->finished_ms; });
  if (finished.size() > kRecentFinishedJobs) finished.resize(kRecentFinishedJobs);
  out.insert(out.end(), finished.begin(), finished.end());
  std::sort(out.begin(), out.end(), [](auto* a, auto* b) { return a->id < b->id; });
  return out;
}

void write_farm(Exposition& e, const MetricsInput& in) {
  const FarmTotals& t = in.totals;
  const JobCounters& n = t.counters;
  const ReprojectionCounts& c = t.counts;
  e.single("epr_osmesa_ready", "gauge", "1 if the master's OSMesa (GL) reprojection context is up.",
           double(in.gl_ready ? 1 : 0));

  e.family("epr_jobs", "gauge", "Jobs the master holds, by state.");
  for (JobState st :
       {JobState::kQueued, JobState::kRunning, JobState::kDone, JobState::kFailed, JobState::kCancelled}) {
    const auto n = std::count_if(in.jobs.begin(), in.jobs.end(), [&](const JobSnapshot& s) { return s.state == st; });
    e.sample("epr_jobs", {{"state", to_string(st)}}, uint64_t(n));
  }
  e.single("epr_tiles_waiting", "gauge",
           "Tiles not yet committed in the current round of the running jobs, plus the first round's tiles of the "
           "queued jobs (the work waiting for workers).",
           in.tiles_waiting);
  e.single("epr_jobs_submitted_total", "counter", "Jobs accepted since the master started.", t.jobs);
  e.single("epr_rounds_total", "counter", "Rounds finished, over all jobs.", t.rounds);
  e.single("epr_eye_paths_traced_total", "counter", "Eye paths traced by workers (sum of M).", t.paths_traced);
  e.single("epr_eye_paths_skipped_total", "counter", "Eye paths not traced because the pixel was skipped.",
           t.paths_skipped);
  e.single("epr_rays_traced_total", "counter", "Rays traced by workers (camera, bounce, shadow, exact visibility).",
           n.rays);
  e.single("epr_vertices_received_total", "counter", "Path vertices and exact samples received from workers.",
           n.vertices_received);
  e.family("epr_reprojection_vertices_total", "counter",
           "Reprojection decisions by outcome (culled includes vertices culled on workers; accepted includes exact "
           "samples).");
  for (const auto& [name, v] : outcomes(c, n)) e.sample("epr_reprojection_vertices_total", {{"outcome", name}}, v);
  e.single("epr_non_finite_dropped_total", "counter", "Non-finite radiance values dropped (pixel sums, samples).",
           n.non_finite);
  e.single("epr_tiles_leased_total", "counter", "Tile leases granted (including re-leases).", n.tiles_leased);
  e.single("epr_tiles_committed_total", "counter", "Tile results committed (exactly once per job, round, tile).",
           n.tiles_committed);
  e.single("epr_tiles_re_leased_total", "counter", "Leases granted for tiles whose earlier lease expired.",
           n.tiles_re_leased);
  e.single("epr_tiles_dropped_total", "counter", "Tile results dropped as duplicate or stale.", n.tiles_dropped);
  e.family("epr_tiles_dropped_by_reason_total", "counter",
           "Tile results dropped in this master's run, by reason (stale round, duplicate, lease of an earlier run).");
  for (const auto& [reason, name] : kDropReasons)
    e.sample("epr_tiles_dropped_by_reason_total", {{"reason", name}}, t.drops.at(reason));
  e.single("epr_tracing_seconds_total", "counter", "Worker thread time spent tracing committed tiles.",
           n.seconds_tracing);
  e.single("epr_reprojection_seconds_total", "counter",
           "Master time spent reprojecting (deep framebuffer, reprojection, downsampling).", n.seconds_reprojecting);
  e.histogram("epr_round_duration_seconds", "Wall time of a round, from opening it to closing it.",
              in.histograms.round);
  e.histogram("epr_round_reprojection_seconds", "Master reprojection time within one round.",
              in.histograms.reprojection);
}

void write_workers(Exposition& e, const std::vector<WorkerSnapshot>& workers) {
  e.single("epr_workers", "gauge", "Registered workers.", uint64_t(workers.size()));
  e.family("epr_worker_info", "gauge", "A registered worker (value 1) with its name.");
  for (const auto& w : workers) e.sample("epr_worker_info", {{"worker", w.id}, {"name", w.name}}, uint64_t(1));
  auto per_worker = [&](const char* name, const char* type, const char* help, auto value) {
    e.family(name, type, help);
    for (const auto& w : workers) e.sample(name, {{"worker", w.id}}, value(w));
  };
  per_worker("epr_worker_threads", "gauge", "Tracing threads the worker announced.",
             [](const WorkerSnapshot& w) { return uint64_t(w.threads); });
  per_worker("epr_worker_heartbeat_age_seconds", "gauge", "Seconds since the worker was last heard from.",
             [](const WorkerSnapshot& w) { return w.heartbeat_age_seconds; });
  per_worker("epr_worker_paths_per_second", "gauge", "Eye paths per second of the worker's tracing time.",
             [](const WorkerSnapshot& w) { return w.paths_per_second; });
  per_worker("epr_worker_leases", "gauge", "Tile leases the worker holds.",
             [](const WorkerSnapshot& w) { return uint64_t(w.leases_held); });
  per_worker("epr_worker_eye_paths_traced_total", "counter", "Eye paths in the worker's committed tiles.",
             [](const WorkerSnapshot& w) { return w.paths_traced; });
  per_worker("epr_worker_tiles_committed_total", "counter", "Tiles the worker committed.",
             [](const WorkerSnapshot& w) { return w.tiles_committed; });
}

void write_jobs(Exposition& e, const std::vector<JobSnapshot>& all) {
  const auto jobs = labelled_jobs(all);
  auto per_job = [&](const std::string& name, const char* type, const char* help, auto value) {
    e.family(name, type, help);
    for (const JobSnapshot* s : jobs) e.sample(name, {{"job", s->id}}, value(*s));
  };
  e.family("epr_job_info", "gauge", "A job (value 1) with its name, scene and mode.");
  for (const JobSnapshot* s : jobs)
    e.sample("epr_job_info",
             {{"job", s->id},
              {"name", s->name},
              {"scene", s->scene_builtin.empty() ? s->scene_hash.substr(0, 12) : s->scene_builtin},
              {"mode", to_string(s->options.mode)}},
             uint64_t(1));
  e.family("epr_job_state", "gauge", "1 for the job's current state, 0 for the others.");
  for (const JobSnapshot* s : jobs)
    for (JobState st :
         {JobState::kQueued, JobState::kRunning, JobState::kDone, JobState::kFailed, JobState::kCancelled})
      e.sample("epr_job_state", {{"job", s->id}, {"state", to_string(st)}}, uint64_t(s->state == st ? 1 : 0));
  per_job("epr_job_round", "gauge", "Rounds the job has finished.",
          [](const JobSnapshot& s) { return uint64_t(std::max(0, s.progress.round)); });
  per_job("epr_job_rounds_planned", "gauge", "Rounds needed without pixel skipping.",
          [](const JobSnapshot& s) { return uint64_t(std::max(0, s.rounds_planned)); });
  per_job("epr_job_progress_ratio", "gauge", "Mean samples per pixel over the target (0..1).",
          [](const JobSnapshot& s) { return progress_fraction(s); });
  per_job("epr_job_spp_mean", "gauge", "Mean samples per pixel (M + M').",
          [](const JobSnapshot& s) { return s.progress.mean_spp; });
  per_job("epr_job_spp_min", "gauge", "Minimum samples per pixel (M + M').",
          [](const JobSnapshot& s) { return s.progress.min_spp; });
  per_job("epr_job_spp_target", "gauge", "Target samples per pixel P.",
          [](const JobSnapshot& s) { return uint64_t(std::max(0, s.options.spp)); });
  per_job("epr_job_elapsed_seconds", "gauge", "Seconds since the job started (to its end once finished).",
          [](const JobSnapshot& s) { return s.seconds_elapsed; });
  e.family("epr_job_eta_seconds", "gauge", "Estimated seconds to completion (absent while unknown).");
  for (const JobSnapshot* s : jobs)
    if (s->eta_seconds >= 0) e.sample("epr_job_eta_seconds", {{"job", s->id}}, s->eta_seconds);
  per_job("epr_job_eye_paths_traced_total", "counter", "Eye paths traced for the job.",
          [](const JobSnapshot& s) { return s.progress.paths_traced; });
  per_job("epr_job_eye_paths_skipped_total", "counter", "Eye paths the job skipped.",
          [](const JobSnapshot& s) { return s.progress.paths_skipped; });
  per_job("epr_job_vertices_received_total", "counter", "Vertices and exact samples received for the job.",
          [](const JobSnapshot& s) { return s.counters.vertices_received; });
  e.family("epr_job_reprojection_vertices_total", "counter", "The job's reprojection decisions by outcome.");
  for (const JobSnapshot* s : jobs) {
    for (const auto& [name, v] : outcomes(s->counts, s->counters))
      e.sample("epr_job_reprojection_vertices_total", {{"job", s->id}, {"outcome", name}}, v);
  }
  per_job("epr_job_tiles_committed_total", "counter", "Tiles committed for the job.",
          [](const JobSnapshot& s) { return s.counters.tiles_committed; });
  per_job("epr_job_tiles_re_leased_total", "counter", "Tiles of the job re-leased after a lease expired.",
          [](const JobSnapshot& s) { return s.counters.tiles_re_leased; });
  per_job("epr_job_tiles_speculative_total", "counter",
          "Speculative copies of the job's tiles handed to idle workers while a lease ran long.",
          [](const JobSnapshot& s) { return s.counters.tiles_speculative; });
  per_job("epr_job_worker_failures_total", "counter",
          "Failed leases of the job counted against workers (expired, refused, reported).",
          [](const JobSnapshot& s) { return s.counters.worker_failures; });
  per_job("epr_job_tracing_seconds_total", "counter", "Worker thread time spent tracing the job's tiles.",
          [](const JobSnapshot& s) { return s.counters.seconds_tracing; });
  per_job("epr_job_reprojection_seconds_total", "counter", "Master time spent reprojecting the job.",
          [](const JobSnapshot& s) { return s.counters.seconds_reprojecting; });
}

}  // namespace

std::string prometheus_text(const MetricsInput& in) {
  Exposition e;
  write_farm(e, in);
  write_workers(e, in.workers);
  write_jobs(e, in.jobs);
  return e.take();
}

}  // namespace epr
