// The JobManager's two threads, each running an object of its own on its stack: the reprojection
// thread's ReprojectionWorker and the reaper's Reaper (job_manager.h, "Threads").
#include "master/server/job_manager.h"
#include "master/server/reaper.h"
#include "master/server/reprojection_worker.h"

namespace epr {

void JobManager::start_threads() {
  reprojection_thread_ = std::thread([this] { ReprojectionWorker(*this).run(); });
  reaper_thread_ = std::thread([this] { Reaper(*this).run(); });
}

}  // namespace epr
