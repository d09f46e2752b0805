// Whole renders on a JobManager in the test process: submit jobs, trace them with in-process workers
// until they end, and read back each job's images and statistics file (window_run_test.cpp,
// window_cut_test.cpp, window_pipeline_test.cpp); a small window run's frames.
#pragma once

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "master/server/job_manager.h"
#include "tests/server/in_process_worker.h"
#include "tests/server/job_images.h"

namespace epr::test {

struct RenderedJob {
  JobImages images;
  nlohmann::json stats;  // the job's statistics file (null when it has none)
};

/// Frame `frame` (1..3) of batch `batch`, one window run of K = `window`: the Cornell box at 32 x 32 in
/// four tiles, 8 paths in rounds of 4, skip with the CPU reprojector, its eye moved `frame` tenths
/// sideways, seed `seed0` + `frame` (window_lease_cameras_test.cpp, window_setup_test.cpp).
inline JobRequest small_run_frame(const std::string& batch, uint32_t frame, uint32_t window, uint64_t seed0) {
  JobRequest req;
  req.options.width = req.options.height = 32;
  req.options.spp = 8;
  req.options.paths_per_round = 4;
  req.options.mode = RenderMode::kSkip;
  req.options.reproject = ReprojectMethod::kCpu;
  req.options.tile_size = 16;
  req.options.seed = seed0 + frame;
  req.camera.eye.x += 0.1f * float(frame);
  req.bundle.builtin = "builtin:cornell";
  req.request_id = batch + "-" + std::to_string(frame);
  req.batch.id = batch;
  req.batch.frame = frame;
  req.batch.frames = 3;
  req.batch.window = window;
  req.batch.window_first = 1;
  req.batch.window_last = 3;
  return req;
}

/// A master in `dir` without checkpoints whose budget holds every frame of a window run at once.
inline MasterOptions all_frames_at_once(const std::filesystem::path& dir) {
  MasterOptions o;
  o.state_dir = dir.string();
  o.checkpoints = false;
  o.memory_budget_bytes = uint64_t(1) << 40;
  return o;
}

/// Submits `reqs` to a JobManager with options `o`, traces them with `workers` in-process workers until
/// every job has ended, and returns each job's images and statistics, in the requests' order.
inline std::vector<RenderedJob> render_jobs(const MasterOptions& o, const std::vector<JobRequest>& reqs,
                                            int workers = 1) {
  JobManager jobs(o);
  std::vector<std::string> ids;
  for (const auto& r : reqs) {
    const auto s = jobs.submit(r);
    EXPECT_EQ(s.error, "");
    ids.push_back(s.id);
  }
  std::vector<std::unique_ptr<JobsWorker>> ws;
  std::vector<JobsWorker*> raw;
  for (int i = 0; i < workers; ++i) {
    ws.push_back(std::make_unique<JobsWorker>(jobs, "w" + std::to_string(i)));
    raw.push_back(ws.back().get());
  }
  trace_until(jobs, raw, ids);
  std::vector<RenderedJob> out;
  for (const auto& id : ids) {
    RenderedJob r{results_of(jobs, id), {}};
    const auto path = jobs.result_path(id, ResultKind::kJson);
    EXPECT_TRUE(path) << "job " << id << " has no statistics file";
    if (path) {
      std::ifstream in(*path);
      r.stats = nlohmann::json::parse(in);
    }
    out.push_back(std::move(r));
  }
  return out;
}

}  // namespace epr::test
