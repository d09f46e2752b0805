// Shared pieces of the server tests: an in-process MasterServer on loopback with chosen MasterOptions,
// a client for it, WorkerNodes on their own threads, and WireWorker — a worker driven call by call over
// real gRPC (real tracing, real stream writer) so a test can stall, fail or misbehave on purpose.
#pragma once

#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <functional>
#include <optional>
#include <thread>

#include "client/local_render.h"
#include "common/image.h"
#include "epr/v1/job_service.grpc.pb.h"
#include "epr/v1/worker_service.grpc.pb.h"
#include "master/server/master_server.h"
#include "tests/job_results.h"
#include "tests/running_node.h"
#include "tests/wait_until.h"
#include "wire/convert.h"
#include "wire/scene_bundle.h"
#include "wire/tile_result_stream.h"
#include "worker/embree_scene.h"
#include "worker/path_tracer.h"
#include "worker/tile_lease.h"
#include "worker/tile_renderer.h"
#include "worker/worker_node.h"

namespace epr::test {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

inline void set_deadline(grpc::ClientContext* ctx, std::chrono::seconds s = 10s) {
  ctx->set_deadline(std::chrono::system_clock::now() + s);
}

/// Polls `done` every 20 ms until it is true or `timeout` passes (a guard, not a speed assertion).
inline bool eventually(const std::function<bool()>& done, std::chrono::milliseconds timeout = 30000ms) {
  return wait_until(done, timeout, 20ms);
}

/// Registers a one-thread worker called `name` on `stub`; returns its id.
inline std::string register_worker(v1::WorkerService::Stub& stub, const std::string& name) {
  grpc::ClientContext ctx;
  set_deadline(&ctx);
  v1::WorkerInfo info;
  info.set_protocol_version(v1::PROTOCOL_VERSION_V1);
  info.set_name(name);
  info.set_threads(1);
  v1::RegisterResponse r;
  const grpc::Status st = stub.Register(&ctx, info, &r);
  EXPECT_TRUE(st.ok()) << st.error_message();
  return r.worker_id().id();
}

/// A worker driven one call at a time.
class WireWorker {
 public:
  WireWorker(const std::shared_ptr<grpc::Channel>& channel, const std::string& name)
      : stub_(v1::WorkerService::NewStub(channel)), id_(register_worker(*stub_, name)) {}
  const std::string& id() const { return id_; }

  /// A tile, or nullopt when the master says Wait. With max_wait_ms > 0 the master may hold the call
  /// that long for a tile to appear (LeaseRequest.max_wait_ms) before it says Wait.
  std::optional<v1::TileLease> lease(uint32_t max_wait_ms = 0) {
    grpc::ClientContext ctx;
    set_deadline(&ctx);
    v1::LeaseRequest req;
    req.mutable_worker_id()->set_id(id_);
    req.set_max_wait_ms(max_wait_ms);
    v1::Lease lease;
    const grpc::Status st = stub_->LeaseTile(&ctx, req, &lease);
    EXPECT_TRUE(st.ok()) << st.error_message();
    if (!lease.has_tile()) return std::nullopt;
    return lease.tile();
  }

  /// Leases until a tile comes (or `timeout`).
  std::optional<v1::TileLease> lease_wait(std::chrono::milliseconds timeout = 30000ms) {
    const auto until = std::chrono::steady_clock::now() + timeout;
    while (std::chrono::steady_clock::now() < until) {
      if (auto t = lease()) return t;
      std::this_thread::sleep_for(5ms);
    }
    return std::nullopt;
  }

  /// The tile traced for real (built-in scenes only) and split into the chunks a worker sends.
  std::vector<v1::TileResultChunk> render(const v1::TileLease& t) const {
    LeasedTile tile;
    const auto err = unpack_tile_lease(t, &tile);
    EXPECT_FALSE(err) << *err;
    const auto& s = t.settings();
    const Scene scene = load_bundle(bundle_scene(t.scene().builtin()), default_cache_root());
    const EmbreeScene es(scene);
    const Camera cam(from_proto(s.camera()), int(s.width()), int(s.height()));
    const PathTracer tracer(es, cam, t.seed(), from_proto(s.russian_roulette()));
    const TileRenderer renderer(tracer, tile.filter);
    const TileResult result = *render_leased_tile(renderer, tile, nullptr);
    const TileResultIdentity id{t.lease_id(), t.job_id(), t.round(), t.tile_index(), id_};
    return split_tile_result(result, id, from_proto(s.codec_bounds()), TileResultLimits{});
  }

  /// Streams `chunks` as one SubmitTile call.
  grpc::Status submit(const std::vector<v1::TileResultChunk>& chunks, v1::SubmitAck* ack) {
    grpc::ClientContext ctx;
    set_deadline(&ctx, 30s);
    auto w = stub_->SubmitTile(&ctx, ack);
    for (const auto& c : chunks)
      if (!w->Write(c)) break;
    w->WritesDone();
    return w->Finish();
  }

