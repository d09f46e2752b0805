// The master's gRPC services in-process, over a real loopback channel: valid and invalid requests,
// and a whole job driven by a hand-written worker loop (real TileRenderer, real stream writer),
// whose result must equal the single-process render of the same job.
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <thread>

#include "client/local_render.h"
#include "epr/v1/job_service.grpc.pb.h"
#include "epr/v1/worker_service.grpc.pb.h"
#include "grpc/health/v1/health.grpc.pb.h"
#include "master/server/master_server.h"
#include "tests/job_results.h"
#include "wire/convert.h"
#include "wire/tile_result_stream.h"
#include "worker/tile_renderer.h"

namespace epr {
namespace {

class MasterServiceTest : public ::testing::Test {
 protected:
  void SetUp() override {
    MasterServerOptions o;
    o.listen = "127.0.0.1:0";
    server_ = std::make_unique<MasterServer>(o);
    channel_ = grpc::CreateChannel(server_->local_target(), grpc::InsecureChannelCredentials());
    jobs_ = v1::JobService::NewStub(channel_);
    workers_ = v1::WorkerService::NewStub(channel_);
  }
  void TearDown() override { server_->shutdown(); }

  static void deadline(grpc::ClientContext* ctx, int seconds = 10) {
    ctx->set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(seconds));
  }

  v1::JobSpec cornell_spec(RenderMode mode, int size = 32, int spp = 4, int k = 2) {
    RenderOptions o;
    o.width = o.height = size;
    o.spp = spp;
    o.paths_per_round = k;
    o.mode = mode;
    o.tile_size = 16;
    return to_job_spec(o, bundle_scene("builtin:cornell"), CameraSpec{});
  }

  grpc::Status submit(const v1::JobSpec& spec, std::string* id = nullptr) {
    grpc::ClientContext ctx;
    deadline(&ctx);
    v1::JobId out;
    auto st = jobs_->SubmitJob(&ctx, spec, &out);
    if (id) *id = out.id();
    return st;
  }

  std::string register_worker() {
    grpc::ClientContext ctx;
    deadline(&ctx);
    v1::WorkerInfo info;
    info.set_protocol_version(v1::PROTOCOL_VERSION_V1);
    info.set_name("test");
    info.set_threads(1);
    v1::RegisterResponse r;
    EXPECT_TRUE(workers_->Register(&ctx, info, &r).ok());
    return r.worker_id().id();
  }

  // One lease-trace-submit cycle. Returns false when the master said Wait.
  bool work_one_tile(const std::string& worker, v1::SubmitAck* ack, v1::TileLease* lease_out = nullptr) {
    v1::Lease lease;
    {
      grpc::ClientContext ctx;
      deadline(&ctx);
      v1::LeaseRequest req;
      req.mutable_worker_id()->set_id(worker);
      EXPECT_TRUE(workers_->LeaseTile(&ctx, req, &lease).ok());
    }
    if (!lease.has_tile()) return false;
    const v1::TileLease& t = lease.tile();
    if (lease_out) *lease_out = t;
    const auto& s = t.settings();
    const Scene scene = load_bundle(bundle_scene(t.scene().builtin()), default_cache_root());
    EmbreeScene es(scene);
    const Camera cam(from_proto(s.camera()), int(s.width()), int(s.height()));
    PathTracer tracer(es, cam, t.seed(), from_proto(s.russian_roulette()));
    VertexFilter f;
    f.mode = s.mode() == v1::RENDER_MODE_PT ? VertexFilter::Mode::kNone : VertexFilter::Mode::kCull;
    f.subpixels = int(s.reprojection().subpixels());
    TileRenderer tr(tracer, f);
    const TileRect rect{int(t.rect().x0()), int(t.rect().y0()), int(t.rect().x1()), int(t.rect().y1())};
    const size_t n = size_t(rect.pixel_count());
    std::vector<uint8_t> skip(n, 0);
    for (size_t i = 0; i < n && i / 8 < t.skip_bits().size(); ++i)
      skip[i] = (uint8_t(t.skip_bits()[i / 8]) >> (i % 8)) & 1;
    std::vector<uint32_t> first(n, t.uniform_first_sample_index());
    for (int i = 0; i < t.first_sample_index_size(); ++i) first[size_t(i)] = t.first_sample_index(i);
    const std::vector<uint32_t> paths(t.pixel_paths().begin(), t.pixel_paths().end());
    const TileResult result = tr.render({rect, skip, first, int(t.paths_per_pixel()), paths});
    TileResultIdentity id{t.lease_id(), t.job_id(), t.round(), t.tile_index(), worker};
    const auto chunks = split_tile_result(result, id, from_proto(s.codec_bounds()), TileResultLimits{});
    grpc::ClientContext ctx;
    deadline(&ctx);
    auto writer = workers_->SubmitTile(&ctx, ack);
    for (const auto& c : chunks) EXPECT_TRUE(writer->Write(c));
    writer->WritesDone();
    EXPECT_TRUE(writer->Finish().ok());
    return true;
  }

