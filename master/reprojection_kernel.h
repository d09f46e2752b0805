// The per-point reprojection decision, written once in C++ and mirrored line by line by the GLSL
// compute shader in gl_reprojector_shaders.cpp (keep both in step: same operations in the same order, so
// that the CPU and GL back-ends take bit-identical decisions). Internal to master/.
//
// The deep framebuffer is used in a compact form, PlaneGrid: per texel the index of its entry in a
// table of (N.x, N.y, N.z, d) planes (kUncovered if no triangle covers the texel). The table is tiny
// for most scenes (one entry per visible plane), so the per-texel array (4 bytes) is the only large
// random-access structure besides the accumulation.
//
// Creases. The plane test alone accepts any point of the texel's plane that projects into the
// texel's footprint, also where another visible surface cuts that footprint and hides part of the
// plane: a floor running on under a thin partition, seen next to it, would take the light of the room
// behind the partition (docs/FAILURE_MODES.md, thin walls). So a texel whose 8 neighbours see other
// planes gets its own table entry (after the plain ones: index >= first_creased) with those planes as
// creases, each oriented so that the texel's own visible point (its centre's hit) lies on the positive
// side -- or, when that point lies on the crease plane within the tolerance, the eye. A point that
// passes the plane test but lies more than crease_tolerance on the negative side of one of its
// texel's creases is past the line where the neighbouring surface meets or crosses the texel's plane:
// behind a concave joint it is hidden, past a convex edge it is not on the texel's surface; either
// way it is occluded. Points on the neighbouring surface itself (distance ~0 to it) pass.
#pragma once

#include <cmath>
#include <cstdint>
#include <cstring>
#include <unordered_map>
#include <vector>

#include "common/camera.h"
#include "common/vertex_record.h"
#include "master/deep_framebuffer.h"
#include "master/reprojector.h"

namespace epr::detail {

struct PlaneGrid {
  static constexpr uint32_t kUncovered = 0xffffffffu;
  int width = 0, height = 0;            // texels: S * image width, S * image height
  int subpixels = 1;                    // S
  float crease_tolerance = 0;           // metres, as built (must match the reprojector's settings)
  bool has_creases = false;             // built with creases (the joint test)
  std::vector<uint32_t> texel_plane;    // per texel: index into planes, or kUncovered
  std::vector<float> planes;            // 4 per entry: N.x, N.y, N.z, d
  uint32_t first_creased = kUncovered;  // entries >= this one have creases (after all plain ones); none by default
  std::vector<uint32_t> crease_range;   // 2 per creased entry (index - first_creased): first crease, count
  std::vector<float> creases;           // 4 per crease: oriented plane N.x, N.y, N.z, d (visible side > 0)
  size_t creased_entries() const { return crease_range.size() / 2; }
};

/// Crease tolerance as a fraction of epsilon. At the default epsilon (3e-4 of the scene's diagonal)
/// it is ~3e-7 of the diagonal: about the wire's position quantisation (half a cell, 2^-22 of the
/// extent per axis) and well above the float rounding of the distance, so points on the neighbouring
/// surface itself are not cut; what it still lets through past a joint is a band that thin (1.4 um in
/// the thin-wall scene, where 1/64 left a measurable 7e-6 on one pixel at 128 x 128).
inline constexpr float kCreaseToleranceFraction = 1.f / 1024.f;

/// Normal agreement. A point within epsilon of a texel's plane may lie on another surface that
/// crosses that plane there: the lit side's floor, within epsilon of a thin partition's plane next to
/// the joint, would land on the partition's dark face. Its normal tells: a point whose (geometric)
/// normal is more than 60 degrees from the texel's plane normal is not on that surface. 60 degrees
/// leaves tessellated curved surfaces alone (neighbouring facets differ by far less).
inline constexpr float kMinNormalCosine = 0.5f;

/// Whether two plane-table rows (N.x, N.y, N.z, d) are one plane: equal, or the opposite winding.
inline bool same_plane(const float* x, const float* y) {
  const bool same = x[0] == y[0] && x[1] == y[1] && x[2] == y[2] && x[3] == y[3];
  const bool opposite = x[0] == -y[0] && x[1] == -y[1] && x[2] == -y[2] && x[3] == -y[3];
  return same || opposite;
}

/// `eye` orients creases the texel's own point cannot (see the file comment); `crease_tolerance` in
/// metres. Without `creases` every entry is plain (first_creased = number of entries).
PlaneGrid make_plane_grid(const DeepFramebuffer& dfb, const Vec3& eye, float crease_tolerance, bool creases = true);

/// make_plane_grid band of rows by band of rows, without the full deep framebuffer: add_band() the
/// grid's rows in order, then finish(). The result is the same whatever the bands (plain planes and
/// crease sets are interned in texel order either way); make_plane_grid is one band.
class PlaneGridBuilder {
 public:
  PlaneGridBuilder(int width, int height, int subpixels, const Vec3& eye, float crease_tolerance, bool creases);
  /// Takes grid rows [row0, row1) from `band` (rows [band.first_row, band.first_row + band.height) of
  /// the grid), which must also hold the rows just above and below them that exist (the crease
  /// neighbours). row0 must be the previous call's row1 (0 the first time).
  void add_band(const DeepFramebuffer& band, int row0, int row1);
  int rows_done() const { return next_row_; }
  /// The plane grid; all rows must have been added. The builder is left empty.
  PlaneGrid finish();

