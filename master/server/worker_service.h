// WorkerService (epr.v1): translates between the wire and JobManager. No tracing, no GL, no waiting
// in here: every handler answers from the manager's state or reads a stream chunk by chunk.
#pragma once

#include "epr/v1/worker_service.grpc.pb.h"
#include "master/server/job_manager.h"

namespace epr {

class WorkerServiceImpl final : public v1::WorkerService::CallbackService {
 public:
  explicit WorkerServiceImpl(JobManager& jobs) : jobs_(jobs) {}

  grpc::ServerUnaryReactor* Register(grpc::CallbackServerContext* ctx, const v1::WorkerInfo* req,
                                     v1::RegisterResponse* resp) override;
  grpc::ServerUnaryReactor* Heartbeat(grpc::CallbackServerContext* ctx, const v1::HeartbeatRequest* req,
                                      v1::HeartbeatResponse* resp) override;
  grpc::ServerWriteReactor<v1::SceneChunk>* FetchScene(grpc::CallbackServerContext* ctx,
                                                       const v1::FetchSceneRequest* req) override;
  grpc::ServerUnaryReactor* LeaseTile(grpc::CallbackServerContext* ctx, const v1::LeaseRequest* req,
                                      v1::Lease* resp) override;
  grpc::ServerUnaryReactor* ReturnLease(grpc::CallbackServerContext* ctx, const v1::ReturnLeaseRequest* req,
                                        v1::ReturnLeaseResponse* resp) override;
  grpc::ServerReadReactor<v1::TileResultChunk>* SubmitTile(grpc::CallbackServerContext* ctx,
                                                           v1::SubmitAck* ack) override;
  grpc::ServerUnaryReactor* Unregister(grpc::CallbackServerContext* ctx, const v1::WorkerId* req,
                                       v1::UnregisterResponse* resp) override;

  static constexpr uint32_t kMaxVerticesPerChunk = 65536;
  static constexpr uint32_t kMaxChunkBytes = 2u << 20;

 private:
  JobManager& jobs_;
};

}  // namespace epr
