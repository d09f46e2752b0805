// End-to-end master ingestion over loopback gRPC, with the workers replaced by a vertex generator so
// that tracing is not the limit.
//
// Setup (not timed): the scene's tiles are traced ONCE with the real TileRenderer (VertexFilter kCull,
// k paths per pixel, seed 1): realistic per-tile vertex counts and positions on visible surfaces.
// Each tile result is encoded once with TileResultWriter into its SubmitTile chunks; a bench worker
// then replays them for every lease (only the header chunk is rewritten with the lease's identity),
// so the client side costs gRPC sends, not encoding. An in-process MasterServer (127.0.0.1:0) runs a
// job (rp mode, k paths in every round, --rounds rounds, --tile pixel tiles) whose tiles 1-2 bench
// workers (BenchWorker: one gRPC channel each) lease and submit; after a Wait they retry after 1 ms
// (not the master's 5 ms), so round barriers cost only what the master itself needs.
// The bench workers run in a separate process (this program re-executed with --serve-clients, the
// synthetic tiles handed over in a file), so that the master's CPU time is this process's CPU time;
// --in-process runs them as threads of this process instead (their gRPC client threads then count
// as the master's). Both share the machine's cores with the master either way.
//
// Measured per (reprojector, clients), in one process, side by side:
//   received    vertices / (time from round 1 opening until JobSnapshot::counters.vertices_received = all
//               sent; round 0 is a warm-up outside the window, so that the job's set-up is too)
//   reprojected vertices / (time until ReprojectionCounts.total() = all sent)
//   CPU         process CPU seconds in that window, split into the bench workers' threads and the rest
//               (= the master: gRPC receive, chunk decoding, job manager, reprojection thread, llvmpipe)
//   split       reprojection thread time (JobSnapshot::counters.seconds_reprojecting, deep framebuffer excluded);
//               assemble = TileResultAssembler as the master runs it (checks; vertices kept packed, the
//               reprojector decodes them in place) and protobuf parse of the chunks, both measured
//               offline on the same chunks (ns per vertex x vertices); the offline decode into
//               VertexRecords is printed for comparison
//   wire        serialised TileResultChunk bytes per vertex (all chunks, and vertex batches alone)
//   threads     the master's CPU seconds in the window per thread name, read from /proc/self/task
//               (epr-reproject: the reprojection thread; "tbb": the TBB workers its large calls use;
//               nexting_thread, default-executo: gRPC's threads, i.e. transport, protobuf parse and
//               assembly; unnamed: llvmpipe's threads under GL; main: this bench's status poll)
//   backlog     JobSnapshot::seconds_round_backlog per round: from a round's last result arriving to
//               the reprojection thread having applied it (the commit queue's backlog at the barrier)
// --batch-records runs the whole series once per value of MasterOptions::reproject_batch_records
// (one master each; 0 = one reprojector call per tile). --master-cpus / --client-cpus pin this
// process (before any thread starts) and the bench workers' process to those cores.
// Bar: >= 10 M vertices/s reprojected.
//
//   ingest_bench [--scene builtin:cornell] [--size 512] [-S 4] [--paths 1] [--rounds 16] [--tile 64]
//                [--backends cpu,gl] [--clients 1,2] [--in-process] [--batch-records 1048576,0]
//                [--master-cpus 0] [--client-cpus 1]
//   ingest_bench --encode-reps 9   only the worker's encode microbenchmark (encode_microbench below)
#include <dirent.h>
#include <sched.h>
#include <spawn.h>
#include <sys/wait.h>
#include <tbb/parallel_for.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "bench/bench_worker.h"
#include "client/job_client.h"
#include "common/log.h"
#include "common/scene_loader.h"
#include "common/thread_name.h"
#include "master/deep_framebuffer.h"
#include "master/gl_context.h"
#include "master/make_reprojector.h"
#include "master/reprojector.h"
#include "master/server/master_server.h"
#include "worker/tile_renderer.h"

using namespace epr;
using namespace epr::bench;
using Clock = std::chrono::steady_clock;

