// The monitoring endpoint over HTTP against an in-process master that renders real jobs (real
// WorkerNode over loopback gRPC): health and readiness, the JSON API against the job's final state
// (gRPC status and the master's stats.json), preview PNGs per layer, errors as JSON, read-only
// methods, /metrics through python3-prometheus-client with counters that increase over a render, and
// `epr render` printing a dashboard URL that answers.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <map>
#include <set>

#include "common/image.h"
#include "monitoring_helpers.h"
#include "worker/worker_node.h"

namespace epr::monitoring_test {
namespace {

class MonitoringEndpointTest : public ::testing::Test {
 protected:
  void SetUp() override {
    master_ = start_master();
    client_ = std::make_unique<JobClient>(master_->local_target());
  }
  void TearDown() override {
    stop_worker();
    master_->shutdown();
  }

  void start_worker() {
    WorkerNodeOptions wo;
    wo.master = master_->local_target();
    wo.threads = 2;
    wo.name = "monitoring-test";
    node_ = std::make_unique<WorkerNode>(wo);
    runner_ = std::thread([n = node_.get()] { n->run(); });
  }
  void stop_worker() {
    if (!node_) return;
    node_->stop();
    runner_.join();
    node_.reset();
  }
  bool wait_done(const std::string& id, double seconds = 120) {
    return wait_for(
        [&] {
          auto s = master_->jobs().get(id);
          return s && s->state != JobState::kQueued && s->state != JobState::kRunning;
        },
        seconds);
  }
  // Renders `o` to completion with one local worker node.
  std::string render(const RenderOptions& o) {
    const std::string id = client_->submit(o);
    start_worker();
    EXPECT_TRUE(wait_done(id)) << "the job did not finish";
    EXPECT_EQ(master_->jobs().get(id)->state, JobState::kDone);
    return id;
  }

