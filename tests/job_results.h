// What the tests that drive a master's JobService over real gRPC share: a job's status, waiting for it
// to end, fetching a result file, and checking a finished job against the single-process render.
#pragma once

#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <chrono>
#include <fstream>
#include <functional>
#include <string>
#include <thread>

#include "client/local_render.h"
#include "common/image.h"
#include "epr/v1/job_service.grpc.pb.h"

namespace epr::test {

/// The job's status; the call must succeed.
inline v1::JobStatus job_status(v1::JobService::Stub& jobs, const std::string& id,
                                std::chrono::seconds deadline = std::chrono::seconds(10)) {
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + deadline);
  v1::JobId req;
  req.set_id(id);
  v1::JobStatus st;
  EXPECT_TRUE(jobs.GetJob(&ctx, req, &st).ok());
  return st;
}

inline bool job_terminal(const v1::JobStatus& st) {
  return st.state() == v1::JOB_STATE_DONE || st.state() == v1::JOB_STATE_FAILED ||
         st.state() == v1::JOB_STATE_CANCELLED;
}

/// Polls `status` every 20 ms until the job is in a terminal state (or `timeout`, a guard against
/// hanging); the last status seen.
inline v1::JobStatus wait_terminal(const std::function<v1::JobStatus()>& status, std::chrono::seconds timeout) {
  const auto until = std::chrono::steady_clock::now() + timeout;
  v1::JobStatus st;
  while (std::chrono::steady_clock::now() < until) {
    st = status();
    if (job_terminal(st)) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  return st;
}

/// The bytes of one result file of job `id`; the call's status goes to `status_out` when given.
inline std::string fetch_result_bytes(v1::JobService::Stub& jobs, const std::string& id, v1::ResultKind kind,
                                      std::chrono::seconds deadline, grpc::Status* status_out = nullptr) {
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + deadline);
  v1::ResultRequest req;
  req.set_job_id(id);
  req.set_kind(kind);
  auto reader = jobs.FetchResult(&ctx, req);
  v1::ResultChunk c;
  std::string bytes;
  while (reader->Read(&c))
    if (c.has_data()) bytes += c.data().data();
  const grpc::Status st = reader->Finish();
  if (status_out) *status_out = st;
  return bytes;
}

/// One result image of job `id`, written to `path` and read back; the call must succeed.
inline Image fetch_result_image(v1::JobService::Stub& jobs, const std::string& id, v1::ResultKind kind,
                                std::chrono::seconds deadline, const std::string& path) {
  grpc::Status st;
  const std::string bytes = fetch_result_bytes(jobs, id, kind, deadline, &st);
  EXPECT_TRUE(st.ok());
  std::ofstream(path, std::ios::binary) << bytes;
  return read_image(path);
}

/// The job's M / M' and path-traced sums (from `fetch`) equal the single-process render's, bit for bit.
inline void expect_same_as_local(const std::function<Image(v1::ResultKind)>& fetch, const RenderOptions& o) {
  const RenderOutputs local = render_local(o);
  const Image counts = fetch(v1::RESULT_KIND_COUNTS_EXR);
  const Image pathtrace = fetch(v1::RESULT_KIND_PATH_TRACED_EXR);
  ASSERT_EQ(counts.data.size(), local.counts.data.size());
  EXPECT_EQ(counts.data, local.counts.data) << "M and M' must be identical";
  EXPECT_EQ(pathtrace.data, local.pathtrace.data) << "path-traced sums must be identical";
}

}  // namespace epr::test
