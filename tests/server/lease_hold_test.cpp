// LeaseTile calls the master holds (LeaseRequest.max_wait_ms) against a real in-process master over
// loopback gRPC: a held call is answered with a tile the moment the job starts or the next round
// opens, with a Wait when its time is up, and forgotten when the worker cancels it.
#include <future>

#include "tests/server/farm_fixture.h"

namespace epr::test {
namespace {

class LeaseHoldTest : public FarmFixture {
 protected:
  // One LeaseTile call with max_wait_ms, run on another thread.
  std::future<std::pair<grpc::Status, v1::Lease>> lease_async(v1::WorkerService::Stub& stub, const std::string& id,
                                                              uint32_t max_wait_ms, grpc::ClientContext* ctx) {
    set_deadline(ctx, 30s);
    return std::async(std::launch::async, [&stub, id, max_wait_ms, ctx] {
      v1::LeaseRequest req;
      req.mutable_worker_id()->set_id(id);
      req.set_max_wait_ms(max_wait_ms);
      v1::Lease lease;
      const grpc::Status st = stub.LeaseTile(ctx, req, &lease);
      return std::make_pair(st, lease);
    });
  }

  void wait_parked(size_t n) {
    for (int i = 0; i < 1000 && server_->jobs().parked_requests() != n; ++i) std::this_thread::sleep_for(5ms);
    ASSERT_EQ(server_->jobs().parked_requests(), n);
  }
};

TEST_F(LeaseHoldTest, HeldCallGetsATileWhenTheJobStarts) {
  start();
  auto stub = v1::WorkerService::NewStub(channel_);
  const std::string id = register_worker(*stub, "held");
  grpc::ClientContext ctx;
  auto call = lease_async(*stub, id, 2000, &ctx);
  wait_parked(1);  // no job yet: held, not answered with a Wait
  const std::string job = submit(cornell(RenderMode::kPathTrace, 16, 4, 2), bundle_scene("builtin:cornell"));
  const auto [st, lease] = call.get();
  ASSERT_TRUE(st.ok()) << st.error_message();
  ASSERT_TRUE(lease.has_tile()) << "a held call must be answered with the new job's tile";
  EXPECT_EQ(lease.tile().job_id(), job);
  EXPECT_EQ(lease.tile().round(), 0u);
  EXPECT_EQ(server_->jobs().parked_requests(), 0u);
}

TEST_F(LeaseHoldTest, HeldCallGetsTheNextRoundsTileWhenTheRoundCloses) {
  start();
  // One 16 x 16 tile, k = 2 of 4 paths: two rounds of one tile each.
  const std::string job = submit(cornell(RenderMode::kPathTrace, 16, 4, 2), bundle_scene("builtin:cornell"));
  WireWorker tracer(channel_, "tracer");
  const auto first = tracer.lease_wait();
  ASSERT_TRUE(first);
  ASSERT_EQ(first->round(), 0u);

  auto stub = v1::WorkerService::NewStub(channel_);
  const std::string id = register_worker(*stub, "held");
  grpc::ClientContext ctx;
  auto call = lease_async(*stub, id, 2000, &ctx);
  wait_parked(1);  // the round's only tile is out: held
  v1::SubmitAck ack;
  const grpc::Status sub = tracer.submit(tracer.render(*first), &ack);
  ASSERT_TRUE(sub.ok()) << sub.error_message();
  ASSERT_EQ(ack.outcome(), v1::SUBMIT_OUTCOME_COMMITTED);

  const auto [st, lease] = call.get();
  ASSERT_TRUE(st.ok()) << st.error_message();
  ASSERT_TRUE(lease.has_tile()) << "the held call must get round 1's tile once round 0 closed";
  EXPECT_EQ(lease.tile().job_id(), job);
  EXPECT_EQ(lease.tile().round(), 1u);
  EXPECT_EQ(lease.tile().tile_index(), 0u);
}

// WorkerInfo.cached_scenes: of two held calls and one tile, the worker that already holds the
// job's scene gets it, although it asked second.
TEST_F(LeaseHoldTest, AWorkerHoldingTheJobsSceneIsAnsweredFirst) {
  start();
  auto stub = v1::WorkerService::NewStub(channel_);
  const std::string plain = register_worker(*stub, "plain");
  std::string cached;
  {
    grpc::ClientContext ctx;
    set_deadline(&ctx);
    v1::WorkerInfo info;
    info.set_protocol_version(v1::PROTOCOL_VERSION_V1);
    info.set_name("cached");
    info.set_threads(1);
    info.add_cached_scenes(content_hash(bundle_scene("builtin:cornell")));
    v1::RegisterResponse r;
    ASSERT_TRUE(stub->Register(&ctx, info, &r).ok());
    cached = r.worker_id().id();
  }
  grpc::ClientContext ctx_plain, ctx_cached;
  auto plain_call = lease_async(*stub, plain, 1500, &ctx_plain);
  wait_parked(1);
  auto cached_call = lease_async(*stub, cached, 1500, &ctx_cached);
  wait_parked(2);
  // One 16 x 16 tile in one round.
  submit(cornell(RenderMode::kPathTrace, 16, 1, 1), bundle_scene("builtin:cornell"));
  const auto [cst, clease] = cached_call.get();
  const auto [pst, please] = plain_call.get();
  ASSERT_TRUE(cst.ok()) << cst.error_message();
  ASSERT_TRUE(pst.ok()) << pst.error_message();
  EXPECT_TRUE(clease.has_tile()) << "the worker with the scene must get the only tile";
  EXPECT_FALSE(please.has_tile());
}

TEST_F(LeaseHoldTest, HeldCallIsAnsweredWithAWaitWhenItsTimeIsUp) {
  start();
  auto stub = v1::WorkerService::NewStub(channel_);
  const std::string id = register_worker(*stub, "held");
  grpc::ClientContext ctx;
  auto call = lease_async(*stub, id, 100, &ctx);
  const auto [st, lease] = call.get();
  ASSERT_TRUE(st.ok()) << st.error_message();
  EXPECT_TRUE(lease.has_wait());
  EXPECT_EQ(server_->jobs().parked_requests(), 0u);

  // Without max_wait_ms the answer is a Wait at once (nothing is held).
  WireWorker plain(channel_, "plain");
  EXPECT_FALSE(plain.lease());
  EXPECT_EQ(server_->jobs().parked_requests(), 0u);
}

TEST_F(LeaseHoldTest, CancelledHeldCallIsForgottenAndTheJobStillEnds) {
  start();
  auto stub = v1::WorkerService::NewStub(channel_);
  const std::string id = register_worker(*stub, "gone");
  grpc::ClientContext ctx;
  auto call = lease_async(*stub, id, 2000, &ctx);
  wait_parked(1);
  ctx.TryCancel();
  const auto [st, lease] = call.get();
  EXPECT_EQ(st.error_code(), grpc::StatusCode::CANCELLED);
  wait_parked(0);
  // The job goes to a working node: no tile was handed to the cancelled call.
  const std::string job = submit(cornell(RenderMode::kPathTrace, 32, 4, 2), bundle_scene("builtin:cornell"));
  RunningNode node(node_options("worker", 2));
  const v1::JobStatus done = wait_done(job, 60s);
  node.stop();
  ASSERT_EQ(done.state(), v1::JOB_STATE_DONE) << done.error_message();
  EXPECT_EQ(done.tiles_re_leased(), 0u);
}

}  // namespace
}  // namespace epr::test
