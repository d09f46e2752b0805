// WorkerNodes against a real in-process MasterServer over loopback gRPC (no fakes): whole jobs give
// the same per-pixel counts and path-traced sums as the single-process render whatever the number of
// workers; file scenes are fetched once and then served from the disk cache; a worker that starts
// before its master, or whose master restarts, registers (again) by itself; stop() gives the leases
// back so another worker finishes the job with nothing lost or counted twice.
#include "worker/worker_node.h"

#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>
#include <spdlog/sinks/base_sink.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <future>
#include <mutex>
#include <optional>
#include <string>
#include <thread>

#include "client/local_render.h"
#include "common/image.h"
#include "common/log.h"
#include "epr/v1/job_service.grpc.pb.h"
#include "master/server/master_server.h"
#include "tests/job_results.h"
#include "tests/running_node.h"
#include "tests/wait_until.h"
#include "wire/convert.h"
#include "wire/scene_bundle.h"

namespace epr {
namespace {
namespace fs = std::filesystem;
using namespace std::chrono_literals;

using test::RunningNode;
using test::wait_until;

const std::string kCornellObj = EPR_SOURCE_DIR "/scenes/cornell-box/CornellBox-Original.obj";

// Counts the warnings (and worse) of one component's logger whose message names `what`, from
// construction to destruction. Attach before the code that logs starts its threads.
class WarningsAbout {
 public:
  WarningsAbout(const std::string& component, std::string what)
      : logger_(logger(component)), sink_(std::make_shared<Sink>(std::move(what))) {
    logger_->sinks().push_back(sink_);
  }
  ~WarningsAbout() {
    auto& sinks = logger_->sinks();
    sinks.erase(std::remove(sinks.begin(), sinks.end(), sink_), sinks.end());
  }
  WarningsAbout(const WarningsAbout&) = delete;
  WarningsAbout& operator=(const WarningsAbout&) = delete;
  int count() const { return sink_->count(); }

 private:
  class Sink : public spdlog::sinks::base_sink<std::mutex> {
   public:
    explicit Sink(std::string what) : what_(std::move(what)) {}
    int count() {
      std::lock_guard lock(base_sink<std::mutex>::mutex_);
      return count_;
    }

   protected:
    void sink_it_(const spdlog::details::log_msg& msg) override {
      if (msg.level >= spdlog::level::warn &&
          std::string_view(msg.payload.data(), msg.payload.size()).find(what_) != std::string_view::npos)
        ++count_;
    }
    void flush_() override {}

   private:
    const std::string what_;
    int count_ = 0;
  };

  std::shared_ptr<spdlog::logger> logger_;
  std::shared_ptr<Sink> sink_;
};

class WorkerNodeTest : public ::testing::Test {
 protected:
  void SetUp() override {
    cache_ = fs::path(::testing::TempDir()) / ("epr-worker-node-" + std::to_string(::getpid()) + "-" +
                                               ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(cache_);
    start_master("127.0.0.1:0");
  }
  void TearDown() override {
    if (master_) master_->shutdown();
    fs::remove_all(cache_);
  }

  // lease_timeout_ms: how long a lease that is neither extended nor returned stays out;
  // heartbeat_interval_ms: asked of the workers, whose heartbeat call may take twice as long (2 to 10 s);
  // speculative: copies of tiles whose lease runs long.
  void start_master(const std::string& listen, int lease_timeout_ms = 20000, int heartbeat_interval_ms = 1000,
                    bool speculative = true) {
    if (master_) master_->shutdown();
    MasterServerOptions o;
    o.listen = listen;
    o.jobs.lease_timeout_ms = lease_timeout_ms;
    o.jobs.heartbeat_interval_ms = heartbeat_interval_ms;
    if (!speculative) o.jobs.speculative_factor = 0;
    o.jobs.worker_timeout_ms = std::max(10000, lease_timeout_ms);
    o.jobs.state_dir = (cache_ / ("master-" + std::to_string(++masters_started_))).string();
    master_ = std::make_unique<MasterServer>(o);
    channel_ = grpc::CreateChannel(master_->local_target(), grpc::InsecureChannelCredentials());
    jobs_ = v1::JobService::NewStub(channel_);
  }

  WorkerNodeOptions node_options(int threads = 1) const {
    WorkerNodeOptions o;
    o.master = master_ ? master_->local_target() : "127.0.0.1:1";
    o.threads = threads;
    o.name = "test-node";
    o.cache_dir = (cache_ / "worker-cache").string();
    o.max_backoff_ms = 300;
    o.min_backoff_ms = 20;
    return o;
  }

  static RenderOptions cornell_options(RenderMode mode, ReprojectMethod method = ReprojectMethod::kCpu, int size = 32,
                                       int spp = 6, int k = 2) {
    RenderOptions o;
    o.width = o.height = size;
    o.spp = spp;
    o.paths_per_round = k;
    o.mode = mode;
    o.reproject = method;
    o.tile_size = 16;
    o.scene = "builtin:cornell";
    return o;
  }

  std::string submit(const RenderOptions& o, const SceneBundleData& bundle) {
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + 10s);
    v1::JobId id;
    const v1::JobSpec spec = to_job_spec(o, bundle, CameraSpec{});
    const grpc::Status st = jobs_->SubmitJob(&ctx, spec, &id);
    EXPECT_TRUE(st.ok()) << st.error_message();
    return id.id();
  }

