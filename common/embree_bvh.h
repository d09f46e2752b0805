// A scene's triangles in an Embree 3 BVH: closest-hit and any-hit queries, the holes of cut-out
// materials (Scene::cut_out_at at the hit's barycentrics) skipped by Embree filter functions, so a
// ray sees what lies behind a hole. The workers trace their paths with it (worker/embree_scene.h)
// and the master its edge pixels' supersampled visibility (master/edge_pixels.h) and its cut
// measurement (master/view_overlap.h); one per scene in a process (scene_bvh.h).
//
// Each object has its own device; errors from Embree are reported through a device error callback
// (logged on the "embree" logger) rather than by checking every call, as in Embree's tutorials.
#pragma once

#include <embree3/rtcore.h>

#include <cstdint>
#include <limits>
#include <span>
#include <vector>

#include "common/camera.h"
#include "common/scene.h"

namespace epr {

struct Hit {
  float t = 0;         // distance along the (unit) ray direction, metres
  uint32_t prim = 0;   // triangle index into Scene::triangles
  float u = 0, v = 0;  // barycentrics of corners 1 and 2
  Vec3 ng;             // Embree's geometric normal: not normalised, right-hand rule on the corner order
};

/// BVHs built in this process so far (for tests and statistics: one per scene, scene_bvh.h).
uint64_t embree_bvh_builds();

class EmbreeBvh {
 public:
  static constexpr uint32_t kMissed = std::numeric_limits<uint32_t>::max();

  /// Builds the BVH. `scene` must outlive this object (the cut-out filters read its materials).
  explicit EmbreeBvh(const Scene& scene);
  ~EmbreeBvh();
  EmbreeBvh(const EmbreeBvh&) = delete;
  EmbreeBvh& operator=(const EmbreeBvh&) = delete;

  /// Closest hit along `ray` within (tnear, tfar); false if none.
  bool intersect(const Ray& ray, float tnear, float tfar, Hit* hit) const;
  /// True if anything blocks the segment origin + t dir, t in (tnear, tfar); dir need not be unit length.
  bool occluded(const Vec3& origin, const Vec3& dir, float tnear, float tfar) const;
  /// Closest hits of coherent rays (neighbouring camera rays), traced together as an Embree stream:
  /// ray i from tnear[i] on, unbounded; hits[i].prim is kMissed where it hits nothing. Each hit is
  /// the closest one, as intersect() finds it (both skip holes with the same filter; where a ray meets
  /// two triangles at one distance, through their common edge, either may be reported).
  void intersect_coherent(std::span<const Ray> rays, std::span<const float> tnear, std::span<Hit> hits) const;

 private:
  void add_geometry(const std::vector<uint32_t>& tris, bool cut_out);
  static void cut_out_filter(const RTCFilterFunctionNArguments* args);
  uint32_t triangle_of(unsigned geom, unsigned prim) const { return tri_of_.empty() ? prim : tri_of_[geom][prim]; }

  const Scene& scene_;
  RTCDevice device_ = nullptr;
  RTCScene rtc_scene_ = nullptr;
  std::vector<std::vector<uint32_t>> tri_of_;  // with cut-outs: per geometry, its primitives' triangles
};

}  // namespace epr
