// monitoring_format and monitoring.h's pure parts without a server: address parsing, histogram
// buckets, farm totals that stay monotone when the master forgets finished jobs, label escaping and
// bounded per-job series.
#include "master/server/monitoring_format.h"

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cmath>
#include <set>

#include "master/server/monitoring.h"
#include "monitoring_helpers.h"

namespace epr::monitoring_test {
namespace {

MonitoringOptions listening_on(const std::string& address) {
  MonitoringOptions o;
  o.listen = address;
  return o;
}

TEST(ParseHostPort, AcceptsHostPortAndBracketedV6) {
  EXPECT_EQ(parse_host_port("0.0.0.0:8080"), std::make_pair(std::string("0.0.0.0"), 8080));
  EXPECT_EQ(parse_host_port("127.0.0.1:0"), std::make_pair(std::string("127.0.0.1"), 0));
  EXPECT_EQ(parse_host_port("[::]:9090"), std::make_pair(std::string("::"), 9090));
  EXPECT_EQ(parse_host_port(":8080"), std::make_pair(std::string("0.0.0.0"), 8080));
  for (const char* bad : {"", "8080", "host:", "host:http", "host:70000", "::1:80", "host:123456"})
    EXPECT_FALSE(parse_host_port(bad)) << bad;
}

TEST(MonitoringServer, RefusesAnAddressInUseAndAMalformedOne) {
  MasterOptions options;
  options.reproject_backend_override = "cpu";
  JobManager jobs(options);
  MonitoringServer first(jobs, listening_on("127.0.0.1:0"));
  ASSERT_GT(first.port(), 0);
  EXPECT_EQ(first.url(), "http://127.0.0.1:" + std::to_string(first.port()) + "/");
  EXPECT_THROW(MonitoringServer(jobs, listening_on("127.0.0.1:" + std::to_string(first.port()))), std::runtime_error);
  EXPECT_THROW(MonitoringServer(jobs, listening_on("nonsense")), std::runtime_error);
  first.stop();
  first.stop();  // idempotent
  jobs.shutdown();
}

TEST(DurationHistogram, BucketsAreUpperBoundsAndTheRestGoesToInf) {
  DurationHistogram h;
  h.observe(0.005);  // on a bound: that bucket
  h.observe(0.3);
  h.observe(1e4);  // above every bound: only in the count
  h.observe(-1);   // a clock step: clamped to 0
  EXPECT_EQ(h.count, 4u);
  EXPECT_EQ(h.buckets[0], 2u);
  EXPECT_EQ(h.buckets[6], 1u);  // 0.5
  uint64_t in_buckets = 0;
  for (auto b : h.buckets) in_buckets += b;
  EXPECT_EQ(in_buckets, 3u);
  EXPECT_DOUBLE_EQ(h.sum, 0.005 + 0.3 + 1e4);
}

JobSnapshot job(const std::string& id, JobState state, uint64_t paths, int64_t finished_ms = 0) {
  JobSnapshot s;
  s.id = id;
  s.state = state;
  s.progress.paths_traced = paths;
  s.progress.round = int(paths);
  s.finished_ms = finished_ms;
  s.options.spp = 8;
  return s;
}

TEST(FarmTotalsTracker, StaysMonotoneWhenJobsAreForgotten) {
  FarmTotalsTracker t;
  EXPECT_EQ(t.update({job("a", JobState::kRunning, 10), job("b", JobState::kDone, 5)}).paths_traced, 15u);
  EXPECT_EQ(t.update({job("a", JobState::kRunning, 12), job("b", JobState::kDone, 5)}).paths_traced, 17u);
  // b is forgotten by the master: it keeps counting.
  const FarmTotals after = t.update({job("a", JobState::kDone, 20)});
  EXPECT_EQ(after.paths_traced, 25u);
  EXPECT_EQ(after.jobs, 2u);
  EXPECT_EQ(after.rounds, 25u);
  EXPECT_EQ(t.update({}).paths_traced, 25u);
}

TEST(PrometheusText, PerJobSeriesAreBoundedAndLabelsEscaped) {
  MetricsInput in;
  for (int i = 0; i < 30; ++i) in.jobs.push_back(job(fmt::format("done{:02d}", i), JobState::kDone, 1, 1000 + i));
  in.jobs.push_back(job("running", JobState::kRunning, 3));
  in.jobs.push_back(job("queued", JobState::kQueued, 0));
  in.jobs.back().name = "a \"quoted\" name\\with\nnewline";
  WorkerSnapshot w;
  w.id = "w1";
  w.name = "host\"x";
  in.workers.push_back(w);
  in.tiles_waiting = 42;
  FarmTotalsTracker tracker;
  in.totals = tracker.update(in.jobs);
  const json m = parse_prometheus(prometheus_text(in), scratch_dir("format"));
  ASSERT_FALSE(m.empty());
  // One value per master, no labels (an autoscaler's input).
  EXPECT_EQ(sample(m, "epr_tiles_waiting"), 42.0);
  EXPECT_EQ(m["epr_tiles_waiting"]["samples"].size(), 1u);
  std::set<std::string> labelled;
  for (const auto& s : m["epr_job_round"]["samples"]) labelled.insert(s[1]["job"]);
  EXPECT_EQ(labelled.size(), 2 + kRecentFinishedJobs);
  EXPECT_TRUE(labelled.count("running"));
  EXPECT_TRUE(labelled.count("queued"));
  EXPECT_TRUE(labelled.count("done29"));  // the most recently finished
  EXPECT_FALSE(labelled.count("done00"));
  // Farm-wide counters still count every job.
  EXPECT_EQ(sample(m, "epr_eye_paths_traced_total"), 33.0);
  EXPECT_EQ(sample(m, "epr_jobs", {{"state", "done"}}), 30.0);
  // Escaped labels come back unchanged through a real parser.
  bool found = false;
  for (const auto& s : m["epr_job_info"]["samples"])
    if (s[1]["job"] == "queued") found = s[1]["name"] == "a \"quoted\" name\\with\nnewline";
  EXPECT_TRUE(found);
  EXPECT_EQ(sample(m, "epr_worker_info", {{"worker", "w1"}, {"name", "host\"x"}}), 1.0);
  // Unknown ETA: no sample rather than a sentinel.
  EXPECT_TRUE(std::isnan(sample(m, "epr_job_eta_seconds", {{"job", "queued"}})));
}

TEST(JobJson, UnknownEtaIsNullAndPercentagesUseAllDecisions) {
  JobSnapshot s = job("j", JobState::kRunning, 0);
  s.counts.accepted = 60;
  s.counts.exact = 10;
  s.counts.occluded = 20;
  s.counts.culled = 5;
  s.counters.worker_culled = 5;
  const json j = to_json(s);
  EXPECT_TRUE(j["eta_seconds"].is_null());
  EXPECT_EQ(j["reprojection"]["considered"], 100);
  EXPECT_EQ(j["reprojection"]["accepted"], 70);
  EXPECT_EQ(j["reprojection"]["culled"], 10);
  EXPECT_DOUBLE_EQ(j["reprojection"]["accepted_percent"].get<double>(), 70.0);
  EXPECT_DOUBLE_EQ(j["reprojection"]["culled_percent"].get<double>(), 10.0);
  EXPECT_EQ(j["state"], "running");
}

TEST(JobJson, ABatchFrameNamesItsBatchAndWindow) {
  JobSnapshot s = job("j", JobState::kRunning, 0);
  EXPECT_TRUE(to_json(s)["batch"].is_null()) << "not part of a batch";
  s.batch.id = "b-1";
  s.batch.frame = 7;
  s.batch.frames = 48;
  s.batch.window = 2;
  s.batch.window_first = 1;
  s.batch.window_last = 16;
  const json b = to_json(s)["batch"];
  EXPECT_EQ(b["id"], "b-1");
  EXPECT_EQ(b["frame"], 7);
  EXPECT_EQ(b["frames"], 48);
  EXPECT_EQ(b["frame_window"], 2);
  EXPECT_EQ(b["window_first"], 1);
  EXPECT_EQ(b["window_last"], 16);
  EXPECT_EQ(b["fed_by_first"], 0) << "before its run starts";
  s.fed_by_first = 5;
  s.fed_by_last = 9;  // a cut after frame 9
  EXPECT_EQ(to_json(s)["batch"]["fed_by_first"], 5);
  EXPECT_EQ(to_json(s)["batch"]["fed_by_last"], 9);
}

}  // namespace
}  // namespace epr::monitoring_test
