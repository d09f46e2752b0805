// A bounded load test on loopback: the real epr-master process (limits set by its --max-* flags),
// 16 client threads each submitting a job and watching it to the end (plus status, list and refused
// calls), jobs queued behind one another, and in-process WorkerNodes joining and leaving all along.
// Every call must succeed within a generous deadline, every job must finish with the same per-pixel
// counts and path-traced sums as the single-process render, and the master's peak RSS (VmHWM) must
// stay under a generous bound computed from the image sizes and the number of jobs.
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <atomic>
#include <deque>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <regex>
#include <thread>

#include "client/local_render.h"
#include "common/image.h"
#include "epr/v1/job_service.grpc.pb.h"
#include "tests/integration/cluster/process.h"
#include "tests/job_results.h"
#include "tests/running_node.h"
#include "wire/convert.h"
#include "wire/scene_bundle.h"
#include "worker/worker_node.h"

namespace epr {
namespace {
namespace fs = std::filesystem;
using test::RunningNode;
using namespace std::chrono_literals;
using epr::testing::Process;
using epr::testing::wait_until;

constexpr int kClients = 16;
constexpr auto kCallDeadline = 30s;  // generous: the machine is shared and slow
constexpr auto kWatchDeadline = 120s;

// Peak resident set of a process, bytes (VmHWM of /proc/PID/status).
uint64_t peak_rss_bytes(pid_t pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/status");
  std::string line;
  while (std::getline(in, line))
    if (line.rfind("VmHWM:", 0) == 0) return std::stoull(line.substr(6)) * 1024;
  return 0;
}

RenderOptions job_options(int j) {
  RenderOptions o;
  o.width = 48 + 16 * (j % 4);
  o.height = 48 + 16 * ((j / 4) % 2);
  o.spp = 4;
  o.paths_per_round = 2;
  o.mode = j % 2 ? RenderMode::kReproject : RenderMode::kSkip;
  o.reproject = ReprojectMethod::kCpu;
  o.tile_size = 16;
  o.seed = uint64_t(1000 + j);
  o.scene = "builtin:cornell";
  return o;
}

TEST(LoadTest, ManyClientsQueuedJobsAndChurningWorkers) {
  const fs::path dir = fs::path(::testing::TempDir()) / ("epr-load-" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  Process master(
      {EPR_MASTER_BIN, "--listen", "127.0.0.1:0", "--http", "", "--state-dir", (dir / "state").string(), "--reproject",
       "cpu", "--log-level", "warn", "--max-image-side", "128", "--max-spp", "64", "--heartbeat-ms", "300"},
      dir / "master");
  std::smatch m;
  std::string err;
  const std::regex listening("epr-master listening on port ([0-9]+)");
  ASSERT_TRUE(
      wait_until([&] { return std::regex_search(err = master.err(), m, listening) || !master.running(); }, 20s) &&
      master.running())
      << "epr-master did not start:\n"
      << err;
  const std::string target = "127.0.0.1:" + m[1].str();

  // Workers join and leave until every job is done (each leaving one gives its leases back).
  std::atomic<bool> all_done{false};
  std::atomic<int> nodes_started{0};
  std::thread churn([&] {
    std::deque<std::unique_ptr<RunningNode>> nodes;
    while (!all_done) {
      WorkerNodeOptions o;
      o.master = target;
      o.threads = 1;
      o.name = "load-" + std::to_string(nodes_started);
      o.cache_dir = (dir / "cache").string();
      o.max_backoff_ms = 300;
      nodes.push_back(std::make_unique<RunningNode>(o));
      ++nodes_started;
      if (nodes.size() > 3) nodes.pop_front();
      for (int i = 0; i < 40 && !all_done; ++i) std::this_thread::sleep_for(10ms);
    }
  });

  std::atomic<int> failed_calls{0}, calls{0}, statuses_streamed{0};
  std::mutex mu;
  std::vector<std::string> errors;
  std::vector<std::string> ids(kClients);
  auto failed = [&](const std::string& what, const grpc::Status& st) {
    ++failed_calls;
    std::lock_guard lock(mu);
    errors.push_back(what + ": " + std::to_string(int(st.error_code())) + " " + st.error_message());
  };
  auto deadline = [](grpc::ClientContext& ctx, auto d) { ctx.set_deadline(std::chrono::system_clock::now() + d); };

  std::vector<std::thread> clients;
  for (int c = 0; c < kClients; ++c) {
    clients.emplace_back([&, c] {
      grpc::ChannelArguments args;
      args.SetInt("grpc.use_local_subchannel_pool", 1);  // one connection per client, like separate programs
      auto stub = v1::JobService::NewStub(grpc::CreateCustomChannel(target, grpc::InsecureChannelCredentials(), args));
      const RenderOptions o = job_options(c);
      v1::JobSpec spec = to_job_spec(o, bundle_scene(o.scene), CameraSpec{});
      spec.set_request_id("load-" + std::to_string(c));
      {
        grpc::ClientContext ctx;
        deadline(ctx, kCallDeadline);
        // The first call opens the client's connection; a connection attempt that fails while the
        // machine is loaded is retried within the deadline instead of failing the call at once.
        ctx.set_wait_for_ready(true);
        v1::JobId id;
        ++calls;
        const grpc::Status st = stub->SubmitJob(&ctx, spec, &id);
        if (!st.ok()) return failed("SubmitJob", st);
        ids[size_t(c)] = id.id();
      }
      if (c % 4 == 0) {
        // A job over the master's --max-image-side is refused with the limit.
        v1::JobSpec big = spec;
        big.set_width(256);
        big.clear_request_id();
        grpc::ClientContext ctx;
        deadline(ctx, kCallDeadline);
        v1::JobId id;
        ++calls;
        const grpc::Status st = stub->SubmitJob(&ctx, big, &id);
        if (st.error_code() != grpc::StatusCode::INVALID_ARGUMENT ||
            st.error_message().find("limited to 128") == std::string::npos)
          failed("oversized SubmitJob was not refused with the limit", st);
      }
      {
        grpc::ClientContext ctx;
        deadline(ctx, kWatchDeadline);
        v1::WatchJobRequest req;
        req.set_job_id(ids[size_t(c)]);
        req.set_min_interval_ms(50);
        ++calls;
        auto reader = stub->WatchJob(&ctx, req);
        v1::JobStatus s;
        while (reader->Read(&s)) {
          ++statuses_streamed;
          if (c % 2 == 0) {
            // Status and list calls while jobs run.
            grpc::ClientContext lctx;
            deadline(lctx, kCallDeadline);
            v1::ListJobsRequest lreq;
            v1::ListJobsResponse lresp;
            ++calls;
            if (const grpc::Status st = stub->ListJobs(&lctx, lreq, &lresp); !st.ok()) failed("ListJobs", st);
          }
        }
        if (const grpc::Status st = reader->Finish(); !st.ok()) failed("WatchJob", st);
        if (s.state() != v1::JOB_STATE_DONE) {
          std::lock_guard lock(mu);
          errors.push_back("job " + s.id() + " ended " + std::to_string(int(s.state())) + ": " + s.error_message());
          ++failed_calls;
        }
      }
    });
  }
  for (auto& t : clients) t.join();
  all_done = true;
  churn.join();
  const uint64_t peak = peak_rss_bytes(master.pid());

  EXPECT_EQ(failed_calls, 0) << [&] {
    std::string all;
    for (const auto& e : errors) all += e + "\n";
    return all;
  }();
  EXPECT_GE(nodes_started, 2);
  EXPECT_GE(statuses_streamed, kClients);

  // Every job equals the single-process render.
  auto stub = v1::JobService::NewStub(grpc::CreateChannel(target, grpc::InsecureChannelCredentials()));
  auto fetch = [&](const std::string& id, v1::ResultKind kind) {
    const fs::path p = dir / (id + "-" + std::to_string(int(kind)) + ".exr");
    return test::fetch_result_image(*stub, id, kind, kCallDeadline, p.string());
  };
  uint64_t pixels = 0;
  for (int c = 0; c < kClients; ++c) {
    const RenderOptions o = job_options(c);
    pixels += uint64_t(o.width) * uint64_t(o.height);
    if (ids[size_t(c)].empty()) continue;
    const RenderOutputs local = render_local(o);
    EXPECT_EQ(fetch(ids[size_t(c)], v1::RESULT_KIND_COUNTS_EXR).data, local.counts.data) << "job " << c;
    EXPECT_EQ(fetch(ids[size_t(c)], v1::RESULT_KIND_PATH_TRACED_EXR).data, local.pathtrace.data) << "job " << c;
  }

  // Generous: the process's fixed cost plus 4 KiB per pixel of every job (a running job's deep
  // framebuffer and images take a few hundred bytes per pixel; finished jobs keep only their previews).
  const uint64_t bound = (256ull << 20) + pixels * (4u << 10);
  std::printf("epr-master peak RSS %.1f MiB (bound %.1f MiB) for %d jobs, %llu pixels in all, %d worker nodes\n",
              double(peak) / (1 << 20), double(bound) / (1 << 20), kClients, (unsigned long long)pixels,
              nodes_started.load());
  EXPECT_GT(peak, 0u);
  EXPECT_LT(peak, bound);
  master.stop();
  fs::remove_all(dir);
}

}  // namespace
}  // namespace epr
