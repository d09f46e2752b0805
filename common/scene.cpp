#include "common/scene.h"

#include <fmt/format.h>

#include <cmath>
#include <stdexcept>

namespace epr {

Vec3 Texture::lookup(Vec2 uv) const {
  if (width <= 0 || height <= 0) return Vec3(0.f);
  float u = uv.x - std::floor(uv.x), v = uv.y - std::floor(uv.y);
  int x = std::min(width - 1, int(u * float(width)));
  int y = std::min(height - 1, int((1 - v) * float(height)));
  const float* p = &rgb[(size_t(y) * size_t(width) + size_t(x)) * 3];
  return {p[0], p[1], p[2]};
}

Bounds3 Scene::bounds() const {
  Bounds3 b;
  for (const Vec3& p : positions) b.extend(p);
  return b;
}

Vec3 Scene::geometric_normal(size_t tri) const {
  const auto& t = triangles[tri];
  const Vec3 n = cross(positions[t[1]] - positions[t[0]], positions[t[2]] - positions[t[0]]);
  const float l = length(n);
  return l > 0 ? n / l : Vec3(0, 0, 1);
}

float Scene::area(size_t tri) const {
  const auto& t = triangles[tri];
  return 0.5f * length(cross(positions[t[1]] - positions[t[0]], positions[t[2]] - positions[t[0]]));
}

void Scene::validate() const {
  if (triangles.empty()) throw std::runtime_error(fmt::format("scene '{}' has no triangles", name));
  if (material_of.size() != triangles.size())
    throw std::runtime_error(fmt::format("scene '{}': material list does not match triangles", name));
  if (!uvs.empty() && uvs.size() != triangles.size())
    throw std::runtime_error(fmt::format("scene '{}': uv list does not match triangles", name));
  for (size_t i = 0; i < positions.size(); ++i)
    if (!is_finite(positions[i])) throw std::runtime_error(fmt::format("scene '{}': vertex {} is not finite", name, i));
  for (size_t i = 0; i < triangles.size(); ++i) {
    for (uint32_t v : triangles[i])
      if (v >= positions.size())
        throw std::runtime_error(
            fmt::format("scene '{}': triangle {} indexes vertex {} of {}", name, i, v, positions.size()));
    if (material_of[i] >= materials.size())
      throw std::runtime_error(fmt::format("scene '{}': triangle {} has no material", name, i));
  }
  for (const Material& m : materials) {
    if (!is_finite(m.kd) || !is_finite(m.ke) || !is_finite(m.ks) || !std::isfinite(m.exponent))
      throw std::runtime_error(fmt::format("scene '{}': material '{}' has non-finite values", name, m.name));
    if (m.kd_texture >= int(textures.size()))
      throw std::runtime_error(fmt::format("scene '{}': material '{}' names a missing texture", name, m.name));
  }
}

void add_triangle(Scene& s, Vec3 a, Vec3 b, Vec3 c, uint32_t mat) {
  const uint32_t base = uint32_t(s.positions.size());
  s.positions.insert(s.positions.end(), {a, b, c});
  s.triangles.push_back({base, base + 1, base + 2});
  s.material_of.push_back(mat);
  if (!s.uvs.empty()) s.uvs.push_back({Vec2{0, 0}, Vec2{1, 0}, Vec2{0, 1}});
}

void add_quad(Scene& s, Vec3 a, Vec3 b, Vec3 c, Vec3 d, uint32_t mat) { add_tessellated_quad(s, a, b, c, d, mat, 1); }

void add_tessellated_quad(Scene& s, Vec3 a, Vec3 b, Vec3 c, Vec3 d, uint32_t mat, int n) {
  n = std::max(1, n);
  const uint32_t base = uint32_t(s.positions.size());
  // Bilinear grid of (n+1)^2 shared vertices.
  for (int j = 0; j <= n; ++j) {
    const float v = float(j) / float(n);
    for (int i = 0; i <= n; ++i) {
      const float u = float(i) / float(n);
      s.positions.push_back(a * ((1 - u) * (1 - v)) + b * (u * (1 - v)) + c * (u * v) + d * ((1 - u) * v));
    }
  }
  auto idx = [&](int i, int j) { return base + uint32_t(j * (n + 1) + i); };
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i) {
      s.triangles.push_back({idx(i, j), idx(i + 1, j), idx(i + 1, j + 1)});
      s.triangles.push_back({idx(i, j), idx(i + 1, j + 1), idx(i, j + 1)});
      s.material_of.push_back(mat);
      s.material_of.push_back(mat);
      if (!s.uvs.empty()) {
        auto uv = [&](int ii, int jj) { return Vec2{float(ii) / float(n), float(jj) / float(n)}; };
        s.uvs.push_back({uv(i, j), uv(i + 1, j), uv(i + 1, j + 1)});
        s.uvs.push_back({uv(i, j), uv(i + 1, j + 1), uv(i, j + 1)});
      }
    }
}

uint32_t add_material(Scene& s, Material m) {
  s.materials.push_back(std::move(m));
  return uint32_t(s.materials.size() - 1);
}

}  // namespace epr