  v1::JobStatus status(const std::string& id) {
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + 10s);
    v1::JobId req;
    req.set_id(id);
    v1::JobStatus st;
    jobs_->GetJob(&ctx, req, &st);
    return st;
  }

  // Waits until the job is in a terminal state (or `timeout`); returns its last status.
  v1::JobStatus wait_done(const std::string& id, std::chrono::seconds timeout = 120s) {
    return test::wait_terminal([&] { return status(id); }, timeout);
  }

  Image fetch_image(const std::string& id, v1::ResultKind kind) {
    const std::string path = (cache_ / ("result-" + std::to_string(++fetches_) + ".exr")).string();
    return test::fetch_result_image(*jobs_, id, kind, 10s, path);
  }

  // The job's M / M' and path-traced sums must equal the single-process render's, bit for bit.
  void expect_same_as_local(const std::string& id, const RenderOptions& o) {
    test::expect_same_as_local([&](v1::ResultKind kind) { return fetch_image(id, kind); }, o);
  }

  fs::path cache_;
  int masters_started_ = 0, fetches_ = 0;
  std::unique_ptr<MasterServer> master_;
  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<v1::JobService::Stub> jobs_;
};

TEST_F(WorkerNodeTest, TwoNodesRenderASkipJobLikeTheSingleProcessRender) {
  const RenderOptions o = cornell_options(RenderMode::kSkip);
  const std::string id = submit(o, bundle_scene(o.scene));
  RunningNode a(node_options(1)), b(node_options(2));
  const v1::JobStatus st = wait_done(id);
  ASSERT_EQ(st.state(), v1::JOB_STATE_DONE) << st.error_message();
  a.stop();
  b.stop();
  const WorkerNodeStats sa = a.stats(), sb = b.stats();
  EXPECT_EQ(sa.tiles_committed + sb.tiles_committed, st.tiles_committed());
  EXPECT_GT(sa.vertices_sent + sb.vertices_sent, 0u);
  EXPECT_EQ(sa.tiles_refused + sb.tiles_refused, 0u);
  EXPECT_EQ(sa.registrations, 1u);
  // Without options.cpu_split the threads' CPU clocks are not read.
  EXPECT_GT(sb.time_others_tracing.tracing + sb.time_none_tracing.tracing, 0.0);
  EXPECT_EQ(sb.cpu.total(), 0.0);
  expect_same_as_local(id, o);
}

// The embedded set-up's in-process channel: every call of the node goes through it, so a node whose
// `master` names a port nothing listens on renders the job, exactly as over the socket.
TEST_F(WorkerNodeTest, InProcessChannelCarriesEveryCall) {
  const RenderOptions o = cornell_options(RenderMode::kSkip);
  const std::string id = submit(o, bundle_scene(o.scene));
  WorkerNodeOptions wo = node_options(2);
  wo.master = "127.0.0.1:1";
  MasterServer* master = master_.get();
  wo.in_process = [master](const grpc::ChannelArguments& args) { return master->in_process_channel(args); };
  RunningNode a(wo);
  const v1::JobStatus st = wait_done(id);
  ASSERT_EQ(st.state(), v1::JOB_STATE_DONE) << st.error_message();
  a.stop();
  const WorkerNodeStats sa = a.stats();
  EXPECT_EQ(sa.tiles_committed, st.tiles_committed());
  EXPECT_EQ(sa.registrations, 1u);
  EXPECT_EQ(sa.reconnects, 0u);
  expect_same_as_local(id, o);
}

// The time split (WorkerNodeStats::time_*, cpu) books every tracing thread's wall time once: over a
// job that runs entirely while the node does, the threads' booked time covers at least threads x the
// job's wall time and at most threads x the node's; tracing wall time holds the tiles' own tracing
// time and (options.cpu_split) the threads' tracing CPU time.
TEST_F(WorkerNodeTest, TimeSplitAccountsForEveryTracingThread) {
  const auto node_started = std::chrono::steady_clock::now();
  WorkerNodeOptions options = node_options(2);
  options.cpu_split = true;
  std::optional<RunningNode> node(std::in_place, options);
  ASSERT_TRUE(wait_until([&] { return node->stats().registered; }));
  const RenderOptions o = cornell_options(RenderMode::kSkip, ReprojectMethod::kCpu, 48, 8, 2);
  const std::string id = submit(o, bundle_scene(o.scene));
  const v1::JobStatus st = wait_done(id);
  ASSERT_EQ(st.state(), v1::JOB_STATE_DONE) << st.error_message();
  const WorkerNodeStats s = node->stats();
  const double node_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - node_started).count();
  node.reset();

