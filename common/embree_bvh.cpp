// See embree_bvh.h.
#include "common/embree_bvh.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <stdexcept>

#include "common/log.h"

namespace epr {
namespace {

std::atomic<uint64_t> builds{0};

void on_embree_error(void*, RTCError code, const char* message) {
  logger("embree")->error("embree error {}: {}", int(code), message ? message : "");
}

void set_ray(const Vec3& origin, const Vec3& dir, float tnear, float tfar, RTCRay* r) {
  r->org_x = origin.x;
  r->org_y = origin.y;
  r->org_z = origin.z;
  r->dir_x = dir.x;
  r->dir_y = dir.y;
  r->dir_z = dir.z;
  r->tnear = tnear;
  r->tfar = tfar;
  r->time = 0;
  r->mask = 0xffffffffu;
  r->id = 0;
  r->flags = 0;
}

}  // namespace

uint64_t embree_bvh_builds() { return builds.load(); }

EmbreeBvh::EmbreeBvh(const Scene& scene) : scene_(scene) {
  ++builds;
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
}

/// One triangle geometry: all of the scene's triangles (`tris` empty, primitive = triangle) or those
/// listed, with the cut-out filters if `cut_out`.
void EmbreeBvh::add_geometry(const std::vector<uint32_t>& tris, bool cut_out) {
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

void EmbreeBvh::cut_out_filter(const RTCFilterFunctionNArguments* args) {
  const auto* self = static_cast<const EmbreeBvh*>(args->geometryUserPtr);
  for (unsigned i = 0; i < args->N; ++i) {
    if (args->valid[i] != -1) continue;
    const unsigned geom = RTCHitN_geomID(args->hit, args->N, i), prim = RTCHitN_primID(args->hit, args->N, i);
    if (self->scene_.cut_out_at(self->tri_of_[geom][prim], RTCHitN_u(args->hit, args->N, i),
                                RTCHitN_v(args->hit, args->N, i)))
      args->valid[i] = 0;
  }
}

EmbreeBvh::~EmbreeBvh() {
  if (rtc_scene_) rtcReleaseScene(rtc_scene_);
  if (device_) rtcReleaseDevice(device_);
}

bool EmbreeBvh::intersect(const Ray& ray, float tnear, float tfar, Hit* hit) const {
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  RTCRayHit rh;
  set_ray(ray.origin, ray.dir, tnear, tfar, &rh.ray);
  rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
  rtcIntersect1(rtc_scene_, &ctx, &rh);
  if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return false;
  hit->t = rh.ray.tfar;
  hit->prim = triangle_of(rh.hit.geomID, rh.hit.primID);
  hit->u = rh.hit.u;
  hit->v = rh.hit.v;
  hit->ng = {rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z};
  return true;
}

bool EmbreeBvh::occluded(const Vec3& origin, const Vec3& dir, float tnear, float tfar) const {
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  RTCRay r;
  set_ray(origin, dir, tnear, tfar, &r);
  rtcOccluded1(rtc_scene_, &ctx, &r);
  return r.tfar < 0;  // Embree sets tfar to -inf on a hit
}

void EmbreeBvh::intersect_coherent(std::span<const Ray> rays, std::span<const float> tnear, std::span<Hit> hits) const {
  if (tnear.size() != rays.size() || hits.size() != rays.size())
    throw std::invalid_argument("intersect_coherent: rays, tnear and hits differ in length");
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  ctx.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
  constexpr size_t kBatch = 64;
  RTCRayHit batch[kBatch];
  for (size_t i0 = 0; i0 < rays.size(); i0 += kBatch) {
    const size_t n = std::min(kBatch, rays.size() - i0);
    for (size_t i = 0; i < n; ++i) {
      RTCRayHit& rh = batch[i];
      set_ray(rays[i0 + i].origin, rays[i0 + i].dir, tnear[i0 + i], INFINITY, &rh.ray);
      rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
      rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    }
    rtcIntersect1M(rtc_scene_, &ctx, batch, unsigned(n), sizeof(RTCRayHit));
    for (size_t i = 0; i < n; ++i) {
      const RTCRayHit& rh = batch[i];
      Hit& h = hits[i0 + i];
      if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) {
        h = Hit{};
        h.prim = kMissed;
        continue;
      }
      h.t = rh.ray.tfar;
      h.prim = triangle_of(rh.hit.geomID, rh.hit.primID);
      h.u = rh.hit.u;
      h.v = rh.hit.v;
      h.ng = {rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z};
    }
  }
}

}  // namespace epr
