// LeaseTile calls kept waiting (long polling). A worker that asks while every tile of the round is
// out, the round is closing or no job has started would otherwise poll every few milliseconds; its
// call is parked instead and answered the moment a tile may be there (a round opened, a tile came
// back) or when its wait is up. Not thread-safe: the JobManager calls it under its mutex and calls
// the answers taken from it without the mutex.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <string>
#include <utility>
#include <variant>
#include <vector>

#include "common/camera.h"
#include "common/math.h"
#include "common/render_options.h"
#include "common/tile.h"

namespace epr {

struct TileLeaseInfo {
  uint64_t lease_id = 0;
  std::string job_id;
  uint32_t round = 0, tile_index = 0;
  TileRect rect;
  std::vector<uint8_t> skip;           // per tile pixel
  std::vector<uint32_t> first_sample;  // per tile pixel, one for every pixel, or empty for 0 (RoundPlan)
  uint32_t paths_per_pixel = 1;
  std::vector<uint32_t> paths;  // per tile pixel, or empty for paths_per_pixel each (RoundPlan)
  uint64_t seed = 0;
  RenderOptions options;
  CameraSpec camera;
  std::vector<CameraSpec> window_cameras;  // TileLease.window_cameras
  Bounds3 codec_bounds;
  std::string scene_hash, scene_builtin;
  uint64_t scene_bytes = 0, triangles = 0;
  int64_t deadline_ms = 0;
};
struct LeaseWait {
  uint32_t retry_after_ms = 200;
};
struct UnknownWorker {};
using LeaseDecision = std::variant<TileLeaseInfo, LeaseWait, UnknownWorker>;

class LeaseParking {
 public:
  using Answer = std::function<void(LeaseDecision)>;
  /// Decides for a worker now; *parkable: the answer is a short Wait that a tile may end soon.
  using Decide = std::function<LeaseDecision(const std::string& worker, bool* parkable)>;

  /// Keeps a call of `worker` until `deadline_ms`; its handle.
  uint64_t park(const std::string& worker, int64_t deadline_ms, Answer answer);
  /// True if the call was still parked (its answer will not be called).
  bool cancel(uint64_t handle) { return parked_.erase(handle) > 0; }
  size_t size() const { return parked_.size(); }
  bool stopped() const { return stopped_; }
  /// Parks no more; every parked call is answered with a Wait (the server is going away).
  void stop();
  /// Decides again for the parked calls, those whose `prefer` is true first: a call that gets a
  /// tile, or whose wait is up, or every call with `all`, becomes due.
  void wake(bool all, int64_t now_ms, const Decide& decide, const std::function<bool(const std::string&)>& prefer);
  /// The decided calls, to be answered without the caller's mutex.
  std::vector<std::pair<Answer, LeaseDecision>> take_due() { return std::exchange(due_, {}); }

 private:
  struct Parked {
    std::string worker;
    int64_t deadline_ms = 0;
    Answer answer;
  };
  std::map<uint64_t, Parked> parked_;  // oldest first
  uint64_t next_ = 1;
  bool stopped_ = false;
  std::vector<std::pair<Answer, LeaseDecision>> due_;
};

}  // namespace epr
