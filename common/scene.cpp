#include "common/scene.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "common/limits.h"

namespace epr {

size_t Texture::texel(Vec2 uv) const {
  float u = uv.x - std::floor(uv.x), v = uv.y - std::floor(uv.y);
  if (!(u >= 0.f && u < 1.f)) u = 0.f;  // non-finite coordinates
  if (!(v >= 0.f && v < 1.f)) v = 0.f;
  const int x = std::min(width - 1, int(u * float(width)));
  const int y = std::min(height - 1, int((1 - v) * float(height)));
  return size_t(y) * size_t(width) + size_t(x);
}

Vec3 Texture::lookup(Vec2 uv) const {
  if (width <= 0 || height <= 0 || rgb.empty()) return Vec3(0.f);
  if (nearest) {
    const float* p = &rgb[texel(uv) * 3];
    return {p[0], p[1], p[2]};
  }
  // Texel centres at (i + 0.5) / width; the four around uv, wrapping at the edges (Repeat).
  float u = uv.x - std::floor(uv.x), v = uv.y - std::floor(uv.y);
  if (!(u >= 0.f && u < 1.f)) u = 0.f;  // non-finite coordinates
  if (!(v >= 0.f && v < 1.f)) v = 0.f;
  const float fx = u * float(width) - 0.5f, fy = (1 - v) * float(height) - 0.5f;
  const float x0f = std::floor(fx), y0f = std::floor(fy);
  const float ax = fx - x0f, ay = fy - y0f;
  const auto wrap = [](int i, int n) { return i < 0 ? i + n : (i >= n ? i - n : i); };
  const int x0 = wrap(int(x0f), width), x1 = wrap(int(x0f) + 1, width);
  const int y0 = wrap(int(y0f), height), y1 = wrap(int(y0f) + 1, height);
  const auto at = [&](int x, int y) {
    const float* p = &rgb[(size_t(y) * size_t(width) + size_t(x)) * 3];
    return Vec3(p[0], p[1], p[2]);
  };
  return (at(x0, y0) * (1 - ax) + at(x1, y0) * ax) * (1 - ay) + (at(x0, y1) * (1 - ax) + at(x1, y1) * ax) * ay;
}

bool Scene::has_cut_outs() const {
  std::vector<bool> cut(materials.size());
  for (size_t m = 0; m < materials.size(); ++m) cut[m] = materials[m].cut_out();
  for (uint32_t m : material_of)
    if (m < cut.size() && cut[m]) return true;
  return false;
}

bool Scene::cut_out_at(size_t tri, float u, float v) const {
  const Material& m = materials[material_of[tri]];
  if (m.alpha_texture < 0) return false;
  Vec2 uv{0.f, 0.f};
  if (!uvs.empty()) {
    const auto& c = uvs[tri];
    const float w = 1.f - u - v;
    uv = {w * c[0].x + u * c[1].x + v * c[2].x, w * c[0].y + u * c[1].y + v * c[2].y};
  }
  return textures[size_t(m.alpha_texture)].alpha_at(uv) < m.alpha_cutoff;
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
  if (!normals.empty() && normals.size() != triangles.size())
    throw std::runtime_error(fmt::format("scene '{}': normal list does not match triangles", name));
  if (!tangents.empty() && tangents.size() != triangles.size())
    throw std::runtime_error(fmt::format("scene '{}': tangent list does not match triangles", name));
  for (size_t i = 0; i < normals.size(); ++i)
    for (size_t k = 0; k < 3; ++k)
      if (!is_finite(normals[i][k]) || !(length(normals[i][k]) > 0.f))
        throw std::runtime_error(
            fmt::format("scene '{}': triangle {} corner {} has a zero or non-finite normal", name, i, k));
  for (size_t i = 0; i < tangents.size(); ++i)
    for (size_t k = 0; k < 3; ++k)
      if (!is_finite(tangents[i][k].t) || !std::isfinite(tangents[i][k].w))
        throw std::runtime_error(fmt::format("scene '{}': triangle {} corner {} has a non-finite tangent", name, i, k));
  for (size_t i = 0; i < positions.size(); ++i) {
    const Vec3& p = positions[i];
    if (!is_finite(p)) throw std::runtime_error(fmt::format("scene '{}': vertex {} is not finite", name, i));
    if (!limits::within_coordinate_limit(p.x, p.y, p.z))
      throw std::runtime_error(
          fmt::format("scene '{}': vertex {} at ({:g}, {:g}, {:g}) exceeds the magnitude limit {:g} (metres)", name, i,
                      p.x, p.y, p.z, limits::kMaxCoordinate));
  }
  for (size_t i = 0; i < triangles.size(); ++i) {
    for (uint32_t v : triangles[i])
      if (v >= positions.size())
        throw std::runtime_error(
            fmt::format("scene '{}': triangle {} indexes vertex {} of {}", name, i, v, positions.size()));
    if (material_of[i] >= materials.size())
      throw std::runtime_error(fmt::format("scene '{}': triangle {} has no material", name, i));
  }
  for (const PunctualLight& l : lights)
    if (auto reason = check_light(l))
      throw std::runtime_error(fmt::format("scene '{}': light '{}': {}", name, l.name, *reason));
  for (const Material& m : materials) {
    if (!is_finite(m.kd) || !is_finite(m.ke) || !is_finite(m.ks) || !std::isfinite(m.exponent))
      throw std::runtime_error(fmt::format("scene '{}': material '{}' has non-finite values", name, m.name));
    // A header-only texture (LoadOptions::decode_textures) has its size but not its texels.
    const auto missing_rgb = [&](int t) {
      return t >= int(textures.size()) || (t >= 0 && !textures[size_t(t)].header_only &&
                                           textures[size_t(t)].rgb.size() != 3 * size_t(textures[size_t(t)].width) *
                                                                                 size_t(textures[size_t(t)].height));
    };
    if (missing_rgb(m.kd_texture) || missing_rgb(m.metallic_roughness_texture) || missing_rgb(m.ke_texture))
      throw std::runtime_error(fmt::format("scene '{}': material '{}' names a missing texture", name, m.name));
    if (!std::isfinite(m.metallic) || !std::isfinite(m.roughness) || !std::isfinite(m.transmission) ||
        !(m.ior >= 1 && m.ior <= 10))
      throw std::runtime_error(
          fmt::format("scene '{}': material '{}' has a non-finite factor or an ior outside [1, 10]", name, m.name));
    if (m.alpha_texture >= int(textures.size()) ||
        (m.alpha_texture >= 0 && !textures[size_t(m.alpha_texture)].header_only &&
         textures[size_t(m.alpha_texture)].alpha.size() !=
             size_t(textures[size_t(m.alpha_texture)].width) * size_t(textures[size_t(m.alpha_texture)].height)))
      throw std::runtime_error(fmt::format("scene '{}': material '{}' names a missing alpha mask", name, m.name));
    if (missing_rgb(m.normal_texture) || !std::isfinite(m.normal_scale))
      throw std::runtime_error(fmt::format("scene '{}': material '{}' names a missing normal map", name, m.name));
    if (m.cut_out() && !std::isfinite(m.alpha_cutoff))
      throw std::runtime_error(fmt::format("scene '{}': material '{}' has a non-finite alpha cut-off", name, m.name));
  }
}

void add_triangle(Scene& s, Vec3 a, Vec3 b, Vec3 c, uint32_t mat) {
  const uint32_t base = uint32_t(s.positions.size());
  s.positions.insert(s.positions.end(), {a, b, c});
  s.triangles.push_back({base, base + 1, base + 2});
  s.material_of.push_back(mat);
  if (!s.uvs.empty()) s.uvs.push_back({Vec2{0, 0}, Vec2{1, 0}, Vec2{0, 1}});
  append_flat_shading(s, 1);
}

void append_flat_shading(Scene& s, size_t count) {
  for (size_t i = s.triangles.size() - count; i < s.triangles.size(); ++i) {
    const Vec3 n = s.geometric_normal(i);
    if (!s.normals.empty()) s.normals.push_back({n, n, n});
    if (!s.tangents.empty()) s.tangents.push_back({});
  }
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
  append_flat_shading(s, size_t(2 * n * n));
}

uint32_t add_material(Scene& s, Material m) {
  s.materials.push_back(std::move(m));
  return uint32_t(s.materials.size() - 1);
}

}  // namespace epr
