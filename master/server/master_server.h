// The master process in one object: JobManager plus the gRPC server with JobService, WorkerService
// and the standard health service, behind the bearer-token interceptor (wire/rpc/auth_interceptor.h)
// when a token is configured. `epr-master` is a thin main around it; `epr render` runs one
// in-process on a loopback port, its workers calling it over the server's in-process channel, so a
// local render and a cluster use the same code paths.
#pragma once

#include <grpcpp/grpcpp.h>

#include <memory>
#include <string>

#include "master/server/job_manager.h"

namespace epr {

struct MasterServerOptions {
  std::string listen = "0.0.0.0:50051";  // gRPC address; port 0 picks a free port
  MasterOptions jobs;
  int max_message_bytes = 8 << 20;  // inline scenes in SubmitJob; tile chunks are <= 2 MiB
  std::string http_listen;          // monitoring HTTP HOST:PORT (master/server/monitoring.h); empty: none
  std::string token;                // bearer token required from clients and workers; empty: none
  // TLS (all empty: plaintext). PEM files: the server's certificate chain and key, and optionally the
  // CA that client certificates must chain to (then clients without a valid certificate are refused).
  std::string tls_cert_file, tls_key_file, tls_client_ca_file;
};

class JobServiceImpl;
class MonitoringServer;
class WorkerServiceImpl;

class MasterServer {
 public:
  /// Starts serving; throws std::runtime_error if the address cannot be bound.
  explicit MasterServer(MasterServerOptions options);
  ~MasterServer();

  int port() const { return port_; }
  /// The monitoring endpoint's port and dashboard URL ("http://127.0.0.1:PORT/"); 0 and "" if disabled.
  int http_port() const;
  std::string dashboard_url() const;
  /// "127.0.0.1:PORT"-style target for clients in this process or on this host.
  std::string local_target() const;
  /// A channel to this server inside the process (no socket): the embedded set-up's worker uses it.
  /// The server's interceptors (the bearer token) apply as on the port; there is no TLS.
  std::shared_ptr<grpc::Channel> in_process_channel(const grpc::ChannelArguments& args) const;
  JobManager& jobs() { return *jobs_; }
  /// Stops accepting calls, cancels streams, stops the job manager. Idempotent.
  void shutdown();
  void wait();

 private:
  MasterServerOptions options_;
  std::unique_ptr<JobManager> jobs_;
  std::unique_ptr<JobServiceImpl> job_service_;
  std::unique_ptr<WorkerServiceImpl> worker_service_;
  std::unique_ptr<grpc::Server> server_;
  std::unique_ptr<MonitoringServer> monitoring_;
  int port_ = 0;
  bool shut_down_ = false;
};

}  // namespace epr
