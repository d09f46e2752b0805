// End-to-end master ingestion over loopback gRPC, with the workers replaced by a vertex generator so
// that tracing is not the limit.
//
// Setup (not timed): the scene's tiles are traced ONCE with the real TileRenderer (VertexFilter kCull,
// k paths per pixel, seed 1): realistic per-tile vertex counts and positions on visible surfaces.
// Each tile result is encoded once with TileResultWriter into its SubmitTile chunks; a bench worker
// then replays them for every lease (only the header chunk is rewritten with the lease's identity),
// so the client side costs gRPC sends, not encoding. An in-process MasterServer (127.0.0.1:0) runs a
// job (rp mode, 1 round per k paths, --rounds rounds) whose tiles 1-2 bench workers (BenchWorker: one
// gRPC channel each) lease and submit; after a Wait they retry after 1 ms (not the master's 100 ms),
// so round barriers cost only what the master itself needs.
//
// Measured per (reprojector, clients), in one process, side by side:
//   received    vertices / (time from the first lease until JobSnapshot.vertices_received = all sent)
//   reprojected vertices / (time until ReprojectionCounts.total() = all sent)
//   CPU         process CPU seconds in that window, split into the bench workers' threads and the rest
//               (= the master: gRPC receive, chunk decoding, job manager, reprojection thread, llvmpipe)
//   split       reprojection thread time (JobSnapshot.seconds_reprojecting, deep framebuffer excluded);
//               decode = TileResultAssembler (checks + VertexCodec decode into VertexRecords) and protobuf
//               parse of the chunks, both measured offline on the same chunks (ns per vertex x vertices)
//   wire        serialised TileResultChunk bytes per vertex (all chunks, and vertex batches alone)
// Bar: >= 10 M vertices/s reprojected.
//
//   ingest_bench [--scene builtin:cornell] [--size 512] [-S 4] [--paths 1] [--rounds 16]
//                [--backends cpu,gl] [--clients 1,2]
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

#include <CLI/CLI.hpp>
#include <tbb/parallel_for.h>

#include "bench/bench_worker.h"
#include "client/job_client.h"
#include "common/log.h"
#include "common/scene_loader.h"
#include "master/deep_framebuffer.h"
#include "master/gl_context.h"
#include "master/reprojector.h"
#include "master/server/master_server.h"
#include "worker/tile_renderer.h"

using namespace epr;
using namespace epr::bench;
using Clock = std::chrono::steady_clock;