  const double booked = s.time_others_tracing.total() + s.time_none_tracing.total();
  EXPECT_GE(booked, 2 * st.seconds_elapsed() - 0.01);
  EXPECT_LE(booked, 2 * node_seconds + 0.01);
  const double tracing = s.time_others_tracing.tracing + s.time_none_tracing.tracing;
  EXPECT_GT(s.cpu.tracing, 0.0);
  EXPECT_GE(tracing, s.seconds_tracing - 0.001);
  EXPECT_GE(tracing, s.cpu.tracing - 0.01);
  EXPECT_LE(s.cpu.total(), booked + 0.01);
  // Nothing negative (a booking against the wrong activity would drive one below zero).
  for (const WorkerTimeSplit* t : {&s.time_others_tracing, &s.time_none_tracing, &s.cpu})
    for (double v : {t->tracing, t->leasing, t->waiting, t->submitting, t->other}) EXPECT_GE(v, 0.0);
}

TEST_F(WorkerNodeTest, ExactModeJobLikeTheSingleProcessRender) {
  const RenderOptions o = cornell_options(RenderMode::kReproject, ReprojectMethod::kExact, 32, 4, 2);
  const std::string id = submit(o, bundle_scene(o.scene));
  RunningNode a(node_options(2));
  const v1::JobStatus st = wait_done(id);
  ASSERT_EQ(st.state(), v1::JOB_STATE_DONE) << st.error_message();
  a.stop();
  EXPECT_GT(a.stats().exact_samples_sent, 0u);
  EXPECT_EQ(a.stats().vertices_sent, 0u);
  expect_same_as_local(id, o);
}

TEST_F(WorkerNodeTest, FileScenesAreFetchedOnceThenServedFromTheCache) {
  RenderOptions o = cornell_options(RenderMode::kPathTrace, ReprojectMethod::kCpu, 24, 2, 1);
  o.scene = kCornellObj;
  const SceneBundleData bundle = bundle_scene(kCornellObj);
  {
    const std::string id = submit(o, bundle);
    RunningNode a(node_options(2));
    const v1::JobStatus st = wait_done(id);
    ASSERT_EQ(st.state(), v1::JOB_STATE_DONE) << st.error_message();
    a.stop();
    EXPECT_EQ(a.stats().scenes_fetched, 1u);  // two threads, one fetch
    EXPECT_EQ(a.stats().scene_bytes_fetched, bundle.total_bytes());
    expect_same_as_local(id, o);
  }
  EXPECT_TRUE(fs::exists(fs::path(node_options().cache_dir) / "scenes" / content_hash(bundle) / ".complete"));
  // A new worker process (same cache folder) and a new job on the same scene: no fetch.
  o.seed = 5;
  const std::string id = submit(o, bundle);
  RunningNode b(node_options(1));
  ASSERT_EQ(wait_done(id).state(), v1::JOB_STATE_DONE);
  b.stop();
  EXPECT_EQ(b.stats().scenes_fetched, 0u);
  EXPECT_GT(b.stats().tiles_committed, 0u);
}

