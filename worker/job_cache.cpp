#include "worker/job_cache.h"

#include <google/protobuf/util/message_differencer.h>

#include <chrono>
#include <future>
#include <stdexcept>

#include "common/log.h"
#include "common/scene_loader.h"
#include "wire/convert.h"
#include "worker/tile_lease.h"

namespace epr {

struct JobCache::Entry {
  std::string master, job_id;
  std::shared_future<std::shared_ptr<const JobContext>> context;

  bool ready() const { return context.wait_for(std::chrono::seconds(0)) == std::future_status::ready; }
};

bool JobContext::matches(const v1::TileLease& lease) const {
  return lease.job_id() == job_id && lease.scene().content_hash() == scene_hash && lease.seed() == seed &&
         google::protobuf::util::MessageDifferencer::Equals(lease.settings(), settings);
}

JobCache::JobCache(size_t max_jobs, SceneLoader loader)
    : max_jobs_(std::max<size_t>(1, max_jobs)), loader_(std::move(loader)) {}

size_t JobCache::size() const {
  MutexLock lock(mu_);
  return jobs_.size();
}

uint64_t JobCache::scene_loads() const {
  MutexLock lock(mu_);
  return scene_loads_;
}

std::shared_ptr<const JobContext> JobCache::get(const v1::TileLease& lease, const std::string& master) {
  // Two rounds at most: a cached context of the same job id with other settings (a job id reused by
  // a restarted master without its checkpoint) is replaced once; after that, build uncached.
  for (int attempt = 0; attempt < 2; ++attempt) {
    std::shared_ptr<Entry> entry;
    std::promise<std::shared_ptr<const JobContext>> promise;
    bool builder = false;
    {
      MutexLock lock(mu_);
      for (auto it = jobs_.begin(); it != jobs_.end(); ++it) {
        if ((*it)->job_id != lease.job_id() || (*it)->master != master) continue;
        if ((*it)->ready()) {
          bool usable = false;
          try {
            usable = (*it)->context.get()->matches(lease);
          } catch (...) {
          }
          if (!usable) {
            jobs_.erase(it);
            break;
          }
        }
        entry = *it;
        jobs_.splice(jobs_.begin(), jobs_, it);  // most recently used
        break;
      }
      if (!entry) {
        entry = std::make_shared<Entry>();
        entry->master = master;
        entry->job_id = lease.job_id();
        entry->context = promise.get_future().share();
        jobs_.push_front(entry);
        builder = true;
      }
    }
    if (builder) {
      try {
        promise.set_value(build(lease, master));
        // Trim only now, so the new job can still share the scene of a job it pushes out.
        MutexLock lock(mu_);
        while (jobs_.size() > max_jobs_ && jobs_.back() != entry) jobs_.pop_back();
      } catch (...) {
        promise.set_exception(std::current_exception());
        MutexLock lock(mu_);
        jobs_.remove(entry);  // not cached: the next lease tries again
        throw;
      }
    }
    std::shared_ptr<const JobContext> ctx = entry->context.get();  // rethrows the builder's error
    if (ctx->matches(lease)) return ctx;
  }
  return build(lease, master);
}

std::shared_ptr<const LoadedScene> JobCache::scene_for(const v1::SceneRef& ref, const std::string& master) {
  {
    MutexLock lock(mu_);
    if (auto it = scenes_.find(ref.content_hash()); it != scenes_.end())
      if (auto s = it->second.lock()) return s;
    ++scene_loads_;
  }
  // Loading and the BVH build happen outside the lock; two jobs loading the same new scene at the
  // same moment both load it (rare, and correct).
  using Clock = std::chrono::steady_clock;
  const auto since = [](Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); };
  const auto start = Clock::now();
  std::shared_ptr<const Scene> scene = loader_(ref, master);
  const double load_s = since(start);
  const auto build = Clock::now();
  auto loaded = std::make_shared<const LoadedScene>(std::move(scene));
  logger("worker")->debug("scene {}: fetched and loaded (or shared) in {:.2f} s, its BVH built in {:.2f} s",
                          ref.content_hash().substr(0, 12), load_s, since(build));
  MutexLock lock(mu_);
  for (auto it = scenes_.begin(); it != scenes_.end();)  // forget scenes nobody holds any more
    it = it->second.expired() ? scenes_.erase(it) : std::next(it);
  scenes_[ref.content_hash()] = loaded;
  return loaded;
}

std::shared_ptr<const JobContext> JobCache::build(const v1::TileLease& lease, const std::string& master) {
  const v1::RenderSettings& s = lease.settings();
  if (auto err = check_render_settings(s)) throw std::invalid_argument(*err);
  auto ctx = std::make_shared<JobContext>();
  ctx->job_id = lease.job_id();
  ctx->scene_hash = lease.scene().content_hash();
  ctx->seed = lease.seed();
  ctx->settings = s;
  ctx->codec_bounds = from_proto(s.codec_bounds());
  ctx->scene = scene_for(lease.scene(), master);
  ctx->camera = Camera(from_proto(s.camera()), int(s.width()), int(s.height()));
  Lighting job;
  if (auto err = from_proto(s.has_environment() ? &s.environment() : nullptr, s.has_sun() ? &s.sun() : nullptr, &job))
    throw std::invalid_argument(*err);
  ctx->sky = std::make_unique<SkyLight>(job_lighting(ctx->scene->scene, job), ctx->scene->embree);
  // check_render_settings accepted the sampler: from_proto knows it.
  ctx->tracer =
      std::make_unique<PathTracer>(ctx->scene->embree, ctx->camera, ctx->seed, from_proto(s.russian_roulette()),
                                   !s.has_mis() || s.mis(), from_proto(s.sampler()).value(), ctx->sky.get());
  return ctx;
}

}  // namespace epr
