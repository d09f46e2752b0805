#include "master/server/master_server.h"

#include <fmt/format.h>
#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/health_check_service_interface.h>

#include "common/log.h"
#include "master/server/job_service.h"
#include "master/server/monitoring.h"
#include "master/server/worker_service.h"
#include "wire/rpc/auth_interceptor.h"
#include "wire/rpc/channel.h"

namespace epr {

MasterServer::MasterServer(MasterServerOptions options) : options_(std::move(options)) {
  const auto creds =
      rpc::server_credentials({options_.tls_cert_file, options_.tls_key_file, options_.tls_client_ca_file});
  jobs_ = std::make_unique<JobManager>(options_.jobs);
  job_service_ = std::make_unique<JobServiceImpl>(*jobs_);
  worker_service_ = std::make_unique<WorkerServiceImpl>(*jobs_);
  grpc::EnableDefaultHealthCheckService(true);
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  grpc::ServerBuilder builder;
  builder.AddListeningPort(options_.listen, creds, &port_);
  builder.RegisterService(job_service_.get());
  builder.RegisterService(worker_service_.get());
  builder.SetMaxReceiveMessageSize(options_.max_message_bytes);
  builder.SetMaxSendMessageSize(options_.max_message_bytes);
  if (auto auth = rpc::make_auth_interceptor(options_.token)) {
    std::vector<std::unique_ptr<grpc::experimental::ServerInterceptorFactoryInterface>> interceptors;
    interceptors.push_back(std::move(auth));
    builder.experimental().SetInterceptorCreators(std::move(interceptors));
  }
  server_ = builder.BuildAndStart();
  if (!server_ || port_ == 0) {
    jobs_->shutdown();
    throw std::runtime_error(fmt::format("cannot listen on {} (address in use or invalid?)", options_.listen));
  }
  if (!options_.http_listen.empty()) {
    MonitoringOptions mo;
    mo.listen = options_.http_listen;
    mo.cpu_reprojector = options_.jobs.reproject_backend_override == "cpu";
    mo.token = options_.token;  // the monitoring pages need the same bearer token (but /healthz, /readyz)
    try {
      monitoring_ = std::make_unique<MonitoringServer>(*jobs_, mo);
    } catch (...) {
      server_->Shutdown();
      jobs_->shutdown();
      throw;
    }
  }
  server_->GetHealthCheckService()->SetServingStatus(true);
  logger("master")->info("master listening on {} (port {}){}{}", options_.listen, port_,
                         options_.tls_cert_file.empty() ? "" : ", TLS",
                         !options_.token.empty() ? ", bearer token required" : "");
}

MasterServer::~MasterServer() { shutdown(); }

std::shared_ptr<grpc::Channel> MasterServer::in_process_channel(const grpc::ChannelArguments& args) const {
  return server_->InProcessChannel(args);
}

std::string MasterServer::local_target() const { return fmt::format("127.0.0.1:{}", port_); }

int MasterServer::http_port() const { return monitoring_ ? monitoring_->port() : 0; }

std::string MasterServer::dashboard_url() const { return monitoring_ ? monitoring_->url() : ""; }

void MasterServer::shutdown() {
  if (shut_down_) return;
  shut_down_ = true;
  if (monitoring_) monitoring_->stop();
  server_->GetHealthCheckService()->SetServingStatus(false);
  jobs_->stop_parking();  // the LeaseTile calls held open are answered: the server need not wait for them
  server_->Shutdown(std::chrono::system_clock::now() + std::chrono::seconds(2));
  jobs_->shutdown();
}

void MasterServer::wait() { server_->Wait(); }

}  // namespace epr
