// Security of the master's services: bearer tokens and TLS, with refused and accepted calls over
// real loopback channels.
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <cstdlib>
#include <fstream>
#include <sstream>

#include "epr/v1/job_service.grpc.pb.h"
#include "epr/v1/worker_service.grpc.pb.h"
#include "grpc/health/v1/health.grpc.pb.h"
#include "master/server/master_server.h"
#include "wire/convert.h"
#include "wire/rpc/channel.h"

namespace epr {
namespace {

using namespace std::chrono_literals;

grpc::Status list_jobs(const std::shared_ptr<grpc::Channel>& channel, const std::string& token) {
  auto stub = v1::JobService::NewStub(channel);
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(5));
  if (!token.empty()) ctx.AddMetadata("authorization", "Bearer " + token);
  v1::ListJobsRequest req;
  v1::ListJobsResponse resp;
  return stub->ListJobs(&ctx, req, &resp);
}

grpc::Status submit_tile(const std::shared_ptr<grpc::Channel>& channel, const std::string& token) {
  auto stub = v1::WorkerService::NewStub(channel);
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(5));
  if (!token.empty()) ctx.AddMetadata("authorization", "Bearer " + token);
  v1::SubmitAck ack;
  auto w = stub->SubmitTile(&ctx, &ack);
  v1::TileResultChunk c;
  c.mutable_trailer();
  w->Write(c);
  w->WritesDone();
  return w->Finish();
}

