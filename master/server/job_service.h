// JobService (epr.v1): clients submit, watch, list, cancel jobs and fetch their results.
// Translates between the wire and JobManager; handlers never wait for rendering.
#pragma once

#include "epr/v1/job_service.grpc.pb.h"
#include "master/server/job_manager.h"

namespace epr {

class JobServiceImpl final : public v1::JobService::CallbackService {
 public:
  explicit JobServiceImpl(JobManager& jobs);

  grpc::ServerUnaryReactor* SubmitJob(grpc::CallbackServerContext* ctx, const v1::JobSpec* req,
                                      v1::JobId* resp) override;
  grpc::ServerUnaryReactor* CheckFrames(grpc::CallbackServerContext* ctx, const v1::CheckFramesRequest* req,
                                        v1::CheckFramesReply* resp) override;
  grpc::ServerReadReactor<v1::SceneChunk>* UploadScene(grpc::CallbackServerContext* ctx, v1::SceneRef* resp) override;
  grpc::ServerUnaryReactor* GetJob(grpc::CallbackServerContext* ctx, const v1::JobId* req,
                                   v1::JobStatus* resp) override;
  grpc::ServerWriteReactor<v1::JobStatus>* WatchJob(grpc::CallbackServerContext* ctx,
                                                    const v1::WatchJobRequest* req) override;
  grpc::ServerUnaryReactor* ListJobs(grpc::CallbackServerContext* ctx, const v1::ListJobsRequest* req,
                                     v1::ListJobsResponse* resp) override;
  grpc::ServerUnaryReactor* CancelJob(grpc::CallbackServerContext* ctx, const v1::JobId* req,
                                      v1::JobStatus* resp) override;
  grpc::ServerWriteReactor<v1::ResultChunk>* FetchResult(grpc::CallbackServerContext* ctx,
                                                         const v1::ResultRequest* req) override;
  grpc::ServerUnaryReactor* GetMasterInfo(grpc::CallbackServerContext* ctx, const v1::MasterInfoRequest* req,
                                          v1::MasterInfo* resp) override;

 private:
  /// Everything SubmitJob checks before it queues a job: the spec, its scene (loaded) and, without a
  /// camera in the spec, the scene's camera at each of `frames` (none: the scene's own camera). Fills
  /// `jr` for the last frame. A refusal removes what the check left in the scene cache.
  grpc::Status checked_request(const v1::JobSpec& req, const std::vector<uint32_t>& frames, JobRequest* jr);

  JobManager& jobs_;
  const std::string instance_;  // MasterInfo.instance: random, per server
};

/// The wire form of a job's progress (shared with tests and the monitoring endpoint's gRPC twin).
void to_proto(const JobSnapshot& s, v1::JobStatus* out);

}  // namespace epr
