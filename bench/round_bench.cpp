// Round overhead of the embedded default (DESIGN.md section 3, "Rounds and their overhead": the bar
// is <= 10 % of a round's wall time outside tracing).
//
// Part 1, the default: render_embedded (in-process master + one WorkerNode with one tracing thread
// per core, over loopback gRPC) on --scene at --size, P = --spp, for pt and skip and k = paths per
// round in --ppr and round schedules in --growth (RenderOptions::round_growth; 0 = k paths in every
// round). Overhead = 1 - (sum of the workers' tile tracing seconds / tracing threads) / the
// job's wall time (JobStatus: seconds_tracing, seconds_elapsed = first round opened .. job done).
// Where the rest goes: the WorkerNode's own accounting of its tracing threads' wall and CPU time over
// the job (WorkerNodeStats::time_others_tracing / time_none_tracing / cpu: tracing, leasing, waiting,
// submitting, other; while another thread traced or while none did) and the master's round closes
// (JobSnapshot::seconds_round_backlog / seconds_round_closing / seconds_writing_results), both
// returned by render_embedded. The rounds alone: the job's wall time minus its result files.
//
// Part 2, where the rest goes: the same jobs on a MasterServer with bench workers instead of a
// WorkerNode (bench_worker.h: the same lease / trace / TileResultWriter / SubmitTile steps, with
// render_leased_tile as WorkerNode uses, but retrying 1 ms after a Wait instead of the master's
// retry_after_ms = 100). Each bench thread's wall time is split into tracing, encode + submit, lease
// round trips and waiting for the next round (Wait answers), so the overhead is attributed directly.
//
// Part 3, the master's per-round work on its own (reprojection thread, workers idle meanwhile):
// FrameState::finish_round for pt and skip (skip reads the accumulation back and downsamples every
// round), FrameState::images() (the preview copy JobManager takes at most once a second in
// close_round) and, apart, the four PNG encodes (done on demand by whoever asks for a preview, off the
// reprojection thread), and the LeaseTile round trip on loopback.
//
// Wall figures are distorted when other processes share the machine; the load average is printed
// with each figure and CPU seconds beside wall seconds.
//
//   round_bench [--scene builtin:cornell] [--size 512] [--spp 64] [--ppr 1] [--growth 0,0.25]
//               [--modes skip,pt] [--tile auto] [--threads 0] [--no-bench-workers]
#include <CLI/CLI.hpp>
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <map>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "bench/bench_worker.h"
#include "client/embedded_render.h"
#include "client/job_client.h"
#include "common/image.h"
#include "common/log.h"
#include "common/scene_loader.h"
#include "master/frame_state.h"
#include "master/gl_context.h"
#include "master/server/master_server.h"
#include "wire/convert.h"
#include "worker/tile_lease.h"
#include "worker/tile_renderer.h"

using namespace epr;
using namespace epr::bench;
using Clock = std::chrono::steady_clock;
namespace fs = std::filesystem;

