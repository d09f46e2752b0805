// The bearer-token interceptor (wire/rpc/auth_interceptor.h) on a real server over loopback, in front
// of a JobService that records what its handlers were given: refused calls end UNAUTHENTICATED, their
// handlers never see the request, nothing they send reaches the client, and the health service stays
// open.
#include "wire/rpc/auth_interceptor.h"

#include <grpcpp/grpcpp.h>
#include <grpcpp/health_check_service_interface.h>
#include <gtest/gtest.h>

#include <mutex>
#include <vector>

#include "epr/v1/job_service.grpc.pb.h"
#include "grpc/health/v1/health.grpc.pb.h"
#include "wire/rpc/channel.h"
#include "wire/rpc/chunked.h"

namespace epr::rpc {
namespace {

using namespace std::chrono_literals;

// Answers every call it gets and records what each handler was given.
class RecordingJobService final : public v1::JobService::CallbackService {
 public:
  grpc::ServerUnaryReactor* CancelJob(grpc::CallbackServerContext* ctx, const v1::JobId* req,
                                      v1::JobStatus* resp) override {
    record(req->id());
    resp->set_id("cancelled:" + req->id());
    auto* r = ctx->DefaultReactor();
    r->Finish(grpc::Status::OK);
    return r;
  }
  grpc::ServerWriteReactor<v1::JobStatus>* WatchJob(grpc::CallbackServerContext*,
                                                    const v1::WatchJobRequest* req) override {
    record(req->job_id());
    return new StatusWriter(req->job_id());
  }
  grpc::ServerReadReactor<v1::SceneChunk>* UploadScene(grpc::CallbackServerContext*, v1::SceneRef* resp) override {
    return new ChunkReader(this, resp);
  }

  std::vector<std::string> seen() {
    std::lock_guard lock(mu_);
    return seen_;
  }

 private:
  void record(const std::string& s) {
    std::lock_guard lock(mu_);
    seen_.push_back(s);
  }

  // Three statuses named after the job.
  class StatusWriter final : public grpc::ServerWriteReactor<v1::JobStatus> {
   public:
    explicit StatusWriter(std::string id) : id_(std::move(id)) { next(); }
    void OnWriteDone(bool ok) override {
      if (!ok) return Finish(grpc::Status(grpc::StatusCode::CANCELLED, "client went away"));
      next();
    }
    void OnDone() override { delete this; }

   private:
    void next() {
      if (sent_ == 3) return Finish(grpc::Status::OK);
      out_.set_id(id_ + "#" + std::to_string(sent_++));
      StartWrite(&out_);
    }
    std::string id_;
    v1::JobStatus out_;
    int sent_ = 0;
  };

  // Records the entry path of every manifest it reads.
  class ChunkReader final : public grpc::ServerReadReactor<v1::SceneChunk> {
   public:
    ChunkReader(RecordingJobService* service, v1::SceneRef* resp) : service_(service), resp_(resp) {
      StartRead(&chunk_);
    }
    void OnReadDone(bool ok) override {
      if (!ok) {
        resp_->set_content_hash("read-to-the-end");
        return Finish(grpc::Status::OK);
      }
      if (chunk_.has_manifest()) service_->record("manifest:" + chunk_.manifest().entry_path());
      StartRead(&chunk_);
    }
    void OnDone() override { delete this; }

   private:
    RecordingJobService* service_;
    v1::SceneRef* resp_;
    v1::SceneChunk chunk_;
  };

  std::mutex mu_;
  std::vector<std::string> seen_;
};

class AuthInterceptor : public ::testing::Test {
 protected:
  void start(const std::string& token) {
    grpc::EnableDefaultHealthCheckService(true);
    grpc::ServerBuilder builder;
    int port = 0;
    builder.AddListeningPort("127.0.0.1:0", server_credentials({}), &port);
    builder.RegisterService(&service_);
    if (auto auth = make_auth_interceptor(token)) {
      std::vector<std::unique_ptr<grpc::experimental::ServerInterceptorFactoryInterface>> interceptors;
      interceptors.push_back(std::move(auth));
      builder.experimental().SetInterceptorCreators(std::move(interceptors));
    }
    server_ = builder.BuildAndStart();
    ASSERT_TRUE(server_ && port);
    channel_ = grpc::CreateChannel("127.0.0.1:" + std::to_string(port), channel_credentials({}));
    stub_ = v1::JobService::NewStub(channel_);
  }
  void TearDown() override {
    if (server_) server_->Shutdown(std::chrono::system_clock::now() + 2s);
  }

  grpc::Status cancel(const std::string& token, const std::string& id, v1::JobStatus* out) {
    grpc::ClientContext ctx;
    prepare_call(ctx, 5s, token);
    v1::JobId req;
    req.set_id(id);
    return stub_->CancelJob(&ctx, req, out);
  }

