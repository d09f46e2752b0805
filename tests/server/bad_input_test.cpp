// Bad input against a real in-process master over loopback gRPC, with its limits configured through
// MasterOptions (the same fields epr-master's --max-* flags set). Every case names the reason it must
// be refused with, so removing the check (or letting another layer answer for it) fails the test:
//  - job specs: zero, huge and over-the-limit sizes, zero, "negative" and over-the-limit sample counts,
//    NaN and infinite camera values, empty and oversized scene bundles (inline and uploaded), unknown
//    modes -> INVALID_ARGUMENT with the reason;
//  - worker messages: unknown leases, results for another round, tiles outside the image, oversized
//    chunks -> refused; NaN and infinite radiance -> dropped and counted, never reaching the image.
#include <cmath>
#include <limits>

#include "tests/server/farm_fixture.h"

namespace epr::test {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
constexpr float kInf = std::numeric_limits<float>::infinity();

class BadInputTest : public FarmFixture {
 protected:
  void SetUp() override {
    FarmFixture::SetUp();
    MasterOptions mo;
    mo.max_image_side = 64;
    mo.max_spp = 16;
    mo.max_scene_bytes = 4096;
    mo.max_worker_failures = 0;  // refusals are counted, but blocking is tested in lease_test.cpp
    start(mo);
  }

  static v1::JobSpec spec(const RenderOptions& o) { return to_job_spec(o, bundle_scene(o.scene), CameraSpec{}); }

