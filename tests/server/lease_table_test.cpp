// Lease policy without gRPC and without sleeping: the table runs on a clock the test sets.
#include "master/server/lease_table.h"

#include <gtest/gtest.h>

namespace epr {
namespace {

struct LeaseTableTest : ::testing::Test {
  int64_t now = 1000;
  JobCounters counters;
  LeasePolicy policy{/*lease_timeout_ms=*/100, /*heartbeat_interval_ms=*/10, /*speculative_factor=*/2.0,
                     /*speculative_floor_ms=*/10, /*max_worker_failures=*/2};
  uint64_t next_lease = 1;

  LeaseTable make(size_t tiles) {
    return LeaseTable(
        "j1", tiles, policy, [this] { return now; }, &counters);
  }
  std::optional<LeaseTable::Grant> lease(LeaseTable& t, const std::string& worker, uint64_t* id = nullptr) {
    const uint64_t l = next_lease++;
    if (id) *id = l;
    return t.lease(worker, l);
  }
  // Round 0 of two tiles: "slow" leases tile 0, "fast" tile 1 and commits it `fast_ms` later (the
  // round's median tile time). The slow lease's id.
  uint64_t slow_and_fast(LeaseTable& t, int64_t fast_ms) {
    t.open_round(0, {0, 1});
    uint64_t slow = 0, fast = 0;
    lease(t, "slow", &slow);
    lease(t, "fast", &fast);
    now += fast_ms;
    std::vector<uint64_t> losers;
    t.commit(1, fast, &losers);
    return slow;
  }
};

TEST_F(LeaseTableTest, LeasesTilesInTheRoundsOrderThenNothing) {
  LeaseTable t = make(4);
  t.open_round(0, {2, 0, 3});  // tile 1 is idle
  std::vector<uint32_t> got;
  while (auto g = lease(t, "a")) got.push_back(g->tile);
  EXPECT_EQ(got, (std::vector<uint32_t>{2, 0, 3}));
  EXPECT_EQ(counters.tiles_leased, 3u);
  EXPECT_EQ(t.waiting(), 0u);
}

TEST_F(LeaseTableTest, IdleAndCommittedTilesTakeNoSecondResult) {
  LeaseTable t = make(2);
  t.open_round(0, {0});
  uint64_t id = 0;
  ASSERT_TRUE(lease(t, "a", &id));
  std::vector<uint64_t> losers;
  EXPECT_EQ(t.commit(0, id, &losers), LeaseTable::CommitOutcome::kCommitted);
  EXPECT_EQ(t.commit(0, id, &losers), LeaseTable::CommitOutcome::kDuplicate);
  EXPECT_EQ(t.commit(1, id, &losers), LeaseTable::CommitOutcome::kDuplicate);  // idle tile
  EXPECT_TRUE(losers.empty());
  EXPECT_FALSE(t.extend(id)) << "a committed lease is no longer wanted";
}

TEST_F(LeaseTableTest, AHeartbeatKeepsALeaseAliveAndSilenceExpiresIt) {
  LeaseTable t = make(2);
  t.open_round(0, {0, 1});
  uint64_t id = 0;
  ASSERT_EQ(lease(t, "a", &id)->deadline_ms, now + 100);
  now += 60;
  ASSERT_EQ(t.extend(id), now + 100);
  now += 60;  // 120 ms after the grant, 60 after the heartbeat
  EXPECT_TRUE(t.expire().empty());
  now += 41;
  const auto expired = t.expire();
  ASSERT_EQ(expired.size(), 1u);
  EXPECT_EQ(expired[0].tile, 0u);
  EXPECT_EQ(expired[0].worker, "a");
  EXPECT_EQ(counters.worker_failures, 1u);
  EXPECT_FALSE(t.extend(id));
  // The expired tile goes first, and its new lease counts as a re-lease.
  auto g = lease(t, "b");
  ASSERT_TRUE(g);
  EXPECT_EQ(g->tile, 0u);
  EXPECT_EQ(counters.tiles_re_leased, 1u);
}

TEST_F(LeaseTableTest, AResultAfterExpiryStillWins) {
  LeaseTable t = make(1);
  t.open_round(0, {0});
  uint64_t id = 0;
  ASSERT_TRUE(lease(t, "a", &id));
  now += 101;
  ASSERT_EQ(t.expire().size(), 1u);
  EXPECT_EQ(t.waiting(), 1u);
  EXPECT_TRUE(t.issued(0, id));
  std::vector<uint64_t> losers;
  EXPECT_EQ(t.commit(0, id, &losers), LeaseTable::CommitOutcome::kCommitted);
  EXPECT_EQ(t.waiting(), 0u) << "the committed tile left the queue";
  EXPECT_FALSE(lease(t, "b"));
}

TEST_F(LeaseTableTest, ALongLeaseOfALiveHolderGetsOneSpeculativeCopyAndTheFirstResultWins) {
  LeaseTable t = make(2);
  t.open_round(0, {0, 1});
  uint64_t slow = 0, fast = 0;
  ASSERT_EQ(lease(t, "slow", &slow)->tile, 0u);
  ASSERT_EQ(lease(t, "fast", &fast)->tile, 1u);
  now += 20;
  std::vector<uint64_t> losers;
  ASSERT_EQ(t.commit(1, fast, &losers), LeaseTable::CommitOutcome::kCommitted);  // median tile time 20 ms
  now += 15;                                                                     // tile 0 out for 35 ms < 2 x 20
  ASSERT_TRUE(t.extend(slow));
  EXPECT_FALSE(lease(t, "fast"));
  now += 10;  // 45 ms > 2 x 20 and > the 10 ms floor; the holder's heartbeat was 10 ms ago
  ASSERT_TRUE(t.extend(slow));
  EXPECT_FALSE(lease(t, "slow")) << "no copy of a tile to its own holder";
  uint64_t copy = 0;
  auto g = lease(t, "fast", &copy);
  ASSERT_TRUE(g);
  EXPECT_EQ(g->tile, 0u);
  EXPECT_TRUE(g->speculative);
  EXPECT_EQ(counters.tiles_speculative, 1u);
  EXPECT_FALSE(lease(t, "other")) << "one copy per tile and round";
  ASSERT_EQ(t.commit(0, copy, &losers), LeaseTable::CommitOutcome::kCommitted);
  EXPECT_EQ(losers, std::vector<uint64_t>{slow});
  EXPECT_FALSE(t.extend(slow));
  EXPECT_EQ(t.commit(0, slow, &losers), LeaseTable::CommitOutcome::kDuplicate);
}

TEST_F(LeaseTableTest, NoSpeculativeCopyOfADeadHoldersTile) {
  LeaseTable t = make(2);
  slow_and_fast(t, 5);
  now += 50;  // long past 2 x 5 ms, but no heartbeat for 55 ms > 1.5 heartbeat intervals
  EXPECT_FALSE(lease(t, "fast"));
  EXPECT_EQ(counters.tiles_speculative, 0u);
}

TEST_F(LeaseTableTest, NoSpeculativeCopyWhenDisabled) {
  policy.speculative_factor = 0;
  policy.speculative_floor_ms = 0;
  LeaseTable t = make(2);
  const uint64_t slow = slow_and_fast(t, 1);
  for (int i = 0; i < 100; ++i) {  // a thousand times the median, the holder alive throughout
    now += 10;
    t.extend(slow);
    ASSERT_FALSE(lease(t, "fast"));
  }
  EXPECT_EQ(counters.tiles_speculative, 0u);
}

TEST_F(LeaseTableTest, SpeculationUsesThePreviousRoundsTimesUntilThisRoundCommits) {
  LeaseTable t = make(2);
  t.open_round(0, {0});
  uint64_t id = 0;
  lease(t, "a", &id);
  now += 100;  // a 100 ms tile: the threshold is 200 ms
  std::vector<uint64_t> losers;
  t.commit(0, id, &losers);
  t.open_round(1, {0, 1});
  lease(t, "a", &id);
  lease(t, "b");
  now += 150;
  t.extend(id);
  EXPECT_FALSE(lease(t, "c")) << "150 ms is under twice the previous round's median";
  now += 60;
  t.extend(id);
  EXPECT_TRUE(lease(t, "c"));
}

TEST_F(LeaseTableTest, FailuresBlockAWorkerAndAJobEveryWorkerIsBlockedForCannotGoOn) {
  LeaseTable t = make(4);
  t.open_round(0, {0, 1, 2, 3});
  uint64_t a1 = 0, a2 = 0, b1 = 0;
  lease(t, "a", &a1);
  lease(t, "a", &a2);
  lease(t, "b", &b1);
  EXPECT_TRUE(t.release(a1, "a", LeaseFailure::kTile, "bad tile"));
  EXPECT_FALSE(t.blocked("a"));
  EXPECT_FALSE(t.release(a1, "a", LeaseFailure::kTile, "again")) << "a lease is given back once";
  EXPECT_TRUE(t.release(a2, "a", LeaseFailure::kTile, "bad tile"));
  EXPECT_TRUE(t.blocked("a"));
  EXPECT_EQ(counters.worker_failures, 2u);
  EXPECT_FALSE(t.all_blocked({"a", "b"}));
  const auto why = t.all_blocked({"a"});
  ASSERT_TRUE(why);
  EXPECT_NE(why->find("bad tile"), std::string::npos) << *why;
  // Someone else's lease, or a return without failure, counts against nobody.
  EXPECT_TRUE(t.release(b1, "a", LeaseFailure::kTile, "not mine"));
  EXPECT_EQ(counters.worker_failures, 2u);
  EXPECT_FALSE(t.blocked("b"));
}

TEST_F(LeaseTableTest, AJobWhoseSceneNoWorkerLoadsSaysSo) {
  LeaseTable t = make(2);
  t.open_round(0, {0, 1});
  for (int i = 0; i < 2; ++i) {
    uint64_t id = 0;
    ASSERT_TRUE(lease(t, "a", &id));
    t.release(id, "a", LeaseFailure::kScene, "scene.obj:3: bad face");
  }
  const auto why = t.all_blocked({"a"});
  ASSERT_TRUE(why);
  EXPECT_NE(why->find("no worker could load the job's scene"), std::string::npos) << *why;
  EXPECT_NE(why->find("scene.obj:3"), std::string::npos) << *why;
}

TEST_F(LeaseTableTest, ANewRoundForgetsTheOldRoundsLeases) {
  LeaseTable t = make(1);
  t.open_round(0, {0});
  uint64_t id = 0;
  lease(t, "a", &id);
  t.open_round(1, {0});
  EXPECT_FALSE(t.issued(0, id));
  EXPECT_FALSE(t.extend(id));
  EXPECT_EQ(t.round(), 1u);
}

TEST_F(LeaseTableTest, ATileWhoseLeasesExpireMaxTileLossesTimesIsGivenUp) {
  policy.max_worker_failures = 0;  // the dead workers' own failures are not what this tests
  policy.max_tile_losses = 3;
  LeaseTable t = make(2);
  t.open_round(0, {0, 1});
  // Tile 1's lease is given back (a graceful stop): that loses no worker.
  uint64_t back = 0;
  ASSERT_EQ(lease(t, "a", &back)->tile, 0u);
  EXPECT_TRUE(t.release(back, "a", LeaseFailure::kNone, ""));
  // Each worker that takes tile 0 vanishes: its lease expires.
  for (int i = 1; i <= 2; ++i) {
    ASSERT_EQ(lease(t, "dies" + std::to_string(i))->tile, 0u);
    now += policy.lease_timeout_ms + 1;
    ASSERT_EQ(t.expire().size(), 1u);
    EXPECT_FALSE(t.lost_tile()) << "after " << i << " losses";
  }
  // The losses count over rounds.
  uint64_t other = 0;
  ASSERT_EQ(lease(t, "b", &other)->tile, 0u);
  std::vector<uint64_t> losers;
  t.commit(0, other, &losers);
  t.open_round(1, {0, 1});
  ASSERT_EQ(lease(t, "dies3")->tile, 0u);
  now += policy.lease_timeout_ms + 1;
  ASSERT_EQ(t.expire().size(), 1u);
  ASSERT_TRUE(t.lost_tile());
  EXPECT_EQ(t.lost_tile()->tile, 0u);
  EXPECT_EQ(t.lost_tile()->losses, 3);
  EXPECT_FALSE(lease(t, "fresh")) << "no tile goes out once one is given up";
}

TEST_F(LeaseTableTest, ZeroMaxTileLossesNeverGivesATileUp) {
  policy.max_worker_failures = 0;
  policy.max_tile_losses = 0;
  LeaseTable t = make(1);
  t.open_round(0, {0});
  for (int i = 0; i < 5; ++i) {
    ASSERT_TRUE(lease(t, "dies" + std::to_string(i)));
    now += policy.lease_timeout_ms + 1;
    ASSERT_EQ(t.expire().size(), 1u);
  }
  EXPECT_FALSE(t.lost_tile());
  EXPECT_TRUE(lease(t, "fresh"));
}

}  // namespace
}  // namespace epr
