// One WorkerNode serving several in-process MasterServers over loopback gRPC (no fakes): each
// master's job is rendered as by a single master (M, M' and path sums equal the single-process
// render); a name's addresses, supplied by a test resolver, are one master each and followed as the
// resolution changes; a master that refuses the worker for good is given up while the others are
// served, and the node ends only when every master refused it.
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <atomic>
#include <filesystem>
#include <fstream>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "client/local_render.h"
#include "epr/v1/job_service.grpc.pb.h"
#include "master/server/master_server.h"
#include "tests/job_results.h"
#include "tests/running_node.h"
#include "tests/wait_until.h"
#include "wire/convert.h"
#include "wire/scene_bundle.h"
#include "worker/worker_node.h"

namespace epr {
namespace {
namespace fs = std::filesystem;
using namespace std::chrono_literals;
using test::RunningNode;
using test::wait_until;

struct Master {
  std::string target;  // HOST:PORT it listens on
  std::unique_ptr<MasterServer> server;
  std::unique_ptr<v1::JobService::Stub> jobs;
};

class MultiMasterNodeTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::path(::testing::TempDir()) / ("epr-multi-master-" + std::to_string(::getpid()) + "-" +
                                             ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    masters_.reserve(4);  // start_master hands out references
  }
  void TearDown() override {
    for (auto& m : masters_) m.server->shutdown();
    fs::remove_all(dir_);
  }

  Master& start_master(const std::string& listen, const std::string& token = "") {
    MasterServerOptions o;
    o.listen = listen;
    o.token = token;
    o.jobs.lease_timeout_ms = 20000;
    o.jobs.worker_timeout_ms = 20000;
    o.jobs.state_dir = (dir_ / ("master-" + std::to_string(masters_.size()))).string();
    Master m;
    m.server = std::make_unique<MasterServer>(o);
    // The listening address itself (local_target() names 127.0.0.1 whatever the listening address).
    const std::string target =
        listen.substr(0, listen.rfind(':') + 1) + std::to_string(port_of(m.server->local_target()));
    m.target = target;
    m.jobs = v1::JobService::NewStub(grpc::CreateChannel(target, grpc::InsecureChannelCredentials()));
    masters_.push_back(std::move(m));
    return masters_.back();
  }

  WorkerNodeOptions node_options(const std::string& master, int threads) const {
    WorkerNodeOptions o;
    o.master = master;
    o.threads = threads;
    o.name = "multi-node";
    o.cache_dir = (dir_ / "worker-cache").string();
    o.max_backoff_ms = 300;
    o.min_backoff_ms = 20;
    return o;
  }

  static RenderOptions job(uint64_t seed) {
    RenderOptions o;
    o.width = o.height = 32;
    o.spp = 6;
    o.paths_per_round = 2;
    o.mode = RenderMode::kSkip;
    o.reproject = ReprojectMethod::kCpu;
    o.tile_size = 16;
    o.scene = "builtin:cornell";
    o.seed = seed;
    return o;
  }

  static std::string submit(Master& m, const RenderOptions& o, const std::string& token = "") {
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + 10s);
    if (!token.empty()) ctx.AddMetadata("authorization", "Bearer " + token);
    v1::JobId id;
    const grpc::Status st = m.jobs->SubmitJob(&ctx, to_job_spec(o, bundle_scene(o.scene), CameraSpec{}), &id);
    EXPECT_TRUE(st.ok()) << st.error_message();
    return id.id();
  }

  static v1::JobStatus wait_done(Master& m, const std::string& id, const std::string& token = "") {
    return test::wait_terminal(
        [&] {
          grpc::ClientContext ctx;
          ctx.set_deadline(std::chrono::system_clock::now() + 10s);
          if (!token.empty()) ctx.AddMetadata("authorization", "Bearer " + token);
          v1::JobId req;
          req.set_id(id);
          v1::JobStatus st;
          m.jobs->GetJob(&ctx, req, &st);
          return st;
        },
        120s);
  }

  void expect_same_as_local(Master& m, const std::string& id, const RenderOptions& o) {
    test::expect_same_as_local(
        [&](v1::ResultKind kind) {
          const std::string path = (dir_ / ("result-" + std::to_string(++fetches_) + ".exr")).string();
          return test::fetch_result_image(*m.jobs, id, kind, 10s, path);
        },
        o);
  }

  static int port_of(const std::string& target) { return std::stoi(target.substr(target.rfind(':') + 1)); }

  static size_t count_state(const WorkerNodeStats& s, MasterState state) {
    size_t n = 0;
    for (const auto& m : s.masters) n += m.state == state;
    return n;
  }

  fs::path dir_;
  std::vector<Master> masters_;
  int fetches_ = 0;
};

