// Dropped tile results counted per reason (stale round, duplicate, lease of an earlier run) over real
// gRPC on loopback, and exported beside the total in the monitoring JSON and /metrics.
#include "master/server/monitoring_format.h"
#include "tests/server/farm_fixture.h"

namespace epr::test {
namespace {

class TileDropsTest : public FarmFixture {};

TEST_F(TileDropsTest, EachDroppedResultIsCountedUnderItsReason) {
  start();
  const std::string id = submit(cornell(RenderMode::kSkip, 32, 4, 2), bundle_scene("builtin:cornell"));
  WireWorker w(channel_, "w");
  auto t = w.lease_wait();
  ASSERT_TRUE(t);
  const auto good = w.render(*t);
  auto send = [&](const std::vector<v1::TileResultChunk>& chunks) {
    v1::SubmitAck ack;
    const grpc::Status st = w.submit(chunks, &ack);
    EXPECT_TRUE(st.ok()) << st.error_message();
    return ack.outcome();
  };
  auto drops = [&] { return server_->jobs().get(id)->drops; };

  auto later_round = good;
  later_round.front().mutable_header()->set_round(t->round() + 1);
  EXPECT_EQ(send(later_round), v1::SUBMIT_OUTCOME_STALE);
  EXPECT_EQ(drops(), (TileDrops{1, 0, 0}));

  // A lease id of epoch 0, below this run's ids (epoch 1 and up): leased by an earlier run.
  auto earlier_run = good;
  earlier_run.front().mutable_header()->set_lease_id(t->lease_id() &
                                                     ((uint64_t(1) << JobManager::kLeaseEpochShift) - 1));
  ASSERT_NE(earlier_run.front().header().lease_id() >> JobManager::kLeaseEpochShift, server_->jobs().epoch());
  EXPECT_EQ(send(earlier_run), v1::SUBMIT_OUTCOME_STALE);
  EXPECT_EQ(drops(), (TileDrops{1, 0, 1}));

  EXPECT_EQ(send(good), v1::SUBMIT_OUTCOME_COMMITTED);
  EXPECT_EQ(send(good), v1::SUBMIT_OUTCOME_DUPLICATE);
  EXPECT_EQ(drops(), (TileDrops{1, 1, 1}));

  // The wire's total goes on counting all of them; the monitoring JSON and /metrics add the reasons.
  EXPECT_EQ(status(id).tiles_dropped(), 3u);
  const JobSnapshot s = *server_->jobs().get(id);
  const nlohmann::json j = to_json(s);
  EXPECT_EQ(j["tiles"]["dropped"], 3);
  EXPECT_EQ(j["tiles"]["dropped_by_reason"],
            (nlohmann::json{{"stale_round", 1}, {"duplicate", 1}, {"earlier_epoch", 1}}));
  MetricsInput in;
  in.jobs = {s};
  in.totals = FarmTotals::of(s);
  const std::string metrics = prometheus_text(in);
  for (const char* line :
       {"epr_tiles_dropped_total 3\n", "epr_tiles_dropped_by_reason_total{reason=\"stale_round\"} 1\n",
        "epr_tiles_dropped_by_reason_total{reason=\"duplicate\"} 1\n",
        "epr_tiles_dropped_by_reason_total{reason=\"earlier_epoch\"} 1\n"})
    EXPECT_NE(metrics.find(line), std::string::npos) << line << metrics;
}

}  // namespace
}  // namespace epr::test
