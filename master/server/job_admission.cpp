// JobManager::admit (job_manager.h): every check a submitted job request passes before submit(), the
// same for SubmitJob and CheckFrames; the gRPC service only translates the spec into a JobRequest.
#include <fmt/format.h>

#include <algorithm>
#include <cctype>

#include "common/camera_animation.h"
#include "common/limits.h"
#include "master/memory_estimate.h"
#include "master/server/job_manager.h"
#include "master/server/window_run.h"
#include "wire/scene_bundle.h"

namespace epr {
namespace {

// A batch id of [A-Za-z0-9_-]{1,64}, a name of at most limits::kMaxNameBytes, and no frame, count or
// name without an id.
std::optional<std::string> batch_error(const BatchMembership& b) {
  if (b.id.empty()) {
    if (b.frame || b.frames || !b.name.empty())
      return std::string("frame, batch_frames and batch_name need a batch_id");
    return std::nullopt;
  }
  const bool ok = b.id.size() <= 64 && std::all_of(b.id.begin(), b.id.end(), [](unsigned char c) {
                    return std::isalnum(c) || c == '_' || c == '-';
                  });
  if (!ok) return fmt::format("batch_id '{}' is not 1 to 64 of [A-Za-z0-9_-]", b.id.substr(0, 80));
  if (b.name.size() > limits::kMaxNameBytes)
    return fmt::format("batch names are limited to {} bytes", limits::kMaxNameBytes);
  return std::nullopt;
}

}  // namespace

std::optional<std::string> JobManager::admit(JobRequest* req, bool has_camera, const std::vector<uint32_t>& frames) {
  if (req->name.size() > limits::kMaxNameBytes)
    return fmt::format("job names are limited to {} bytes", limits::kMaxNameBytes);
  if (auto err = batch_error(req->batch)) return err;
  // The limits first (cheap, and a huge bundle is not parsed), then the scene itself, so that a
  // malformed file is refused naming file and line, not a job that fails later. Without a camera the
  // job takes the scene's own.
  if (auto err = validate(*req)) return err;
  // A frame this master cannot hold is refused now, with what it would need, not after the setup
  // (the service answers INVALID_ARGUMENT, not RESOURCE_EXHAUSTED: the same request never fits).
  if (auto err = memory_budget_error(req->options, options_.checkpoints && !options_.state_dir.empty(),
                                     options_.memory_budget_bytes, windowed(req->batch) ? run_length(req->batch) : 1))
    return windowed(req->batch) ? fmt::format("frame {}: {}", *req->batch.frame, *err) : err;
  CameraSpec scene_camera;
  CameraAnimation animation;  // frames without a camera: the scene's camera at each frame
  const bool frame_camera = !has_camera && !frames.empty();
  // From here on the scene is in the master's cache: a refusal removes it again.
  auto refuse = [&](std::string why) {
    discard_checked_scene(content_hash(req->bundle));
    return std::optional<std::string>(std::move(why));
  };
  if (auto err = check_scene(req->bundle, &scene_camera, frame_camera ? &animation : nullptr, req->options.lighting))
    return refuse(*err);
  if (has_camera) return std::nullopt;
  const CameraSpec own = scene_camera;
  for (uint32_t frame : frames.empty() ? std::vector<uint32_t>{0} : frames) {
    if (frame_camera) {
      if (auto err = animation.frame_problem(frame, own)) return refuse(*err);
      scene_camera = animation.at(frame, own);
    }
    if (auto err = scene_camera.validate())
      return refuse(frame_camera ? fmt::format("frame {}: the scene's camera: {}", frame, *err)
                                 : "the scene's own camera: " + *err);
  }
  req->camera = scene_camera;
  return std::nullopt;
}

}  // namespace epr
