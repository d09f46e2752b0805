// Security of the master's services: bearer tokens and TLS, with refused and accepted calls over
// real loopback channels.
#include <gtest/gtest.h>

#include <cstdlib>
#include <fstream>
#include <sstream>

#include <grpcpp/grpcpp.h>

#include "epr/v1/job_service.grpc.pb.h"
#include "epr/v1/worker_service.grpc.pb.h"
#include "master/server/master_server.h"

namespace epr {
namespace {

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
  // Streams too: without the token the stream is refused before any chunk is looked at.
  EXPECT_EQ(submit_tile(channel, "").error_code(), grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_EQ(submit_tile(channel, "s3cret-token").error_code(), grpc::StatusCode::INVALID_ARGUMENT);
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
                          "> " + dir + "/openssl.log 2>&1";
  ASSERT_EQ(std::system(cmd.c_str()), 0) << "openssl could not make a test certificate: " << read_all(dir + "/openssl.log");
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