namespace {

double since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

// The threads (ids) TBB started while the synthetic tiles were traced, before the master existed.
std::set<std::string> tbb_threads;

// CPU seconds of this process's threads, summed per thread name (/proc/self/task/*/stat); the main
// thread is "main", TBB's workers "tbb", threads started later without a name "unnamed" (with GL:
// llvmpipe's). gRPC's own are "nexting_thread" (completion queue) and "default-executo(r)".
std::map<std::string, double> thread_cpu_by_name() {
  std::map<std::string, double> by_name;
  const double tick = double(::sysconf(_SC_CLK_TCK));
  const std::string self = std::to_string(::getpid());
  for (const auto& e : std::filesystem::directory_iterator("/proc/self/task")) {
    std::ifstream in(e.path() / "stat");
    std::string line;
    if (!std::getline(in, line)) continue;  // the thread ended
    const size_t open = line.find('('), close = line.rfind(')');
    if (open == std::string::npos || close == std::string::npos) continue;
    std::string name = line.substr(open + 1, close - open - 1);
    std::istringstream rest(line.substr(close + 2));
    std::string field;
    unsigned long long utime = 0, stime = 0;
    for (int i = 3; i <= 15 && rest >> field; ++i) {  // fields 14 and 15: utime, stime
      if (i == 14) utime = std::stoull(field);
      if (i == 15) stime = std::stoull(field);
    }
    if (e.path().filename() == self)
      name = "main";
    else if (tbb_threads.count(e.path().filename()))
      name = "tbb";
    else if (name == "ingest_bench")
      name = "unnamed";
    by_name[name] += double(utime + stime) / tick;
  }
  return by_name;
}

// "0,2-3" -> those CPUs.
cpu_set_t parse_cpus(const std::string& list) {
  cpu_set_t set;
  CPU_ZERO(&set);
  std::istringstream in(list);
  std::string part;
  while (std::getline(in, part, ',')) {
    const size_t dash = part.find('-');
    const int lo = std::stoi(part.substr(0, dash)),
              hi = dash == std::string::npos ? lo : std::stoi(part.substr(dash + 1));
    for (int c = lo; c <= hi; ++c) CPU_SET(c, &set);
  }
  return set;
}

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
  double decode_ns = 0;                                 // assembling with a decode into VertexRecords
  std::vector<std::vector<VertexRecord>> decoded;       // per tile, decoded
  std::vector<std::string> packed;                      // per tile, as the master keeps them
};

// Reprojection alone, offline, tile by tile as the master's reprojection thread calls it: process CPU
// and wall nanoseconds per vertex (median of `runs`). The process is otherwise idle here.
struct ReprojectCost {
  double cpu_ns = 0, wall_ns = 0;
};
ReprojectCost reprojection_cost(const std::string& backend, const std::string& spec, int size, int S,
                                const Synthetic& syn, int runs, bool packed) {
  const Scene scene = load_scene(spec);
  const Camera cam(scene.camera, size, size);
  std::unique_ptr<GlContext> gl;
  if (backend == "gl") gl = std::make_unique<GlContext>();
  const DeepFramebuffer dfb =
      gl ? build_deep_framebuffer_gl(*gl, scene, cam, S) : build_deep_framebuffer_cpu(scene, cam, S);
  ReprojectorSettings rs;
  rs.epsilon = default_epsilon(scene.bounds());
  auto r = make_reprojector(backend, cam, dfb, rs, gl.get());
  r->reproject(syn.decoded.front());  // warm-up (GL: shader compilation)
  (void)r->counts();
  const VertexCodec codec(scene.bounds());
  std::vector<double> cpu, wall;
  for (int i = 0; i < runs; ++i) {
    r->reset();
    const double c0 = process_cpu_seconds();
    const auto t0 = Clock::now();
    if (packed) {
      for (const auto& p : syn.packed) r->reproject_packed(p, codec);
    } else {
      for (const auto& v : syn.decoded) r->reproject(v);
    }
    (void)r->counts();  // GL: waits for the GPU work
    wall.push_back(since(t0));
    cpu.push_back(process_cpu_seconds() - c0);
  }
  std::sort(cpu.begin(), cpu.end());
  std::sort(wall.begin(), wall.end());
  return {1e9 * cpu[cpu.size() / 2] / double(syn.vertices), 1e9 * wall[wall.size() / 2] / double(syn.vertices)};
}

// Every tile of a size x size frame of `scene` traced once, k paths per pixel, with the worker's
// culling (kCull, S subpixels); with `pack`, the kept vertices are also encoded while tracing, as
// WorkerNode's TileRenderer does.
std::vector<TileResult> trace_all_tiles(const Scene& scene, int size, int S, int k, int tile_size, bool pack) {
  EmbreeScene es(scene);
  const Camera cam(scene.camera, size, size);
  PathTracer tracer(es, cam, 1, RussianRoulette::paper());
  VertexFilter filter;
  filter.mode = VertexFilter::Mode::kCull;
  filter.subpixels = S;
  const TileRenderer renderer = pack ? TileRenderer(tracer, filter, scene.bounds()) : TileRenderer(tracer, filter);
  const auto rects = make_tiles(size, size, tile_size);
  std::vector<TileResult> results(rects.size());
  tbb::parallel_for(size_t(0), rects.size(), [&](size_t t) { results[t] = renderer.render({rects[t], {}, {}, k}); });
  return results;
}