TEST_F(WorkerNodeTest, WorkerWaitsForItsMasterAndSurvivesARestart) {
  const int port = master_->port();
  const std::string target = master_->local_target();
  master_->shutdown();
  master_.reset();

  // The worker starts while nobody listens: it keeps trying, with backoff, without crashing. Its
  // log says so: a warning naming the master for each of its first failed attempts.
  WarningsAbout attempts("worker", target);
  WorkerNodeOptions wo = node_options(2);
  wo.master = target;
  RunningNode node(wo);
  EXPECT_TRUE(wait_until([&] { return attempts.count() >= 2; })) << "the worker did not try again";
  EXPECT_EQ(node.stats().registrations, 0u);
  EXPECT_FALSE(node.stats().registered);

  start_master("127.0.0.1:" + std::to_string(port));
  const RenderOptions o = cornell_options(RenderMode::kSkip);
  const std::string first = submit(o, bundle_scene(o.scene));
  ASSERT_EQ(wait_done(first).state(), v1::JOB_STATE_DONE);
  EXPECT_GE(node.stats().registrations, 1u);
  expect_same_as_local(first, o);

  // The master restarts (a new process would forget every worker id): the worker registers again.
  const uint64_t registrations = node.stats().registrations;
  master_->shutdown();
  master_.reset();
  // The new master comes up once the worker has noticed that the old one is gone.
  EXPECT_TRUE(wait_until([&] { return !node.stats().registered; })) << "the worker did not notice the master leave";
  start_master("127.0.0.1:" + std::to_string(port));
  const RenderOptions o2 = cornell_options(RenderMode::kReproject, ReprojectMethod::kCpu, 32, 4, 1);
  const std::string second = submit(o2, bundle_scene(o2.scene));
  const v1::JobStatus st = wait_done(second);
  ASSERT_EQ(st.state(), v1::JOB_STATE_DONE) << st.error_message();
  EXPECT_GT(node.stats().registrations, registrations);
  EXPECT_GE(node.stats().reconnects, 1u);
  expect_same_as_local(second, o2);
}

