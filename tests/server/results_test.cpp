// Results and listings over real gRPC against an in-process master: partial results of a running job
// (allow_partial) and a cancelled job's last committed round, the job list's order, a job that takes
// its scene's own camera, the statistics' reprojection percentages (the same as the monitoring
// endpoint's), and the scene cache after refused submissions.
#include <cmath>
#include <nlohmann/json.hpp>

#include "common/scene_loader.h"
#include "master/server/monitoring_format.h"
#include "tests/server/farm_fixture.h"

namespace epr::test {
namespace {

using json = nlohmann::json;

struct Fetched {
  grpc::Status status;
  v1::ResultHeader header;
  std::string bytes;
};

class ResultsTest : public FarmFixture {
 protected:
  Fetched fetch(const std::string& id, v1::ResultKind kind, bool allow_partial) {
    grpc::ClientContext ctx;
    set_deadline(&ctx);
    v1::ResultRequest req;
    req.set_job_id(id);
    req.set_kind(kind);
    req.set_allow_partial(allow_partial);
    auto reader = jobs_->FetchResult(&ctx, req);
    Fetched out;
    v1::ResultChunk c;
    while (reader->Read(&c)) {
      if (c.has_header()) out.header = c.header();
      if (c.has_data()) out.bytes += c.data().data();
    }
    out.status = reader->Finish();
    return out;
  }

  Image image(const Fetched& f) {
    const fs::path p = dir_ / ("fetched-" + std::to_string(++fetches_) + ".exr");
    std::ofstream(p, std::ios::binary) << f.bytes;
    return read_image(p.string());
  }

  v1::JobStatus cancel(const std::string& id) {
    grpc::ClientContext ctx;
    set_deadline(&ctx);
    v1::JobId req;
    req.set_id(id);
    v1::JobStatus st;
    EXPECT_TRUE(jobs_->CancelJob(&ctx, req, &st).ok());
    return st;
  }

  std::vector<std::string> list(uint32_t page_size, const std::string& token = "", std::string* next = nullptr,
                                std::vector<v1::JobState> states = {}) {
    grpc::ClientContext ctx;
    set_deadline(&ctx);
    v1::ListJobsRequest req;
    req.set_page_size(page_size);
    req.set_page_token(token);
    for (auto s : states) req.add_states(s);
    v1::ListJobsResponse resp;
    EXPECT_TRUE(jobs_->ListJobs(&ctx, req, &resp).ok());
    if (next) *next = resp.next_page_token();
    std::vector<std::string> ids;
    for (const auto& j : resp.jobs()) ids.push_back(j.id());
    return ids;
  }

  /// Leases, traces and submits every tile of the job's current round with a worker driven by hand.
  void trace_round(WireWorker& w, size_t tiles) {
    for (size_t i = 0; i < tiles; ++i) {
      const auto t = w.lease_wait();
      ASSERT_TRUE(t) << "no tile " << i;
      v1::SubmitAck ack;
      ASSERT_TRUE(w.submit(w.render(*t), &ack).ok());
    }
  }