  std::unique_ptr<MasterServer> master_;
  std::unique_ptr<JobClient> client_;
  std::unique_ptr<WorkerNode> node_;
  std::thread runner_;
};

TEST_F(MonitoringEndpointTest, HealthAndReadinessAnswerJson) {
  auto http = http_client(*master_);
  EXPECT_EQ(get_json(http, "/healthz"), (json{{"status", "ok"}}));
  // Forced CPU reprojector: ready without OSMesa, and it says so.
  const json ready = get_json(http, "/readyz");
  EXPECT_EQ(ready["ready"], true);
  EXPECT_EQ(ready["osmesa"], false);
  EXPECT_EQ(ready["reprojector"], "cpu");
}

TEST(MonitoringReadiness, ReadyzReportsTheOsmesaContext) {
  // Default back-end: GL if OSMesa gives a context. /readyz answers 503 until the context is up and
  // then 200 with osmesa=true; on a machine without OSMesa it stays 503 and names the reason.
  auto master = start_master("");
  auto http = http_client(*master);
  json body;
  int status = 0;
  wait_for(
      [&] {
        auto r = http.Get("/readyz");
        if (!r) return false;
        status = r->status;
        body = json::parse(r->body);
        return status == 200;
      },
      30);
  if (master->jobs().gl_ready()) {
    EXPECT_EQ(status, 200) << body;
    EXPECT_EQ(body["osmesa"], true);
    EXPECT_EQ(body["reprojector"], "gl");
  } else {
    EXPECT_EQ(status, 503) << body;
    EXPECT_EQ(body["ready"], false);
    EXPECT_TRUE(body.contains("reason"));
  }
  master->shutdown();
}

TEST_F(MonitoringEndpointTest, JobJsonMatchesTheFinalStateGrpcAndStatsJson) {
  const RenderOptions o = small_job(8);
  const std::string id = render(o);
  auto http = http_client(*master_);
  const json j = get_json(http, "/api/v1/jobs/" + id);
  ASSERT_TRUE(j.is_object());

  // Every documented field is there.
  for (const char* key : {"id",
                          "name",
                          "state",
                          "error",
                          "scene",
                          "settings",
                          "round",
                          "rounds_planned",
                          "progress",
                          "elapsed_seconds",
                          "eta_seconds",
                          "spp",
                          "pixels",
                          "eye_paths",
                          "rays_traced",
                          "vertices_received",
                          "reprojection",
                          "non_finite_dropped",
                          "time",
                          "tiles",
                          "workers_active",
                          "workers"})
    EXPECT_TRUE(j.contains(key)) << key;
  for (const char* key : {"min", "mean", "target", "paths_mean", "reprojected_mean"})
    EXPECT_TRUE(j["spp"].contains(key)) << key;
  for (const char* key :
       {"considered", "accepted", "occluded", "culled", "accepted_percent", "occluded_percent", "culled_percent"})
    EXPECT_TRUE(j["reprojection"].contains(key)) << key;
  for (const char* key : {"leased", "committed", "re_leased", "dropped"}) EXPECT_TRUE(j["tiles"].contains(key)) << key;
  for (const char* key : {"tracing_seconds", "reprojecting_seconds"}) EXPECT_TRUE(j["time"].contains(key)) << key;

  // The final state, internally consistent.
  EXPECT_EQ(j["id"], id);
  EXPECT_EQ(j["state"], "done");
  EXPECT_EQ(j["progress"], 1.0);
  EXPECT_EQ(j["eta_seconds"], 0.0);
  EXPECT_EQ(j["settings"]["width"], o.width);
  EXPECT_EQ(j["settings"]["mode"], "skip");
  EXPECT_EQ(j["pixels"]["total"], o.width * o.height);
  EXPECT_GE(j["spp"]["min"].get<double>(), o.spp);  // skip mode ends when every pixel has P samples
  EXPECT_GE(j["spp"]["mean"].get<double>(), j["spp"]["min"].get<double>());
  EXPECT_EQ(j["spp"]["target"], o.spp);
  EXPECT_NEAR(j["spp"]["paths_mean"].get<double>() * o.width * o.height, j["eye_paths"]["traced"].get<double>(), 0.5);
  EXPECT_GT(j["eye_paths"]["skipped"].get<uint64_t>(), 0u);  // the cornell box reprojects enough to skip
  const json& rp = j["reprojection"];
  EXPECT_EQ(rp["considered"].get<uint64_t>(), rp["accepted"].get<uint64_t>() + rp["occluded"].get<uint64_t>() +
                                                  rp["culled"].get<uint64_t>() + rp["not_diffuse"].get<uint64_t>() +
                                                  rp["invalid"].get<uint64_t>());
  EXPECT_EQ(rp["considered"].get<uint64_t>(),
            j["vertices_received"].get<uint64_t>() + rp["culled_by_workers"].get<uint64_t>());
  EXPECT_GT(rp["accepted_percent"].get<double>(), 0.0);
  EXPECT_NEAR(
      rp["accepted_percent"].get<double>() + rp["occluded_percent"].get<double>() + rp["culled_percent"].get<double>(),
      100.0 - 100.0 * (rp["not_diffuse"].get<double>() + rp["invalid"].get<double>()) / rp["considered"].get<double>(),
      1e-9);
  EXPECT_EQ(j["tiles"]["committed"], j["tiles"]["leased"]);  // nothing failed
  EXPECT_EQ(j["tiles"]["re_leased"], 0);
  EXPECT_EQ(j["tiles"]["dropped"], 0);
  EXPECT_GT(j["time"]["tracing_seconds"].get<double>(), 0.0);
  EXPECT_GT(j["time"]["reprojecting_seconds"].get<double>(), 0.0);
  ASSERT_EQ(j["workers"].size(), 1u);
  const json& w = j["workers"][0];
  EXPECT_EQ(w["name"], "monitoring-test");
  EXPECT_GE(w["heartbeat_age_seconds"].get<double>(), 0.0);
  EXPECT_LT(w["heartbeat_age_seconds"].get<double>(), 10.0);
  EXPECT_GT(w["paths_per_second"].get<double>(), 0.0);
  EXPECT_EQ(w["paths_traced"], j["eye_paths"]["traced"]);

  // One source of truth: the gRPC status says the same.
  const v1::JobStatus st = client_->get(id);
  EXPECT_EQ(j["round"].get<uint32_t>(), st.round());
  EXPECT_EQ(j["rounds_planned"].get<uint32_t>(), st.rounds_planned());
  EXPECT_EQ(j["spp"]["min"].get<double>(), double(st.spp_min()));
  EXPECT_EQ(j["spp"]["mean"].get<double>(), st.spp_mean());
  EXPECT_EQ(j["eye_paths"]["traced"].get<uint64_t>(), st.paths_traced());
  EXPECT_EQ(j["eye_paths"]["skipped"].get<uint64_t>(), st.paths_skipped());
  EXPECT_EQ(j["rays_traced"].get<uint64_t>(), st.rays_traced());
  EXPECT_EQ(j["vertices_received"].get<uint64_t>(), st.vertices_received());
  EXPECT_EQ(rp["accepted"].get<uint64_t>(), st.vertices_accepted());
  EXPECT_EQ(rp["occluded"].get<uint64_t>(), st.vertices_occluded());
  EXPECT_EQ(rp["culled"].get<uint64_t>(), st.vertices_culled());
  EXPECT_EQ(j["tiles"]["committed"].get<uint64_t>(), st.tiles_committed());
  EXPECT_EQ(j["elapsed_seconds"].get<double>(), st.seconds_elapsed());
  EXPECT_EQ(j["time"]["reprojecting_seconds"].get<double>(), st.seconds_reprojecting());

  // And the master's own statistics file of the finished job.
  const auto stats_path = master_->jobs().result_path(id, ResultKind::kJson);
  ASSERT_TRUE(stats_path);
  const json stats = json::parse(read_file(*stats_path));
  EXPECT_EQ(j["rays_traced"], stats["rays"]);
  EXPECT_EQ(j["vertices_received"], stats["vertices_received"]);
  EXPECT_EQ(j["tiles"]["committed"], stats["tiles_committed"]);
  EXPECT_EQ(rp["culled_by_workers"], stats["culled_worker"]);

  // The list carries the same job document (without the per-job worker copy).
  const json list = get_json(http, "/api/v1/jobs");
  ASSERT_EQ(list["jobs"].size(), 1u);
  json one = j;
  one.erase("workers");
  EXPECT_EQ(list["jobs"][0], one);
  EXPECT_EQ(list["workers"].size(), 1u);
}

TEST_F(MonitoringEndpointTest, PreviewLayersArePngsOfTheImageSize) {
  RenderOptions o = small_job(6);
  o.width = 80;  // not square, not a multiple of the tile size
  o.height = 36;
  const std::string id = render(o);
  auto http = http_client(*master_);
  const fs::path dir = scratch_dir("layers");
  std::set<std::string> digests;
  for (const std::string layer : {"combined", "pathtrace", "reprojection", "samples"}) {
    SCOPED_TRACE(layer);
    auto r = http.Get(("/api/v1/jobs/" + id + "/image.png?layer=" + layer).c_str());
    ASSERT_TRUE(r);
    ASSERT_EQ(r->status, 200) << r->body;
    EXPECT_EQ(r->get_header_value("Content-Type"), "image/png");
    EXPECT_EQ(png_size(r->body), std::make_pair(uint32_t(o.width), uint32_t(o.height)));
    // A real PNG decoder (OpenImageIO) reads it back at that size.
    const fs::path file = dir / (layer + ".png");
    std::ofstream(file, std::ios::binary) << r->body;
    const Image img = read_image(file.string());
    EXPECT_EQ(img.width, o.width);
    EXPECT_EQ(img.height, o.height);
    digests.insert(r->body);
    // The ETag lets a poller skip unchanged previews.
    const std::string etag = r->get_header_value("ETag");
    EXPECT_FALSE(etag.empty());
    auto again = http.Get(("/api/v1/jobs/" + id + "/image.png?layer=" + layer).c_str(), {{"If-None-Match", etag}});
    ASSERT_TRUE(again);
    EXPECT_EQ(again->status, 304);
  }
  EXPECT_EQ(digests.size(), 4u) << "the layers should be four different images";
  // The default layer is the combined image.
  auto def = http.Get(("/api/v1/jobs/" + id + "/image.png").c_str());
  ASSERT_TRUE(def);
  auto combined = http.Get(("/api/v1/jobs/" + id + "/image.png?layer=combined").c_str());
  ASSERT_TRUE(combined);
  EXPECT_EQ(def->body, combined->body);
}

TEST_F(MonitoringEndpointTest, ErrorsAreJson) {
  auto http = http_client(*master_);
  json e = get_json(http, "/api/v1/jobs/j999999-dead", 404);
  EXPECT_EQ(e["reason"], "no_job");
  EXPECT_NE(e["error"].get<std::string>().find("j999999-dead"), std::string::npos);
  e = get_json(http, "/api/v1/jobs/j999999-dead/image.png?layer=combined", 404);
  EXPECT_EQ(e["reason"], "no_job");
  e = get_json(http, "/no/such/path", 404);
  EXPECT_TRUE(e.contains("error"));

  // A job without workers: no round has closed, so no preview yet.
  const std::string id = client_->submit(small_job());
  e = get_json(http, "/api/v1/jobs/" + id + "/image.png?layer=samples", 404);
  EXPECT_EQ(e["reason"], "pending");
  e = get_json(http, "/api/v1/jobs/" + id + "/image.png?layer=depth", 400);
  EXPECT_EQ(e["reason"], "bad_layer");
  const json j = get_json(http, "/api/v1/jobs/" + id);
  EXPECT_EQ(j["round"], 0);
  EXPECT_TRUE(j["eta_seconds"].is_null());

  // A path-tracing job has no reprojection layers, even when finished.
  client_->cancel(id);
  RenderOptions pt = small_job(2);
  pt.mode = RenderMode::kPathTrace;
  const std::string pt_id = render(pt);
  e = get_json(http, "/api/v1/jobs/" + pt_id + "/image.png?layer=reprojection", 404);
  EXPECT_EQ(e["reason"], "layer_unavailable");
  auto r = http.Get(("/api/v1/jobs/" + pt_id + "/image.png?layer=pathtrace").c_str());
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 200);
}

TEST_F(MonitoringEndpointTest, RefusesWrites) {
  const std::string id = client_->submit(small_job());
  ASSERT_TRUE(wait_for([&] { return master_->jobs().get(id)->state == JobState::kRunning; }, 30));
  auto http = http_client(*master_);
  for (const std::string& path :
       std::vector<std::string>{"/", "/api/v1/jobs", "/api/v1/jobs/" + id, "/api/v1/jobs/" + id + "/image.png",
                                "/metrics", "/healthz", "/nowhere"}) {
    SCOPED_TRACE(path);
    std::vector<httplib::Result> results;
    results.push_back(http.Post(path.c_str(), "{\"state\":\"cancelled\"}", "application/json"));
    results.push_back(http.Put(path.c_str(), "{}", "application/json"));
    results.push_back(http.Delete(path.c_str()));
    results.push_back(http.Patch(path.c_str(), "{}", "application/json"));
    results.push_back(http.Options(path.c_str()));
    for (auto& r : results) {
      ASSERT_TRUE(r);
      EXPECT_EQ(r->status, 405);
      EXPECT_EQ(r->get_header_value("Allow"), "GET, HEAD");
      EXPECT_TRUE(json::parse(r->body, nullptr, false).contains("error")) << r->body;
    }
  }
  // Nothing changed, and the connection still serves reads.
  EXPECT_EQ(master_->jobs().get(id)->state, JobState::kRunning);
  EXPECT_EQ(get_json(http, "/api/v1/jobs/" + id)["state"], "running");
  auto head = http.Head("/healthz");
  ASSERT_TRUE(head);
  EXPECT_EQ(head->status, 200);
}

TEST_F(MonitoringEndpointTest, DashboardIsServedSelfContained) {
  auto http = http_client(*master_);
  auto r = http.Get("/");
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 200);
  EXPECT_EQ(r->get_header_value("Content-Type"), "text/html; charset=utf-8");
  EXPECT_NE(r->body.find("<title>eprfarm</title>"), std::string::npos);
  EXPECT_NE(r->body.find("window.eprDashboard"), std::string::npos);
  // No network: nothing is loaded from elsewhere.
  for (const char* remote : {"http://", "https://", "//cdn", "<link rel=\"stylesheet\" href"})
    EXPECT_EQ(r->body.find(remote), std::string::npos) << remote;
}

