#include "master/server/master_server.h"

#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/health_check_service_interface.h>

#include <fmt/format.h>

#include "common/log.h"
#include "master/server/job_service.h"
#include "master/server/worker_service.h"

namespace epr {

MasterServer::MasterServer(MasterServerOptions options) : options_(std::move(options)) {
  jobs_ = std::make_unique<JobManager>(options_.jobs);
  job_service_ = std::make_unique<JobServiceImpl>(*jobs_);
  worker_service_ = std::make_unique<WorkerServiceImpl>(*jobs_);
  grpc::EnableDefaultHealthCheckService(true);
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  grpc::ServerBuilder builder;
  builder.AddListeningPort(options_.listen, grpc::InsecureServerCredentials(), &port_);
  builder.RegisterService(job_service_.get());
  builder.RegisterService(worker_service_.get());
  builder.SetMaxReceiveMessageSize(options_.max_message_bytes);
  builder.SetMaxSendMessageSize(options_.max_message_bytes);
  server_ = builder.BuildAndStart();
  if (!server_ || port_ == 0) {
    jobs_->shutdown();
    throw std::runtime_error(fmt::format("cannot listen on {} (address in use or invalid?)", options_.listen));
  }
  server_->GetHealthCheckService()->SetServingStatus(true);
  logger("master")->info("master listening on {} (port {})", options_.listen, port_);
}

MasterServer::~MasterServer() { shutdown(); }

std::string MasterServer::local_target() const { return fmt::format("127.0.0.1:{}", port_); }

void MasterServer::shutdown() {
  if (shut_down_) return;
  shut_down_ = true;
  server_->GetHealthCheckService()->SetServingStatus(false);
  server_->Shutdown(std::chrono::system_clock::now() + std::chrono::seconds(2));
  jobs_->shutdown();
}

void MasterServer::wait() { server_->Wait(); }

}  // namespace epr