  // Drives the job to the end with a WireWorker, applying `tamper` to the first tile's chunks.
  void run_job(const std::string& id, WireWorker& w,
               const std::function<void(std::vector<v1::TileResultChunk>&)>& tamper = nullptr) {
    bool tampered = false;
    for (int guard = 0; guard < 5000 && !terminal(status(id)); ++guard) {
      auto t = w.lease();
      if (!t) {
        std::this_thread::sleep_for(5ms);
        continue;
      }
      auto chunks = w.render(*t);
      if (tamper && !tampered) {
        tamper(chunks);
        tampered = true;
      }
      v1::SubmitAck ack;
      const grpc::Status st = w.submit(chunks, &ack);
      ASSERT_TRUE(st.ok()) << st.error_message();
      ASSERT_EQ(ack.outcome(), v1::SUBMIT_OUTCOME_COMMITTED) << ack.reason();
    }
  }
};

TEST_F(BadInputTest, JobSpecsAreRefusedWithTheirReason) {
  struct Case {
    const char* name;
    std::function<void(v1::JobSpec&)> mutate;
    const char* reason;
  };
  auto files = [](v1::JobSpec& s) {
    s.mutable_scene()->clear_content_hash();
    return s.mutable_scene()->mutable_files();
  };
  const std::vector<Case> cases = {
      {"zero width", [](v1::JobSpec& s) { s.set_width(0); }, "image size 0x"},
      {"zero height", [](v1::JobSpec& s) { s.set_height(0); }, "image size 32x0"},
      {"huge width", [](v1::JobSpec& s) { s.set_width(4000000000u); }, "absurdly large"},
      {"over the master's side limit", [](v1::JobSpec& s) { s.set_height(128); }, "limited to 64 pixels"},
      {"zero spp", [](v1::JobSpec& s) { s.set_target_spp(0); }, "--spp 0"},
      {"negative spp", [](v1::JobSpec& s) { s.set_target_spp(uint32_t(-4)); }, "absurdly large"},
      {"absurd spp", [](v1::JobSpec& s) { s.set_target_spp(5000000); }, "--spp 5000000"},
      {"over the master's spp limit", [](v1::JobSpec& s) { s.set_target_spp(32); }, "limit of 16"},
      {"paths per round over spp", [](v1::JobSpec& s) { s.set_paths_per_round(9); }, "--paths-per-round 9"},
      {"nan eye", [](v1::JobSpec& s) { s.mutable_camera()->mutable_eye()->set_x(NAN); }, "non-finite"},
      {"infinite look", [](v1::JobSpec& s) { s.mutable_camera()->mutable_look()->set_z(kInf); }, "non-finite"},
      {"infinite fov", [](v1::JobSpec& s) { s.mutable_camera()->set_fov_y_degrees(kInf); }, "non-finite"},
      {"nan epsilon", [](v1::JobSpec& s) { s.mutable_reprojection()->set_epsilon_fraction(NAN); }, "--epsilon"},
      {"zero reprojected weight", [](v1::JobSpec& s) { s.mutable_reprojection()->set_reprojected_weight(0); },
       "--reprojected-weight 0 must be in (0, 1]"},
      {"reprojected weight over 1", [](v1::JobSpec& s) { s.mutable_reprojection()->set_reprojected_weight(1.5f); },
       "--reprojected-weight 1.5 must be in (0, 1]"},
      {"nan reprojected weight", [](v1::JobSpec& s) { s.mutable_reprojection()->set_reprojected_weight(NAN); },
       "--reprojected-weight nan must be in (0, 1]"},
      {"unknown mode", [](v1::JobSpec& s) { s.set_mode(v1::RenderMode(42)); }, "unknown render mode 42"},
      {"unknown method", [](v1::JobSpec& s) { s.mutable_reprojection()->set_method(v1::ReprojectionMethod(9)); },
       "unknown reprojection method 9"},
      {"empty bundle", [&](v1::JobSpec& s) { files(s)->set_entry_path("scene.obj"); }, "the scene bundle is empty"},
      {"oversized bundle",
       [&](v1::JobSpec& s) {
         auto* f = files(s);
         f->set_entry_path("big.obj");
         auto* file = f->add_files();
         file->set_path("big.obj");
         std::string obj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
         while (obj.size() <= 5000) obj += "# padding padding padding padding padding\n";
         file->set_data(obj);
       },
       "over the limit of 4096"},
  };
  for (const Case& c : cases) {
    v1::JobSpec s = spec(cornell(RenderMode::kSkip, 32, 8, 2));
    c.mutate(s);
    const grpc::Status st = submit(s);
    EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << c.name;
    EXPECT_NE(st.error_message().find(c.reason), std::string::npos) << c.name << ": " << st.error_message();
  }
  // Still serving, and the limits are limits, not off by one.
  std::string id;
  EXPECT_TRUE(submit(spec(cornell(RenderMode::kSkip, 64, 16, 2)), &id).ok());
  EXPECT_FALSE(id.empty());
}

TEST_F(BadInputTest, OversizedUploadIsRefused) {
  grpc::ClientContext ctx;
  set_deadline(&ctx);
  v1::SceneRef ref;
  auto w = jobs_->UploadScene(&ctx, &ref);
  v1::SceneChunk c;
  auto* m = c.mutable_manifest();
  m->set_entry_path("big.obj");
  m->set_total_bytes(8192);
  auto* f = m->add_files();
  f->set_path("big.obj");
  f->set_size_bytes(8192);
  w->Write(c);
  w->WritesDone();
  const grpc::Status st = w->Finish();
  EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(st.error_message().find("over the limit of 4096"), std::string::npos) << st.error_message();
}

TEST_F(BadInputTest, WorkerMessagesThatDoNotFitTheirLeaseAreRefused) {
  const std::string id = submit(cornell(RenderMode::kSkip, 32, 4, 2), bundle_scene("builtin:cornell"));
  WireWorker w(channel_, "w");
  auto t = w.lease_wait();
  ASSERT_TRUE(t);
  const auto good = w.render(*t);
  auto expect_refused = [&](const char* what, const std::vector<v1::TileResultChunk>& chunks, const char* reason) {
    v1::SubmitAck ack;
    const grpc::Status st = w.submit(chunks, &ack);
    EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << what;
    EXPECT_NE(st.error_message().find(reason), std::string::npos) << what << ": " << st.error_message();
  };
  {
    // A lease id below the master's counter, but never issued for this tile.
    auto chunks = good;
    chunks.front().mutable_header()->set_lease_id(t->lease_id() - 1);
    expect_refused("unknown lease", chunks, "was not issued");
    EXPECT_EQ(status(id).worker_failures(), 0u) << "a lease the worker does not hold is not held against it";
  }
  {
    // A result for another round is stale: drained, acknowledged, counted, not committed.
    auto chunks = good;
    chunks.front().mutable_header()->set_round(t->round() + 1);
    v1::SubmitAck ack;
    ASSERT_TRUE(w.submit(chunks, &ack).ok());
    EXPECT_EQ(ack.outcome(), v1::SUBMIT_OUTCOME_STALE);
    const v1::JobStatus st = status(id);
    EXPECT_EQ(st.tiles_committed(), 0u);
    EXPECT_EQ(st.tiles_dropped(), 1u);
  }
  v1::SubmitAck ack;
  ASSERT_TRUE(w.submit(good, &ack).ok());
  EXPECT_EQ(ack.outcome(), v1::SUBMIT_OUTCOME_COMMITTED);

  // Each refusal below is pinned on the lease the header names (the worker's own), which goes back
  // to the queue: the next lease_wait() gets a tile again.
  {
    // One pixel chunk over max_chunk_bytes (2 MiB) although under gRPC's message limit.
    auto t2 = w.lease_wait();
    ASSERT_TRUE(t2);
    auto chunks = w.render(*t2);
    v1::TileResultChunk big;
    auto* p = big.mutable_pixels();
    p->set_first_pixel(0);
    for (int i = 0; i < 3 * 200000; ++i) p->add_radiance_sum(1.f);
    for (int i = 0; i < 200000; ++i) p->add_path_count(2);
    chunks.insert(chunks.begin() + 1, big);
    expect_refused("oversized chunk", chunks, "exceeds max_chunk_bytes");
    EXPECT_EQ(status(id).worker_failures(), 1u);
  }
  {
    auto t3 = w.lease_wait();
    ASSERT_TRUE(t3);
    auto chunks = w.render(*t3);
    v1::TileResultChunk batch;
    batch.mutable_vertices()->set_count(1u << 20);
    chunks.insert(chunks.begin() + 1, batch);
    expect_refused("oversized vertex batch", chunks, "exceeds max_vertices_per_chunk");
    EXPECT_EQ(status(id).worker_failures(), 2u);
  }
  {
    auto t4 = w.lease_wait();
    ASSERT_TRUE(t4);
    auto chunks = w.render(*t4);
    chunks.front().mutable_header()->set_tile_index(9999);
    expect_refused("tile outside the image", chunks, "outside the job's 4 tiles");
    EXPECT_EQ(status(id).worker_failures(), 3u);
  }
  EXPECT_EQ(status(id).tiles_committed(), 1u) << "nothing refused was committed";
}

TEST_F(BadInputTest, NonFiniteRadianceIsDroppedCountedAndNeverReachesTheImage) {
  RenderOptions o = cornell(RenderMode::kReproject, 32, 4, 2);
  o.reproject = ReprojectMethod::kExact;  // pixel sums and float exact samples on the wire
  const std::string id = submit(o, bundle_scene(o.scene));
  WireWorker w(channel_, "w");
  int poisoned = 0;
  run_job(id, w, [&](std::vector<v1::TileResultChunk>& chunks) {
    for (auto& c : chunks) {
      if (c.has_pixels() && c.pixels().radiance_sum_size() >= 9) {
        auto* r = c.mutable_pixels()->mutable_radiance_sum();
        r->Set(0, kNaN);   // pixel 0
        r->Set(4, kInf);   // pixel 1
        r->Set(8, -kInf);  // pixel 2
        poisoned += 3;
      }
      if (c.has_exact_samples() && c.exact_samples().radiance_size() >= 3) {
        c.mutable_exact_samples()->mutable_radiance()->Set(1, kNaN);
        ++poisoned;
      }
    }
  });
  ASSERT_GE(poisoned, 4) << "the first tile must carry pixel sums and exact samples";
  const v1::JobStatus st = wait_done(id);
  ASSERT_EQ(st.state(), v1::JOB_STATE_DONE) << st.error_message();
  EXPECT_GE(st.non_finite_dropped(), uint64_t(poisoned));
  for (auto kind : {v1::RESULT_KIND_EXR, v1::RESULT_KIND_PATH_TRACED_EXR, v1::RESULT_KIND_REPROJECTED_EXR}) {
    const Image img = fetch_image(id, kind);
    ASSERT_FALSE(img.data.empty());
    size_t bad = 0;
    for (float v : img.data) bad += !std::isfinite(v);
    EXPECT_EQ(bad, 0u) << "result kind " << int(kind);
  }
}

}  // namespace
}  // namespace epr::test
