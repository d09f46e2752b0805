#include "wire/scene_shelf.h"

#include <map>

#include "common/check.h"

namespace epr {
namespace {

// A shelved scene (held weakly) and its BVH holder: held by the pointers the shelf hands out, which
// share its ownership and point at the scene, so that the BVH lives as long as they do.
struct Slot {
  std::weak_ptr<const Scene> scene;
  std::weak_ptr<const SceneBvh> bvh;
};

struct Shelf {
  Mutex mu;
  std::map<std::string, Slot> scenes EPR_GUARDED_BY(mu);
};

Shelf& shelf() {
  static Shelf* s = new Shelf;  // never destroyed: users may outlive static destruction
  return *s;
}

// The slot's BVH holder, made if nobody holds one; null if the slot's scene is gone.
std::shared_ptr<const SceneBvh> holder(Slot& slot) {
  std::shared_ptr<const Scene> scene = slot.scene.lock();
  if (!scene) return nullptr;
  std::shared_ptr<const SceneBvh> h = slot.bvh.lock();
  if (!h) slot.bvh = h = std::make_shared<const SceneBvh>(std::move(scene));
  return h;
}

// The scene as the shelf hands it out: a pointer to it that holds its BVH holder.
std::shared_ptr<const Scene> handed_out(const std::shared_ptr<const SceneBvh>& h) {
  return h ? std::shared_ptr<const Scene>(h, &h->scene()) : nullptr;
}

}  // namespace

std::shared_ptr<const Scene> shelved_scene(const std::string& content_hash) {
  Shelf& s = shelf();
  MutexLock lock(s.mu);
  auto it = s.scenes.find(content_hash);
  return it == s.scenes.end() ? nullptr : handed_out(holder(it->second));
}

std::shared_ptr<const Scene> shelve_scene(const std::string& content_hash, std::shared_ptr<const Scene> scene) {
  Shelf& s = shelf();
  MutexLock lock(s.mu);
  for (auto it = s.scenes.begin(); it != s.scenes.end();)  // forget the scenes nobody holds any more
    it = it->second.scene.expired() ? s.scenes.erase(it) : std::next(it);
  Slot& slot = s.scenes[content_hash];
  if (auto earlier = holder(slot)) return handed_out(earlier);
  slot = Slot{scene, {}};
  return handed_out(holder(slot));
}

std::shared_ptr<const SceneBvh> shelved_bvh(const std::shared_ptr<const Scene>& scene) {
  {
    Shelf& s = shelf();
    MutexLock lock(s.mu);
    for (auto& [hash, slot] : s.scenes)
      if (auto held = slot.scene.lock(); held && held.get() == scene.get()) return holder(slot);
  }
  return std::make_shared<const SceneBvh>(scene);
}

}  // namespace epr
