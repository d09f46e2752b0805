#include "common/tangents.h"

#include <cmath>
#include <cstring>
#include <unordered_map>

namespace epr {
namespace {

// A welded vertex: position, normal and uv, bit for bit, and the handedness of its triangles.
struct VertexKey {
  float v[8];
  int sign;
  bool operator==(const VertexKey& o) const { return sign == o.sign && std::memcmp(v, o.v, sizeof(v)) == 0; }
};

struct VertexKeyHash {
  size_t operator()(const VertexKey& k) const {
    uint64_t h = 1469598103934665603ull ^ uint64_t(k.sign + 2);
    for (float f : k.v) {
      uint32_t bits;
      std::memcpy(&bits, &f, 4);
      h = (h ^ bits) * 1099511628211ull;
    }
    return size_t(h);
  }
};

struct Sum {
  Vec3 t{0.f}, b{0.f};
};

Vec3 project_unit(Vec3 d, Vec3 n) {
  const Vec3 p = d - n * dot(n, d);
  const float l = length(p);
  return l > 0 && std::isfinite(l) ? p / l : Vec3(0.f);
}

float corner_angle(Vec3 a, Vec3 b, Vec3 c) {  // the angle at a
  const Vec3 e1 = b - a, e2 = c - a;
  return std::atan2(length(cross(e1, e2)), dot(e1, e2));
}

}  // namespace

UvDerivatives uv_derivatives(const std::array<Vec3, 3>& p, const std::array<Vec2, 3>& uv) {
  const Vec3 e1 = p[1] - p[0], e2 = p[2] - p[0];
  const float du1 = uv[1].x - uv[0].x, dv1 = uv[1].y - uv[0].y;
  const float du2 = uv[2].x - uv[0].x, dv2 = uv[2].y - uv[0].y;
  const float r = du1 * dv2 - du2 * dv1;
  if (!(std::abs(r) > 0) || !std::isfinite(r)) return {};
  const float inv = 1 / r;
  return {(e1 * dv2 - e2 * dv1) * inv, (e2 * du1 - e1 * du2) * inv};
}

void generate_tangents(Scene& scene, const std::vector<bool>& needed) {
  const size_t n = scene.triangles.size();
  scene.tangents.resize(n);  // new entries zero: no tangent
  if (scene.uvs.size() != n) return;
  std::unordered_map<VertexKey, Sum, VertexKeyHash> sums;
  std::vector<std::array<VertexKey, 3>> keys(n);
  for (size_t i = 0; i < n; ++i) {
    if (!needed[i]) continue;
    const auto& tri = scene.triangles[i];
    const std::array<Vec3, 3> p{scene.positions[tri[0]], scene.positions[tri[1]], scene.positions[tri[2]]};
    const UvDerivatives d = uv_derivatives(p, scene.uvs[i]);
    const Vec3 ng = scene.geometric_normal(i);
    const int sign = dot(cross(ng, d.dp_du), d.dp_dv) < 0 ? -1 : 1;
    for (int k = 0; k < 3; ++k) {
      const Vec3 nk = scene.normals.empty() ? ng : scene.normals[i][size_t(k)];
      const Vec2 uv = scene.uvs[i][size_t(k)];
      VertexKey key{{p[size_t(k)].x, p[size_t(k)].y, p[size_t(k)].z, nk.x, nk.y, nk.z, uv.x, uv.y}, sign};
      keys[i][size_t(k)] = key;
      const float w = corner_angle(p[size_t(k)], p[size_t(k + 1) % 3], p[size_t(k + 2) % 3]);
      Sum& s = sums[key];
      s.t += project_unit(d.dp_du, nk) * w;
      s.b += project_unit(d.dp_dv, nk) * w;
    }
  }
  for (size_t i = 0; i < n; ++i) {
    if (!needed[i]) continue;
    for (size_t k = 0; k < 3; ++k) {
      const Sum& s = sums[keys[i][k]];
      const Vec3 nk = scene.normals.empty() ? scene.geometric_normal(i) : scene.normals[i][k];
      const Vec3 t = project_unit(s.t, nk);
      scene.tangents[i][k] = {t, dot(cross(nk, t), s.b) < 0 ? -1.f : 1.f};
    }
  }
}

Vec3 apply_normal_map(Vec3 n, const Tangent& t, Vec3 texel, float scale) {
  const Vec3 tt = project_unit(t.t, n);
  if (is_black(tt)) return n;
  const Vec3 b = cross(n, tt) * (t.w < 0 ? -1.f : 1.f);
  const Vec3 m = tt * ((2 * texel.x - 1) * scale) + b * ((2 * texel.y - 1) * scale) + n * (2 * texel.z - 1);
  const float l = length(m);
  return l > 0 && std::isfinite(l) ? m / l : n;
}

}  // namespace epr