  /// Per lease: still wanted?
  std::vector<bool> heartbeat(const std::vector<uint64_t>& leases) {
    grpc::ClientContext ctx;
    set_deadline(&ctx);
    v1::HeartbeatRequest req;
    req.mutable_worker_id()->set_id(id_);
    for (uint64_t l : leases) req.add_lease_ids(l);
    v1::HeartbeatResponse resp;
    const grpc::Status st = stub_->Heartbeat(&ctx, req, &resp);
    EXPECT_TRUE(st.ok()) << st.error_message();
    std::vector<bool> out;
    for (const auto& s : resp.leases()) out.push_back(s.valid());
    return out;
  }

  grpc::Status give_back(uint64_t lease, v1::LeaseFailure failure, const std::string& reason) {
    grpc::ClientContext ctx;
    set_deadline(&ctx);
    v1::ReturnLeaseRequest req;
    req.mutable_worker_id()->set_id(id_);
    req.add_lease_ids(lease);
    req.set_reason(reason);
    req.set_failure(failure);
    v1::ReturnLeaseResponse resp;
    return stub_->ReturnLease(&ctx, req, &resp);
  }

  void unregister() {
    grpc::ClientContext ctx;
    set_deadline(&ctx);
    v1::WorkerId req;
    req.set_id(id_);
    v1::UnregisterResponse resp;
    EXPECT_TRUE(stub_->Unregister(&ctx, req, &resp).ok());
  }

 private:
  std::unique_ptr<v1::WorkerService::Stub> stub_;
  std::string id_;
};

/// A master in this process with the given MasterOptions, and a JobService client.
class FarmFixture : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::path(::testing::TempDir()) / ("epr-farm-" + std::to_string(::getpid()) + "-" +
                                             ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override {
    if (server_) server_->shutdown();
    fs::remove_all(dir_);
  }

  void start(MasterOptions jobs = {}) {
    MasterServerOptions o;
    o.listen = "127.0.0.1:0";
    o.jobs = std::move(jobs);
    o.jobs.state_dir = (dir_ / "master").string();
    server_ = std::make_unique<MasterServer>(o);
    channel_ = grpc::CreateChannel(server_->local_target(), grpc::InsecureChannelCredentials());
    jobs_ = v1::JobService::NewStub(channel_);
  }

  WorkerNodeOptions node_options(const std::string& name, int threads = 1) const {
    WorkerNodeOptions o;
    o.master = server_->local_target();
    o.threads = threads;
    o.name = name;
    o.cache_dir = (dir_ / ("cache-" + name)).string();
    o.max_backoff_ms = 300;
    o.min_backoff_ms = 20;
    return o;
  }

  static RenderOptions cornell(RenderMode mode, int size = 64, int spp = 4, int k = 2) {
    RenderOptions o;
    o.width = o.height = size;
    o.spp = spp;
    o.paths_per_round = k;
    o.mode = mode;
    o.reproject = ReprojectMethod::kCpu;
    o.tile_size = 16;
    o.scene = "builtin:cornell";
    return o;
  }

  grpc::Status submit(const v1::JobSpec& spec, std::string* id = nullptr) {
    grpc::ClientContext ctx;
    set_deadline(&ctx);
    v1::JobId out;
    const grpc::Status st = jobs_->SubmitJob(&ctx, spec, &out);
    if (id) *id = out.id();
    return st;
  }
  std::string submit(const RenderOptions& o, const SceneBundleData& bundle) {
    std::string id;
    const grpc::Status st = submit(to_job_spec(o, bundle, CameraSpec{}), &id);
    EXPECT_TRUE(st.ok()) << st.error_message();
    return id;
  }

  v1::JobStatus status(const std::string& id) { return job_status(*jobs_, id); }

  static bool terminal(const v1::JobStatus& st) { return job_terminal(st); }

  /// Polls until the job is in a terminal state (or `timeout`, a guard against hanging).
  v1::JobStatus wait_done(const std::string& id, std::chrono::seconds timeout = 120s) {
    return wait_terminal([&] { return status(id); }, timeout);
  }

  Image fetch_image(const std::string& id, v1::ResultKind kind) {
    const std::string path = (dir_ / ("result-" + std::to_string(++fetches_) + ".exr")).string();
    return fetch_result_image(*jobs_, id, kind, 10s, path);
  }

  /// The job's M / M' and path-traced sums equal the single-process render's, bit for bit.
  void expect_same_as_local(const std::string& id, const RenderOptions& o) {
    test::expect_same_as_local([&](v1::ResultKind kind) { return fetch_image(id, kind); }, o);
  }

  fs::path dir_;
  int fetches_ = 0;
  std::unique_ptr<MasterServer> server_;
  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<v1::JobService::Stub> jobs_;
};

}  // namespace epr::test
