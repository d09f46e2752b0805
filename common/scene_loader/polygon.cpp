// Triangulation of OBJ faces: shorter-diagonal quads and ear clipping (polygon.h).
#include "common/scene_loader/polygon.h"

#include <cmath>
#include <limits>

namespace epr::loader {
namespace {

/// Whether (tx, ty) lies inside the triangle (x[k], y[k]), by the crossing test (W. R. Franklin's
/// pnpoly): points on an edge count for one side only.
bool inside_triangle(const float x[3], const float y[3], float tx, float ty) {
  bool c = false;
  for (int i = 0, j = 2; i < 3; j = i++)
    if (((y[i] > ty) != (y[j] > ty)) && (tx < (x[j] - x[i]) * (ty - y[i]) / (y[j] - y[i]) + x[i])) c = !c;
  return c;
}

void split_quad(const std::vector<Vec3>& p, const uint32_t* vertex, std::vector<std::array<uint32_t, 3>>* out) {
  const Vec3 &v0 = p[vertex[0]], &v1 = p[vertex[1]], &v2 = p[vertex[2]], &v3 = p[vertex[3]];
  const float e02x = v2.x - v0.x, e02y = v2.y - v0.y, e02z = v2.z - v0.z;
  const float e13x = v3.x - v1.x, e13y = v3.y - v1.y, e13z = v3.z - v1.z;
  const float sqr02 = e02x * e02x + e02y * e02y + e02z * e02z;
  const float sqr13 = e13x * e13x + e13y * e13y + e13z * e13z;
  if (sqr02 < sqr13) {
    out->push_back({0, 1, 2});
    out->push_back({0, 2, 3});
  } else {
    out->push_back({0, 1, 3});
    out->push_back({1, 2, 3});
  }
}

/// The two axes (0 x, 1 y, 2 z) of the plane the polygon is clipped in: at the first corner whose
/// edges are not collinear, the axes other than the normal's largest component (y z when none is).
std::array<int, 2> projection_axes(const std::vector<Vec3>& p, const uint32_t* vertex, size_t n) {
  std::array<int, 2> axes = {1, 2};
  for (size_t k = 0; k < n; ++k) {
    const Vec3 &v0 = p[vertex[k]], &v1 = p[vertex[(k + 1) % n]], &v2 = p[vertex[(k + 2) % n]];
    const float e0x = v1.x - v0.x, e0y = v1.y - v0.y, e0z = v1.z - v0.z;
    const float e1x = v2.x - v1.x, e1y = v2.y - v1.y, e1z = v2.z - v1.z;
    const float cx = std::fabs(e0y * e1z - e0z * e1y);
    const float cy = std::fabs(e0z * e1x - e0x * e1z);
    const float cz = std::fabs(e0x * e1y - e0y * e1x);
    const float epsilon = std::numeric_limits<float>::epsilon();
    if (cx > epsilon || cy > epsilon || cz > epsilon) {
      if (!(cx > cy && cx > cz)) {
        axes[0] = 0;
        if (cz > cx && cz > cy) axes[1] = 1;
      }
      break;
    }
  }
  return axes;
}

void clip_ears(const std::vector<Vec3>& p, const uint32_t* vertex, size_t n,
               std::vector<std::array<uint32_t, 3>>* out) {
  const std::array<int, 2> axes = projection_axes(p, vertex, n);
  std::vector<uint32_t> remaining(n);  // corner numbers of the polygon still to clip
  for (size_t k = 0; k < n; ++k) remaining[k] = uint32_t(k);
  size_t guess = 0;
  // Attempts left without clipping an ear; a polygon with none left to clip ends the search.
  size_t attempts = n, previous_size = n;
  while (remaining.size() > 3 && attempts > 0) {
    const size_t m = remaining.size();
    if (guess >= m) guess -= m;
    if (previous_size != m) {
      previous_size = m;
      attempts = m;
    } else {
      --attempts;
    }
    uint32_t ind[3];
    float vx[3], vy[3];
    for (size_t k = 0; k < 3; ++k) {
      ind[k] = remaining[(guess + k) % m];
      const Vec3& v = p[vertex[ind[k]]];
      vx[k] = v[axes[0]];
      vy[k] = v[axes[1]];
    }
    const float e0x = vx[1] - vx[0], e0y = vy[1] - vy[0];
    const float e1x = vx[2] - vx[1], e1y = vy[2] - vy[1];
    const float cross = e0x * e1y - e0y * e1x;
    // A corner whose turn has the opposite sign of the shoelace term of its first edge is taken for
    // reflex and is no ear (the library's test).
    const float area = (vx[0] * vy[1] - vy[0] * vx[1]) * 0.5f;
    if (cross * area < 0.f) {
      ++guess;
      continue;
    }
    bool overlap = false;
    for (size_t other = 3; other < m && !overlap; ++other) {
      const Vec3& v = p[vertex[remaining[(guess + other) % m]]];
      overlap = inside_triangle(vx, vy, v[axes[0]], v[axes[1]]);
    }
    if (overlap) {
      ++guess;
      continue;
    }
    out->push_back({ind[0], ind[1], ind[2]});
    remaining.erase(remaining.begin() + std::ptrdiff_t((guess + 1) % m));
  }
  if (remaining.size() == 3) out->push_back({remaining[0], remaining[1], remaining[2]});
}

}  // namespace

void triangulate_face(const std::vector<Vec3>& positions, const uint32_t* vertex, size_t n,
                      std::vector<std::array<uint32_t, 3>>* out) {
  if (n == 3)
    out->push_back({0, 1, 2});
  else if (n == 4)
    split_quad(positions, vertex, out);
  else
    clip_ears(positions, vertex, n, out);
}

}  // namespace epr::loader
