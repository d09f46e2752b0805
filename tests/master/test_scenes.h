// Scenes, cameras and vertex sets shared by the master's tests and the reprojection benchmark.
//
// Scenes: the built-in "cornell" and "hall" (common/builtin_scenes.h) when that header exists,
// otherwise inline stand-ins of the same shape (a Cornell-like box with two blocks; a long hall with
// a row of square columns). Vertex sets ("real-like"): points on the scene's surfaces as a path
// tracer produces them -- uniformly by area over all triangles, normal = face normal flipped towards
// the inside of the scene (the side a path arrives from), random radiance -- mixed with points
// jittered in-plane around visible deep-framebuffer texels (mostly accepted) and random points in and
// around the scene bounds with random normals (mostly culled/occluded).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <random>
#include <string>
#include <vector>

#include "common/camera.h"
#include "common/math.h"
#include "common/scene.h"
#include "common/vertex_record.h"
#include "master/deep_framebuffer.h"

#if __has_include("common/builtin_scenes.h")
#include "common/builtin_scenes.h"
#define EPR_TEST_HAVE_BUILTIN_SCENES 1
#else
#define EPR_TEST_HAVE_BUILTIN_SCENES 0
#endif

namespace epr::test {

inline Scene inline_cornell() {
  Scene s;
  s.name = "inline:cornell";
  const uint32_t m = add_material(s, Material{});
  const float n = 1;
  // Floor, ceiling, back, left, right walls (inward facing); open front.
  add_quad(s, {-n, 0, n}, {n, 0, n}, {n, 0, -n}, {-n, 0, -n}, m);
  add_quad(s, {-n, 2, -n}, {n, 2, -n}, {n, 2, n}, {-n, 2, n}, m);
  add_quad(s, {-n, 0, -n}, {n, 0, -n}, {n, 2, -n}, {-n, 2, -n}, m);
  add_quad(s, {-n, 0, n}, {-n, 0, -n}, {-n, 2, -n}, {-n, 2, n}, m);
  add_quad(s, {n, 0, -n}, {n, 0, n}, {n, 2, n}, {n, 2, -n}, m);
  // Two blocks: axis-aligned tall one, rotated short one.
  auto block = [&](Vec3 c, float hx, float hz, float h, float angle) {
    const float ca = std::cos(angle), sa = std::sin(angle);
    auto P = [&](float x, float y, float z) { return Vec3(c.x + ca * x - sa * z, y, c.z + sa * x + ca * z); };
    const Vec3 b0 = P(-hx, 0, -hz), b1 = P(hx, 0, -hz), b2 = P(hx, 0, hz), b3 = P(-hx, 0, hz);
    const Vec3 t0 = P(-hx, h, -hz), t1 = P(hx, h, -hz), t2 = P(hx, h, hz), t3 = P(-hx, h, hz);
    add_quad(s, t3, t2, t1, t0, m);
    add_quad(s, b3, b2, t2, t3, m);
    add_quad(s, b1, b0, t0, t1, m);
    add_quad(s, b0, b3, t3, t0, m);
    add_quad(s, b2, b1, t1, t2, m);
  };
  block({-0.35f, 0, -0.3f}, 0.3f, 0.3f, 1.2f, 0.f);
  block({0.35f, 0, 0.35f}, 0.3f, 0.3f, 0.6f, -0.3f);
  s.camera = CameraSpec{};  // eye (0, 1, 3.9) looking at (0, 1, 0)
  return s;
}

inline Scene inline_hall() {
  Scene s;
  s.name = "inline:hall";
  const uint32_t m = add_material(s, Material{});
  const float L = 15, Wd = 6, Ht = 12;
  add_tessellated_quad(s, {-Wd, 0, L}, {Wd, 0, L}, {Wd, 0, -L}, {-Wd, 0, -L}, m, 8);
  add_tessellated_quad(s, {-Wd, Ht, -L}, {Wd, Ht, -L}, {Wd, Ht, L}, {-Wd, Ht, L}, m, 8);
  add_quad(s, {-Wd, 0, -L}, {Wd, 0, -L}, {Wd, Ht, -L}, {-Wd, Ht, -L}, m);
  add_quad(s, {Wd, 0, L}, {-Wd, 0, L}, {-Wd, Ht, L}, {Wd, Ht, L}, m);
  add_tessellated_quad(s, {-Wd, 0, L}, {-Wd, 0, -L}, {-Wd, Ht, -L}, {-Wd, Ht, L}, m, 8);
  add_tessellated_quad(s, {Wd, 0, -L}, {Wd, 0, L}, {Wd, Ht, L}, {Wd, Ht, -L}, m, 8);
  for (float x : {-3.f, 3.f})
    for (float z = -12; z <= 12; z += 3) {
      const float r = 0.4f;
      add_quad(s, {x - r, 0, z + r}, {x + r, 0, z + r}, {x + r, 8, z + r}, {x - r, 8, z + r}, m);
      add_quad(s, {x + r, 0, z - r}, {x - r, 0, z - r}, {x - r, 8, z - r}, {x + r, 8, z - r}, m);
      add_quad(s, {x - r, 0, z - r}, {x - r, 0, z + r}, {x - r, 8, z + r}, {x - r, 8, z - r}, m);
      add_quad(s, {x + r, 0, z + r}, {x + r, 0, z - r}, {x + r, 8, z - r}, {x + r, 8, z + r}, m);
    }
  s.camera.eye = {0, 2, 14};
  s.camera.look = {0.5f, 3, 0};
  s.camera.up = {0, 1, 0};
  s.camera.fov_y_degrees = 60;
  return s;
}

/// "cornell" or "hall": the built-in scene when available, else the inline stand-in.
inline Scene scene_named(const std::string& name) {
#if EPR_TEST_HAVE_BUILTIN_SCENES
  return make_builtin_scene(name);
#else
  return name == "hall" ? inline_hall() : inline_cornell();
#endif
}

/// Points on the surfaces, area-weighted, normals towards the inside (the scene's centre).
inline void add_surface_points(const Scene& s, size_t n, std::mt19937& rng, std::vector<VertexRecord>& out) {
  std::vector<double> cdf(s.triangle_count());
  double acc = 0;
  for (size_t t = 0; t < s.triangle_count(); ++t) cdf[t] = acc += s.area(t);
  std::uniform_real_distribution<double> pick(0, acc);
  std::uniform_real_distribution<float> u(0, 1), rad(0, 4);
  const Vec3 centre = s.bounds().centre();
  for (size_t i = 0; i < n; ++i) {
    const size_t t =
        std::min(cdf.size() - 1, size_t(std::lower_bound(cdf.begin(), cdf.end(), pick(rng)) - cdf.begin()));
    const auto& tri = s.triangles[t];
    float a = u(rng), b = u(rng);
    if (a + b > 1) a = 1 - a, b = 1 - b;
    const Vec3 p0 = s.positions[tri[0]], p1 = s.positions[tri[1]], p2 = s.positions[tri[2]];
    VertexRecord r;
    r.position = p0 + (p1 - p0) * a + (p2 - p0) * b;
    Vec3 nn = s.geometric_normal(t);
    if (dot(nn, centre - r.position) < 0) nn = -nn;
    r.normal = nn;
    r.radiance = {rad(rng), rad(rng), rad(rng)};
    r.flags = u(rng) < 0.95f ? VertexRecord::kDiffuse : 0;
    out.push_back(r);
  }
}

/// Points jittered within the plane of random covered texels (up to `jitter` metres), facing the eye.
inline void add_visible_points(const DeepFramebuffer& dfb, const Camera& cam, size_t n, float jitter, std::mt19937& rng,
                               std::vector<VertexRecord>& out) {
  std::vector<size_t> covered;
  for (size_t t = 0; t < dfb.texel_count(); ++t)
    if (dfb.covered[t]) covered.push_back(t);
  if (covered.empty()) return;
  std::uniform_int_distribution<size_t> pick(0, covered.size() - 1);
  std::uniform_real_distribution<float> u(-1, 1), rad(0, 4);
  for (size_t i = 0; i < n; ++i) {
    const size_t t = covered[pick(rng)];
    Vec3 nn = dfb.normal_at(t);
    const Frame f = Frame::from_normal(nn);
    VertexRecord r;
    r.position = dfb.position_at(t) + f.s * (u(rng) * jitter) + f.t * (u(rng) * jitter);
    if (dot(nn, cam.eye() - r.position) < 0) nn = -nn;
    r.normal = nn;
    r.radiance = {rad(rng), rad(rng), rad(rng)};
    r.flags = VertexRecord::kDiffuse;
    out.push_back(r);
  }
}

/// Points on visible planes whose projection lands within float rounding of a subpixel boundary
/// (the ray through raster position (k / S, v) or (u, k / S) hits the texel's plane there): which
/// side they fall on depends on the last bit of the projection, so they expose any arithmetic
/// difference between two implementations of the projection.
inline void add_boundary_points(const DeepFramebuffer& dfb, const Camera& cam, size_t n, std::mt19937& rng,
                                std::vector<VertexRecord>& out) {
  const int S = dfb.subpixels;
  std::uniform_int_distribution<int> gx(1, dfb.width - 1), gy(1, dfb.height - 1);
  std::uniform_real_distribution<float> u(0, 1), rad(0, 4);
  for (size_t i = 0, tries = 0; i < n && tries < 20 * n; ++tries) {
    const bool vertical = u(rng) < 0.5f;
    const float x = vertical ? float(gx(rng)) : float(gx(rng)) + u(rng);
    const float y = vertical ? float(gy(rng)) + u(rng) : float(gy(rng));
    const size_t t = dfb.index(std::min(dfb.width - 1, int(x)), std::min(dfb.height - 1, int(y)));
    if (!dfb.covered[t]) continue;
    const Ray ray = cam.generate_ray(x / float(S), y / float(S));
    Vec3 nn = dfb.normal_at(t);
    const float denom = dot(nn, ray.dir);
    if (std::fabs(denom) < 1e-3f) continue;
    const float dist = (dfb.plane_offset[t] - dot(nn, ray.origin)) / denom;
    VertexRecord r;
    r.position = ray.origin + ray.dir * dist;
    if (dot(nn, cam.eye() - r.position) < 0) nn = -nn;
    r.normal = nn;
    r.radiance = {rad(rng), rad(rng), rad(rng)};
    r.flags = VertexRecord::kDiffuse;
    out.push_back(r);
    ++i;
  }
}

/// Random points in a box 1.5x the scene bounds, random unit normals.
inline void add_random_points(const Scene& s, size_t n, std::mt19937& rng, std::vector<VertexRecord>& out) {
  const Bounds3 b = s.bounds();
  const Vec3 c = b.centre(), h = b.diagonal() * 0.75f;
  std::uniform_real_distribution<float> u(-1, 1), rad(0, 4);
  for (size_t i = 0; i < n; ++i) {
    VertexRecord r;
    r.position = {c.x + h.x * u(rng), c.y + h.y * u(rng), c.z + h.z * u(rng)};
    Vec3 nn;
    do nn = {u(rng), u(rng), u(rng)};
    while (dot(nn, nn) > 1 || dot(nn, nn) < 1e-4f);
    r.normal = normalize(nn);
    r.radiance = {rad(rng), rad(rng), rad(rng)};
    r.flags = VertexRecord::kDiffuse;
    out.push_back(r);
  }
}

/// A shuffled mix: 50 % surface points, 30 % visible (jittered) points, 20 % random points.
inline std::vector<VertexRecord> real_like_points(const Scene& s, const DeepFramebuffer& dfb, const Camera& cam,
                                                  size_t n, uint32_t seed) {
  std::mt19937 rng(seed);
  std::vector<VertexRecord> v;
  v.reserve(n);
  add_surface_points(s, n / 2, rng, v);
  add_visible_points(dfb, cam, n * 3 / 10, s.bounds().diagonal_length() / float(dfb.width), rng, v);
  add_random_points(s, n - v.size(), rng, v);
  std::shuffle(v.begin(), v.end(), rng);
  return v;
}

}  // namespace epr::test