 private:
  // Creased texels hold kCreasedBit | (creased entry) until finish() knows the number of plain entries.
  static constexpr uint32_t kCreasedBit = 0x80000000u;
  struct Key {
    uint32_t b[4];
    bool operator==(const Key& o) const { return std::memcmp(b, o.b, 16) == 0; }
  };
  struct KeyHash {
    size_t operator()(const Key& k) const;
  };
  struct SetHash {
    size_t operator()(const std::vector<uint32_t>& v) const;
  };
  PlaneGrid g_;
  Vec3 eye_;
  int next_row_ = 0;
  std::unordered_map<Key, uint32_t, KeyHash> plain_;                      // plane -> plain entry
  std::unordered_map<std::vector<uint32_t>, uint32_t, SetHash> creased_;  // (own plane, codes...) -> creased entry
  std::vector<float> creased_planes_;                                     // 4 per creased entry
  std::vector<uint32_t> band_plain_;                                      // plain entry per texel of the band
  std::vector<std::vector<uint32_t>> row_sets_, row_texels_;              // crease sets of the band's rows
};

/// The plane grid a reprojector with `settings` needs for `dfb` (validated against `camera`).
PlaneGrid plane_grid_for(const Camera& camera, const DeepFramebuffer& dfb, const ReprojectorSettings& settings);

/// Uniform inputs of the kernel (the GL shader receives the same values as uniforms).
struct KernelParams {
  Vec3 eye, forward, right, up;
  float tan_half_x = 1, tan_half_y = 1;
  float width = 1, height = 1;   // image size in pixels (float, as in Camera::project)
  float s = 4;                   // subpixels per axis
  float grid_w = 4, grid_h = 4;  // S * width, S * height
  uint32_t grid_wi = 4;
  float epsilon = 0;
  float crease_tolerance = 0;                  // epsilon * kCreaseToleranceFraction
  float min_normal_cosine = kMinNormalCosine;  // -1 without the joint test
};
KernelParams make_kernel_params(const Camera& camera, int subpixels, float epsilon, bool joint_test = true);

/// Throws std::invalid_argument for bad settings or a deep framebuffer that does not fit the camera.
void validate_reprojector_inputs(const Camera& camera, const DeepFramebuffer& dfb, const ReprojectorSettings& s);
/// The same for a plane grid: its size and S must fit the camera, and its crease tolerance and
/// creases must be those `s` asks for.
void validate_reprojector_inputs(const Camera& camera, const PlaneGrid& grid, const ReprojectorSettings& s);

enum class Decision : uint8_t { kAccepted, kCulled, kBackfacing, kOccluded };

inline bool finite_bits(float v) {
  uint32_t b;
  std::memcpy(&b, &v, 4);
  return (b & 0x7f800000u) != 0x7f800000u;
}

/// Step 1-2 of the semantics (done on the CPU by both back-ends, before upload for GL).
inline bool record_is_finite(const VertexRecord& r) {
  return finite_bits(r.position.x) && finite_bits(r.position.y) && finite_bits(r.position.z) &&
         finite_bits(r.normal.x) && finite_bits(r.normal.y) && finite_bits(r.normal.z) && finite_bits(r.radiance.x) &&
         finite_bits(r.radiance.y) && finite_bits(r.radiance.z);
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

/// Steps 5-6 for a candidate whose texel's entry is `plane` (grid.texel_plane[texel], or a
/// back-end's narrower copy of it, widened; PlaneGrid::kUncovered if no triangle covers the texel).
inline Decision plane_test_entry(const KernelParams& k, const PlaneGrid& grid, const Vec3& p, const Vec3& n,
                                 uint32_t plane) {
  if (plane == PlaneGrid::kUncovered) return Decision::kOccluded;
  const float* t = &grid.planes[4 * size_t(plane)];
  const float dist = p.x * t[0] + p.y * t[1] + p.z * t[2] - t[3];
  if (!(std::fabs(dist) <= k.epsilon)) return Decision::kOccluded;
  const float cosine = n.x * t[0] + n.y * t[1] + n.z * t[2];
  if (!(std::fabs(cosine) >= k.min_normal_cosine)) return Decision::kOccluded;
  if (plane < grid.first_creased) return Decision::kAccepted;
  const uint32_t* r = &grid.crease_range[2 * size_t(plane - grid.first_creased)];
  for (uint32_t c = r[0]; c < r[0] + r[1]; ++c) {
    const float* q = &grid.creases[4 * size_t(c)];
    const float e = p.x * q[0] + p.y * q[1] + p.z * q[2] - q[3];
    if (e < -k.crease_tolerance) return Decision::kOccluded;
  }
  return Decision::kAccepted;
}

/// Steps 5-6: coverage, plane distance, normal agreement and creases of a candidate at `texel`.
inline Decision plane_test(const KernelParams& k, const PlaneGrid& grid, const Vec3& p, const Vec3& n, uint32_t texel) {
  return plane_test_entry(k, grid, p, n, grid.texel_plane[texel]);
}

/// Steps 3-6 for a finite record: the decision and, if accepted, the subpixel index.
inline Decision classify(const KernelParams& k, const PlaneGrid& grid, const Vec3& p, const Vec3& n,
                         uint32_t* subpixel) {
  uint32_t texel = 0;
  const Decision d = project_and_face(k, p, n, &texel);
  if (d != Decision::kAccepted) return d;
  const Decision e = plane_test(k, grid, p, n, texel);
  if (e == Decision::kAccepted) *subpixel = texel;
  return e;
}

}  // namespace epr::detail