Synthetic make_tiles_once(const std::string& spec, int size, int S, int k, int tile_size,
                          const TileResultLimits& limits) {
  Synthetic syn;
  const Scene scene = load_scene(spec);
  std::vector<TileResult> traced = trace_all_tiles(scene, size, S, k, tile_size, false);
  const auto rects = make_tiles(size, size, tile_size);
  syn.tiles.resize(traced.size());
  for (size_t t = 0; t < traced.size(); ++t) syn.tiles[t].result = std::move(traced[t]);

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
      if (first)
        d.header = std::move(c);
      else
        d.body.push_back(std::move(c));
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
  double parse = 0, assemble = 0, decode = 0;
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
    // Decoding into VertexRecords (for the records path and the comparison).
    p0 = thread_cpu_seconds();
    TileResultAssembler a(e);
    for (const auto& c : parsed)
      if (auto err = a.add(c)) throw std::runtime_error("offline assembly: " + *err);
    AssembledTile tile = a.take();
    decode += thread_cpu_seconds() - p0;
    if (tile.vertices.size() != syn.tiles[t].vertices) throw std::runtime_error("offline assembly lost vertices");
    syn.decoded.push_back(std::move(tile.vertices));
    // As the master does it: packed, the batch's bytes moved out of the chunk.
    e.keep_packed = true;
    p0 = thread_cpu_seconds();
    TileResultAssembler b(std::move(e));
    for (auto& c : parsed)
      if (auto err = b.add(&c)) throw std::runtime_error("offline assembly: " + *err);
    AssembledTile kept = b.take();
    assemble += thread_cpu_seconds() - p0;
    if (kept.vertex_count() != syn.tiles[t].vertices) throw std::runtime_error("offline assembly lost vertices");
    syn.packed.push_back(std::move(kept.packed_vertices));
  }
  syn.decode_ns = 1e9 * decode / double(syn.vertices);
  syn.parse_ns = 1e9 * parse / double(syn.vertices);
  syn.assemble_ns = 1e9 * assemble / double(syn.vertices);
  return syn;
}

struct Figures {
  std::string backend;
  int clients = 0;
  uint64_t vertices = 0, tiles = 0;
  double t_recv = 0, t_proj = 0;    // seconds from the first lease
  double cpu = 0, cpu_clients = 0;  // master and bench-worker CPU seconds in the window
  double reproject = 0;             // reprojection thread seconds in the window
  double waits = 0;                 // Wait answers at round barriers
  double load = 0;
  uint64_t batch_records = 0;                // MasterOptions::reproject_batch_records
  double backlog = 0, closing = 0;           // seconds_round_backlog / _closing, summed over the rounds
  std::map<std::string, double> thread_cpu;  // master threads' CPU seconds in the window, by name
};

// ---- the bench workers' loop (threads of this process, or of the --serve-clients process) ---------

struct ClientTotals {
  uint64_t tiles = 0, waits = 0;
  double thread_cpu = 0;  // CPU seconds of the loop threads themselves (not gRPC's own threads)
};

// Leases and submits replayed tiles until `done`; each worker on its own thread.
ClientTotals client_loop(std::vector<std::unique_ptr<BenchWorker>>& workers, const std::vector<TileData>& tiles,
                         const std::atomic<bool>& done) {
  std::atomic<uint64_t> n_tiles{0}, n_waits{0};
  std::mutex mu;
  double cpu = 0;
  std::vector<std::thread> threads;
  for (auto& wp : workers)
    threads.emplace_back([&, w = wp.get()] {
      set_thread_name("bench-client");
      const double c0 = thread_cpu_seconds();
      while (!done) {
        auto l = w->lease();
        if (std::holds_alternative<uint32_t>(l)) {
          ++n_waits;
          std::this_thread::sleep_for(std::chrono::milliseconds(1));
          continue;
        }
        const v1::TileLease& lease = std::get<v1::TileLease>(l);
        const TileData& d = tiles.at(lease.tile_index());
        v1::TileResultChunk header = d.header;
        auto* h = header.mutable_header();
        h->set_lease_id(lease.lease_id());
        h->set_job_id(lease.job_id());
        h->set_round(lease.round());
        h->set_tile_index(lease.tile_index());
        h->mutable_worker_id()->set_id(w->id());
        const v1::SubmitAck ack = w->submit(header, d.body);
        if (!ack.accepted()) std::fprintf(stderr, "tile not committed: %s\n", ack.reason().c_str());
        ++n_tiles;
      }
      std::lock_guard lock(mu);
      cpu += thread_cpu_seconds() - c0;
    });
  for (auto& t : threads) t.join();
  return {n_tiles, n_waits, cpu};
}

// The synthetic tiles as a file: per tile its chunk count, then each chunk as length + bytes.
void save_tiles(const std::string& path, const Synthetic& syn) {
  std::ofstream out(path, std::ios::binary);
  auto put32 = [&](uint32_t v) { out.write(reinterpret_cast<const char*>(&v), 4); };
  put32(uint32_t(syn.tiles.size()));
  for (const TileData& d : syn.tiles) {
    put32(uint32_t(1 + d.body.size()));
    for (size_t i = 0; i <= d.body.size(); ++i) {
      const std::string b = (i == 0 ? d.header : d.body[i - 1]).SerializeAsString();
      put32(uint32_t(b.size()));
      out.write(b.data(), std::streamsize(b.size()));
    }
  }
  if (!out) throw std::runtime_error("cannot write " + path);
}

