// A scene with its Embree BVH (embree_bvh.h), built on first use and then shared by every user of
// the scene: the tracing of the workers in this process (worker/embree_scene.h), the master's edge
// pixels of each of its frames (master/edge_pixels.h) and its cut measurement (master/view_overlap.h).
// The scene shelf keeps one per shelved scene (wire/scene_shelf.h: shelved_bvh). Embree answers
// concurrent queries of one BVH, so one build serves them all.
#pragma once

#include <memory>
#include <mutex>

#include "common/embree_bvh.h"
#include "common/scene.h"

namespace epr {

class SceneBvh {
 public:
  /// Holds a share of `scene`.
  explicit SceneBvh(std::shared_ptr<const Scene> scene);
  /// `scene` must outlive this object.
  explicit SceneBvh(const Scene& scene);
  SceneBvh(const SceneBvh&) = delete;
  SceneBvh& operator=(const SceneBvh&) = delete;

  const Scene& scene() const { return scene_; }
  /// The BVH, built by the first caller while later ones wait for it (a build that throws is tried
  /// again by the next caller). Not to be called first from inside a TBB task whose siblings call it
  /// too: the build runs TBB tasks, and a waiting thread could take a sibling that waits on itself.
  const EmbreeBvh& bvh() const;

 private:
  std::shared_ptr<const Scene> owner_;
  const Scene& scene_;
  mutable std::once_flag once_;
  mutable std::unique_ptr<const EmbreeBvh> bvh_;
};

}  // namespace epr