// ---- /metrics -------------------------------------------------------------------------------------

TEST_F(MonitoringEndpointTest, MetricsParseAndCountersIncreaseOverARender) {
  auto http = http_client(*master_);
  const fs::path scratch = scratch_dir("metrics");
  auto scrape = [&] {
    auto r = http.Get("/metrics");
    EXPECT_TRUE(r && r->status == 200);
    if (!r) return json{};
    EXPECT_EQ(r->get_header_value("Content-Type"), "text/plain; version=0.0.4; charset=utf-8");
    return parse_prometheus(r->body, scratch);
  };

  const std::string id = client_->submit(small_job(12));
  const json before = scrape();
  ASSERT_FALSE(before.empty());

  // Conventions: typed and documented families, counters named *_total, base units, histograms whole.
  for (const auto& [name, f] : before.items()) {
    SCOPED_TRACE(name);
    EXPECT_NE(f["type"], "unknown");
    EXPECT_FALSE(f["help"].get<std::string>().empty());
    EXPECT_EQ(name.rfind("epr_", 0), 0u);
    for (const char* unit : {"_ms", "milliseconds", "_kb", "_mb"}) EXPECT_EQ(name.find(unit), std::string::npos);
    if (f["type"] == "counter") {
      for (const auto& s : f["samples"]) EXPECT_EQ(s[0], name + "_total");
    }
  }
  for (const char* h : {"epr_round_duration_seconds", "epr_round_reprojection_seconds"}) {
    ASSERT_TRUE(before.contains(h)) << h;
    EXPECT_EQ(before[h]["type"], "histogram");
  }
  // The reprojection thread may already have started the job (deep framebuffer) when the scrape
  // comes: queued or running, exactly one of them, and nothing traced before the scrape... only if
  // it is still queued.
  const double queued = sample(before, "epr_jobs", {{"state", "queued"}});
  EXPECT_EQ(queued + sample(before, "epr_jobs", {{"state", "running"}}), 1.0);
  EXPECT_EQ(sample(before, "epr_jobs_submitted_total"), 1.0);
  if (queued == 1.0) {
    EXPECT_EQ(sample(before, "epr_eye_paths_traced_total"), 0.0);
  }
  EXPECT_EQ(sample(before, "epr_job_state", {{"job", id}, {"state", "queued"}}) +
                sample(before, "epr_job_state", {{"job", id}, {"state", "running"}}),
            1.0);

  // Scrape while the job renders: every counter sample only ever grows.
  start_worker();
  std::vector<json> scrapes{before};
  wait_for(
      [&] {
        scrapes.push_back(scrape());
        auto s = master_->jobs().get(id);
        return s && s->state == JobState::kDone;
      },
      120);
  scrapes.push_back(scrape());
  ASSERT_EQ(master_->jobs().get(id)->state, JobState::kDone);
  std::map<std::string, double> last;
  for (const json& m : scrapes)
    for (const auto& [name, f] : m.items()) {
      const bool monotone = f["type"] == "counter" || f["type"] == "histogram";
      if (!monotone) continue;
      for (const auto& s : f["samples"]) {
        const std::string key = s[0].get<std::string>() + s[1].dump();
        const double v = s[2].get<double>();
        if (last.count(key)) {
          EXPECT_GE(v, last[key]) << key << " went down";
        }
        last[key] = v;
      }
    }

  const json& after = scrapes.back();
  const json j = get_json(http, "/api/v1/jobs/" + id);
  for (const char* counter :
       {"epr_rounds_total", "epr_eye_paths_traced_total", "epr_eye_paths_skipped_total", "epr_rays_traced_total",
        "epr_vertices_received_total", "epr_tiles_leased_total", "epr_tiles_committed_total",
        "epr_tracing_seconds_total", "epr_reprojection_seconds_total"})
    EXPECT_GT(sample(after, counter), sample(before, counter)) << counter;
  EXPECT_GT(sample(after, "epr_reprojection_vertices_total", {{"outcome", "accepted"}}), 0.0);
  // Counters agree with the JSON (one source of truth).
  EXPECT_EQ(sample(after, "epr_eye_paths_traced_total"), j["eye_paths"]["traced"].get<double>());
  EXPECT_EQ(sample(after, "epr_rounds_total"), j["round"].get<double>());
  EXPECT_EQ(sample(after, "epr_tiles_committed_total"), j["tiles"]["committed"].get<double>());
  EXPECT_EQ(sample(after, "epr_reprojection_vertices_total", {{"outcome", "occluded"}}),
            j["reprojection"]["occluded"].get<double>());
  EXPECT_EQ(sample(after, "epr_job_eye_paths_traced_total", {{"job", id}}), j["eye_paths"]["traced"].get<double>());
  EXPECT_EQ(sample(after, "epr_job_spp_min", {{"job", id}}), j["spp"]["min"].get<double>());
  EXPECT_EQ(sample(after, "epr_job_state", {{"job", id}, {"state", "done"}}), 1.0);
  // One histogram observation per closed round; buckets are cumulative and end at the count.
  const double rounds = j["round"].get<double>();
  for (const std::string h : {"epr_round_duration_seconds", "epr_round_reprojection_seconds"}) {
    SCOPED_TRACE(h);
    EXPECT_EQ(sample(after, h + "_count"), rounds);
    EXPECT_EQ(sample(after, h + "_bucket", {{"le", "+Inf"}}), rounds);
    double prev = 0;
    for (const auto& s : after[h]["samples"])
      if (s[0] == h + "_bucket") {
        EXPECT_GE(s[2].get<double>(), prev);
        prev = s[2].get<double>();
      }
    EXPECT_GE(sample(after, h + "_sum"), 0.0);
  }
  EXPECT_LE(sample(after, "epr_round_reprojection_seconds_sum"),
            sample(after, "epr_reprojection_seconds_total") + 1e-9);
  // The worker's series.
  const auto workers = master_->jobs().workers();
  ASSERT_EQ(workers.size(), 1u);
  EXPECT_EQ(sample(after, "epr_worker_info", {{"worker", workers[0].id}, {"name", "monitoring-test"}}), 1.0);
  EXPECT_EQ(sample(after, "epr_worker_eye_paths_traced_total", {{"worker", workers[0].id}}),
            j["eye_paths"]["traced"].get<double>());
}

