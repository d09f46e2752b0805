// One pool of workers serving several independent masters: real epr-master and epr-worker processes
// on loopback, each worker given every master's address (--master A,B). Each master's job must equal
// `epr render --single-process` of the same job, as with one master (M, M' and the path-traced
// estimate bit-identical, the combined image within float rounding: tests/integration/cluster); a
// master that is down when the workers start is picked up once it starts; a master SIGKILLed mid-job
// and restarted on its state directory resumes its job from the checkpoint while the other master's
// job goes on.
//
// Workers log at debug level: their lease lines ("lease N: job J round R tile T from MASTER") say
// which master granted which tile (the " from MASTER" part appears with several masters). Each test keeps its folder of
// logs and prints their tails when it fails.
#include "multi_master_fixture.h"

namespace epr::testing {
namespace {

// Two masters, one job each, three workers given both addresses: both jobs end, each equal to its
// single-process render, and every worker registered with both masters.
TEST_F(MultiMasterTest, TwoMastersShareThreeWorkers) {
  masters_.reserve(2);
  const Args ja = job_flags(21, 6), jb = job_flags(22, 6);
  start_reference(ja, "ref-a");
  start_reference(jb, "ref-b");
  MasterProc& a = add_master("master-a");
  MasterProc& b = add_master("master-b");
  for (const char* n : {"w1", "w2", "w3"}) start_worker(n);
  ASSERT_TRUE(wait_until([&] { return registered(a) >= 3 && registered(b) >= 3; }, 30s))
      << "the workers did not register with both masters";
  const std::string ida = submit(a, ja), idb = submit(b, jb);
  ASSERT_FALSE(ida.empty());
  ASSERT_FALSE(idb.empty());
  note("jobs %s (master-a) and %s (master-b) submitted", ida.c_str(), idb.c_str());
  ASSERT_NO_FATAL_FAILURE(expect_job_equals_reference(a, ida, "a", "ref-a"));
  ASSERT_NO_FATAL_FAILURE(expect_job_equals_reference(b, idb, "b", "ref-b"));
  note("both jobs done and equal to their references");
  EXPECT_GT(leased_from(a), 0u);
  EXPECT_GT(leased_from(b), 0u);
  for (auto& w : workers_) {
    EXPECT_EQ(count_of(w->err(), "registered with " + a.address() + " as "), 1u) << w->name();
    EXPECT_EQ(count_of(w->err(), "registered with " + b.address() + " as "), 1u) << w->name();
  }
  // SIGTERM: each worker leaves both masters.
  for (auto& w : workers_) {
    EXPECT_EQ(w->stop(10s), 0) << w->err();
    EXPECT_EQ(count_of(w->err(), "left " + a.address() + " ("), 1u) << w->name();
    EXPECT_EQ(count_of(w->err(), "left " + b.address() + " ("), 1u) << w->name();
  }
}

// A master that is down when the workers start: they serve the other one, and register with the late
// one once it listens; its job then ends equal to its reference. The late one is named by a host name
// (localhost), so the worker's own resolution runs as well.
TEST_F(MultiMasterTest, AMasterDownAtTheStartIsPickedUpLater) {
  masters_.reserve(2);
  const Args ja = job_flags(23, 6), jb = job_flags(24, 4);
  start_reference(ja, "ref-a");
  start_reference(jb, "ref-b");
  MasterProc& a = add_master("master-a");
  MasterProc& late = add_master("master-b", /*start=*/false);
  late.host = "localhost";  // a name: the worker resolves it (getaddrinfo: one address, 127.0.0.1)
  start_worker("w1");
  start_worker("w2");
  ASSERT_TRUE(wait_until([&] { return registered(a) >= 2; }, 30s));
  const std::string ida = submit(a, ja);
  ASSERT_FALSE(ida.empty());
  // The workers trace a's job while b is down, and say b is unreachable.
  ASSERT_TRUE(wait_until([&] { return leased_from(a) >= 4; }, 30s)) << "master-a got no work done";
  for (auto& w : workers_) EXPECT_NE(w->err().find("cannot register with " + late.address() + ":"), std::string::npos);
  note("master-a served while master-b is down");
  ASSERT_NO_FATAL_FAILURE(start_master(late));
  ASSERT_TRUE(wait_until([&] { return registered(late) >= 2; }, 30s)) << "the workers did not find master-b";
  note("both workers registered with master-b");
  const std::string idb = submit(late, jb);
  ASSERT_FALSE(idb.empty());
  ASSERT_NO_FATAL_FAILURE(expect_job_equals_reference(a, ida, "a", "ref-a"));
  ASSERT_NO_FATAL_FAILURE(expect_job_equals_reference(late, idb, "b", "ref-b"));
}

// Master b is SIGKILLed mid-job: master a's job goes on while b is down (tiles of a keep being
// leased); b restarted on its state directory resumes its job from the checkpoint; both jobs end
// equal to their references.
TEST_F(MultiMasterTest, AMasterKilledMidJobResumesWhileTheOtherGoesOn) {
  masters_.reserve(2);
  const Args ja = job_flags(25, 64), jb = job_flags(26, 12);
  start_reference(ja, "ref-a");
  start_reference(jb, "ref-b");
  MasterProc& a = add_master("master-a");
  MasterProc& b = add_master("master-b");
  start_worker("w1");
  start_worker("w2");
  ASSERT_TRUE(wait_until([&] { return registered(a) >= 2 && registered(b) >= 2; }, 30s));
  const std::string ida = submit(a, ja), idb = submit(b, jb);
  ASSERT_FALSE(ida.empty());
  ASSERT_FALSE(idb.empty());
  ASSERT_TRUE(wait_until([&] { return leased_from(b, 2) > 0; }, 60s)) << "master-b's job never reached round 2";
  ASSERT_EQ(b.proc->err().find("job " + idb + " done"), std::string::npos) << "b's job ended before the kill";
  b.proc->signal(SIGKILL);
  ASSERT_EQ(b.proc->wait_for(5s), 128 + SIGKILL);
  b.old_logs.push_back(b.proc->err());
  const size_t a_before = leased_from(a);
  note("master-b SIGKILLed; %zu tiles of master-a leased so far", a_before);
  // With b down, a's job is not stalled: more of its tiles are leased (8 = two rounds of 4 tiles).
  EXPECT_TRUE(wait_until([&] { return leased_from(a) >= a_before + 8; }, 30s))
      << "master-a's job stalled while master-b was down";
  ASSERT_EQ(a.proc->err().find("job " + ida + " done"), std::string::npos)
      << "a's job ended before b came back: make it longer";
  note("master-a's job went on: %zu tiles leased", leased_from(a));
  ASSERT_NO_FATAL_FAILURE(start_master(b));
  const std::regex loaded("run ([0-9]+), 1 jobs loaded, 1 resume from their checkpoint, 0 start from round 0");
  EXPECT_TRUE(std::regex_search(b.proc->err(), loaded)) << b.proc->err();
  ASSERT_TRUE(wait_until([&] { return registered(b) >= 2; }, 30s)) << "the workers did not register again with b";
  note("master-b restarted; both workers registered again");
  ASSERT_NO_FATAL_FAILURE(expect_job_equals_reference(a, ida, "a", "ref-a"));
  ASSERT_NO_FATAL_FAILURE(expect_job_equals_reference(b, idb, "b", "ref-b"));
  for (auto& w : workers_) EXPECT_EQ(count_of(w->err(), "registered with " + a.address() + " as "), 1u) << w->name();
}

}  // namespace
}  // namespace epr::testing
