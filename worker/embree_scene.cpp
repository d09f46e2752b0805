#include "worker/embree_scene.h"

#include <algorithm>
#include <cmath>

namespace epr {

EmbreeScene::EmbreeScene(const Scene& scene) : EmbreeScene(std::make_shared<const SceneBvh>(scene)) {}

EmbreeScene::EmbreeScene(std::shared_ptr<const SceneBvh> shared)
    : shared_(std::move(shared)), scene_(shared_->scene()), bvh_(shared_->bvh()) {
  const Scene& scene = scene_;
  // Step-off distance: relative to the scene's extent, so that metre- and kilometre-scale scenes
  // both avoid self-intersection without light leaking through thin geometry.
  const Bounds3 b = scene.bounds();
  const float extent = std::max({std::abs(b.lo.x), std::abs(b.lo.y), std::abs(b.lo.z), std::abs(b.hi.x),
                                 std::abs(b.hi.y), std::abs(b.hi.z), 1.f});
  ray_epsilon_ = 2e-5f * extent;

  if (scene.materials.size() <= 256)
    material8_.assign(scene.material_of.begin(), scene.material_of.end());
  else if (scene.materials.size() <= 65536)
    material16_.assign(scene.material_of.begin(), scene.material_of.end());
  build_emitter_table();
}

void EmbreeScene::build_emitter_table() {
  std::vector<float> weights, areas;
  for (size_t i = 0; i < scene_.triangles.size(); ++i) {
    const Material& m = scene_.materials[scene_.material_of[i]];
    if (!m.emissive()) continue;
    const float area = scene_.area(i);
    const float w = area * luminance(m.ke);
    if (!(w > 0)) continue;
    const auto& t = scene_.triangles[i];
    emitters_.push_back({scene_.positions[t[0]], scene_.positions[t[1]], scene_.positions[t[2]],
                         scene_.geometric_normal(i), m.ke, 0.f, m.emits_front_only, uint32_t(i)});
    weights.push_back(w);
    areas.push_back(area);
  }
  if (!emitters_.empty()) emitter_selection_ = AliasTable(weights);
  double total = 0, power = 0;
  for (size_t k = 0; k < weights.size(); ++k) {
    total += weights[k];
    power += kPi * weights[k] * (emitters_[k].front_only ? 1 : 2);
  }
  inv_emitter_weight_ = total > 0 ? float(1 / total) : 0.f;
  emitted_power_ = power;
  for (size_t k = 0; k < emitters_.size(); ++k) emitters_[k].pdf_area = emitter_selection_.pmf(k) / areas[k];
}

}  // namespace epr
