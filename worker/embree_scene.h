// The scene's triangles in an Embree 3 BVH: closest-hit and any-hit (shadow) queries.
//
// One device per process; errors from Embree are reported through a device error callback (logged
// on the "worker" logger) rather than by checking every call, as in Embree's tutorials.
#pragma once

#include <cstdint>

#include <embree3/rtcore.h>

#include "common/camera.h"
#include "common/scene.h"

namespace epr {

struct Hit {
  float t = 0;      // distance along the (unit) ray direction, metres
  uint32_t prim = 0;  // triangle index into Scene::triangles
  float u = 0, v = 0;  // barycentrics of corners 1 and 2
};

class EmbreeScene {
 public:
  /// Builds the BVH. `scene` must outlive this object (materials are read from it while tracing).
  explicit EmbreeScene(const Scene& scene);
  ~EmbreeScene();
  EmbreeScene(const EmbreeScene&) = delete;
  EmbreeScene& operator=(const EmbreeScene&) = delete;

  /// Closest hit along `ray` within (tnear, tfar); false if none.
  bool intersect(const Ray& ray, float tnear, float tfar, Hit* hit) const;
  /// True if anything blocks the segment origin + t dir, t in (tnear, tfar).
  bool occluded(const Vec3& origin, const Vec3& dir, float tnear, float tfar) const;

  const Scene& scene() const { return scene_; }
  /// Offset in metres used to step off a surface (scaled to the scene's extent).
  float ray_epsilon() const { return ray_epsilon_; }

 private:
  const Scene& scene_;
  RTCDevice device_ = nullptr;
  RTCScene rtc_scene_ = nullptr;
  float ray_epsilon_ = 1e-4f;
};

}  // namespace epr
