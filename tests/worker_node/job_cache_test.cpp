// Per-job tracing state: built once per job (also when many threads ask at once), shared scenes,
// bounded, rebuilt when the settings change, and a failed build is retried on the next request.
#include "worker/job_cache.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <mutex>
#include <stdexcept>
#include <thread>

#include "common/builtin_scenes.h"
#include "wire/convert.h"
#include "wire/scene_bundle.h"

namespace epr {
namespace {

v1::TileLease lease_for(const std::string& job, const std::string& builtin = "builtin:cornell", uint64_t seed = 1) {
  const Scene scene = make_builtin_scene(builtin.substr(8));
  RenderOptions o;
  o.width = 16;
  o.height = 16;
  o.mode = RenderMode::kReproject;
  v1::TileLease lease;
  lease.set_job_id(job);
  lease.set_seed(seed);
  to_render_settings(o, scene.camera, scene.bounds(), lease.mutable_settings());
  SceneBundleData b;
  b.builtin = builtin;
  lease.mutable_scene()->set_builtin(builtin);
  lease.mutable_scene()->set_content_hash(content_hash(b));
  return lease;
}

// Counts the scene loads. With a gate of N callers, a load does not finish before N threads have
// called arrive() right before their JobCache::get(), so the build is still running when they reach
// the cache. (A caller preempted between arrive() and get() may find the build over instead; every
// assertion below holds for it as well.)
struct CountingLoader {
  std::atomic<int> calls{0};
  std::atomic<bool> fail{false};
  int gate = 0;

  void arrive() {
    std::lock_guard lock(mu);
    ++arrived;
    cv.notify_all();
  }
  /// False if a load gave up waiting for its callers (the guard against a hang, not a timing claim).
  bool gate_held() const { return !gate_timed_out; }

  JobCache::SceneLoader fn() {
    return [this](const v1::SceneRef& ref, const std::string&) {
      ++calls;
      {
        std::unique_lock lock(mu);
        if (!cv.wait_for(lock, std::chrono::seconds(60), [&] { return arrived >= gate; })) gate_timed_out = true;
      }
      if (fail) throw std::runtime_error("scene unavailable");
      return std::make_shared<const Scene>(make_builtin_scene(ref.builtin().substr(8)));
    };
  }

 private:
  std::mutex mu;
  std::condition_variable cv;
  int arrived = 0;
  std::atomic<bool> gate_timed_out{false};
};

TEST(JobCache, BuildsOncePerJobEvenUnderConcurrency) {
  CountingLoader loader;
  JobCache cache(3, loader.fn());
  const auto lease = lease_for("a");
  std::vector<std::shared_ptr<const JobContext>> got(6);
  loader.gate = int(got.size());
  std::vector<std::thread> threads;
  for (size_t i = 0; i < got.size(); ++i)
    threads.emplace_back([&, i] {
      loader.arrive();
      got[i] = cache.get(lease);
    });
  for (auto& t : threads) t.join();
  EXPECT_TRUE(loader.gate_held());
  for (const auto& g : got) EXPECT_EQ(g, got[0]);
  EXPECT_EQ(loader.calls, 1);
  EXPECT_EQ(got[0]->camera.width(), 16);
  EXPECT_EQ(got[0]->seed, 1u);
  EXPECT_TRUE(got[0]->matches(lease));
  EXPECT_EQ(cache.get(lease), got[0]);
}

TEST(JobCache, JobsShareTheirSceneAndTheCacheIsBounded) {
  CountingLoader loader;
  JobCache cache(2, loader.fn());
  auto a = cache.get(lease_for("a"));
  auto b = cache.get(lease_for("b", "builtin:cornell", 2));
  EXPECT_EQ(loader.calls, 1);  // same content hash: one scene, one BVH
  EXPECT_EQ(a->scene, b->scene);
  EXPECT_NE(a, b);
  cache.get(lease_for("c", "builtin:furnace"));
  EXPECT_EQ(loader.calls, 2);
  EXPECT_EQ(cache.size(), 2u);  // "a" was dropped
  a.reset();
  b.reset();
  // "a" comes back: "b" still holds the Cornell box, so only the job state is rebuilt.
  cache.get(lease_for("a"));
  EXPECT_EQ(loader.calls, 2);
}

TEST(JobCache, ChangedSettingsRebuildTheJob) {
  CountingLoader loader;
  JobCache cache(3, loader.fn());
  auto lease = lease_for("a");
  const auto first = cache.get(lease);
  lease.mutable_settings()->set_width(32);
  const auto second = cache.get(lease);
  EXPECT_NE(first, second);
  EXPECT_EQ(second->camera.width(), 32);
  EXPECT_EQ(cache.size(), 1u);
}

TEST(JobCache, TheTracerTakesTheDirectLightEstimatorFromTheSettings) {
  CountingLoader loader;
  JobCache cache(3, loader.fn());
  auto lease = lease_for("a");
  ASSERT_TRUE(lease.settings().has_mis());  // to_render_settings states it explicitly
  EXPECT_TRUE(cache.get(lease)->tracer->mis());
  lease.mutable_settings()->set_mis(false);
  EXPECT_FALSE(cache.get(lease)->tracer->mis());
  lease.mutable_settings()->clear_mis();  // a master that predates the field: MIS
  EXPECT_TRUE(cache.get(lease)->tracer->mis());
}

TEST(JobCache, FailuresReachEveryWaiterAndAreRetried) {
  CountingLoader loader;
  loader.fail = true;
  JobCache cache(3, loader.fn());
  const auto lease = lease_for("a");
  std::atomic<int> failures{0};
  loader.gate = 4;
  std::vector<std::thread> threads;
  for (int i = 0; i < 4; ++i)
    threads.emplace_back([&] {
      loader.arrive();
      try {
        cache.get(lease);
      } catch (const std::runtime_error&) {
        ++failures;
      }
    });
  for (auto& t : threads) t.join();
  EXPECT_TRUE(loader.gate_held());
  EXPECT_EQ(failures, 4);
  EXPECT_EQ(cache.size(), 0u);
  loader.fail = false;
  EXPECT_TRUE(cache.get(lease));
}

TEST(JobCache, UnusableSettingsThrow) {
  CountingLoader loader;
  JobCache cache(3, loader.fn());
  auto lease = lease_for("a");
  lease.mutable_settings()->set_width(0);
  EXPECT_THROW(cache.get(lease), std::invalid_argument);
  EXPECT_EQ(loader.calls, 0);
}

}  // namespace
}  // namespace epr
