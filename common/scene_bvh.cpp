// See scene_bvh.h.
#include "common/scene_bvh.h"

namespace epr {

SceneBvh::SceneBvh(std::shared_ptr<const Scene> scene) : owner_(std::move(scene)), scene_(*owner_) {}

SceneBvh::SceneBvh(const Scene& scene) : scene_(scene) {}

const EmbreeBvh& SceneBvh::bvh() const {
  std::call_once(once_, [this] { bvh_ = std::make_unique<const EmbreeBvh>(scene_); });
  return *bvh_;
}

}  // namespace epr