// A name resolving to several addresses (the test's resolver answers; 127.0.0.x are all loopback):
// one master per address; when the answer changes, the master that left it is left and the new one
// is served; each master's job equals the single-process render.
TEST_F(MultiMasterNodeTest, ANameResolvingToSeveralAddressesIsFollowed) {
  Master& a = start_master("127.0.0.1:0");
  const int port = port_of(a.server->local_target());
  Master& b = start_master("127.0.0.2:" + std::to_string(port));
  std::mutex mu;
  std::vector<std::string> answer{"127.0.0.1", "127.0.0.9"};  // nothing listens on .9
  std::atomic<int> resolutions{0};
  WorkerNodeOptions o = node_options("masters.test:" + std::to_string(port), 2);
  o.resolve_interval_ms = 100;
  o.resolver = [&](const std::string& host) -> std::optional<std::vector<std::string>> {
    EXPECT_EQ(host, "masters.test");
    ++resolutions;
    std::lock_guard lock(mu);
    return answer;
  };
  const RenderOptions ja = job(3), jb = job(4);
  const std::string ida = submit(a, ja), idb = submit(b, jb);
  RunningNode node(o);
  ASSERT_TRUE(wait_until([&] { return wait_done(a, ida).state() == v1::JOB_STATE_DONE; }, 120s));
  {
    const WorkerNodeStats s = node.stats();
    ASSERT_EQ(s.masters.size(), 2u);
    EXPECT_EQ(s.masters[0].name, "masters.test:" + std::to_string(port) + " (127.0.0.1)");
    EXPECT_EQ(s.masters[0].state, MasterState::kConnected);
    EXPECT_NE(s.masters[1].state, MasterState::kConnected);  // .9: nobody there
    EXPECT_EQ(s.masters[1].name, "masters.test:" + std::to_string(port) + " (127.0.0.9)");
  }
  // The Service gains .2 and loses .9.
  {
    std::lock_guard lock(mu);
    answer = {"127.0.0.2", "127.0.0.1"};
  }
  const v1::JobStatus stb = wait_done(b, idb);
  ASSERT_EQ(stb.state(), v1::JOB_STATE_DONE) << stb.error_message();
  EXPECT_GE(resolutions.load(), 2) << "the name was not resolved again";
  ASSERT_TRUE(wait_until([&] { return count_state(node.stats(), MasterState::kConnected) == 2; }, 30s));
  const WorkerNodeStats s = node.stats();
  ASSERT_EQ(s.masters.size(), 2u);
  EXPECT_EQ(s.masters[1].name, "masters.test:" + std::to_string(port) + " (127.0.0.2)");
  EXPECT_EQ(a.server->jobs().workers().size(), 1u);
  EXPECT_EQ(b.server->jobs().workers().size(), 1u);
  node.stop();
  expect_same_as_local(a, ida, ja);
  expect_same_as_local(b, idb, jb);
}

// A master that refuses the worker for good (another token) is given up with its reason while the
// other one is served; when every master refuses, run() returns every reason.
TEST_F(MultiMasterNodeTest, AMasterThatRefusesIsGivenUpAndTheOthersServed) {
  Master& good = start_master("127.0.0.1:0", "right-token");
  Master& other = start_master("127.0.0.1:0", "other-token");
  const std::string token_file = (dir_ / "token").string();
  std::ofstream(token_file) << "right-token\n";
  fs::permissions(token_file, fs::perms::owner_read | fs::perms::owner_write);
  WorkerNodeOptions o = node_options(good.target + "," + other.target, 1);
  o.token_file = token_file;
  const RenderOptions j = job(5);
  const std::string id = submit(good, j, "right-token");
  {
    RunningNode node(o);
    ASSERT_EQ(wait_done(good, id, "right-token").state(), v1::JOB_STATE_DONE);
    ASSERT_TRUE(wait_until([&] { return count_state(node.stats(), MasterState::kRefused) == 1; }, 30s));
    const WorkerNodeStats s = node.stats();
    ASSERT_EQ(s.masters.size(), 2u);
    EXPECT_EQ(s.masters[0].state, MasterState::kConnected);
    EXPECT_EQ(s.masters[1].state, MasterState::kRefused);
    EXPECT_NE(s.masters[1].detail.find(other.target), std::string::npos) << s.masters[1].detail;
  }

  std::ofstream(token_file) << "wrong-token\n";
  WorkerNode all_refuse(o);
  std::optional<std::string> refused = all_refuse.run();
  ASSERT_TRUE(refused.has_value());
  EXPECT_NE(refused->find(good.target), std::string::npos) << *refused;
  EXPECT_NE(refused->find(other.target), std::string::npos) << *refused;
}

}  // namespace
}  // namespace epr