std::vector<TileData> load_tiles(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  auto get32 = [&] {
    uint32_t v = 0;
    in.read(reinterpret_cast<char*>(&v), 4);
    if (!in) throw std::runtime_error("truncated " + path);
    return v;
  };
  std::vector<TileData> tiles(get32());
  for (TileData& d : tiles) {
    const uint32_t chunks = get32();
    for (uint32_t i = 0; i < chunks; ++i) {
      std::string b(get32(), '\0');
      in.read(b.data(), std::streamsize(b.size()));
      v1::TileResultChunk c;
      if (!in || !c.ParseFromString(b)) throw std::runtime_error("bad chunk in " + path);
      if (i == 0)
        d.header = std::move(c);
      else
        d.body.push_back(std::move(c));
    }
  }
  return tiles;
}

// --serve-clients: registers `clients` bench workers, says "ready", replays tiles until its stdin
// closes, then prints "cpu SECONDS tiles N waits N" (process CPU from "ready" on).
int serve_clients(const std::string& file, const std::string& target, int clients) {
  const std::vector<TileData> tiles = load_tiles(file);
  std::vector<std::unique_ptr<BenchWorker>> workers;
  for (int i = 0; i < clients; ++i)
    workers.push_back(std::make_unique<BenchWorker>(target, "bench-" + std::to_string(i), 1));
  std::atomic<bool> done{false};
  std::thread stdin_watch([&] {
    char buf[64];
    while (::read(0, buf, sizeof buf) > 0) {
    }
    done = true;
  });
  const double c0 = process_cpu_seconds();
  std::printf("ready\n");
  std::fflush(stdout);
  const ClientTotals t = client_loop(workers, tiles, done);
  stdin_watch.join();
  std::printf("cpu %.6f tiles %llu waits %llu\n", process_cpu_seconds() - c0, (unsigned long long)t.tiles,
              (unsigned long long)t.waits);
  std::fflush(stdout);
  return 0;
}