TEST_F(WorkerNodeTest, StopReturnsLeasesAndAnotherWorkerFinishes) {
  // A lease that is not returned runs out after 100 s and the master warns of it; with no speculative
  // copies the job cannot end without its tile, so no warning means stop() gave it back (with copies,
  // a copy to the second worker finished the job without the return).
  // A heartbeat that misses its deadline ends a worker's session instead: its submissions in flight are
  // cancelled (the master may have committed a tile whose answer the worker then never sees) and its
  // leases are returned on a best-effort 1 s call, so they may run out. Under ThreadSanitizer on a
  // loaded machine the default 2 s deadline was missed: the job counted a tile no worker had (960
  // against 959), or the leases held the job. This test is about stop(): 5 s heartbeats (10 s deadline).
  // The master's threads log through the sink: none may run while it is attached or detached.
  master_->shutdown();
  master_.reset();
  WarningsAbout expired("master", "lease expired");
  struct MasterGone {
    std::unique_ptr<MasterServer>& master;
    ~MasterGone() {
      if (master) master->shutdown();
      master.reset();
    }
  } master_gone{master_};
  start_master("127.0.0.1:0", 100'000, 5000, /*speculative=*/false);
  // Big enough that the first worker is stopped in the middle of it.
  const RenderOptions o = cornell_options(RenderMode::kPathTrace, ReprojectMethod::kCpu, 128, 32, 1);
  const std::string id = submit(o, bundle_scene(o.scene));
  auto first = std::make_unique<RunningNode>(node_options(2));
  wait_until([&] { return first->stats().tiles_committed >= 20; }, 120s);
  ASSERT_GE(first->stats().tiles_committed, 20u);
  const auto took = first->stop();
  EXPECT_LT(took.count(), 5.0) << "stop() must not wait for lease deadlines";
  const WorkerNodeStats s1 = first->stats();
  EXPECT_FALSE(s1.registered);
  ASSERT_NE(status(id).state(), v1::JOB_STATE_DONE) << "make the job larger: it finished before stop()";
  // The stopped worker unregistered: the master no longer lists it.
  for (const auto& w : master_->jobs().workers()) EXPECT_NE(w.id, s1.worker_id);

  RunningNode second(node_options(2));
  // A guard against hanging, not a speed assertion: under ThreadSanitizer on a loaded machine the
  // rest of the job took over 100 s.
  const v1::JobStatus st = wait_done(id, 300s);
  ASSERT_EQ(st.state(), v1::JOB_STATE_DONE) << st.error_message();
  second.stop();
  // Each committed tile was counted by the worker that sent it, as COMMITTED -- or as DUPLICATE when the
  // answer to a commit was lost (a deadline under load) and the retry found it already committed.
  const WorkerNodeStats s2 = second.stats();
  EXPECT_GE(st.tiles_committed(), s1.tiles_committed + s2.tiles_committed);
  const uint64_t lost = s1.reconnects + s2.reconnects;
  EXPECT_LE(st.tiles_committed(), s1.tiles_committed + s2.tiles_committed + s1.tiles_duplicate + s2.tiles_duplicate)
      << "sessions lost (their answers with them): " << lost;
  EXPECT_EQ(expired.count(), 0) << "leases ran out instead of being returned; sessions lost: " << lost;
  expect_same_as_local(id, o);
}

// A registration the master refuses for good (a name over its 256-byte limit) ends run() with the
// master's reason instead of a retry loop that would never end.
TEST_F(WorkerNodeTest, PermanentRefusalEndsRunWithTheReason) {
  WorkerNodeOptions wo = node_options(1);
  wo.name = std::string(300, 'n');
  WorkerNode node(wo);
  auto run = std::async(std::launch::async, [&] { return node.run(); });
  if (run.wait_for(60s) != std::future_status::ready) {
    node.stop();
    FAIL() << "run() kept retrying a permanent INVALID_ARGUMENT";
  }
  const std::optional<std::string> why = run.get();
  ASSERT_TRUE(why.has_value());
  EXPECT_NE(why->find("INVALID_ARGUMENT"), std::string::npos) << *why;
  EXPECT_NE(why->find("256 bytes"), std::string::npos) << *why;
  EXPECT_NE(why->find(master_->local_target()), std::string::npos) << *why;
  EXPECT_EQ(node.stats().registrations, 0u);
}

// A cache folder that cannot be created (a HOME that is not writable) does not stop the worker: it
// fetches into a private temporary folder, which is gone once the node is.
TEST_F(WorkerNodeTest, UnwritableCacheFallsBackToAPrivateFolder) {
  RenderOptions o = cornell_options(RenderMode::kPathTrace, ReprojectMethod::kCpu, 16, 1, 1);
  o.scene = kCornellObj;
  const std::string id = submit(o, bundle_scene(kCornellObj));
  WorkerNodeOptions wo = node_options(1);
  wo.cache_dir = "/dev/null/epr-cache";  // below a file: cannot be created, not even by root
  std::string fallback;
  {
    WarningsAbout warned("worker", "/dev/null/epr-cache");
    RunningNode node(wo);
    const v1::JobStatus st = wait_done(id);
    ASSERT_EQ(st.state(), v1::JOB_STATE_DONE) << st.error_message();
    EXPECT_EQ(node.stats().scenes_fetched, 1u);
    EXPECT_EQ(warned.count(), 1) << "the fallback is announced once, naming the folder";
    for (const auto& e : fs::directory_iterator(fs::temp_directory_path()))
      if (e.path().filename().string().rfind("epr-worker-cache-" + std::to_string(::getpid()) + "-", 0) == 0)
        fallback = e.path().string();
    EXPECT_FALSE(fallback.empty()) << "no private cache folder while the node runs";
  }
  EXPECT_FALSE(fs::exists(fallback)) << fallback << " is left behind";
}

}  // namespace
}  // namespace epr
