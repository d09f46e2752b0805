#include "wire/scene_shelf.h"

#include <map>

#include "common/check.h"

namespace epr {
namespace {

struct Shelf {
  Mutex mu;
  std::map<std::string, std::weak_ptr<const Scene>> scenes EPR_GUARDED_BY(mu);
};

Shelf& shelf() {
  static Shelf* s = new Shelf;  // never destroyed: users may outlive static destruction
  return *s;
}

}  // namespace

std::shared_ptr<const Scene> shelved_scene(const std::string& content_hash) {
  Shelf& s = shelf();
  MutexLock lock(s.mu);
  auto it = s.scenes.find(content_hash);
  return it == s.scenes.end() ? nullptr : it->second.lock();
}

std::shared_ptr<const Scene> shelve_scene(const std::string& content_hash, std::shared_ptr<const Scene> scene) {
  Shelf& s = shelf();
  MutexLock lock(s.mu);
  for (auto it = s.scenes.begin(); it != s.scenes.end();)  // forget the scenes nobody holds any more
    it = it->second.expired() ? s.scenes.erase(it) : std::next(it);
  std::weak_ptr<const Scene>& slot = s.scenes[content_hash];
  if (auto earlier = slot.lock()) return earlier;
  slot = scene;
  return scene;
}

}  // namespace epr