TEST(Auth, BearerTokenIsRequiredWhenConfigured) {
  MasterServerOptions o;
  o.listen = "127.0.0.1:0";
  o.token = "s3cret-token";
  MasterServer server(o);
  auto channel = grpc::CreateChannel(server.local_target(), grpc::InsecureChannelCredentials());
  EXPECT_EQ(list_jobs(channel, "").error_code(), grpc::StatusCode::UNAUTHENTICATED);
  const grpc::Status wrong = list_jobs(channel, "s3cret-tokeN");
  EXPECT_EQ(wrong.error_code(), grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_EQ(wrong.error_message().find("s3cret"), std::string::npos) << "the reason must not echo the token";
  EXPECT_TRUE(list_jobs(channel, "s3cret-token").ok());
  // The scheme is case-insensitive (RFC 7235); a scheme run into the token is not one.
  for (const char* value : {"bearer s3cret-token", "BEARER s3cret-token", "Bearer  s3cret-token"}) {
    auto stub = v1::JobService::NewStub(channel);
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(5));
    ctx.AddMetadata("authorization", value);
    v1::ListJobsResponse resp;
    EXPECT_TRUE(stub->ListJobs(&ctx, v1::ListJobsRequest(), &resp).ok()) << value;
  }
  {
    auto stub = v1::JobService::NewStub(channel);
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(5));
    ctx.AddMetadata("authorization", "Bearers3cret-token");
    v1::ListJobsResponse resp;
    EXPECT_EQ(stub->ListJobs(&ctx, v1::ListJobsRequest(), &resp).error_code(), grpc::StatusCode::UNAUTHENTICATED);
  }
  // Streams too: without the token the stream is refused before any chunk is looked at.
  EXPECT_EQ(submit_tile(channel, "").error_code(), grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_EQ(submit_tile(channel, "s3cret-token").error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  server.shutdown();
}

// Every method of JobService and WorkerService, called without the token with a request that would
// change the master's state if its handler acted on it, is refused and changes nothing.
TEST(Auth, RefusedCallsActOnNothing) {
  const std::string token = "s3cret-token";
  MasterServerOptions o;
  o.listen = "127.0.0.1:0";
  o.token = token;
  MasterServer server(o);
  auto channel = grpc::CreateChannel(server.local_target(), grpc::InsecureChannelCredentials());
  auto jobs = v1::JobService::NewStub(channel);
  auto workers = v1::WorkerService::NewStub(channel);
  auto ctx = [](const std::string& t) {
    auto c = std::make_unique<grpc::ClientContext>();
    rpc::prepare_call(*c, 10s, t);
    return c;
  };
  constexpr auto kRefused = grpc::StatusCode::UNAUTHENTICATED;

  // With the token: a running job and a worker holding one of its tiles.
  v1::WorkerInfo info;
  info.set_protocol_version(v1::PROTOCOL_VERSION_V1);
  info.set_name("holder");
  info.set_threads(1);
  v1::RegisterResponse reg;
  ASSERT_TRUE(workers->Register(ctx(token).get(), info, &reg).ok());
  v1::WorkerId worker = reg.worker_id();
  RenderOptions ro;
  ro.width = ro.height = 32;
  ro.spp = 4;
  ro.paths_per_round = 2;
  ro.tile_size = 16;
  const v1::JobSpec spec = to_job_spec(ro, bundle_scene("builtin:cornell"), CameraSpec{});
  v1::JobId job;
  ASSERT_TRUE(jobs->SubmitJob(ctx(token).get(), spec, &job).ok());
  v1::LeaseRequest lease_req;
  *lease_req.mutable_worker_id() = worker;
  lease_req.set_max_wait_ms(5000);
  v1::Lease lease;
  ASSERT_TRUE(workers->LeaseTile(ctx(token).get(), lease_req, &lease).ok());
  ASSERT_TRUE(lease.has_tile());
  const uint64_t lease_id = lease.tile().lease_id();

  // Without it, every call is refused.
  v1::JobId other;
  EXPECT_EQ(jobs->SubmitJob(ctx("").get(), spec, &other).error_code(), kRefused);
  v1::JobStatus status;
  EXPECT_EQ(jobs->CancelJob(ctx("").get(), job, &status).error_code(), kRefused);
  EXPECT_EQ(jobs->GetJob(ctx("").get(), job, &status).error_code(), kRefused);
  EXPECT_EQ(status.id(), "");
  v1::ListJobsResponse listed;
  EXPECT_EQ(jobs->ListJobs(ctx("").get(), v1::ListJobsRequest(), &listed).error_code(), kRefused);
  EXPECT_EQ(listed.jobs_size(), 0);
  {
    auto c = ctx("");
    v1::WatchJobRequest req;
    req.set_job_id(job.id());
    auto reader = jobs->WatchJob(c.get(), req);
    EXPECT_FALSE(reader->Read(&status));
    EXPECT_EQ(reader->Finish().error_code(), kRefused);
  }
  {
    auto c = ctx("");
    v1::ResultRequest req;
    req.set_job_id(job.id());
    req.set_kind(v1::RESULT_KIND_EXR);
    req.set_allow_partial(true);
    auto reader = jobs->FetchResult(c.get(), req);
    v1::ResultChunk chunk;
    EXPECT_FALSE(reader->Read(&chunk));
    EXPECT_EQ(reader->Finish().error_code(), kRefused);
  }
  {
    auto c = ctx("");
    v1::SceneRef ref;
    auto writer = jobs->UploadScene(c.get(), &ref);
    SceneBundleData b;
    b.entry_path = "t.obj";
    b.files = {{"t.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"}};
    v1::SceneChunk manifest;
    manifest.mutable_manifest()->set_content_hash(content_hash(b));
    writer->Write(manifest);
    writer->WritesDone();
    EXPECT_EQ(writer->Finish().error_code(), kRefused);
  }
  v1::RegisterResponse reg2;
  EXPECT_EQ(workers->Register(ctx("").get(), info, &reg2).error_code(), kRefused);
  EXPECT_EQ(reg2.worker_id().id(), "");
  v1::Lease second;
  EXPECT_EQ(workers->LeaseTile(ctx("").get(), lease_req, &second).error_code(), kRefused);
  EXPECT_FALSE(second.has_tile());
  v1::ReturnLeaseRequest ret;
  *ret.mutable_worker_id() = worker;
  ret.add_lease_ids(lease_id);
  ret.set_failure(v1::LEASE_FAILURE_TILE);
  v1::ReturnLeaseResponse ret_resp;
  EXPECT_EQ(workers->ReturnLease(ctx("").get(), ret, &ret_resp).error_code(), kRefused);
  {
    auto c = ctx("");
    v1::SubmitAck ack;
    auto writer = workers->SubmitTile(c.get(), &ack);
    v1::TileResultChunk header;
    header.mutable_header()->mutable_worker_id()->set_id(worker.id());
    header.mutable_header()->set_lease_id(lease_id);
    header.mutable_header()->set_job_id(job.id());
    writer->Write(header);
    writer->WritesDone();
    EXPECT_EQ(writer->Finish().error_code(), kRefused);
  }
  {
    auto c = ctx("");
    v1::FetchSceneRequest req;
    *req.mutable_worker_id() = worker;
    auto reader = workers->FetchScene(c.get(), req);
    v1::SceneChunk chunk;
    EXPECT_FALSE(reader->Read(&chunk));
    EXPECT_EQ(reader->Finish().error_code(), kRefused);
  }
  v1::UnregisterResponse unreg;
  EXPECT_EQ(workers->Unregister(ctx("").get(), worker, &unreg).error_code(), kRefused);
  v1::HeartbeatRequest beat;
  *beat.mutable_worker_id() = worker;
  beat.add_lease_ids(lease_id);
  v1::HeartbeatResponse beat_resp;
  EXPECT_EQ(workers->Heartbeat(ctx("").get(), beat, &beat_resp).error_code(), kRefused);
  EXPECT_EQ(beat_resp.leases_size(), 0);

  // With the token again: one job, not cancelled, one tile leased, and the worker still holds it.
  ASSERT_TRUE(jobs->ListJobs(ctx(token).get(), v1::ListJobsRequest(), &listed).ok());
  ASSERT_EQ(listed.jobs_size(), 1);
  EXPECT_EQ(listed.jobs(0).id(), job.id());
  EXPECT_NE(listed.jobs(0).state(), v1::JOB_STATE_CANCELLED);
  EXPECT_EQ(listed.jobs(0).tiles_leased(), 1u);
  ASSERT_TRUE(workers->Heartbeat(ctx(token).get(), beat, &beat_resp).ok());
  ASSERT_EQ(beat_resp.leases_size(), 1);
  EXPECT_TRUE(beat_resp.leases(0).valid()) << "a refused ReturnLease, SubmitTile or Unregister let the lease go";

  // The health service stays open for probes.
  auto health = grpc::health::v1::Health::NewStub(channel);
  grpc::health::v1::HealthCheckResponse serving;
  ASSERT_TRUE(health->Check(ctx("").get(), grpc::health::v1::HealthCheckRequest(), &serving).ok());
  EXPECT_EQ(serving.status(), grpc::health::v1::HealthCheckResponse::SERVING);
  server.shutdown();
}

TEST(Auth, NoTokenConfiguredMeansOpen) {
  MasterServerOptions o;
  o.listen = "127.0.0.1:0";
  MasterServer server(o);
  auto channel = grpc::CreateChannel(server.local_target(), grpc::InsecureChannelCredentials());
  EXPECT_TRUE(list_jobs(channel, "").ok());
  server.shutdown();
}

std::string read_all(const std::string& path) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

TEST(Auth, TlsServerRefusesPlaintextAndAcceptsTrustedClients) {
  const std::string dir = ::testing::TempDir() + "/epr-tls";
  std::system(("mkdir -p " + dir).c_str());
  const std::string cmd = "openssl req -x509 -newkey rsa:2048 -nodes -keyout " + dir + "/key.pem -out " + dir +
                          "/cert.pem -days 1 -subj /CN=localhost -addext subjectAltName=DNS:localhost,IP:127.0.0.1 "
                          "> " +
                          dir + "/openssl.log 2>&1";
  ASSERT_EQ(std::system(cmd.c_str()), 0) << "openssl could not make a test certificate: "
                                         << read_all(dir + "/openssl.log");
  MasterServerOptions o;
  o.listen = "127.0.0.1:0";
  o.tls_cert_file = dir + "/cert.pem";
  o.tls_key_file = dir + "/key.pem";
  o.token = "t0k";
  MasterServer server(o);
  const std::string target = "localhost:" + std::to_string(server.port());

  auto plain = grpc::CreateChannel(target, grpc::InsecureChannelCredentials());
  EXPECT_FALSE(list_jobs(plain, "t0k").ok());

  grpc::SslCredentialsOptions ssl;
  ssl.pem_root_certs = read_all(dir + "/cert.pem");
  auto secure = grpc::CreateChannel(target, grpc::SslCredentials(ssl));
  EXPECT_TRUE(list_jobs(secure, "t0k").ok());
  EXPECT_EQ(list_jobs(secure, "").error_code(), grpc::StatusCode::UNAUTHENTICATED);

  grpc::SslCredentialsOptions untrusted;  // the system's roots do not know this certificate
  auto stranger = grpc::CreateChannel(target, grpc::SslCredentials(untrusted));
  EXPECT_FALSE(list_jobs(stranger, "t0k").ok());
  server.shutdown();
}

}  // namespace
}  // namespace epr