// The bench workers as a child process (this program with --serve-clients).
class ClientProcess {
 public:
  ClientProcess(const std::string& self, const std::string& file, const std::string& target, int clients,
                const std::string& cpus) {
    int in[2], out[2];
    if (::pipe(in) != 0 || ::pipe(out) != 0) throw std::runtime_error("pipe failed");
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_adddup2(&fa, in[0], 0);
    posix_spawn_file_actions_adddup2(&fa, out[1], 1);
    posix_spawn_file_actions_addclose(&fa, in[1]);
    posix_spawn_file_actions_addclose(&fa, out[0]);
    const std::string n = std::to_string(clients);
    std::vector<std::string> args = {self, "--serve-clients", file, "--target", target, "--clients", n};
    std::vector<char*> argv;
    for (auto& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    if (posix_spawn(&pid_, self.c_str(), &fa, nullptr, argv.data(), environ) != 0)
      throw std::runtime_error("cannot start " + self);
    posix_spawn_file_actions_destroy(&fa);
    if (!cpus.empty()) {  // before it prints "ready", i.e. before its gRPC threads exist
      const cpu_set_t set = parse_cpus(cpus);
      if (::sched_setaffinity(pid_, sizeof set, &set) != 0) throw std::runtime_error("cannot pin the clients");
    }
    ::close(in[0]);
    ::close(out[1]);
    to_child_ = in[1];
    from_child_ = ::fdopen(out[0], "r");
    if (line().rfind("ready", 0) != 0) throw std::runtime_error("the client process did not start");
  }
  ~ClientProcess() {
    if (to_child_ >= 0) ::close(to_child_);
    if (from_child_) std::fclose(from_child_);
    if (pid_ > 0) ::waitpid(pid_, nullptr, 0);
  }
  /// Stops the clients; their CPU seconds and counts.
  std::pair<double, ClientTotals> finish() {
    ::close(to_child_);
    to_child_ = -1;
    const std::string l = line();
    double cpu = 0;
    unsigned long long tiles = 0, waits = 0;
    if (std::sscanf(l.c_str(), "cpu %lf tiles %llu waits %llu", &cpu, &tiles, &waits) != 3)
      throw std::runtime_error("unexpected client report: " + l);
    ::waitpid(pid_, nullptr, 0);
    pid_ = -1;
    return {cpu, {tiles, waits}};
  }

 private:
  std::string line() {
    char buf[256];
    if (!std::fgets(buf, sizeof buf, from_child_)) return "";
    return buf;
  }
  pid_t pid_ = -1;
  int to_child_ = -1;
  FILE* from_child_ = nullptr;
};

struct RunSetup {
  std::string spec;
  int size = 512, S = 4, k = 1, rounds = 16, tile = 64;
  bool in_process = false;
  std::string self, tiles_file, client_cpus;
};

Figures run_job(MasterServer& master, const RunSetup& rs, ReprojectMethod method, int clients, const Synthetic& syn) {
  Figures f;
  f.backend = to_string(method);
  f.clients = clients;
  RenderOptions o;
  o.scene = rs.spec;
  o.width = o.height = rs.size;
  o.subpixels = rs.S;
  o.mode = RenderMode::kReproject;
  o.reproject = method;
  o.spp = (rs.rounds + 1) * rs.k;  // round 0: warm-up
  o.paths_per_round = rs.k;
  o.round_growth = 0;  // the same synthetic round, again and again
  o.tile_size = rs.tile;
  o.seed = 1;
  std::unique_ptr<ClientProcess> child;
  std::vector<std::unique_ptr<BenchWorker>> workers;
  if (rs.in_process) {
    for (int i = 0; i < clients; ++i)
      workers.push_back(std::make_unique<BenchWorker>(master.local_target(), "bench-" + std::to_string(i), 1));
  } else {
    child = std::make_unique<ClientProcess>(rs.self, rs.tiles_file, master.local_target(), clients, rs.client_cpus);
  }
  JobClient client(master.local_target());
  const std::string id = client.submit(o);
  JobManager& jobs = master.jobs();
  std::atomic<bool> done{false};
  ClientTotals in_process_totals;
  std::thread in_process_clients;
  if (rs.in_process)
    in_process_clients = std::thread([&] { in_process_totals = client_loop(workers, syn.tiles, done); });
  // Round 0 is a warm-up: the job's set-up (scene, deep framebuffer; a master may build the frame
  // while round 0 is traced) stays out of the window, which starts when round 1 opens.
  JobSnapshot s0;
  for (;;) {
    auto s = jobs.get(id);
    if (!s) throw std::runtime_error("job vanished");
    if (s->state == JobState::kRunning && s->progress.round >= 1) {
      s0 = *s;
      break;
    }
    if (s->state != JobState::kQueued && s->state != JobState::kRunning)
      throw std::runtime_error("job did not run: " + s->error);
    std::this_thread::sleep_for(std::chrono::microseconds(200));
  }
  const auto threads0 = thread_cpu_by_name();
  const double cpu0 = process_cpu_seconds();
  const auto t0 = Clock::now();
  const uint64_t total = uint64_t(rs.rounds + 1) * syn.vertices;  // the warm-up's included
  f.vertices = uint64_t(rs.rounds) * syn.vertices;                // in the window

  // Monitor: when did the master receive, and reproject, everything?
  double reproject1 = 0, cpu1 = 0;
  for (;;) {
    auto s = jobs.get(id);
    if (!s) throw std::runtime_error("job vanished");
    if (!f.t_recv && s->counters.vertices_received >= total) f.t_recv = since(t0);
    if (!f.t_proj && s->counts.total() >= total) {
      f.t_proj = since(t0);
      cpu1 = process_cpu_seconds();
      reproject1 = s->counters.seconds_reprojecting;
      f.thread_cpu = thread_cpu_by_name();
      for (const auto& [name, c] : threads0) f.thread_cpu[name] -= c;
      f.backlog = s->seconds_round_backlog - s0.seconds_round_backlog;
      f.closing = s->seconds_round_closing - s0.seconds_round_closing;
    }
    if (is_terminal(s->state)) {
      if (s->state != JobState::kDone)
        throw std::runtime_error("job ended " + std::string(to_string(s->state)) + ": " + s->error);
      if (!f.t_proj) throw std::runtime_error("job done before all vertices were counted");
      break;
    }
    std::this_thread::sleep_for(std::chrono::microseconds(500));
  }
  done = true;
  if (rs.in_process) {
    in_process_clients.join();
    // The rest of the process is the master.
    f.cpu_clients = f.thread_cpu["bench-client"];
    f.cpu = cpu1 - cpu0 - f.cpu_clients;
    f.tiles = in_process_totals.tiles;
    f.waits = double(in_process_totals.waits);
  } else {
    const auto [cpu, totals] = child->finish();
    f.cpu = cpu1 - cpu0;  // this process is the master (and the 0.5 ms status poll above)
    f.cpu_clients = cpu;  // from the child's "ready" to its end: a little more than the window
    f.tiles = totals.tiles;
    f.waits = double(totals.waits);
  }
  f.reproject = reproject1 - s0.counters.seconds_reprojecting;
  f.load = load_average();
  return f;
}

// The worker's vertex path from the traced records to the chunks handed to gRPC, offline, one thread,
// `reps` times over every tile of one synthetic round (median thread CPU per vertex sent):
//   codec   VertexCodec::encode_batch over each tile's culled records (the arithmetic alone)
//   writer  TileResultWriter from the records: encode, then chunking, until every chunk is out
// and the path WorkerNode takes since the vertices are encoded while tracing:
//   in-render  encode_batch appending TileRenderer::kEncodeBatch records at a time to the tile's
//              string, as TileRenderer does once that many kept records have gathered
//   packed     TileResultWriter from a TileResult the renderer packed: chunking and one copy
// The packed tiles (traced again with codec bounds) must give the writer's bytes exactly; checked.
void encode_microbench(const std::string& spec, int size, int S, int k, int tile_size, int reps) {
  const Scene scene = load_scene(spec);
  const std::vector<TileResult> results = trace_all_tiles(scene, size, S, k, tile_size, false);
  uint64_t vertices = 0;
  for (const TileResult& r : results) vertices += r.vertices.size();
  const VertexCodec codec(scene.bounds());
  const TileResultLimits limits;
  const std::vector<TileResult> packed_results = trace_all_tiles(scene, size, S, k, tile_size, true);
  for (size_t t = 0; t < results.size(); ++t) {
    auto a = split_tile_result(results[t], {1, "bench", 0, uint32_t(t), "bench"}, scene.bounds(), limits);
    auto b = split_tile_result(packed_results[t], {1, "bench", 0, uint32_t(t), "bench"}, scene.bounds(), limits);
    for (auto* chunks : {&a, &b})  // the tracing wall time is the one field that may differ
      chunks->back().mutable_trailer()->mutable_stats()->set_seconds_tracing(0);
    bool same = a.size() == b.size();
    for (size_t i = 0; same && i < a.size(); ++i) same = a[i].SerializeAsString() == b[i].SerializeAsString();
    if (!same) throw std::runtime_error("tile " + std::to_string(t) + ": packed while tracing != encoded after");
  }
  std::vector<double> codec_ns, writer_ns, inrender_ns, packed_ns;
  uint64_t sink = 0;
  // Thread CPU per vertex of writing every tile of `tiles` into its SubmitTile chunks.
  const auto writer_pass = [&](const std::vector<TileResult>& tiles) {
    const double c0 = thread_cpu_seconds();
    for (size_t t = 0; t < tiles.size(); ++t) {
      TileResultWriter w(tiles[t], {1, "bench", 0, uint32_t(t), "bench"}, scene.bounds(), limits);
      v1::TileResultChunk c;
      while (w.next(&c)) {
        if (c.has_vertices()) sink += c.vertices().packed().size();
        c.Clear();
      }
    }
    return 1e9 * (thread_cpu_seconds() - c0) / double(vertices);
  };
  for (int rep = 0; rep < reps; ++rep) {
    double c0 = thread_cpu_seconds();
    for (const TileResult& r : results) {
      std::string packed;
      codec.encode_batch(r.vertices, &packed);
      sink += packed.size();
    }
    codec_ns.push_back(1e9 * (thread_cpu_seconds() - c0) / double(vertices));
    writer_ns.push_back(writer_pass(results));
    c0 = thread_cpu_seconds();
    for (const TileResult& r : results) {
      std::string packed;
      EncodeCounts counts;
      const std::span<const VertexRecord> all(r.vertices);
      for (size_t i = 0; i < all.size(); i += TileRenderer::kEncodeBatch)
        codec.encode_batch(all.subspan(i, std::min(TileRenderer::kEncodeBatch, all.size() - i)), &packed, &counts);
      sink += packed.size();
    }
    inrender_ns.push_back(1e9 * (thread_cpu_seconds() - c0) / double(vertices));
    packed_ns.push_back(writer_pass(packed_results));
  }
  auto med = [](std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v[v.size() / 2];
  };
  std::printf(
      "encode microbench: %zu tiles, %llu vertices sent, %d reps, load %.2f: thread CPU per vertex (median): "
      "codec %.1f ns, writer from records %.1f ns; encoding while tracing: in-render encode %.1f ns + writer "
      "from packed %.1f ns = %.1f ns (bytes identical; checksum %llu); minima: codec %.1f, writer %.1f, "
      "in-render %.1f + packed %.1f ns\n",
      results.size(), (unsigned long long)vertices, reps, load_average(), med(codec_ns), med(writer_ns),
      med(inrender_ns), med(packed_ns), med(inrender_ns) + med(packed_ns), (unsigned long long)sink,
      *std::min_element(codec_ns.begin(), codec_ns.end()), *std::min_element(writer_ns.begin(), writer_ns.end()),
      *std::min_element(inrender_ns.begin(), inrender_ns.end()), *std::min_element(packed_ns.begin(), packed_ns.end()));
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Master ingestion over loopback gRPC with synthetic workers"};
  RunSetup rs;
  rs.spec = "builtin:cornell";
  rs.tile = RenderOptions{}.tile_size;
  std::vector<std::string> backends = {"cpu", "gl"};
  std::vector<int> client_counts = {1, 2};
  std::string serve_file, target;
  bool checkpoints = false;
  std::vector<uint64_t> batch_values = {MasterOptions{}.reproject_batch_records};
  std::string master_cpus;
  app.add_option("--scene", rs.spec);
  app.add_option("--size", rs.size, "image side, pixels");
  app.add_option("-S,--subpixels", rs.S);
  app.add_option("--paths", rs.k, "paths per pixel and round (k) of the synthetic tiles");
  app.add_option("--rounds", rs.rounds, "rounds per job");
  app.add_option("--tile", rs.tile, "tile size, pixels");
  app.add_option("--backends", backends, "reprojectors: cpu, gl")->delimiter(',');
  app.add_option("--clients", client_counts, "bench workers (gRPC channels, one thread each)")->delimiter(',');
  app.add_flag("--in-process", rs.in_process, "run the bench workers as threads of this process");
  app.add_flag("--checkpoints", checkpoints, "checkpoint every round as a master with --state-dir does");
  app.add_option("--batch-records", batch_values,
                 "the series once per value of the master's reproject_batch_records (0: one call per tile)")
      ->delimiter(',');
  app.add_option("--master-cpus", master_cpus, "pin this process (the master) to these CPUs, e.g. 0 or 0-1");
  app.add_option("--client-cpus", rs.client_cpus, "pin the bench workers' process to these CPUs");
  app.add_option("--serve-clients", serve_file, "(internal) be the bench workers' process");
  app.add_option("--target", target, "(internal) the master's address");
  int encode_reps = 0;
  app.add_option("--encode-reps", encode_reps, "only the worker's encode microbenchmark, this many repetitions");
  CLI11_PARSE(app, argc, argv);
  set_log_level("warn");
  if (!serve_file.empty()) return serve_clients(serve_file, target, client_counts.front());
  rs.self = std::filesystem::canonical("/proc/self/exe").string();
  if (!master_cpus.empty()) {  // before TBB, gRPC or OSMesa start a thread: they all inherit it
    const cpu_set_t set = parse_cpus(master_cpus);
    if (::sched_setaffinity(0, sizeof set, &set) != 0) throw std::runtime_error("cannot pin the master");
  }
  if (encode_reps > 0) {
    encode_microbench(rs.spec, rs.size, rs.S, rs.k, rs.tile, encode_reps);
    return 0;
  }

  std::printf(
      "ingest_bench: %s %dx%d S=%d, k=%d paths/pixel/round, %d rounds per job, tiles %dx%d, clients %s, %u "
      "hardware threads, master on CPUs %s, clients on %s, load average %.2f\n",
      rs.spec.c_str(), rs.size, rs.size, rs.S, rs.k, rs.rounds, rs.tile, rs.tile,
      rs.in_process ? "in this process" : "in a separate process", std::thread::hardware_concurrency(),
      master_cpus.empty() ? "(any)" : master_cpus.c_str(), rs.client_cpus.empty() ? "(any)" : rs.client_cpus.c_str(),
      load_average());
  std::fflush(stdout);
  const auto tsyn = Clock::now();
  Synthetic syn = make_tiles_once(rs.spec, rs.size, rs.S, rs.k, rs.tile, TileResultLimits{});
  for (const auto& e : std::filesystem::directory_iterator("/proc/self/task"))
    if (e.path().filename() != std::to_string(::getpid())) tbb_threads.insert(e.path().filename());
  std::printf(
      "synthetic round: %zu tiles, %.3g paths, %.3g vertices recorded, %.3g sent (%.2f per pixel, %.0f per "
      "tile); made in %.1f s\n",
      syn.tiles.size(), double(syn.paths), double(syn.recorded), double(syn.vertices),
      double(syn.vertices) / (double(rs.size) * rs.size), double(syn.vertices) / double(syn.tiles.size()), since(tsyn));
  std::printf(
      "wire: %.2f bytes/vertex for whole tile results (pixels, header, trailer included), %.2f for the "
      "vertex batches alone\n",
      double(syn.bytes) / double(syn.vertices), double(syn.vertex_bytes) / double(syn.vertices));
  std::printf(
      "offline, one thread, CPU time per vertex: worker encode (TileResultWriter) %.1f ns; master protobuf "
      "parse %.1f ns, assemble (TileResultAssembler, vertices kept packed) %.1f ns (decoding into "
      "VertexRecords instead: %.1f ns)\n",
      syn.encode_ns, syn.parse_ns, syn.assemble_ns, syn.decode_ns);
  std::map<std::string, ReprojectCost> rcost;
  for (const std::string& b : backends) {
    rcost[b] = reprojection_cost(b, rs.spec, rs.size, rs.S, syn, 5, /*packed=*/true);
    const ReprojectCost rec = reprojection_cost(b, rs.spec, rs.size, rs.S, syn, 5, /*packed=*/false);
    std::printf(
        "offline reprojection (%s, per-tile calls as on the master): packed %.1f ns/vertex process CPU, %.1f ns "
        "wall (%.1f M/s); decoded records %.1f ns CPU, %.1f ns wall\n",
        b.c_str(), rcost[b].cpu_ns, rcost[b].wall_ns, 1e3 / rcost[b].wall_ns, rec.cpu_ns, rec.wall_ns);
  }
  std::fflush(stdout);

  const std::string state_dir =
      (std::filesystem::temp_directory_path() / ("ingest_bench_" + std::to_string(::getpid()))).string();
  std::filesystem::create_directories(state_dir);
  rs.tiles_file = state_dir + "/tiles.bin";
  if (!rs.in_process) save_tiles(rs.tiles_file, syn);
  std::vector<Figures> all;
  for (const uint64_t batch : batch_values) {
    MasterServerOptions mo;
    mo.listen = "127.0.0.1:0";
    mo.jobs.state_dir = state_dir + "/master";
    mo.jobs.checkpoints = checkpoints;  // ingestion alone unless asked: a checkpoint is per round, not per vertex
    mo.jobs.reproject_batch_records = batch;
    MasterServer master(mo);
    for (int i = 0; i < 200 && !master.jobs().gl_ready(); ++i)
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    for (const std::string& b : backends) {
      const ReprojectMethod m = b == "gl" ? ReprojectMethod::kGl : ReprojectMethod::kCpu;
      if (m == ReprojectMethod::kGl && !master.jobs().gl_ready()) {
        std::printf("(no OSMesa context: gl skipped)\n");
        continue;
      }
      for (int c : client_counts) {
        all.push_back(run_job(master, rs, m, c, syn));
        Figures& f = all.back();
        f.batch_records = batch;
        std::printf(
            "  %s, batch %llu, %d client(s): %.3g vertices in %.2f s (%.2f M/s reprojected), master %.2f CPU-s "
            "(%.0f ns/vertex), clients %.2f CPU-s, round backlog %.1f ms, closing %.1f ms per round, load %.2f\n   "
            " master threads, ns/vertex:",
            f.backend.c_str(), (unsigned long long)batch, f.clients, double(f.vertices), f.t_proj,
            f.vertices / f.t_proj / 1e6, f.cpu, 1e9 * f.cpu / double(f.vertices), f.cpu_clients,
            1e3 * f.backlog / rs.rounds, 1e3 * f.closing / rs.rounds, f.load);
        for (const auto& [name, c] : f.thread_cpu)
          if (c > 0) std::printf(" %s %.1f", name.c_str(), 1e9 * c / double(f.vertices));
        std::printf("\n");
        std::fflush(stdout);
      }
    }
    master.shutdown();
  }
  std::filesystem::remove_all(state_dir);

  std::printf("\n%-4s %7s %3s | %9s %9s | %8s %8s %8s | %9s %9s | %7s %7s %7s %7s | %7s %6s %7s\n", "rp", "batch",
              "cli", "recv M/s", "reproj M/s", "master", "ns/vert", "clients", "M/mst-CPU", "M/CPU", "reproj", "parse",
              "assmbl", "other", "rp busy", "waits", "load");
  for (const Figures& f : all) {
    const double v = double(f.vertices);
    const double master_cpu = f.cpu;
    const double parse = syn.parse_ns * 1e-9 * v, assemble = syn.assemble_ns * 1e-9 * v;
    const double reproj = rcost[f.backend].cpu_ns * 1e-9 * v;
    const double other = master_cpu - reproj - parse - assemble;
    std::printf(
        "%-4s %7llu %3d | %9.2f %9.2f | %8.2f %8.0f %8.2f | %9.2f %9.2f | %6.0f%% %6.0f%% %6.0f%% %6.0f%% | %6.0f%% "
        "%6.0f %7.2f\n",
        f.backend.c_str(), (unsigned long long)f.batch_records, f.clients, v / f.t_recv / 1e6, v / f.t_proj / 1e6,
        master_cpu, 1e9 * master_cpu / v, f.cpu_clients, v / master_cpu / 1e6, v / (master_cpu + f.cpu_clients) / 1e6,
        100 * reproj / master_cpu, 100 * parse / master_cpu, 100 * assemble / master_cpu, 100 * other / master_cpu,
        100 * f.reproject / f.t_proj, f.waits, f.load);
  }
  std::printf(
      "(recv / reproj: vertices per wall second until the master had received / reprojected all of them, "
      "bar >= 10 M/s reprojected; master: the master's CPU seconds in that window (%s), ns/vert per vertex; "
      "clients: the bench workers' CPU seconds; M/mst-CPU: vertices per master CPU-second; M/CPU: per CPU-second "
      "of master and clients together; reproj/parse/assmbl/other: share of master CPU -- reproj, parse and "
      "assmbl are the offline per-vertex CPU costs x vertices, other = the rest (gRPC transport on the master, "
      "loopback TCP, wake-ups, job manager, this bench's 0.5 ms status polling); rp busy: the reprojection "
      "thread's wall time in the reprojector over the window; waits: Wait answers at round barriers)\n",
      rs.in_process ? "process CPU minus the bench threads' own CPU; their gRPC client threads count here"
                    : "this process's CPU; the clients run in another process");
  return 0;
}