namespace {

double since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

double median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

struct JobFigures {
  double elapsed = 0;  // master: job started .. done, seconds
  double tracing = 0;  // sum of worker tile tracing seconds
  double reproj = 0;   // master seconds in the reprojector (incl. deep framebuffer build)
  double wall = 0;     // the whole call (setup, outputs, fetch)
  double cpu = 0;      // process CPU seconds of the whole call
  int rounds = 0, threads = 0;
  double median_round = 0;  // seconds between round updates (watch stream)
  double load = 0;
  // The embedded WorkerNode's tracing threads over the job (WorkerNodeStats, summed over nodes):
  // while another of its threads traced / while none did.
  WorkerTimeSplit others, none, thread_cpu;
  double job_cpu = 0;  // process CPU seconds from the first update showing the job running to the one showing it done
  uint64_t tiles = 0;
  double backlog = 0, closing = 0, writing = 0;  // the master's JobSnapshot::seconds_round_* and _writing_results
  uint32_t round_checkpoints = 0;                // JobSnapshot::round_checkpoints (--checkpoints)
  double overhead() const { return 1 - tracing / threads / elapsed; }
};

int g_tile_size = 0;                // --tile; 0: auto_tile_size() as `epr render` picks it, tapered
bool g_taper_tiles = false;         // --taper-tiles
bool g_checkpoints = false;         // --checkpoints
double g_checkpoint_interval = -1;  // --checkpoint-interval

RenderOptions options(const std::string& scene, int size, int spp, RenderMode mode, int ppr, float growth) {
  RenderOptions o;
  o.round_growth = growth;
  o.tile_size = g_tile_size;
  o.taper_tiles = g_taper_tiles;
  o.scene = scene;
  o.width = o.height = size;
  o.spp = spp;
  o.mode = mode;
  o.paths_per_round = ppr;
  o.seed = 1;
  return o;
}

JobFigures run_embedded(const RenderOptions& o, int threads, const fs::path& tmp) {
  RenderOptions opts = o;
  opts.out = (tmp / "embedded").string();
  EmbeddedOptions eo;
  eo.workers = 1;
  eo.worker_threads = threads;
  eo.state_dir = (tmp / "state").string();
  eo.checkpoints = g_checkpoints;
  eo.checkpoint_interval_s =
      g_checkpoint_interval;  // `epr render` keeps its state in a temporary folder: no checkpoints
  std::vector<std::pair<uint32_t, Clock::time_point>> rounds;
  const double c0 = process_cpu_seconds();
  const auto t0 = Clock::now();
  double cpu_running = -1, cpu_done = -1;
  const EmbeddedResult r = render_embedded(opts, eo, [&](const v1::JobStatus& s) {
    if (rounds.empty() || rounds.back().first != s.round()) rounds.emplace_back(s.round(), Clock::now());
    if (cpu_running < 0 && s.state() != v1::JOB_STATE_QUEUED) cpu_running = process_cpu_seconds();
    if (cpu_done < 0 && s.state() == v1::JOB_STATE_DONE) cpu_done = process_cpu_seconds();
  });
  JobFigures f;
  f.wall = since(t0);
  f.cpu = process_cpu_seconds() - c0;
  f.elapsed = r.status.seconds_elapsed();
  f.tracing = r.status.seconds_tracing();
  f.reproj = r.status.seconds_reprojecting();
  f.rounds = int(r.status.round());
  f.threads = threads;
  std::vector<double> d;
  for (size_t i = 1; i < rounds.size(); ++i)
    if (rounds[i].first == rounds[i - 1].first + 1)
      d.push_back(std::chrono::duration<double>(rounds[i].second - rounds[i - 1].second).count());
  f.median_round = median(d);
  f.load = load_average();
  f.job_cpu = cpu_done - cpu_running;
  if (r.master_view) {
    f.backlog = r.master_view->seconds_round_backlog;
    f.closing = r.master_view->seconds_round_closing;
    f.writing = r.master_view->seconds_writing_results;
    f.round_checkpoints = r.master_view->round_checkpoints;
  }
  for (const WorkerNodeStats& w : r.workers) {
    auto add = [](WorkerTimeSplit& a, const WorkerTimeSplit& b) {
      a.tracing += b.tracing;
      a.leasing += b.leasing;
      a.waiting += b.waiting;
      a.submitting += b.submitting;
      a.other += b.other;
    };
    add(f.others, w.time_others_tracing);
    add(f.none, w.time_none_tracing);
    add(f.thread_cpu, w.cpu);
    f.tiles += w.tiles_leased;
  }
  fs::remove_all(eo.state_dir);
  return f;
}

// ---- bench workers that trace for real --------------------------------------------------------------

struct ThreadSplit {
  double tracing = 0, submit = 0, lease = 0, waiting = 0, total = 0;  // wall seconds
  double tracing_cpu = 0, submit_cpu = 0, lease_cpu = 0;              // the thread's CPU seconds
  uint64_t tiles = 0, waits = 0;
  ThreadSplit& operator+=(const ThreadSplit& o) {
    tracing += o.tracing;
    submit += o.submit;
    lease += o.lease;
    waiting += o.waiting;
    total += o.total;
    tracing_cpu += o.tracing_cpu;
    submit_cpu += o.submit_cpu;
    lease_cpu += o.lease_cpu;
    tiles += o.tiles;
    waits += o.waits;
    return *this;
  }
};

struct Tracer {
  explicit Tracer(const v1::TileLease& l)
      : scene(load_scene(l.scene().builtin())),
        embree(scene),
        camera(from_proto(l.settings().camera()), int(l.settings().width()), int(l.settings().height())),
        tracer(embree, camera, l.seed(), from_proto(l.settings().russian_roulette())),
        codec_bounds(from_proto(l.settings().codec_bounds())) {}
  Scene scene;
  EmbreeScene embree;
  Camera camera;
  PathTracer tracer;
  Bounds3 codec_bounds;
};

struct BenchJob {
  JobFigures fig;
  ThreadSplit split;  // summed over threads
};

BenchJob run_bench_workers(const RenderOptions& o, int threads, const fs::path& tmp) {
  MasterServerOptions mo;
  mo.listen = "127.0.0.1:0";
  mo.jobs.state_dir = (tmp / "state").string();
  mo.jobs.checkpoints = g_checkpoints;
  mo.jobs.checkpoint_interval_s = g_checkpoint_interval;
  MasterServer master(mo);
  for (int i = 0; i < 200 && !master.jobs().gl_ready(); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(10));
  std::vector<std::unique_ptr<BenchWorker>> workers;
  for (int i = 0; i < threads; ++i)
    workers.push_back(std::make_unique<BenchWorker>(master.local_target(), "bench-" + std::to_string(i), 1));
  const double c0 = process_cpu_seconds();
  const auto t0 = Clock::now();
  JobClient client(master.local_target());
  const std::string id = client.submit(o);
  std::atomic<bool> done{false};
  std::mutex mu;
  std::unique_ptr<Tracer> tracer;  // built by the first lease, shared (read-only) by the threads
  BenchJob out;
  std::vector<std::thread> pool;
  for (int i = 0; i < threads; ++i)
    pool.emplace_back([&, i] {
      BenchWorker& w = *workers[size_t(i)];
      ThreadSplit s;
      // The split runs from the thread's first lease of a tile to the end of its last submit; waiting
      // counts only when another tile followed (not the wait for the job's end and its output files).
      Clock::time_point first{}, last{};
      bool started = false;
      double pending_wait = 0;
      uint64_t pending_waits = 0;
      while (!done) {
        auto ls = Clock::now();
        const double lc = thread_cpu_seconds();
        auto l = w.lease();
        const double lt = since(ls), lct = thread_cpu_seconds() - lc;
        if (std::holds_alternative<uint32_t>(l)) {
          std::this_thread::sleep_for(std::chrono::milliseconds(1));
          pending_wait += since(ls);
          ++pending_waits;
          continue;
        }
        if (!started) {
          started = true;
          first = ls;
        } else {
          s.waiting += pending_wait;
          s.waits += pending_waits;
        }
        pending_wait = 0;
        pending_waits = 0;
        s.lease += lt;
        s.lease_cpu += lct;
        const v1::TileLease& lease = std::get<v1::TileLease>(l);
        {
          std::lock_guard lock(mu);
          if (!tracer) tracer = std::make_unique<Tracer>(lease);
        }
        LeasedTile tile;
        if (auto err = unpack_tile_lease(lease, &tile)) throw std::runtime_error("bad lease: " + *err);
        const auto tt = Clock::now();
        const double tc = thread_cpu_seconds();
        const TileRenderer renderer(tracer->tracer, tile.filter, tracer->codec_bounds);  // as WorkerNode
        const auto result = render_leased_tile(renderer, tile, {});
        s.tracing += since(tt);
        s.tracing_cpu += thread_cpu_seconds() - tc;
        const auto st = Clock::now();
        const double sc = thread_cpu_seconds();
        TileResultWriter writer(*result, {lease.lease_id(), lease.job_id(), lease.round(), lease.tile_index(), w.id()},
                                tracer->codec_bounds, w.limits());
        w.submit(writer);
        last = Clock::now();
        s.submit += std::chrono::duration<double>(last - st).count();
        s.submit_cpu += thread_cpu_seconds() - sc;
        ++s.tiles;
      }
      if (started) s.total = std::chrono::duration<double>(last - first).count();
      std::lock_guard lock(mu);
      out.split += s;
    });
  std::vector<std::pair<int, Clock::time_point>> rounds;
  for (;;) {
    auto snap = master.jobs().get(id);
    if (!snap) throw std::runtime_error("job vanished");
    if (rounds.empty() || rounds.back().first != snap->progress.round)
      rounds.emplace_back(snap->progress.round, Clock::now());
    if (snap->state == JobState::kDone) {
      out.fig.elapsed = snap->seconds_elapsed;
      out.fig.tracing = snap->counters.seconds_tracing;
      out.fig.reproj = snap->counters.seconds_reprojecting;
      out.fig.rounds = snap->progress.round;
      break;
    }
    if (snap->state != JobState::kRunning && snap->state != JobState::kQueued)
      throw std::runtime_error("job ended " + std::string(to_string(snap->state)) + ": " + snap->error);
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  done = true;
  for (auto& t : pool) t.join();
  out.fig.wall = since(t0);
  out.fig.cpu = process_cpu_seconds() - c0;
  out.fig.threads = threads;
  std::vector<double> d;
  for (size_t i = 1; i < rounds.size(); ++i)
    d.push_back(std::chrono::duration<double>(rounds[i].second - rounds[i - 1].second).count());
  out.fig.median_round = median(d);
  out.fig.load = load_average();
  workers.clear();
  master.shutdown();
  fs::remove_all(mo.jobs.state_dir);
  return out;
}

// ---- the master's per-round work, offline ------------------------------------------------------------

struct MasterRoundCosts {
  double finish_round = 0, finish_round_cpu = 0;  // seconds per call (median), wall and process CPU
  double images = 0, images_cpu = 0;              // images(): the preview copy on the reprojection thread
  double previews = 0, previews_cpu = 0;          // 4 PNG encodes (on demand, elsewhere)
  double reproject_round = 0;                     // reprojecting one round's vertices (rp/skip), wall
};

MasterRoundCosts master_round_costs(const std::string& spec, int size, RenderMode mode, ReprojectMethod method,
                                    int runs) {
  RenderOptions o = options(spec, size, 1'000'000, mode, 1, 0.f);
  o.reproject = method;
  o.min_paths = 1'000'000;  // never skip: every round does the same work
  const Scene scene = load_scene(spec);
  const Camera cam(scene.camera, size, size);
  EmbreeScene es(scene);
  PathTracer tracer(es, cam, 1, RussianRoulette::paper());
  VertexFilter filter;
  filter.mode = mode == RenderMode::kPathTrace ? VertexFilter::Mode::kNone : VertexFilter::Mode::kCull;
  TileRenderer renderer(tracer, filter);
  const auto tiles = make_tiles(size, size, g_tile_size, g_taper_tiles);
  std::vector<TileResult> results;
  std::vector<std::string> packed;  // the vertices as the master receives them
  const VertexCodec codec(scene.bounds());
  for (const TileRect& r : tiles) {
    results.push_back(renderer.render({r, {}, {}, 1}));
    packed.emplace_back();
    codec.encode_batch(results.back().vertices, &packed.back());
  }
  std::unique_ptr<GlContext> gl;
  if (mode != RenderMode::kPathTrace && method == ReprojectMethod::kGl) gl = std::make_unique<GlContext>();
  FrameState frame(o, cam, scene, gl.get());
  MasterRoundCosts c;
  std::vector<double> fr, frc, im, imc, pv, pvc, rp;
  for (int i = 0; i < runs; ++i) {
    const auto t0 = Clock::now();
    for (size_t t = 0; t < results.size(); ++t) {
      const TileResult& r = results[t];
      frame.add_paths(r.rect.x0, r.rect.y0, r.rect.x1, r.rect.y1, r.path_sum, r.path_count);
      frame.reproject_packed(packed[t]);
    }
    (void)frame.counts();
    rp.push_back(since(t0));
    double c1 = process_cpu_seconds();
    auto t1 = Clock::now();
    frame.finish_round();
    fr.push_back(since(t1));
    frc.push_back(process_cpu_seconds() - c1);
    c1 = process_cpu_seconds();
    t1 = Clock::now();
    const FrameImages img = frame.images();
    im.push_back(since(t1));
    imc.push_back(process_cpu_seconds() - c1);
    c1 = process_cpu_seconds();
    t1 = Clock::now();
    size_t bytes = encode_png_srgb(combined_image(img)).size() + encode_png_srgb(pathtrace_image(img)).size();
    if (frame.reprojects()) {
      bytes += encode_png_srgb(img.reprojection).size();
      bytes += encode_png_srgb(heat_map(img.reprojected, 16.f)).size();
    }
    pv.push_back(since(t1));
    pvc.push_back(process_cpu_seconds() - c1);
    if (bytes == 0) std::fprintf(stderr, "empty previews\n");
  }
  c.finish_round = median(fr);
  c.finish_round_cpu = median(frc);
  c.images = median(im);
  c.images_cpu = median(imc);
  c.previews = median(pv);
  c.previews_cpu = median(pvc);
  c.reproject_round = median(rp);
  return c;
}

// LeaseTile round trip on loopback (the master answers Wait: no job), median over `n` calls.
std::pair<double, double> lease_rtt(int n) {
  MasterServerOptions mo;
  mo.listen = "127.0.0.1:0";
  mo.jobs.state_dir = (fs::temp_directory_path() / ("round_bench_rtt_" + std::to_string(::getpid()))).string();
  mo.jobs.checkpoints = g_checkpoints;
  mo.jobs.checkpoint_interval_s = g_checkpoint_interval;
  MasterServer master(mo);
  std::vector<double> t;
  double cpu = 0;
  {
    BenchWorker w(master.local_target(), "rtt", 1);
    for (int i = 0; i < 20; ++i) (void)w.lease();
    const double c0 = process_cpu_seconds();
    for (int i = 0; i < n; ++i) {
      const auto t0 = Clock::now();
      (void)w.lease();
      t.push_back(since(t0));
    }
    cpu = (process_cpu_seconds() - c0) / n;
  }
  master.shutdown();
  fs::remove_all(mo.jobs.state_dir);
  return {median(t), cpu};
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Round overhead of the embedded default"};
  std::string scene = "builtin:cornell";
  int size = 512, spp = 64, threads = 0, runs = 5;
  std::vector<int> pprs = {1};
  std::vector<float> growths = {0.f, RenderOptions{}.round_growth};
  std::vector<std::string> modes = {"skip", "pt"};
  bool no_bench_workers = false, no_embedded = false, no_master_costs = false;
  app.add_option("--scene", scene);
  app.add_option("--size", size, "image side, pixels");
  app.add_option("--spp", spp, "P");
  app.add_option("--ppr", pprs, "paths per round (k) values")->delimiter(',');
  app.add_option("--growth", growths, "round_growth values (0: k paths in every round)")->delimiter(',');
  app.add_option("--modes", modes, "pt, skip, rp")->delimiter(',');
  app.add_option("--threads", threads, "tracing threads (0: all cores)");
  app.add_option("--runs", runs, "runs of the offline per-round measurements (median)");
  app.add_option("--tile", g_tile_size, "tile size of the jobs, pixels (default: auto and tapered, as epr render)");
  app.add_flag("--taper-tiles", g_taper_tiles, "with --tile: tapered tiles");
  app.add_flag("--no-bench-workers", no_bench_workers, "only the embedded default (part 1)");
  app.add_flag("--checkpoints", g_checkpoints,
               "checkpoint rounds as a master with --state-dir does (the embedded default does not)");
  app.add_option("--checkpoint-interval", g_checkpoint_interval,
                 "with --checkpoints: seconds between round checkpoints (0: every round; < 0: automatic)");
  app.add_flag("--no-embedded", no_embedded, "skip part 1");
  app.add_flag("--no-master-costs", no_master_costs, "skip part 3 (e.g. when profiling part 1 with perf)");
  CLI11_PARSE(app, argc, argv);
  set_log_level("warn");
  if (threads <= 0) threads = int(std::max(1u, std::thread::hardware_concurrency()));
  if (g_tile_size <= 0) {  // as `epr render` does unless told
    g_tile_size = auto_tile_size(size, size, threads);
    g_taper_tiles = true;
  }
  const fs::path tmp = fs::temp_directory_path() / ("round_bench_" + std::to_string(::getpid()));
  fs::create_directories(tmp);
  auto mode_of = [](const std::string& m) {
    return m == "skip" ? RenderMode::kSkip : m == "rp" ? RenderMode::kReproject : RenderMode::kPathTrace;
  };

  std::printf(
      "round_bench: %s %dx%d, P=%d, tiles %dx%d%s, %d tracing threads, %u hardware threads, load average "
      "%.2f\n",
      scene.c_str(), size, size, spp, g_tile_size, g_tile_size, g_taper_tiles ? " (tapered)" : "", threads,
      std::thread::hardware_concurrency(), load_average());
  std::fflush(stdout);

  struct Row {
    std::string mode;
    int ppr;
    float growth;
    JobFigures emb;
    BenchJob bench;
  };
  std::vector<Row> rows;
  for (const std::string& m : modes)
    for (float g : growths)
      for (int k : pprs) {
        Row row{m, k, g, {}, {}};
        const RenderOptions o = options(scene, size, spp, mode_of(m), k, g);
        if (!no_embedded) {
          row.emb = run_embedded(o, threads, tmp);
          std::printf(
              "  embedded     %-4s g=%.2f k=%d: %2d rounds, job %.2f s (call %.2f s, %.2f CPU-s), tracing %.2f s / %d "
              "threads -> overhead %.1f%%, load %.2f\n",
              m.c_str(), g, k, row.emb.rounds, row.emb.elapsed, row.emb.wall, row.emb.cpu, row.emb.tracing, threads,
              100 * row.emb.overhead(), row.emb.load);
          std::fflush(stdout);
        }
        if (!no_bench_workers) {
          row.bench = run_bench_workers(o, threads, tmp);
          const JobFigures& f = row.bench.fig;
          std::printf(
              "  bench worker %-4s g=%.2f k=%d: %2d rounds, job %.2f s (%.2f CPU-s), tracing %.2f s / %d threads -> "
              "overhead %.1f%%, load %.2f\n",
              m.c_str(), g, k, f.rounds, f.elapsed, f.cpu, f.tracing, threads, 100 * f.overhead(), f.load);
          std::fflush(stdout);
        }
        rows.push_back(row);
      }

  std::printf("\n==== Part 1+2: share of the job's wall time outside tracing (bar <= 10%%)\n");
  std::printf("%-5s %4s %3s | %6s %8s %8s %9s %9s | %8s %9s %9s | %8s %8s %8s %8s %8s | %6s\n", "mode", "g", "k",
              "rounds", "emb s", "emb ovh", "ovh/round", "round s", "bench s", "bench ovh", "ovh/round", "trace",
              "submit", "lease", "wait", "other", "load");
  for (const Row& r : rows) {
    const JobFigures& e = r.emb;
    const JobFigures& b = r.bench.fig;
    const ThreadSplit& s = r.bench.split;
    auto share = [&](double x) { return s.total > 0 ? 100 * x / s.total : 0.0; };
    std::printf(
        "%-5s %4.2f %3d | %6d %8.2f %7.1f%% %7.1fms %8.3fs | %8.2f %8.1f%% %7.1fms | %7.1f%% %7.1f%% %7.1f%% %7.1f%% "
        "%7.1f%% | %6.2f\n",
        r.mode.c_str(), r.growth, r.ppr, e.rounds ? e.rounds : b.rounds, e.elapsed,
        100 * (e.elapsed ? e.overhead() : 0), e.rounds ? 1e3 * (e.elapsed - e.tracing / e.threads) / e.rounds : 0.0,
        e.median_round, b.elapsed, 100 * (b.elapsed ? b.overhead() : 0),
        b.rounds ? 1e3 * (b.elapsed - b.tracing / b.threads) / b.rounds : 0.0, share(s.tracing), share(s.submit),
        share(s.lease), share(s.waiting), share(s.total - s.tracing - s.submit - s.lease - s.waiting),
        e.load ? e.load : b.load);
  }
  std::printf("\n==== The embedded WorkerNode's tracing threads over the job: where their wall time went\n");
  std::printf("%-5s %4s %3s | %-14s | %7s %7s %7s %7s %7s %7s | %9s %9s\n", "mode", "g", "k", "while", "total", "trace",
              "lease", "wait", "submit", "other", "idle/rnd", "tiles");
  for (const Row& r : rows) {
    const JobFigures& e = r.emb;
    if (!e.rounds) continue;
    const double all = e.others.total() + e.none.total();
    auto line = [&](const char* what, const WorkerTimeSplit& t) {
      auto pc = [&](double x) { return all > 0 ? 100 * x / all : 0.0; };
      std::printf("%-5s %4.2f %3d | %-14s | %6.1f%% %6.1f%% %6.1f%% %6.1f%% %6.1f%% %6.1f%% | %7.1fms %9llu\n",
                  r.mode.c_str(), r.growth, r.ppr, what, pc(t.total()), pc(t.tracing), pc(t.leasing), pc(t.waiting),
                  pc(t.submitting), pc(t.other), 1e3 * (t.total() - t.tracing) / e.threads / e.rounds,
                  (unsigned long long)e.tiles);
    };
    line("another traces", e.others);
    line("none traces", e.none);
    const WorkerTimeSplit& c = e.thread_cpu;
    std::printf(
        "%-5s %4.2f %3d | %-14s | %6.2fs %6.2fs %6.2fs %6.2fs %6.2fs %6.2fs | CPU view: 1 - tracing CPU / "
        "process CPU over the job (%.2f s) = %.1f%%\n",
        r.mode.c_str(), r.growth, r.ppr, "thread CPU", c.total(), c.tracing, c.leasing, c.waiting, c.submitting,
        c.other, e.job_cpu, e.job_cpu > 0 ? 100 * (1 - c.tracing / e.job_cpu) : 0.0);
    std::printf("      thread-seconds %.2f over a job of %.2f s x %d threads = %.2f\n", all, e.elapsed, e.threads,
                e.elapsed * e.threads);
    std::printf(
        "      master, per round: last result -> applied (backlog) %.1f ms, applied -> next round open %.1f "
        "ms; writing the results at the end %.0f ms (%.1f%% of the job); overhead of the rounds alone "
        "(job wall minus the results) %.1f%%\n",
        1e3 * e.backlog / e.rounds, 1e3 * e.closing / e.rounds, 1e3 * e.writing, 100 * e.writing / e.elapsed,
        100 * (1 - e.tracing / e.threads / (e.elapsed - e.writing)));
    if (g_checkpoints) std::printf("      round checkpoints: %u of %d rounds\n", e.round_checkpoints, e.rounds);
  }
  std::printf(
      "(shares of the tracing threads' summed wall time from the job running to done; 'another traces': a "
      "thread's time while another thread of the node traced -- its idle part is a round's tail; 'none "
      "traces': while no other thread traced -- its idle part is the node waiting for the master; "
      "idle/rnd: the idle part / threads / rounds, i.e. the wall time per round it costs)\n");

  std::printf("\n==== CPU view (robust to load): share of the process's CPU time not spent tracing\n");
  std::printf("%-5s %4s %3s | %9s %9s %9s | %9s %9s | %11s %11s\n", "mode", "g", "k", "trace CPU", "emb CPU", "emb ovh",
              "bench CPU", "bench ovh", "trace/round", "tiles");
  for (const Row& r : rows) {
    const double tc = r.bench.split.tracing_cpu;
    if (tc <= 0) continue;
    const int rounds = r.bench.fig.rounds;
    std::printf("%-5s %4.2f %3d | %9.2f %9.2f %8.1f%% %9.2f %8.1f%% | %9.1fms %11llu\n", r.mode.c_str(), r.growth,
                r.ppr, tc, r.emb.cpu, r.emb.cpu > 0 ? 100 * (1 - tc / r.emb.cpu) : 0.0, r.bench.fig.cpu,
                100 * (1 - tc / r.bench.fig.cpu), rounds ? 1e3 * tc / threads / rounds : 0.0,
                (unsigned long long)r.bench.split.tiles);
  }
  std::printf(
      "(trace CPU: thread CPU seconds inside render_leased_tile, summed over the bench threads -- the same "
      "paths as the embedded job, which is deterministic; emb/bench CPU: process CPU seconds of the whole "
      "call / job; trace/round: trace CPU / threads / rounds = a round's tracing wall time on an idle machine)\n");

  std::printf("\nbench workers, per tile (thread CPU): ");
  for (const Row& r : rows) {
    const ThreadSplit& s = r.bench.split;
    if (!s.tiles) continue;
    std::printf("%s g=%.2f k=%d: trace %.2f ms, submit %.2f ms, lease %.2f ms; ", r.mode.c_str(), r.growth, r.ppr,
                1e3 * s.tracing_cpu / double(s.tiles), 1e3 * s.submit_cpu / double(s.tiles),
                1e3 * s.lease_cpu / double(s.tiles));
  }
  std::printf("\n");
  std::printf(
      "(emb: render_embedded with WorkerNode; bench: bench workers retrying 1 ms after a Wait. ovh = 1 - "
      "tracing / threads / job wall; ovh/round = (job wall - tracing / threads) / rounds; round s: median "
      "wall between round updates; trace/submit/lease/wait/other: shares of the bench threads' wall time from "
      "their first tile -- submit includes encoding, wait = Wait answers and the 1 ms sleeps after them)\n");
  std::fflush(stdout);

  if (no_master_costs) {
    fs::remove_all(tmp);
    return 0;
  }
  std::printf("\n==== Part 3: the master's per-round work on its own (%dx%d, median of %d), load %.2f\n", size, size,
              runs, load_average());
  std::printf("%-5s %-4s | %12s %12s | %12s %12s | %12s %12s | %14s\n", "mode", "rp", "finish_round", "CPU", "images()",
              "CPU", "4 PNGs", "CPU", "reproject round");
  for (const std::string& m : modes) {
    std::vector<ReprojectMethod> methods = {ReprojectMethod::kGl};
    if (m != "pt") methods.push_back(ReprojectMethod::kCpu);
    for (ReprojectMethod rm : methods) {
      const MasterRoundCosts c = master_round_costs(scene, size, mode_of(m), rm, runs);
      std::printf("%-5s %-4s | %10.1fms %10.1fms | %10.1fms %10.1fms | %10.1fms %10.1fms | %12.1fms\n", m.c_str(),
                  m == "pt" ? "-" : to_string(rm), 1e3 * c.finish_round, 1e3 * c.finish_round_cpu, 1e3 * c.images,
                  1e3 * c.images_cpu, 1e3 * c.previews, 1e3 * c.previews_cpu, 1e3 * c.reproject_round);
      std::fflush(stdout);
    }
  }
  const auto [rtt, rtt_cpu] = lease_rtt(2000);
  std::printf(
      "LeaseTile round trip on loopback: %.0f us median wall, %.0f us process CPU per call (client + "
      "master)\n",
      1e6 * rtt, 1e6 * rtt_cpu);
  std::printf(
      "(finish_round: M', skip mask and progress -- skip mode reads the accumulation back and downsamples "
      "every round; images(): the preview copy close_round takes at most once a second; 4 PNGs: the encodes a "
      "preview request costs, on the requesting thread; reproject round: add_paths + reproject_packed of one "
      "round's tiles of --tile pixels)\n");
  fs::remove_all(tmp);
  std::printf("load average at end %.2f\n", load_average());
  return 0;
}