  RecordingJobService service_;
  std::unique_ptr<grpc::Server> server_;
  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<v1::JobService::Stub> stub_;
};

TEST_F(AuthInterceptor, NoTokenConfiguredLetsEveryCallThrough) {
  EXPECT_EQ(make_auth_interceptor(""), nullptr);
  start("");
  v1::JobStatus out;
  ASSERT_TRUE(cancel("", "job-1", &out).ok());
  EXPECT_EQ(out.id(), "cancelled:job-1");
}

TEST_F(AuthInterceptor, RefusedUnaryCallsNeverReachTheHandlerWithTheirRequest) {
  start("s3cret");
  v1::JobStatus out;
  const grpc::Status none = cancel("", "job-1", &out);
  EXPECT_EQ(none.error_code(), grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_NE(none.error_message().find("requires a bearer token"), std::string::npos) << none.error_message();
  const grpc::Status wrong = cancel("s3creT", "job-2", &out);
  EXPECT_EQ(wrong.error_code(), grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_EQ(wrong.error_message().find("s3cre"), std::string::npos) << "the reason must not echo the token";
  EXPECT_EQ(out.id(), "") << "nothing the handler sent may reach a refused client";
  {
    grpc::ClientContext ctx;  // the right token under another scheme
    ctx.AddMetadata("authorization", "Basic s3cret");
    v1::JobId req;
    req.set_id("job-3");
    EXPECT_EQ(stub_->CancelJob(&ctx, req, &out).error_code(), grpc::StatusCode::UNAUTHENTICATED);
  }
  ASSERT_TRUE(cancel("s3cret", "job-4", &out).ok());
  EXPECT_EQ(out.id(), "cancelled:job-4");
  for (const std::string& s : service_.seen()) EXPECT_TRUE(s.empty() || s == "job-4") << "a handler saw " << s;
}

TEST_F(AuthInterceptor, RefusedStreamsCarryNothingEitherWay) {
  start("s3cret");
  {
    grpc::ClientContext ctx;
    prepare_call(ctx, 5s, "");
    v1::WatchJobRequest req;
    req.set_job_id("job-9");
    auto reader = stub_->WatchJob(&ctx, req);
    v1::JobStatus st;
    EXPECT_FALSE(reader->Read(&st)) << "a refused watch sent " << st.id();
    EXPECT_EQ(reader->Finish().error_code(), grpc::StatusCode::UNAUTHENTICATED);
  }
  {
    grpc::ClientContext ctx;
    prepare_call(ctx, 5s, "");
    v1::SceneRef ref;
    auto writer = stub_->UploadScene(&ctx, &ref);
    SceneBundleData bundle;
    bundle.entry_path = "refused.obj";
    bundle.files = {{"refused.obj", std::string(3 * kChunkBytes, 'v')}};
    send_scene(bundle, [&](const v1::SceneChunk& c) { return writer->Write(c); });
    writer->WritesDone();
    EXPECT_EQ(writer->Finish().error_code(), grpc::StatusCode::UNAUTHENTICATED);
    EXPECT_EQ(ref.content_hash(), "");
  }
  {
    grpc::ClientContext ctx;
    prepare_call(ctx, 5s, "s3cret");
    v1::WatchJobRequest req;
    req.set_job_id("job-10");
    auto reader = stub_->WatchJob(&ctx, req);
    int n = 0;
    for (v1::JobStatus st; reader->Read(&st);) EXPECT_EQ(st.id(), "job-10#" + std::to_string(n++));
    EXPECT_TRUE(reader->Finish().ok());
    EXPECT_EQ(n, 3);
  }
  for (const std::string& s : service_.seen()) EXPECT_TRUE(s.empty() || s == "job-10") << "a handler saw " << s;
}

TEST_F(AuthInterceptor, HealthChecksNeedNoToken) {
  start("s3cret");
  auto health = grpc::health::v1::Health::NewStub(channel_);
  grpc::ClientContext ctx;
  prepare_call(ctx, 5s, "");
  grpc::health::v1::HealthCheckRequest req;
  grpc::health::v1::HealthCheckResponse resp;
  ASSERT_TRUE(health->Check(&ctx, req, &resp).ok());
  EXPECT_EQ(resp.status(), grpc::health::v1::HealthCheckResponse::SERVING);
  EXPECT_TRUE(is_open_method("/grpc.health.v1.Health/Watch"));
  EXPECT_TRUE(is_open_method("/grpc.reflection.v1alpha.ServerReflection/ServerReflectionInfo"));
  EXPECT_FALSE(is_open_method("/epr.v1.WorkerService/Register"));
  EXPECT_FALSE(is_open_method("/grpc.health.v1.HealthX/Check"));
}

TEST_F(AuthInterceptor, ReadStreamCancelsOnTheFirstBadMessage) {
  start("");
  grpc::ClientContext ctx;
  prepare_call(ctx, 5s, "");
  v1::WatchJobRequest req;
  req.set_job_id("job-5");
  auto reader = stub_->WatchJob(&ctx, req);
  int taken = 0;
  const StreamEnd end =
      read_stream<v1::JobStatus>(ctx, *reader, [&](const v1::JobStatus& st) -> std::optional<std::string> {
        ++taken;
        if (st.id() == "job-5#1") return "the second status is bad";
        return std::nullopt;
      });
  EXPECT_EQ(taken, 2);
  EXPECT_EQ(end.error, "the second status is bad");
  EXPECT_FALSE(end.ok());
}

}  // namespace
}  // namespace epr::rpc
