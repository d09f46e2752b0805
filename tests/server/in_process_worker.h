// A worker inside the test process that talks to a JobManager directly: it leases, traces (the same
// TileRenderer, chunking and assembly as over gRPC) and commits tiles of whichever jobs the manager
// hands out, keeping one tracer per job. For tests of the manager's scheduling without gRPC.
#pragma once

#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <climits>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <variant>
#include <vector>

#include "common/scene_loader.h"
#include "master/server/job_manager.h"
#include "wire/scene_bundle.h"
#include "wire/tile_result_stream.h"
#include "worker/embree_scene.h"
#include "worker/path_tracer.h"
#include "worker/tile_renderer.h"

namespace epr::test {

class JobsWorker {
 public:
  explicit JobsWorker(JobManager& jobs, const std::string& name = "test")
      : jobs_(jobs), id_(jobs.register_worker(name, 1)) {}
  const std::string& id() const { return id_; }

  std::optional<TileLeaseInfo> lease() {
    auto d = jobs_.lease_tile(id_);
    if (auto* l = std::get_if<TileLeaseInfo>(&d)) return *l;
    return std::nullopt;
  }

  /// Traces the tile and commits it; the master's answer (nullopt: refused as stale).
  std::optional<CommitOutcome> submit(const TileLeaseInfo& l) {
    Tracer& t = tracer(l);
    VertexFilter f;
    f.mode = l.options.mode == RenderMode::kPathTrace ? VertexFilter::Mode::kNone : VertexFilter::Mode::kCull;
    f.subpixels = l.options.subpixels;
    const TileResult r =
        TileRenderer(*t.tracer, f).render({l.rect, l.skip, l.first_sample, int(l.paths_per_pixel), l.paths});
    const TileResultIdentity identity{l.lease_id, l.job_id, l.round, l.tile_index, id_};
    const auto chunks = split_tile_result(r, identity, l.codec_bounds, {});
    TileCheck e = jobs_.expect(identity);
    if (e.verdict != TileVerdict::kExpected) {
      EXPECT_TRUE(e.stale()) << e.why;
      return std::nullopt;
    }
    TileResultAssembler a(std::move(e.expectation));
    for (const auto& c : chunks) EXPECT_FALSE(a.add(c));
    EXPECT_TRUE(a.complete());
    return jobs_.commit(l.job_id, l.round, l.tile_index, a.take());
  }

 private:
  struct Tracer {
    std::unique_ptr<Scene> scene;
    std::unique_ptr<EmbreeScene> embree;
    std::unique_ptr<Camera> camera;
    std::unique_ptr<PathTracer> tracer;
  };
  Tracer& tracer(const TileLeaseInfo& l) {
    Tracer& t = tracers_[l.job_id];
    if (!t.tracer) {
      t.scene = std::make_unique<Scene>(load_bundle(bundle_scene(l.scene_builtin), default_cache_root()));
      t.embree = std::make_unique<EmbreeScene>(*t.scene);
      t.camera = std::make_unique<Camera>(l.camera, l.options.width, l.options.height);
      t.tracer = std::make_unique<PathTracer>(*t.embree, *t.camera, l.seed, l.options.rr);
    }
    return t;
  }

  JobManager& jobs_;
  std::string id_;
  std::map<std::string, Tracer> tracers_;
};

/// A folder for one test's master state: PREFIX-PID-NAME-N under the temporary directory, removed if
/// it is there (N counts the calls, so every call gets its own).
inline std::filesystem::path fresh_dir(const std::string& prefix, const std::string& name) {
  static int n = 0;
  const std::filesystem::path d = std::filesystem::temp_directory_path() /
                                  (prefix + "-" + std::to_string(::getpid()) + "-" + name + "-" + std::to_string(++n));
  std::filesystem::remove_all(d);
  return d;
}

/// Asks `done` every 2 ms until it is true or `timeout` has passed; its last answer.
inline bool poll_until(const std::function<bool()>& done,
                       std::chrono::milliseconds timeout = std::chrono::milliseconds(60000)) {
  for (auto end = std::chrono::steady_clock::now() + timeout; std::chrono::steady_clock::now() < end;) {
    if (done()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  return done();
}

/// Leases, traces and commits tiles of whatever job the manager hands out, the workers taking turns,
/// until every one of `ids` is done or has closed `until_round` rounds; fails the test when one fails
/// or after `limit`.
inline void trace_until(JobManager& jobs, const std::vector<JobsWorker*>& workers, const std::vector<std::string>& ids,
                        int until_round = INT_MAX, std::chrono::seconds limit = std::chrono::seconds(300)) {
  size_t turn = 0;
  for (auto end = std::chrono::steady_clock::now() + limit; std::chrono::steady_clock::now() < end;) {
    bool all = true;
    for (const auto& id : ids) {
      const auto s = jobs.get(id);
      ASSERT_TRUE(s);
      ASSERT_NE(s->state, JobState::kFailed) << s->error;
      all &= s->state == JobState::kDone || (s->state == JobState::kRunning && int(s->progress.round) >= until_round);
    }
    if (all) return;
    JobsWorker& w = *workers[turn++ % workers.size()];
    if (auto l = w.lease())
      w.submit(*l);
    else
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  FAIL() << "the jobs did not get there within " << limit.count() << " s";
}

}  // namespace epr::test
