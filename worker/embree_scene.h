// The scene prepared for tracing: its triangles in an Embree 3 BVH (common/embree_bvh.h: closest-hit
// and any-hit queries, cut-out holes skipped; its own, or one shared with the scene's other users in
// the process, common/scene_bvh.h), plus what a path needs per hit and per light sample,
// prepared once here rather than per ray: a compact per-triangle material index and the table of
// emitting triangles. A hit's geometric normal is Embree's (Hit::ng), which costs no memory access.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <memory>
#include <vector>

#include "common/camera.h"
#include "common/embree_bvh.h"
#include "common/sampling.h"
#include "common/scene.h"
#include "common/scene_bvh.h"

namespace epr {

/// An emitting triangle as next event estimation samples it.
struct Emitter {
  Vec3 p0, p1, p2;  // corners, world space, metres
  Vec3 normal;      // unit geometric normal, right-hand rule on the corner order
  Vec3 le;          // emitted radiance Ke, W / (m^2 sr)
  float pdf_area;   // probability of choosing this triangle / its area, 1/m^2
  bool front_only;  // emits on the normal's side only (else on both sides)
  uint32_t tri;     // the scene's triangle (for its emission texture)

  /// |cos| at the light of a direction `to_light` from a shading point, or 0 where the emitter shows
  /// that point its dark back.
  float cos_towards(const Vec3& to_light) const {
    const float c = dot(normal, to_light);
    return front_only ? std::max(0.f, -c) : std::abs(c);
  }
};

class EmbreeScene {
 public:
  /// Builds the BVH. `scene` must outlive this object (materials are read from it while tracing).
  explicit EmbreeScene(const Scene& scene);
  /// Traces `shared`'s scene with its BVH (built now unless it was).
  explicit EmbreeScene(std::shared_ptr<const SceneBvh> shared);
  EmbreeScene(const EmbreeScene&) = delete;
  EmbreeScene& operator=(const EmbreeScene&) = delete;

  /// Closest hit along `ray` within (tnear, tfar); false if none.
  bool intersect(const Ray& ray, float tnear, float tfar, Hit* hit) const {
    return bvh_.intersect(ray, tnear, tfar, hit);
  }
  /// True if anything blocks the segment origin + t dir, t in (tnear, tfar); dir need not be unit length.
  bool occluded(const Vec3& origin, const Vec3& dir, float tnear, float tfar) const {
    return bvh_.occluded(origin, dir, tnear, tfar);
  }

  const Scene& scene() const { return scene_; }
  /// Scene::material_of[prim], read from a copy of 1 byte per triangle when the scene has at most
  /// 256 materials, 2 bytes up to 65536: a hit's one memory access outside Embree, and the smaller
  /// the table the likelier it is cached next to Embree's BVH.
  uint32_t material(uint32_t prim) const {
    if (!material8_.empty()) return material8_[prim];
    return material16_.empty() ? scene_.material_of[prim] : material16_[prim];
  }

  /// Emitting triangles (Ke non-zero, area > 0), chosen with probability proportional to
  /// area x luminance(Ke).
  const std::vector<Emitter>& emitters() const { return emitters_; }
  /// The emitter for a uniform u in [0,1); null if the scene has none.
  const Emitter* sample_emitter(float u) const {
    return emitters_.empty() ? nullptr : &emitters_[emitter_selection_.sample(u)];
  }
  /// Area density (1/m^2) with which next event estimation picks a point on an emitting triangle of
  /// material `m`: pmf / area = area * luminance(Ke) / (total weight * area) = luminance(Ke) / total
  /// weight, the same for every triangle of the material. 0 for a material no emitter uses (then only
  /// BSDF sampling can find its light). Used by multiple importance sampling.
  float emitter_pdf_area(const Material& m) const { return luminance(m.ke) * inv_emitter_weight_; }
  /// Power the emitting triangles emit (luminance, W): the sum of pi x area x luminance(Ke) per side
  /// that emits.
  double emitted_power() const { return emitted_power_; }
  /// Offset in metres used to step off a surface (scaled to the scene's extent).
  float ray_epsilon() const { return ray_epsilon_; }

 private:
  void build_emitter_table();

  const std::shared_ptr<const SceneBvh> shared_;
  const Scene& scene_;
  const EmbreeBvh& bvh_;
  float ray_epsilon_ = 1e-4f;
  std::vector<uint8_t> material8_;
  std::vector<uint16_t> material16_;
  std::vector<Emitter> emitters_;
  AliasTable emitter_selection_;
  float inv_emitter_weight_ = 0;  // 1 / sum over emitters of area x luminance(Ke)
  double emitted_power_ = 0;
};

}  // namespace epr