  v1::JobStatus status(const std::string& id) { return test::job_status(*jobs_, id); }

  std::string fetch(const std::string& id, v1::ResultKind kind, grpc::Status* status_out = nullptr) {
    return test::fetch_result_bytes(*jobs_, id, kind, std::chrono::seconds(10), status_out);
  }

  std::unique_ptr<MasterServer> server_;
  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<v1::JobService::Stub> jobs_;
  std::unique_ptr<v1::WorkerService::Stub> workers_;
};

// The options a master reads back from `spec` (which must be valid).
RenderOptions read_back(const v1::JobSpec& spec) {
  RenderOptions o;
  CameraSpec cam;
  const auto err = from_job_spec(spec, &o, &cam);
  EXPECT_FALSE(err) << *err;
  return o;
}

// The joint test travels with a job; a spec without it (an older client) gets the default, on.
TEST(JobSpecConversion, JointTestTravelsAndDefaultsToOn) {
  RenderOptions o;
  o.scene = "builtin:cornell";
  o.mode = RenderMode::kReproject;
  o.joint_test = false;
  v1::JobSpec spec = to_job_spec(o, bundle_scene(o.scene), CameraSpec{});
  EXPECT_FALSE(read_back(spec).joint_test);
  spec.mutable_reprojection()->clear_joint_test();
  EXPECT_TRUE(read_back(spec).joint_test);
}

// Tapered tiles travel with a job; unset, a job has square tiles only.
TEST(JobSpecConversion, TaperedTilesTravelAndDefaultToOff) {
  RenderOptions o;
  o.scene = "builtin:cornell";
  o.taper_tiles = true;
  v1::JobSpec spec = to_job_spec(o, bundle_scene(o.scene), CameraSpec{});
  EXPECT_TRUE(read_back(spec).taper_tiles);
  spec.clear_taper_tiles();
  EXPECT_FALSE(read_back(spec).taper_tiles);
}

TEST_F(MasterServiceTest, HealthServiceSaysServing) {
  auto health = grpc::health::v1::Health::NewStub(channel_);
  grpc::ClientContext ctx;
  deadline(&ctx);
  grpc::health::v1::HealthCheckRequest req;
  grpc::health::v1::HealthCheckResponse resp;
  ASSERT_TRUE(health->Check(&ctx, req, &resp).ok());
  EXPECT_EQ(resp.status(), grpc::health::v1::HealthCheckResponse::SERVING);
}

TEST_F(MasterServiceTest, InvalidJobSpecsAreRejectedWithReasons) {
  struct Case {
    const char* name;
    std::function<void(v1::JobSpec&)> mutate;
    const char* reason;
  };
  const std::vector<Case> cases = {
      {"zero width", [](v1::JobSpec& s) { s.set_width(0); }, "image size"},
      {"huge size", [](v1::JobSpec& s) { s.set_width(4000000000u); }, "absurd"},
      {"zero spp", [](v1::JobSpec& s) { s.set_target_spp(0); }, "spp"},
      {"nan camera", [](v1::JobSpec& s) { s.mutable_camera()->mutable_eye()->set_x(NAN); }, "non-finite"},
      {"unknown mode", [](v1::JobSpec& s) { s.set_mode(v1::RenderMode(42)); }, "mode"},
      {"no scene", [](v1::JobSpec& s) { s.clear_scene(); }, "no scene"},
      {"bad builtin", [](v1::JobSpec& s) { s.mutable_scene()->set_builtin("builtin:nope"); }, "nope"},
      {"escaping path",
       [](v1::JobSpec& s) {
         auto* f = s.mutable_scene()->mutable_files();
         s.mutable_scene()->clear_content_hash();
         f->set_entry_path("../x.obj");
         auto* file = f->add_files();
         file->set_path("../x.obj");
         file->set_data("v 0 0 0\n");
       },
       "safe relative path"},
      {"malformed obj",
       [](v1::JobSpec& s) {
         auto* f = s.mutable_scene()->mutable_files();
         s.mutable_scene()->clear_content_hash();
         f->set_entry_path("box.obj");
         auto* file = f->add_files();
         file->set_path("box.obj");
         file->set_data("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n");
       },
       "box.obj:4"},
      {"hash mismatch",
       [](v1::JobSpec& s) {
         auto* f = s.mutable_scene()->mutable_files();
         f->set_entry_path("t.obj");
         auto* file = f->add_files();
         file->set_path("t.obj");
         file->set_data("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
         s.mutable_scene()->set_content_hash("00");
       },
       "content_hash"},
  };
  for (const Case& c : cases) {
    v1::JobSpec spec = cornell_spec(RenderMode::kPathTrace);
    c.mutate(spec);
    const grpc::Status st = submit(spec);
    EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << c.name;
    EXPECT_NE(st.error_message().find(c.reason), std::string::npos) << c.name << ": " << st.error_message();
  }
  // The master is still serving after all that.
  std::string id;
  EXPECT_TRUE(submit(cornell_spec(RenderMode::kPathTrace), &id).ok());
  EXPECT_FALSE(id.empty());
}

TEST_F(MasterServiceTest, UnknownIdsAndUnfinishedResults) {
  grpc::ClientContext ctx;
  deadline(&ctx);
  v1::JobId req;
  req.set_id("no-such-job");
  v1::JobStatus st;
  EXPECT_EQ(jobs_->GetJob(&ctx, req, &st).error_code(), grpc::StatusCode::NOT_FOUND);

  std::string id;
  ASSERT_TRUE(submit(cornell_spec(RenderMode::kPathTrace), &id).ok());
  grpc::Status fs;
  fetch(id, v1::RESULT_KIND_EXR, &fs);
  EXPECT_EQ(fs.error_code(), grpc::StatusCode::FAILED_PRECONDITION);

  grpc::ClientContext lctx;
  deadline(&lctx);
  v1::LeaseRequest lr;
  lr.mutable_worker_id()->set_id("ghost");
  v1::Lease lease;
  EXPECT_EQ(workers_->LeaseTile(&lctx, lr, &lease).error_code(), grpc::StatusCode::NOT_FOUND);

  grpc::ClientContext rctx;
  deadline(&rctx);
  v1::WorkerInfo info;
  info.set_threads(1);
  v1::RegisterResponse rr;
  EXPECT_EQ(workers_->Register(&rctx, info, &rr).error_code(), grpc::StatusCode::FAILED_PRECONDITION);
}

TEST_F(MasterServiceTest, MalformedTileStreamsAreRejected) {
  const std::string worker = register_worker();
  {
    // Data before the header.
    grpc::ClientContext ctx;
    deadline(&ctx);
    v1::SubmitAck ack;
    auto w = workers_->SubmitTile(&ctx, &ack);
    v1::TileResultChunk c;
    c.mutable_trailer();
    w->Write(c);
    w->WritesDone();
    EXPECT_EQ(w->Finish().error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  }
  {
    // A lease that was never issued.
    grpc::ClientContext ctx;
    deadline(&ctx);
    v1::SubmitAck ack;
    auto w = workers_->SubmitTile(&ctx, &ack);
    v1::TileResultChunk c;
    c.mutable_header()->set_lease_id(~uint64_t(0));
    c.mutable_header()->set_job_id("x");
    w->Write(c);
    w->WritesDone();
    const auto st = w->Finish();
    EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    EXPECT_NE(st.error_message().find("lease"), std::string::npos);
  }
}

TEST_F(MasterServiceTest, WholeJobOverGrpcEqualsSingleProcessRender) {
  const v1::JobSpec spec = cornell_spec(RenderMode::kSkip, 32, 6, 2);
  std::string id;
  ASSERT_TRUE(submit(spec, &id).ok());
  const std::string worker = register_worker();
  int committed = 0, duplicates = 0;
  for (int guard = 0; guard < 2000; ++guard) {
    const auto st = status(id);
    if (st.state() == v1::JOB_STATE_DONE || st.state() == v1::JOB_STATE_FAILED) break;
    v1::SubmitAck ack;
    v1::TileLease lease;
    if (!work_one_tile(worker, &ack, &lease)) {
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
      continue;
    }
    if (ack.outcome() == v1::SUBMIT_OUTCOME_COMMITTED) ++committed;
    if (committed == 1 && duplicates == 0) {
      // Submitting the same tile again is acknowledged as a duplicate and changes nothing.
      v1::TileResultChunk h;
      TileResult empty;
      empty.rect = {int(lease.rect().x0()), int(lease.rect().y0()), int(lease.rect().x1()), int(lease.rect().y1())};
      empty.path_sum.assign(size_t(empty.rect.pixel_count()), Vec3(0.f));
      empty.path_count.assign(size_t(empty.rect.pixel_count()), lease.paths_per_pixel());
      TileResultIdentity tid{lease.lease_id(), lease.job_id(), lease.round(), lease.tile_index(), worker};
      grpc::ClientContext ctx;
      deadline(&ctx);
      v1::SubmitAck dup;
      auto w = workers_->SubmitTile(&ctx, &dup);
      for (const auto& c : split_tile_result(empty, tid, from_proto(lease.settings().codec_bounds()), {})) w->Write(c);
      w->WritesDone();
      ASSERT_TRUE(w->Finish().ok());
      EXPECT_EQ(dup.outcome(), v1::SUBMIT_OUTCOME_DUPLICATE);
      ++duplicates;
    }
  }
  const auto st = status(id);
  ASSERT_EQ(st.state(), v1::JOB_STATE_DONE) << st.error_message();
  EXPECT_GT(committed, 0);
  EXPECT_EQ(st.tiles_dropped(), 1u);

  RenderOptions o;
  CameraSpec cam;
  ASSERT_FALSE(from_job_spec(spec, &o, &cam));
  o.scene = "builtin:cornell";
  const RenderOutputs local = render_local(o);

  const std::string counts = fetch(id, v1::RESULT_KIND_COUNTS_EXR);
  const std::string pathtrace = fetch(id, v1::RESULT_KIND_PATH_TRACED_EXR);
  ASSERT_FALSE(counts.empty());
  const std::string dir = ::testing::TempDir();
  std::ofstream(dir + "/c.exr", std::ios::binary) << counts;
  std::ofstream(dir + "/p.exr", std::ios::binary) << pathtrace;
  const Image rc = read_image(dir + "/c.exr"), rp = read_image(dir + "/p.exr");
  ASSERT_EQ(rc.data.size(), local.counts.data.size());
  EXPECT_EQ(rc.data, local.counts.data) << "M and M' must be identical";
  EXPECT_EQ(rp.data, local.pathtrace.data) << "path-traced sums must be identical";
}

TEST_F(MasterServiceTest, CheckFramesRefusesABadFrameAndQueuesNothing) {
  // The camera passes through its target between the keys: frame 3 is degenerate.
  const std::string dir = ::testing::TempDir() + "/epr-check-frames";
  std::filesystem::create_directories(dir);
  std::ofstream(dir + "/through.json") << R"({"builtin": "cornell", "animation": {"camera": [
  {"frame": 1, "eye": [0, 1, 2], "look": [0, 1, 0]},
  {"frame": 5, "eye": [0, 1, -2]}]}})";
  RenderOptions o;
  o.width = o.height = 16;
  o.spp = 1;
  v1::JobSpec spec = to_job_spec(o, bundle_scene(dir + "/through.json"), CameraSpec{});
  spec.clear_camera();
  auto check = [&](std::vector<uint32_t> frames) {
    grpc::ClientContext ctx;
    deadline(&ctx);
    v1::CheckFramesRequest req;
    *req.mutable_spec() = spec;
    for (uint32_t f : frames) req.add_frames(f);
    v1::CheckFramesReply reply;
    return jobs_->CheckFrames(&ctx, req, &reply);
  };
  EXPECT_TRUE(check({1, 2, 4, 5}).ok());
  const grpc::Status bad = check({1, 2, 3, 4});
  EXPECT_EQ(bad.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(bad.error_message().find("frame 3: camera eye and look-at point coincide"), std::string::npos)
      << bad.error_message();
  EXPECT_EQ(check({}).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  spec.set_frame(2);
  EXPECT_EQ(check({1}).error_code(), grpc::StatusCode::INVALID_ARGUMENT) << "a frame in the spec is ambiguous";

  grpc::ClientContext ctx;
  deadline(&ctx);
  v1::ListJobsRequest req;
  v1::ListJobsResponse jobs;
  ASSERT_TRUE(jobs_->ListJobs(&ctx, req, &jobs).ok());
  EXPECT_EQ(jobs.jobs_size(), 0) << "checking frames queues nothing";
}

}  // namespace
}  // namespace epr
