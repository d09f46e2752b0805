// A worker's farewell (Unregister) against a real in-process master over loopback gRPC: the leases it
// still holds are leased again at once, not after their timeout. A stopping worker cancels its
// LeaseTile call; when the master had answered it first, the worker never learns of that lease and
// cannot return it (seen under TSan: WorkerNodeTest.StopReturnsLeasesAndAnotherWorkerFinishes).
#include <set>

#include "tests/server/farm_fixture.h"

namespace epr::test {
namespace {

class FarewellTest : public FarmFixture {};

TEST_F(FarewellTest, LeasesStillHeldAtUnregisterAreLeasedAgainAtOnce) {
  MasterOptions mo;
  mo.lease_timeout_ms = 600'000;  // an unreturned lease would stay out for the whole test
  mo.speculative_factor = 0;      // and no copy of its tile is made
  start(mo);
  const RenderOptions o = cornell(RenderMode::kPathTrace, 32, 2, 1);  // 4 tiles per round
  const std::string id = submit(o, bundle_scene(o.scene));
  WireWorker leaving(channel_, "leaving"), other(channel_, "other");
  const auto held = leaving.lease_wait();
  ASSERT_TRUE(held);

  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + 30s);
  v1::WorkerId wid;
  wid.set_id(leaving.id());
  v1::UnregisterResponse resp;
  ASSERT_TRUE(v1::WorkerService::NewStub(channel_)->Unregister(&ctx, wid, &resp).ok());

  // The round's four tiles, the one the leaving worker held among them, without waiting.
  std::set<uint32_t> tiles;
  for (int i = 0; i < 4; ++i)
    if (const auto t = other.lease()) tiles.insert(t->tile_index());
  EXPECT_EQ(tiles.size(), 4u);
  EXPECT_EQ(tiles.count(held->tile_index()), 1u) << "the tile held at Unregister was not leased again";
  EXPECT_EQ(status(id).tiles_re_leased(), 1u);
}

}  // namespace
}  // namespace epr::test
