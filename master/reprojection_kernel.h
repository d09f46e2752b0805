// The per-point reprojection decision, written once in C++ and mirrored line by line by the GLSL
// compute shader in gl_reprojector.cpp (keep both in step: same operations in the same order, so
// that the CPU and GL back-ends take bit-identical decisions). Internal to master/.
//
// The deep framebuffer is used in a compact form, PlaneGrid: per texel the index of its plane in a
// table of distinct (N.x, N.y, N.z, d) tuples (kUncovered if no triangle covers the texel). The table
// is tiny for most scenes (one entry per visible triangle), so the per-texel array (4 bytes) is the
// only large random-access structure besides the accumulation.
#pragma once

#include <cmath>
#include <cstdint>
#include <cstring>
#include <vector>

#include "common/camera.h"
#include "common/vertex_record.h"
#include "master/deep_framebuffer.h"
#include "master/reprojector.h"

namespace epr::detail {

struct PlaneGrid {
  static constexpr uint32_t kUncovered = 0xffffffffu;
  int width = 0, height = 0;
  std::vector<uint32_t> texel_plane;  // per texel: index into planes, or kUncovered
  std::vector<float> planes;          // 4 per plane: N.x, N.y, N.z, d
};
PlaneGrid make_plane_grid(const DeepFramebuffer& dfb);

/// Uniform inputs of the kernel (the GL shader receives the same values as uniforms).
struct KernelParams {
  Vec3 eye, forward, right, up;
  float tan_half_x = 1, tan_half_y = 1;
  float width = 1, height = 1;    // image size in pixels (float, as in Camera::project)
  float s = 4;                    // subpixels per axis
  float grid_w = 4, grid_h = 4;   // S * width, S * height
  uint32_t grid_wi = 4;
  float epsilon = 0;
};
KernelParams make_kernel_params(const Camera& camera, int subpixels, float epsilon);

/// Throws std::invalid_argument for bad settings or a deep framebuffer that does not fit the camera.
void validate_reprojector_inputs(const Camera& camera, const DeepFramebuffer& dfb, const ReprojectorSettings& s);

enum class Decision : uint8_t { kAccepted, kCulled, kBackfacing, kOccluded };

inline bool finite_bits(float v) {
  uint32_t b;
  std::memcpy(&b, &v, 4);
  return (b & 0x7f800000u) != 0x7f800000u;
}

/// Step 1-2 of the semantics (done on the CPU by both back-ends, before upload for GL).
inline bool record_is_finite(const VertexRecord& r) {
  return finite_bits(r.position.x) && finite_bits(r.position.y) && finite_bits(r.position.z) &&
         finite_bits(r.normal.x) && finite_bits(r.normal.y) && finite_bits(r.normal.z) &&
         finite_bits(r.radiance.x) && finite_bits(r.radiance.y) && finite_bits(r.radiance.z);
}

/// Steps 3-4 for a finite record: projection, culling and the facing test. Returns kAccepted for a
/// candidate that still needs the deep-framebuffer test, with its texel (= subpixel) index.
/// The projection is Camera::project's, expression for expression.
inline Decision project_and_face(const KernelParams& k, const Vec3& p, const Vec3& n, uint32_t* texel) {
  const float dx = p.x - k.eye.x, dy = p.y - k.eye.y, dz = p.z - k.eye.z;
  const float z = dx * k.forward.x + dy * k.forward.y + dz * k.forward.z;
  if (!(z > 0)) return Decision::kCulled;
  const float sx = (dx * k.right.x + dy * k.right.y + dz * k.right.z) / z;
  const float sy = (dx * k.up.x + dy * k.up.y + dz * k.up.z) / z;
  const float rx = (sx / k.tan_half_x + 1) * 0.5f * k.width;
  const float ry = (1 - sy / k.tan_half_y) * 0.5f * k.height;
  const float gx = rx * k.s, gy = ry * k.s;
  if (!(gx >= 0 && gx < k.grid_w && gy >= 0 && gy < k.grid_h)) return Decision::kCulled;
  const float ex = k.eye.x - p.x, ey = k.eye.y - p.y, ez = k.eye.z - p.z;
  const float facing = n.x * ex + n.y * ey + n.z * ez;
  if (!(facing > 0)) return Decision::kBackfacing;
  *texel = uint32_t(gy) * k.grid_wi + uint32_t(gx);
  return Decision::kAccepted;
}

/// Steps 5-6: coverage and plane distance of a candidate at `texel`.
inline Decision plane_test(const KernelParams& k, const PlaneGrid& grid, const Vec3& p, uint32_t texel) {
  const uint32_t plane = grid.texel_plane[texel];
  if (plane == PlaneGrid::kUncovered) return Decision::kOccluded;
  const float* t = &grid.planes[4 * size_t(plane)];
  const float dist = p.x * t[0] + p.y * t[1] + p.z * t[2] - t[3];
  return std::fabs(dist) <= k.epsilon ? Decision::kAccepted : Decision::kOccluded;
}

/// Steps 3-6 for a finite record: the decision and, if accepted, the subpixel index.
inline Decision classify(const KernelParams& k, const PlaneGrid& grid, const Vec3& p, const Vec3& n, uint32_t* subpixel) {
  uint32_t texel = 0;
  const Decision d = project_and_face(k, p, n, &texel);
  if (d != Decision::kAccepted) return d;
  const Decision e = plane_test(k, grid, p, texel);
  if (e == Decision::kAccepted) *subpixel = texel;
  return e;
}

}  // namespace epr::detail