  fs::path scene_cache() const { return dir_ / "master" / "cache" / "scenes"; }
};

void expect_finite_image(const Image& img, int w, int h) {
  EXPECT_EQ(img.width, w);
  EXPECT_EQ(img.height, h);
  double sum = 0;
  for (float v : img.data) {
    ASSERT_TRUE(std::isfinite(v));
    sum += v;
  }
  EXPECT_GT(sum, 0.0);  // the Cornell box is lit
}

TEST_F(ResultsTest, RunningJobServesItsLatestRoundOnlyWhenAskedAndACancelledJobKeepsIt) {
  start();
  RenderOptions o = cornell(RenderMode::kReproject, 32, /*spp=*/4, /*k=*/1);  // 4 rounds of 4 tiles
  const std::string id = submit(o, bundle_scene("builtin:cornell"));
  ASSERT_TRUE(eventually([&] { return status(id).state() == v1::JOB_STATE_RUNNING; }));

  // Nothing committed yet: no results, even when partial ones are welcome.
  Fetched early = fetch(id, v1::RESULT_KIND_EXR, true);
  EXPECT_EQ(early.status.error_code(), grpc::StatusCode::FAILED_PRECONDITION);
  EXPECT_NE(early.status.error_message().find("no committed round"), std::string::npos) << early.status.error_message();

  WireWorker w(channel_, "by-hand");
  trace_round(w, 4);
  // The round's copy is taken as it closes, just after the next round opened.
  Fetched exr;
  ASSERT_TRUE(eventually([&] {
    exr = fetch(id, v1::RESULT_KIND_EXR, true);
    return exr.status.ok();
  })) << exr.status.error_message();
  EXPECT_EQ(status(id).state(), v1::JOB_STATE_RUNNING);
  EXPECT_TRUE(exr.header.partial());
  EXPECT_EQ(exr.header.round(), 1u);
  EXPECT_EQ(exr.header.total_bytes(), exr.bytes.size());
  const Image running = image(exr);
  expect_finite_image(running, 32, 32);

  // Without allow_partial a running job still has no results, and says why.
  const Fetched refused = fetch(id, v1::RESULT_KIND_EXR, false);
  EXPECT_EQ(refused.status.error_code(), grpc::StatusCode::FAILED_PRECONDITION);
  EXPECT_NE(refused.status.error_message().find("running"), std::string::npos) << refused.status.error_message();
  EXPECT_NE(refused.status.error_message().find("allow_partial"), std::string::npos) << refused.status.error_message();

  // The other kinds of the same round.
  const Fetched stats = fetch(id, v1::RESULT_KIND_JSON, true);
  ASSERT_TRUE(stats.status.ok()) << stats.status.error_message();
  const json j = json::parse(stats.bytes);
  EXPECT_EQ(j["partial"], true);
  EXPECT_EQ(j["state"], "running");
  EXPECT_EQ(j["rounds"], 1);
  EXPECT_EQ(j["job"], id);
  EXPECT_EQ(j["tiles_committed"], 4);
  const Fetched png = fetch(id, v1::RESULT_KIND_PNG, true);
  ASSERT_TRUE(png.status.ok()) << png.status.error_message();
  EXPECT_EQ(png.bytes.compare(0, 4, "\x89PNG"), 0);
  const Fetched samples = fetch(id, v1::RESULT_KIND_SAMPLES_EXR, true);
  ASSERT_TRUE(samples.status.ok()) << samples.status.error_message();
  const Image mprime = image(samples);
  EXPECT_EQ(mprime.width, 32);
  EXPECT_EQ(mprime.height, 32);

  // Cancelled: the same round is served, with or without allow_partial, first from the copy in memory
  // and then from the files the master stores for the job.
  EXPECT_EQ(cancel(id).state(), v1::JOB_STATE_CANCELLED);
  const Fetched after = fetch(id, v1::RESULT_KIND_EXR, false);
  ASSERT_TRUE(after.status.ok()) << after.status.error_message();
  EXPECT_TRUE(after.header.partial());
  EXPECT_EQ(after.header.round(), 1u);
  EXPECT_EQ(image(after).data, running.data);
  const fs::path stored = dir_ / "master" / "jobs" / id;
  ASSERT_TRUE(eventually([&] {
    return fs::exists(stored / "combined.exr") && fs::exists(stored / "stats.json") &&
           fs::exists(stored / "samples.png");
  }));
  const Fetched from_file = fetch(id, v1::RESULT_KIND_EXR, false);
  ASSERT_TRUE(from_file.status.ok()) << from_file.status.error_message();
  EXPECT_TRUE(from_file.header.partial());
  EXPECT_EQ(from_file.header.round(), 1u);
  EXPECT_EQ(image(from_file).data, running.data);
  const Fetched cancelled_stats = fetch(id, v1::RESULT_KIND_JSON, false);
  ASSERT_TRUE(cancelled_stats.status.ok()) << cancelled_stats.status.error_message();
  const json c = json::parse(cancelled_stats.bytes);
  EXPECT_EQ(c["partial"], true);
  EXPECT_EQ(c["state"], "cancelled");
  EXPECT_EQ(c["rounds"], 1);

  // A master restarted on the same state directory serves them too.
  server_->shutdown();
  server_.reset();
  start();
  const Fetched restarted = fetch(id, v1::RESULT_KIND_EXR, false);
  ASSERT_TRUE(restarted.status.ok()) << restarted.status.error_message();
  EXPECT_TRUE(restarted.header.partial());
  EXPECT_EQ(restarted.header.round(), 1u);
  EXPECT_EQ(image(restarted).data, running.data);
}

TEST_F(ResultsTest, RunningJobHoldsAnImageCopyOnlyWhileAskedAndACancelledOneStoresItsFrame) {
  MasterOptions m;
  m.preview_interest_ms = 0;  // a copy lasts until the next round closes
  start(m);
  RenderOptions o = cornell(RenderMode::kReproject, 32, /*spp=*/4, /*k=*/1);  // 4 rounds of 4 tiles
  const std::string id = submit(o, bundle_scene("builtin:cornell"));
  ASSERT_TRUE(eventually([&] { return status(id).state() == v1::JOB_STATE_RUNNING; }));
  WireWorker w(channel_, "by-hand");
  trace_round(w, 4);
  ASSERT_TRUE(eventually([&] { return status(id).round() == 1; }));
  // Nobody asked: the closed round left no copy of the images behind.
  EXPECT_EQ(server_->jobs().preview_copy_bytes(), 0u);
  // The first ask takes one (path sums, L_rp, M, M': 8 floats per pixel) and is served from it.
  const Fetched first = fetch(id, v1::RESULT_KIND_EXR, true);
  ASSERT_TRUE(first.status.ok()) << first.status.error_message();
  EXPECT_EQ(first.header.round(), 1u);
  EXPECT_EQ(server_->jobs().preview_copy_bytes(), size_t(32 * 32 * 8 * sizeof(float)));

  // The next round closes with no ask since: the copy goes.
  trace_round(w, 4);
  ASSERT_TRUE(eventually([&] { return status(id).round() == 2; }));
  EXPECT_EQ(server_->jobs().preview_copy_bytes(), 0u);

  // Cancelled without a copy: its frame as it stands becomes its partial results, which are those
  // of the same job rendered to the rounds it closed.
  EXPECT_EQ(cancel(id).state(), v1::JOB_STATE_CANCELLED);
  o.spp = 2;
  const std::string whole = submit(o, bundle_scene("builtin:cornell"));
  trace_round(w, 4);
  trace_round(w, 4);
  ASSERT_EQ(wait_done(whole).state(), v1::JOB_STATE_DONE);
  for (v1::ResultKind kind : {v1::RESULT_KIND_PATH_TRACED_EXR, v1::RESULT_KIND_COUNTS_EXR, v1::RESULT_KIND_EXR}) {
    SCOPED_TRACE(v1::ResultKind_Name(kind));
    const Fetched partial = fetch(id, kind, false);
    ASSERT_TRUE(partial.status.ok()) << partial.status.error_message();
    EXPECT_TRUE(partial.header.partial());
    EXPECT_EQ(partial.header.round(), 2u);
    const Fetched done = fetch(whole, kind, false);
    ASSERT_TRUE(done.status.ok()) << done.status.error_message();
    EXPECT_EQ(image(partial).data, image(done).data);
  }
  const json stats = json::parse(fetch(id, v1::RESULT_KIND_JSON, false).bytes);
  EXPECT_EQ(stats["rounds"], 2);
  EXPECT_EQ(stats["state"], "cancelled");
}

TEST_F(ResultsTest, JobCancelledBeforeItsFirstRoundHasNoResults) {
  start();
  const std::string id = submit(cornell(RenderMode::kPathTrace, 32), bundle_scene("builtin:cornell"));
  const std::string queued = submit(cornell(RenderMode::kPathTrace, 32), bundle_scene("builtin:cornell"));
  const Fetched q = fetch(queued, v1::RESULT_KIND_EXR, true);
  EXPECT_EQ(q.status.error_code(), grpc::StatusCode::FAILED_PRECONDITION);
  EXPECT_NE(q.status.error_message().find("queued"), std::string::npos) << q.status.error_message();
  EXPECT_EQ(cancel(id).state(), v1::JOB_STATE_CANCELLED);
  for (bool partial : {false, true}) {
    const Fetched f = fetch(id, v1::RESULT_KIND_EXR, partial);
    EXPECT_EQ(f.status.error_code(), grpc::StatusCode::FAILED_PRECONDITION);
    EXPECT_NE(f.status.error_message().find("no committed round"), std::string::npos) << f.status.error_message();
  }
}

TEST_F(ResultsTest, ListIsNewestFirstAndPagesGoBackInTime) {
  start();  // no worker: the first job runs forever, the others stay queued
  std::vector<std::string> ids;
  for (int i = 0; i < 3; ++i)
    ids.push_back(submit(cornell(RenderMode::kPathTrace, 32), bundle_scene("builtin:cornell")));
  EXPECT_EQ(list(1), (std::vector<std::string>{ids[2]}));
  EXPECT_EQ(list(0), (std::vector<std::string>{ids[2], ids[1], ids[0]}));
  std::string next;
  EXPECT_EQ(list(2, "", &next), (std::vector<std::string>{ids[2], ids[1]}));
  ASSERT_FALSE(next.empty());
  // A job submitted between two pages neither repeats nor shifts the next page.
  const std::string newest = submit(cornell(RenderMode::kPathTrace, 32), bundle_scene("builtin:cornell"));
  std::string last;
  EXPECT_EQ(list(2, next, &last), (std::vector<std::string>{ids[0]}));
  EXPECT_TRUE(last.empty());
  EXPECT_EQ(list(1, "", nullptr, {v1::JOB_STATE_QUEUED}), (std::vector<std::string>{newest}));
  // The first job runs once the reprojection thread has its GL context (slow on a loaded machine).
  ASSERT_TRUE(eventually([&] { return status(ids[0]).state() == v1::JOB_STATE_RUNNING; }));
  EXPECT_EQ(list(0, "", nullptr, {v1::JOB_STATE_RUNNING}), (std::vector<std::string>{ids[0]}));
}

TEST_F(ResultsTest, JobWithoutCameraTakesTheScenesOwn) {
  start();
  RunningNode node(node_options("w", 2));
  // A scene JSON with a camera of its own (not CameraSpec's default).
  const fs::path scene = dir_ / "view.json";
  std::ofstream(scene)
      << R"({"builtin": "cornell", "camera": {"eye": [0.6, 1.3, 3.2], "look": [0, 0.9, 0], "fov": 45}})";
  const SceneBundleData bundle = bundle_scene(scene.string());
  const CameraSpec own = load_scene(scene.string()).camera;
  ASSERT_NE(own.eye.x, CameraSpec{}.eye.x);
  RenderOptions o = cornell(RenderMode::kPathTrace, 32, 4, 2);
  v1::JobSpec without = to_job_spec(o, bundle, CameraSpec{});
  without.clear_camera();
  std::string a, b;
  ASSERT_TRUE(submit(without, &a).ok());
  ASSERT_TRUE(submit(to_job_spec(o, bundle, own), &b).ok());
  const v1::JobStatus sa = wait_done(a), sb = wait_done(b);
  ASSERT_EQ(sa.state(), v1::JOB_STATE_DONE) << sa.error_message();
  ASSERT_EQ(sb.state(), v1::JOB_STATE_DONE) << sb.error_message();
  EXPECT_EQ(sa.effective().camera().SerializeAsString(), sb.effective().camera().SerializeAsString());
  EXPECT_EQ(fetch_image(a, v1::RESULT_KIND_EXR).data, fetch_image(b, v1::RESULT_KIND_EXR).data);

  // A built-in scene's own view, too.
  v1::JobSpec wall = to_job_spec(o, bundle_scene("builtin:wall"), CameraSpec{});
  wall.clear_camera();
  std::string c;
  ASSERT_TRUE(submit(wall, &c).ok());
  EXPECT_EQ(from_proto(status(c).effective().camera()).eye.z, load_scene("builtin:wall").camera.eye.z);
  cancel(c);
}

TEST_F(ResultsTest, DoneJobsStatisticsCountWhatTheWorkersCulledLikeTheMonitoringEndpoint) {
  start();
  RunningNode node(node_options("w", 2));
  RenderOptions o = cornell(RenderMode::kReproject, 32, 4, 2);
  o.scene = "builtin:wall";  // nearly every vertex is culled on the workers (docs: the wall)
  const std::string id = submit(o, bundle_scene("builtin:wall"));
  const v1::JobStatus st = wait_done(id);
  ASSERT_EQ(st.state(), v1::JOB_STATE_DONE) << st.error_message();
  const Fetched f = fetch(id, v1::RESULT_KIND_JSON, false);
  ASSERT_TRUE(f.status.ok()) << f.status.error_message();
  EXPECT_FALSE(f.header.partial());
  EXPECT_EQ(f.header.round(), st.round());
  const json stats = json::parse(f.bytes);
  EXPECT_EQ(stats["partial"], false);
  const auto snap = server_->jobs().get(id);
  ASSERT_TRUE(snap);
  const json mon = to_json(*snap)["reprojection"];
  EXPECT_GT(mon["culled_by_workers"].get<uint64_t>(), 0u);
  EXPECT_EQ(stats["culled_worker"], mon["culled_by_workers"]);
  EXPECT_EQ(stats["considered"], mon["considered"]);
  for (const char* k : {"accepted_percent", "occluded_percent", "culled_percent"})
    EXPECT_DOUBLE_EQ(stats[k].get<double>(), mon[k].get<double>()) << k;
  EXPECT_GT(stats["culled_percent"].get<double>(), 90.0);
  EXPECT_LT(stats["accepted_percent"].get<double>(), 10.0);
  EXPECT_EQ(st.vertices_culled(), mon["culled"].get<uint64_t>());
}

TEST_F(ResultsTest, RefusedSubmissionsLeaveNothingInTheSceneCache) {
  start();
  auto cached = [&] {
    std::vector<std::string> names;
    std::error_code ec;
    for (fs::directory_iterator it(scene_cache(), ec), end; !ec && it != end; it.increment(ec))
      names.push_back(it->path().filename().string());
    return names;
  };
  const RenderOptions o = cornell(RenderMode::kPathTrace, 32);
  // A malformed OBJ: refused once it is loaded, from the cache.
  SceneBundleData bad;
  bad.entry_path = "box.obj";
  bad.files = {{"box.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n"}};
  grpc::Status st = submit(to_job_spec(o, bad, CameraSpec{}));
  EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(st.error_message().find("box.obj:4"), std::string::npos) << st.error_message();
  EXPECT_TRUE(cached().empty()) << cached().front();
  // A well-formed scene whose own camera is unusable (eye == look), refused after loading.
  SceneBundleData blind;
  blind.entry_path = "s.json";
  blind.files = {{"s.json", R"({"builtin": "cornell", "camera": {"eye": [0, 1, 0], "look": [0, 1, 0]}})"}};
  v1::JobSpec no_camera = to_job_spec(o, blind, CameraSpec{});
  no_camera.clear_camera();
  st = submit(no_camera);
  EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(st.error_message().find("camera"), std::string::npos) << st.error_message();
  EXPECT_TRUE(cached().empty()) << cached().front();
  // An accepted one stays (its job loads it from there).
  SceneBundleData good;
  good.entry_path = "s.json";
  good.files = {{"s.json", R"({"builtin": "cornell"})"}};
  EXPECT_TRUE(submit(to_job_spec(o, good, CameraSpec{})).ok());
  EXPECT_EQ(cached(), (std::vector<std::string>{content_hash(good)}));
}

}  // namespace
}  // namespace epr::test
