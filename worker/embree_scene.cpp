#include "worker/embree_scene.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "common/log.h"

namespace epr {
namespace {

void on_embree_error(void*, RTCError code, const char* message) {
  logger("worker")->error("embree error {}: {}", int(code), message ? message : "");
}

}  // namespace

EmbreeScene::EmbreeScene(const Scene& scene) : scene_(scene) {
  device_ = rtcNewDevice(nullptr);
  if (!device_) throw std::runtime_error("cannot create Embree device");
  rtcSetDeviceErrorFunction(device_, on_embree_error, nullptr);

  rtc_scene_ = rtcNewScene(device_);
  rtcSetSceneFlags(rtc_scene_, RTC_SCENE_FLAG_ROBUST);
  if (!scene.has_cut_outs()) {
    add_geometry({}, false);
  } else {
    std::vector<uint32_t> opaque, cut;
    for (uint32_t t = 0; t < uint32_t(scene.triangles.size()); ++t)
      (scene.materials[scene.material_of[t]].cut_out() ? cut : opaque).push_back(t);
    if (!opaque.empty()) add_geometry(opaque, false);
    add_geometry(cut, true);
  }
  rtcCommitScene(rtc_scene_);

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

/// One triangle geometry: all of the scene's triangles (`tris` empty, primitive = triangle) or those
/// listed, with the cut-out filters if `cut_out`.
void EmbreeScene::add_geometry(const std::vector<uint32_t>& tris, bool cut_out) {
  const Scene& scene = scene_;
  const size_t n = tris.empty() ? scene.triangles.size() : tris.size();
  RTCGeometry geom = rtcNewGeometry(device_, RTC_GEOMETRY_TYPE_TRIANGLE);
  auto* verts = static_cast<float*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                                            3 * sizeof(float), scene.positions.size()));
  for (size_t i = 0; i < scene.positions.size(); ++i) {
    verts[3 * i + 0] = scene.positions[i].x;
    verts[3 * i + 1] = scene.positions[i].y;
    verts[3 * i + 2] = scene.positions[i].z;
  }
  auto* idx = static_cast<uint32_t*>(
      rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(uint32_t), n));
  for (size_t i = 0; i < n; ++i)
    for (int k = 0; k < 3; ++k) idx[3 * i + k] = scene.triangles[tris.empty() ? i : tris[i]][k];
  if (cut_out) {
    rtcSetGeometryUserData(geom, this);
    rtcSetGeometryIntersectFilterFunction(geom, cut_out_filter);
    rtcSetGeometryOccludedFilterFunction(geom, cut_out_filter);
  }
  rtcCommitGeometry(geom);
  const unsigned id = rtcAttachGeometry(rtc_scene_, geom);
  rtcReleaseGeometry(geom);
  if (!tris.empty()) {
    tri_of_.resize(std::max<size_t>(tri_of_.size(), id + 1));
    tri_of_[id] = tris;
  }
}

void EmbreeScene::cut_out_filter(const RTCFilterFunctionNArguments* args) {
  const auto* self = static_cast<const EmbreeScene*>(args->geometryUserPtr);
  for (unsigned i = 0; i < args->N; ++i) {
    if (args->valid[i] != -1) continue;
    const unsigned geom = RTCHitN_geomID(args->hit, args->N, i), prim = RTCHitN_primID(args->hit, args->N, i);
    const uint32_t tri = self->tri_of_[geom][prim];
    if (self->scene_.cut_out_at(tri, RTCHitN_u(args->hit, args->N, i), RTCHitN_v(args->hit, args->N, i)))
      args->valid[i] = 0;
  }
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

EmbreeScene::~EmbreeScene() {
  if (rtc_scene_) rtcReleaseScene(rtc_scene_);
  if (device_) rtcReleaseDevice(device_);
}

bool EmbreeScene::intersect(const Ray& ray, float tnear, float tfar, Hit* hit) const {
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  RTCRayHit rh;
  rh.ray.org_x = ray.origin.x;
  rh.ray.org_y = ray.origin.y;
  rh.ray.org_z = ray.origin.z;
  rh.ray.dir_x = ray.dir.x;
  rh.ray.dir_y = ray.dir.y;
  rh.ray.dir_z = ray.dir.z;
  rh.ray.tnear = tnear;
  rh.ray.tfar = tfar;
  rh.ray.time = 0;
  rh.ray.mask = 0xffffffffu;
  rh.ray.id = 0;
  rh.ray.flags = 0;
  rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
  rtcIntersect1(rtc_scene_, &ctx, &rh);
  if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return false;
  hit->t = rh.ray.tfar;
  hit->prim = tri_of_.empty() ? rh.hit.primID : tri_of_[rh.hit.geomID][rh.hit.primID];
  hit->u = rh.hit.u;
  hit->v = rh.hit.v;
  hit->ng = {rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z};
  return true;
}

bool EmbreeScene::occluded(const Vec3& origin, const Vec3& dir, float tnear, float tfar) const {
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  RTCRay r;
  r.org_x = origin.x;
  r.org_y = origin.y;
  r.org_z = origin.z;
  r.dir_x = dir.x;
  r.dir_y = dir.y;
  r.dir_z = dir.z;
  r.tnear = tnear;
  r.tfar = tfar;
  r.time = 0;
  r.mask = 0xffffffffu;
  r.id = 0;
  r.flags = 0;
  rtcOccluded1(rtc_scene_, &ctx, &r);
  return r.tfar < 0;  // Embree sets tfar to -inf on a hit
}

}  // namespace epr