// ---- epr render -----------------------------------------------------------------------------------

TEST(EprRenderDashboard, PrintsAWorkingDashboardUrl) {
  const fs::path dir = scratch_dir("epr-render");
  // Long enough (a few seconds) that the dashboard can be asked while the render runs.
  const std::string cmd = std::string(EPR_CLIENT_BIN) +
                          " render builtin:cornell --width 96 --height 96 --spp 256 --mode pt --out " +
                          (dir / "r").string() + " 2>&1";
  FILE* p = popen(cmd.c_str(), "r");
  ASSERT_NE(p, nullptr);
  char line[4096];
  std::string output, url;
  int healthz = 0, jobs_listed = -1;
  while (fgets(line, sizeof line, p)) {
    output += line;
    std::cmatch m;
    if (url.empty() && std::regex_search(line, m, std::regex(R"(^dashboard: (http://127\.0\.0\.1:([0-9]+)/)\s*$)"))) {
      url = m[1];
      httplib::Client c("127.0.0.1", std::stoi(m[2]));
      c.set_read_timeout(5, 0);
      if (auto r = c.Get("/healthz")) healthz = r->status;
      if (auto r = c.Get("/api/v1/jobs"); r && r->status == 200) jobs_listed = int(json::parse(r->body)["jobs"].size());
    }
  }
  EXPECT_EQ(pclose(p), 0) << output;
  ASSERT_FALSE(url.empty()) << "no 'dashboard: http://127.0.0.1:PORT/' line on stderr:\n" << output;
  EXPECT_EQ(healthz, 200) << "the printed dashboard did not answer while the render ran";
  EXPECT_GE(jobs_listed, 0);

  // --http "" disables it.
  const std::string quiet = std::string(EPR_CLIENT_BIN) +
                            " render builtin:cornell --width 16 --height 16 --spp 1 --http '' --out " +
                            (dir / "q").string() + " 2>&1";
  FILE* q = popen(quiet.c_str(), "r");
  ASSERT_NE(q, nullptr);
  std::string quiet_out;
  while (fgets(line, sizeof line, q)) quiet_out += line;
  EXPECT_EQ(pclose(q), 0) << quiet_out;
  EXPECT_EQ(quiet_out.find("dashboard:"), std::string::npos) << quiet_out;
}

}  // namespace
}  // namespace epr::monitoring_test
