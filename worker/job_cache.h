// Per-job tracing state on a worker: the scene (with its Embree BVH), the camera and the path tracer
// of each job it leases tiles of, built on the first lease of a job and reused for the next ones.
//
// Bounded: at most max_jobs jobs are kept (least recently used dropped first); a job that is dropped
// while a thread still traces one of its tiles lives until that tile is done (shared ownership).
// Jobs with the same scene (content hash) share one Scene + BVH while any of them is alive, whichever
// master they come from (the hash names the content).
// Thread-safe: when several threads ask for a job that is not built yet, one builds it and the
// others wait for it; a failed build is reported to every waiter and retried on the next request.
#pragma once

#include <cstddef>
#include <functional>
#include <list>
#include <map>
#include <memory>
#include <string>

#include "common/camera.h"
#include "common/check.h"
#include "common/math.h"
#include "common/scene.h"
#include "epr/v1/worker_service.pb.h"
#include "wire/scene_shelf.h"
#include "worker/embree_scene.h"
#include "worker/path_tracer.h"

namespace epr {

/// A scene and its BVH; not movable (the BVH refers to the scene). The scene, and with it its BVH,
/// may be shared with the process's other users (wire/scene_shelf.h).
struct LoadedScene {
  explicit LoadedScene(std::shared_ptr<const Scene> s)
      : owner(std::move(s)), scene(*owner), embree(shelved_bvh(owner)) {}
  explicit LoadedScene(Scene s) : LoadedScene(std::make_shared<const Scene>(std::move(s))) {}
  LoadedScene(const LoadedScene&) = delete;
  LoadedScene& operator=(const LoadedScene&) = delete;

  std::shared_ptr<const Scene> owner;
  const Scene& scene;
  EmbreeScene embree;
};

/// Everything needed to trace a job's tiles.
struct JobContext {
  std::string job_id;
  std::string scene_hash;
  uint64_t seed = 0;
  v1::RenderSettings settings;  // as in the lease that built it
  Bounds3 codec_bounds;
  std::shared_ptr<const LoadedScene> scene;
  Camera camera;
  std::unique_ptr<SkyLight> sky;  // the scene's environment and sun, or the job's (settings)
  std::unique_ptr<PathTracer> tracer;

  /// True if `lease` belongs to this job with the same scene, seed and settings.
  bool matches(const v1::TileLease& lease) const;
};

class JobCache {
 public:
  /// Loads the scene a lease names (generate a built-in, or fetch and load a file scene from
  /// `master`, the master that granted the lease). May throw; the message ends up in the worker's log
  /// and the ReturnLease reason.
  using SceneLoader = std::function<std::shared_ptr<const Scene>(const v1::SceneRef&, const std::string& master)>;

  JobCache(size_t max_jobs, SceneLoader loader);

  /// The job's context, building it if needed (which may take long: a scene fetch and a BVH build).
  /// Jobs are told apart by `master` and job id (masters number their jobs independently). Throws
  /// what the loader throws, or std::invalid_argument for unusable settings.
  std::shared_ptr<const JobContext> get(const v1::TileLease& lease, const std::string& master = {}) EPR_EXCLUDES(mu_);

  /// Jobs currently kept.
  size_t size() const EPR_EXCLUDES(mu_);
  /// Times a scene was loaded (the loader called), for tests and stats.
  uint64_t scene_loads() const EPR_EXCLUDES(mu_);

 private:
  struct Entry;
  // Both run without the lock: loading a scene and building its BVH take long.
  std::shared_ptr<const JobContext> build(const v1::TileLease& lease, const std::string& master) EPR_EXCLUDES(mu_);
  std::shared_ptr<const LoadedScene> scene_for(const v1::SceneRef& ref, const std::string& master) EPR_EXCLUDES(mu_);

  const size_t max_jobs_;
  const SceneLoader loader_;
  mutable Mutex mu_;
  std::list<std::shared_ptr<Entry>> jobs_ EPR_GUARDED_BY(mu_);                          // most recently used first
  std::map<std::string, std::weak_ptr<const LoadedScene>> scenes_ EPR_GUARDED_BY(mu_);  // by content hash
  uint64_t scene_loads_ EPR_GUARDED_BY(mu_) = 0;
};

}  // namespace epr