namespace {

double since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

struct TileData {
  TileResult result;
  v1::TileResultChunk header;             // template: the lease's identity is filled in per submit
  std::vector<v1::TileResultChunk> body;  // pixels, vertex batches, trailer
  uint64_t vertices = 0, bytes = 0, vertex_bytes = 0;
};

struct Synthetic {
  std::vector<TileData> tiles;
  uint64_t vertices = 0, bytes = 0, vertex_bytes = 0, paths = 0, recorded = 0;
  double encode_ns = 0, assemble_ns = 0, parse_ns = 0;  // per vertex, one thread (CPU time)
  std::vector<std::vector<VertexRecord>> decoded;       // per tile, as the master decodes them
};

// Reprojection alone, offline, tile by tile as the master's reprojection thread calls it: process CPU
// and wall nanoseconds per vertex (median of `runs`). The process is otherwise idle here.
struct ReprojectCost {
  double cpu_ns = 0, wall_ns = 0;
};
ReprojectCost reprojection_cost(const std::string& backend, const std::string& spec, int size, int S,
                                const Synthetic& syn, int runs) {
  const Scene scene = load_scene(spec);
  const Camera cam(scene.camera, size, size);
  std::unique_ptr<GlContext> gl;
  if (backend == "gl") gl = std::make_unique<GlContext>();
  const DeepFramebuffer dfb = gl ? build_deep_framebuffer_gl(*gl, scene, cam, S) : build_deep_framebuffer_cpu(scene, cam, S);
  ReprojectorSettings rs;
  rs.epsilon = default_epsilon(scene.bounds());
  auto r = make_reprojector(backend, cam, dfb, rs, gl.get());
  r->reproject(syn.decoded.front());  // warm-up (GL: shader compilation)
  (void)r->counts();
  std::vector<double> cpu, wall;
  for (int i = 0; i < runs; ++i) {
    r->reset();
    const double c0 = process_cpu_seconds();
    const auto t0 = Clock::now();
    for (const auto& v : syn.decoded) r->reproject(v);
    (void)r->counts();  // GL: waits for the GPU work
    wall.push_back(since(t0));
    cpu.push_back(process_cpu_seconds() - c0);
  }
  std::sort(cpu.begin(), cpu.end());
  std::sort(wall.begin(), wall.end());
  return {1e9 * cpu[cpu.size() / 2] / double(syn.vertices), 1e9 * wall[wall.size() / 2] / double(syn.vertices)};
}

Synthetic make_tiles_once(const std::string& spec, int size, int S, int k, const TileResultLimits& limits) {
  Synthetic syn;
  const Scene scene = load_scene(spec);
  EmbreeScene es(scene);
  const Camera cam(scene.camera, size, size);
  PathTracer tracer(es, cam, 1, RussianRoulette::paper());
  VertexFilter filter;
  filter.mode = VertexFilter::Mode::kCull;
  filter.subpixels = S;
  TileRenderer renderer(tracer, filter);
  const auto rects = make_tiles(size, size, 32);
  syn.tiles.resize(rects.size());
  tbb::parallel_for(size_t(0), rects.size(), [&](size_t t) {
    syn.tiles[t].result = renderer.render({rects[t], {}, {}, k});
  });

  // Encode once (worker-side cost, timed).
  const double c0 = thread_cpu_seconds();
  for (size_t t = 0; t < rects.size(); ++t) {
    TileData& d = syn.tiles[t];
    TileResultWriter w(d.result, {1, "bench", 0, uint32_t(t), "bench"}, scene.bounds(), limits);
    v1::TileResultChunk c;
    bool first = true;
    while (w.next(&c)) {
      const uint64_t b = c.ByteSizeLong();
      d.bytes += b;
      if (c.has_vertices()) {
        d.vertex_bytes += b;
        d.vertices += c.vertices().count();
      }
      if (first) d.header = std::move(c);
      else d.body.push_back(std::move(c));
      first = false;
      c = v1::TileResultChunk();
    }
  }
  const double encode = thread_cpu_seconds() - c0;
  for (const TileData& d : syn.tiles) {
    syn.vertices += d.vertices;
    syn.bytes += d.bytes;
    syn.vertex_bytes += d.vertex_bytes;
    syn.paths += d.result.stats.paths.paths;
    syn.recorded += d.result.stats.vertices_recorded;
  }
  syn.encode_ns = 1e9 * encode / double(syn.vertices);

  // Master-side decode, offline: protobuf parse of the serialised chunks, then the assembler.
  std::vector<std::vector<std::string>> wire(syn.tiles.size());
  for (size_t t = 0; t < syn.tiles.size(); ++t) {
    wire[t].push_back(syn.tiles[t].header.SerializeAsString());
    for (const auto& c : syn.tiles[t].body) wire[t].push_back(c.SerializeAsString());
  }
  double parse = 0, assemble = 0;
  for (size_t t = 0; t < syn.tiles.size(); ++t) {
    std::vector<v1::TileResultChunk> parsed(wire[t].size());
    double p0 = thread_cpu_seconds();
    for (size_t i = 0; i < wire[t].size(); ++i) parsed[i].ParseFromString(wire[t][i]);
    parse += thread_cpu_seconds() - p0;
    TileExpectation e;
    e.job_id = "bench";
    e.round = 0;
    e.tile_index = uint32_t(t);
    e.x0 = uint32_t(rects[t].x0);
    e.y0 = uint32_t(rects[t].y0);
    e.x1 = uint32_t(rects[t].x1);
    e.y1 = uint32_t(rects[t].y1);
    e.image_width = e.image_height = uint32_t(size);
    e.subpixels = uint32_t(S);
    e.codec_bounds = scene.bounds();
    e.payload = TileExpectation::Payload::kVertices;
    e.limits = limits;
    e.paths_per_pixel = uint32_t(k);
    p0 = thread_cpu_seconds();
    TileResultAssembler a(std::move(e));
    for (const auto& c : parsed)
      if (auto err = a.add(c)) throw std::runtime_error("offline assembly: " + *err);
    AssembledTile tile = a.take();
    assemble += thread_cpu_seconds() - p0;
    if (tile.vertices.size() != syn.tiles[t].vertices) throw std::runtime_error("offline assembly lost vertices");
    syn.decoded.push_back(std::move(tile.vertices));
  }
  syn.parse_ns = 1e9 * parse / double(syn.vertices);
  syn.assemble_ns = 1e9 * assemble / double(syn.vertices);
  return syn;
}

struct Figures {
  std::string backend;
  int clients = 0;
  uint64_t vertices = 0, tiles = 0;
  double t_recv = 0, t_proj = 0;      // seconds from the first lease
  double cpu = 0, cpu_clients = 0;    // process and bench-worker CPU seconds in the window
  double reproject = 0;               // reprojection thread seconds in the window
  double waits = 0, wait_seconds = 0; // Wait answers and time the workers spent waiting (summed)
  double load = 0;
};

Figures run_job(MasterServer& master, const std::string& spec, int size, int S, int k, int rounds,
                ReprojectMethod method, int clients, const Synthetic& syn) {
  Figures f;
  f.backend = to_string(method);
  f.clients = clients;
  RenderOptions o;
  o.scene = spec;
  o.width = o.height = size;
  o.subpixels = S;
  o.mode = RenderMode::kReproject;
  o.reproject = method;
  o.spp = rounds * k;
  o.paths_per_round = k;
  o.seed = 1;
  std::vector<std::unique_ptr<BenchWorker>> workers;
  for (int i = 0; i < clients; ++i)
    workers.push_back(std::make_unique<BenchWorker>(master.local_target(), "bench-" + std::to_string(i), 1));
  JobClient client(master.local_target());
  const std::string id = client.submit(o);
  JobManager& jobs = master.jobs();
  // Wait for the job to start (deep framebuffer built): the window starts at the first lease.
  for (;;) {
    auto s = jobs.get(id);
    if (s && s->state == JobState::kRunning) break;
    if (s && s->state != JobState::kQueued) throw std::runtime_error("job did not start: " + s->error);
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  const uint64_t total = uint64_t(rounds) * syn.vertices;
  f.vertices = total;
  std::atomic<bool> done{false};
  std::atomic<uint64_t> tiles{0}, waits{0};
  std::mutex mu;
  double client_cpu = 0, wait_seconds = 0;

  const double cpu0 = process_cpu_seconds();
  const auto t0 = Clock::now();
  std::vector<std::thread> threads;
  for (int i = 0; i < clients; ++i)
    threads.emplace_back([&, i] {
      BenchWorker& w = *workers[size_t(i)];
      const double c0 = thread_cpu_seconds();
      double waited = 0;
      while (!done) {
        auto l = w.lease();
        if (auto* wait = std::get_if<uint32_t>(&l)) {
          ++waits;
          const auto ws = Clock::now();
          std::this_thread::sleep_for(std::chrono::milliseconds(1));
          waited += since(ws);
          continue;
        }
        const v1::TileLease& lease = std::get<v1::TileLease>(l);
        const TileData& d = syn.tiles.at(lease.tile_index());
        v1::TileResultChunk header = d.header;
        auto* h = header.mutable_header();
        h->set_lease_id(lease.lease_id());
        h->set_job_id(lease.job_id());
        h->set_round(lease.round());
        h->set_tile_index(lease.tile_index());
        h->mutable_worker_id()->set_id(w.id());
        const v1::SubmitAck ack = w.submit(header, d.body);
        if (!ack.accepted()) std::fprintf(stderr, "tile not committed: %s\n", ack.reason().c_str());
        ++tiles;
      }
      std::lock_guard lock(mu);
      client_cpu += thread_cpu_seconds() - c0;
      wait_seconds += waited;
    });

  // Monitor: when did the master receive, and reproject, everything?
  double reproject0 = -1, reproject1 = 0, cpu1 = 0;
  for (;;) {
    auto s = jobs.get(id);
    if (!s) throw std::runtime_error("job vanished");
    // The job's seconds_reprojecting includes the deep framebuffer build; it is first published with the
    // first applied tile, which is the baseline (that tile's own reprojection, ~0.1 ms, is left out).
    if (reproject0 < 0 && s->counts.total() > 0) reproject0 = s->seconds_reprojecting;
    if (!f.t_recv && s->vertices_received >= total) f.t_recv = since(t0);
    if (!f.t_proj && s->counts.total() >= total) {
      f.t_proj = since(t0);
      cpu1 = process_cpu_seconds();
      reproject1 = s->seconds_reprojecting;
    }
    if (s->state == JobState::kDone || s->state == JobState::kFailed || s->state == JobState::kCancelled) {
      if (s->state != JobState::kDone) throw std::runtime_error("job ended " + std::string(to_string(s->state)) + ": " + s->error);
      if (!f.t_proj) throw std::runtime_error("job done before all vertices were counted");
      break;
    }
    std::this_thread::sleep_for(std::chrono::microseconds(500));
  }
  done = true;
  for (auto& t : threads) t.join();
  f.cpu = cpu1 - cpu0;
  f.cpu_clients = client_cpu;
  f.reproject = reproject1 - reproject0;
  f.tiles = tiles;
  f.waits = double(waits);
  f.wait_seconds = wait_seconds;
  f.load = load_average();
  return f;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Master ingestion over loopback gRPC with synthetic workers"};
  std::string spec = "builtin:cornell";
  int size = 512, S = 4, k = 1, rounds = 16;
  std::vector<std::string> backends = {"cpu", "gl"};
  std::vector<int> client_counts = {1, 2};
  app.add_option("--scene", spec);
  app.add_option("--size", size, "image side, pixels");
  app.add_option("-S,--subpixels", S);
  app.add_option("--paths", k, "paths per pixel and round (k) of the synthetic tiles");
  app.add_option("--rounds", rounds, "rounds per job");
  app.add_option("--backends", backends, "reprojectors: cpu, gl")->delimiter(',');
  app.add_option("--clients", client_counts, "bench worker threads (gRPC channels)")->delimiter(',');
  CLI11_PARSE(app, argc, argv);
  set_log_level("warn");

  std::printf("ingest_bench: %s %dx%d S=%d, k=%d paths/pixel/round, %d rounds per job, %u hardware threads, "
              "load average %.2f\n",
              spec.c_str(), size, size, S, k, rounds, std::thread::hardware_concurrency(), load_average());
  std::fflush(stdout);
  const auto tsyn = Clock::now();
  Synthetic syn = make_tiles_once(spec, size, S, k, TileResultLimits{});
  std::printf("synthetic round: %zu tiles, %.3g paths, %.3g vertices recorded, %.3g sent (%.2f per pixel, %.0f per "
              "tile); made in %.1f s\n",
              syn.tiles.size(), double(syn.paths), double(syn.recorded), double(syn.vertices),
              double(syn.vertices) / (double(size) * size), double(syn.vertices) / double(syn.tiles.size()),
              since(tsyn));
  std::printf("wire: %.2f bytes/vertex for whole tile results (pixels, header, trailer included), %.2f for the "
              "vertex batches alone\n",
              double(syn.bytes) / double(syn.vertices), double(syn.vertex_bytes) / double(syn.vertices));
  std::printf("offline, one thread, CPU time per vertex: worker encode (TileResultWriter) %.1f ns; master protobuf "
              "parse %.1f ns, assemble + decode (TileResultAssembler) %.1f ns\n",
              syn.encode_ns, syn.parse_ns, syn.assemble_ns);
  std::map<std::string, ReprojectCost> rcost;
  for (const std::string& b : backends) {
    rcost[b] = reprojection_cost(b, spec, size, S, syn, 5);
    std::printf("offline reprojection (%s, per-tile calls as on the master): %.1f ns/vertex process CPU, %.1f ns "
                "wall (%.1f M/s)\n",
                b.c_str(), rcost[b].cpu_ns, rcost[b].wall_ns, 1e3 / rcost[b].wall_ns);
  }
  std::fflush(stdout);

  const std::string state_dir =
      (std::filesystem::temp_directory_path() / ("ingest_bench_" + std::to_string(::getpid()))).string();
  MasterServerOptions mo;
  mo.listen = "127.0.0.1:0";
  mo.jobs.state_dir = state_dir;
  MasterServer master(mo);
  for (int i = 0; i < 200 && !master.jobs().gl_ready(); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(10));

  std::vector<Figures> all;
  for (const std::string& b : backends) {
    const ReprojectMethod m = b == "gl" ? ReprojectMethod::kGl : ReprojectMethod::kCpu;
    if (m == ReprojectMethod::kGl && !master.jobs().gl_ready()) {
      std::printf("(no OSMesa context: gl skipped)\n");
      continue;
    }
    for (int c : client_counts) {
      all.push_back(run_job(master, spec, size, S, k, rounds, m, c, syn));
      const Figures& f = all.back();
      std::printf("  %s, %d client(s): %.3g vertices in %.2f s (%.2f M/s reprojected), load %.2f\n", f.backend.c_str(),
                  f.clients, double(f.vertices), f.t_proj, f.vertices / f.t_proj / 1e6, f.load);
      std::fflush(stdout);
    }
  }
  master.shutdown();
  std::filesystem::remove_all(state_dir);

  std::printf("\n%-4s %3s | %9s %9s | %8s %8s %8s | %9s %9s | %7s %7s %7s %7s | %7s %6s %7s\n", "rp", "cli",
              "recv M/s", "reproj M/s", "CPU-s", "workers", "master", "M/mst-CPU", "M/CPU", "reproj", "parse", "decode",
              "other", "rp busy", "waits", "load");
  for (const Figures& f : all) {
    const double v = double(f.vertices);
    const double master_cpu = f.cpu - f.cpu_clients;
    const double parse = syn.parse_ns * 1e-9 * v, decode = syn.assemble_ns * 1e-9 * v;
    const double reproj = rcost[f.backend].cpu_ns * 1e-9 * v;
    const double other = master_cpu - reproj - parse - decode;
    std::printf("%-4s %3d | %9.2f %9.2f | %8.2f %8.2f %8.2f | %9.2f %9.2f | %6.0f%% %6.0f%% %6.0f%% %6.0f%% | %6.0f%% "
                "%6.0f %7.2f\n",
                f.backend.c_str(), f.clients, v / f.t_recv / 1e6, v / f.t_proj / 1e6, f.cpu, f.cpu_clients, master_cpu,
                v / master_cpu / 1e6, v / f.cpu / 1e6, 100 * reproj / master_cpu, 100 * parse / master_cpu,
                100 * decode / master_cpu, 100 * other / master_cpu, 100 * f.reproject / f.t_proj, f.waits, f.load);
  }
  std::printf("(recv / reproj: vertices per wall second until the master had received / reprojected all of them, "
              "bar >= 10 M/s reprojected; CPU-s: process CPU in that window = workers (the bench clients' threads) "
              "+ master; M/mst-CPU: vertices per master CPU-second; reproj/parse/decode/other: share of master CPU "
              "-- reproj, parse and decode are the offline per-vertex CPU costs x vertices, other = the rest (gRPC "
              "transport on the master, job manager, this bench's 0.5 ms status polling); rp busy: the reprojection "
              "thread's wall time in the reprojector over the window; waits: Wait answers at round barriers)\n");
  return 0;
}
