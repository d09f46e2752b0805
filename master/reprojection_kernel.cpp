// The plane grid, kernel parameters and input checks the CPU and GL reprojectors share. See
// reprojection_kernel.h.
#include "master/reprojection_kernel.h"

#include <fmt/format.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <stdexcept>
#include <string>
#include <unordered_map>

namespace epr {
namespace detail {

PlaneGrid make_plane_grid(const DeepFramebuffer& dfb, const Vec3& eye, float crease_tolerance, bool creases) {
  PlaneGrid g;
  g.width = dfb.width;
  g.height = dfb.height;
  g.subpixels = dfb.subpixels;
  g.crease_tolerance = crease_tolerance;
  g.has_creases = creases;
  g.texel_plane.assign(dfb.texel_count(), PlaneGrid::kUncovered);
  struct Key {
    uint32_t b[4];
    bool operator==(const Key& o) const { return std::memcmp(b, o.b, 16) == 0; }
  };
  struct Hash {
    size_t operator()(const Key& k) const {
      uint64_t h = 0x9e3779b97f4a7c15ull;
      for (uint32_t v : k.b) h = (h ^ v) * 0xbf58476d1ce4e5b9ull;
      return size_t(h ^ (h >> 31));
    }
  };
  // Plain entries: one per distinct plane.
  std::unordered_map<Key, uint32_t, Hash> index;
  Key last{};
  uint32_t last_plane = PlaneGrid::kUncovered;
  for (size_t t = 0; t < dfb.texel_count(); ++t) {
    if (!dfb.covered[t]) continue;
    const float v[4] = {dfb.normal[3 * t], dfb.normal[3 * t + 1], dfb.normal[3 * t + 2], dfb.plane_offset[t]};
    Key key;
    std::memcpy(key.b, v, 16);
    if (last_plane == PlaneGrid::kUncovered || !(key == last)) {
      auto [it, inserted] = index.try_emplace(key, uint32_t(index.size()));
      if (inserted) g.planes.insert(g.planes.end(), v, v + 4);
      last = key;
      last_plane = it->second;
    }
    g.texel_plane[t] = last_plane;
  }
  g.first_creased = uint32_t(g.planes.size() / 4);
  if (!creases) return g;

  // Crease sets: per texel, the other planes its 8 neighbours see, each as 2 * plane + (1 if flipped),
  // sorted. Rows in parallel; the sets are interned below in texel order (deterministic indices).
  const int W = dfb.width, H = dfb.height;
  auto row_sets = std::vector<std::vector<uint32_t>>(size_t(H));    // concatenated sets of a row
  auto row_texels = std::vector<std::vector<uint32_t>>(size_t(H));  // (texel x, set begin, set size) per creased texel
  // Another entry of the same plane (a zero of the other sign, or the opposite winding): not a crease;
  // oriented by the eye it would cut the far half of the texel's own epsilon band.
  auto same_plane = [&](uint32_t a, uint32_t b) {
    const float* x = &g.planes[4 * size_t(a)];
    const float* y = &g.planes[4 * size_t(b)];
    const bool same = x[0] == y[0] && x[1] == y[1] && x[2] == y[2] && x[3] == y[3];
    const bool opposite = x[0] == -y[0] && x[1] == -y[1] && x[2] == -y[2] && x[3] == -y[3];
    return same || opposite;
  };
  auto oriented = [&](uint32_t q, const Vec3& point, double* side) {
    const float* pl = &g.planes[4 * size_t(q)];
    *side = double(pl[0]) * point.x + double(pl[1]) * point.y + double(pl[2]) * point.z - double(pl[3]);
    return std::fabs(*side) > double(crease_tolerance);
  };
  tbb::parallel_for(0, H, [&](int y) {
    std::vector<uint32_t> set;
    for (int x = 0; x < W; ++x) {
      const size_t t = dfb.index(x, y);
      const uint32_t own = g.texel_plane[t];
      if (own == PlaneGrid::kUncovered) continue;
      set.clear();
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          const int nx = x + dx, ny = y + dy;
          if ((dx == 0 && dy == 0) || nx < 0 || ny < 0 || nx >= W || ny >= H) continue;
          const uint32_t q = g.texel_plane[dfb.index(nx, ny)];
          if (q == PlaneGrid::kUncovered || q == own || same_plane(own, q)) continue;
          double side = 0;
          if (!oriented(q, dfb.position_at(t), &side) && !oriented(q, eye, &side)) continue;
          const uint32_t code = 2 * q + (side < 0 ? 1u : 0u);
          if (std::find(set.begin(), set.end(), code) == set.end()) set.push_back(code);
        }
      if (set.empty()) continue;
      std::sort(set.begin(), set.end());
      auto& rs = row_sets[size_t(y)];
      row_texels[size_t(y)].insert(row_texels[size_t(y)].end(),
                                   {uint32_t(x), uint32_t(rs.size()), uint32_t(set.size())});
      rs.insert(rs.end(), set.begin(), set.end());
    }
  });
  struct SetHash {
    size_t operator()(const std::vector<uint32_t>& v) const {
      uint64_t h = 0x9e3779b97f4a7c15ull;
      for (uint32_t x : v) h = (h ^ x) * 0xbf58476d1ce4e5b9ull;
      return size_t(h ^ (h >> 31));
    }
  };
  std::unordered_map<std::vector<uint32_t>, uint32_t, SetHash> creased_entry;  // (own plane, codes...) -> entry
  std::vector<uint32_t> key;
  for (int y = 0; y < H; ++y) {
    const auto& rt = row_texels[size_t(y)];
    for (size_t i = 0; i < rt.size(); i += 3) {
      const size_t t = dfb.index(int(rt[i]), y);
      const uint32_t own = g.texel_plane[t];
      key.assign(1, own);
      key.insert(key.end(), row_sets[size_t(y)].begin() + rt[i + 1],
                 row_sets[size_t(y)].begin() + rt[i + 1] + rt[i + 2]);
      auto [it, inserted] = creased_entry.try_emplace(key, uint32_t(g.planes.size() / 4));
      if (inserted) {
        const std::array<float, 4> plane{g.planes[4 * size_t(own)], g.planes[4 * size_t(own) + 1],
                                         g.planes[4 * size_t(own) + 2], g.planes[4 * size_t(own) + 3]};
        g.planes.insert(g.planes.end(), plane.begin(), plane.end());
        g.crease_range.push_back(uint32_t(g.creases.size() / 4));
        g.crease_range.push_back(uint32_t(key.size() - 1));
        for (size_t c = 1; c < key.size(); ++c) {
          const float s = (key[c] & 1u) ? -1.f : 1.f;
          const float* pl = &g.planes[4 * size_t(key[c] >> 1)];
          g.creases.insert(g.creases.end(), {s * pl[0], s * pl[1], s * pl[2], s * pl[3]});
        }
      }
      g.texel_plane[t] = it->second;
    }
  }
  return g;
}

KernelParams make_kernel_params(const Camera& camera, int subpixels, float epsilon, bool joint_test) {
  KernelParams k;
  k.eye = camera.eye();
  k.forward = camera.forward();
  k.right = camera.right();
  k.up = camera.up();
  k.tan_half_x = camera.tan_half_x();
  k.tan_half_y = camera.tan_half_y();
  k.width = float(camera.width());
  k.height = float(camera.height());
  k.s = float(subpixels);
  k.grid_w = float(subpixels * camera.width());
  k.grid_h = float(subpixels * camera.height());
  k.grid_wi = uint32_t(subpixels * camera.width());
  k.epsilon = epsilon;
  k.crease_tolerance = epsilon * kCreaseToleranceFraction;
  k.min_normal_cosine = joint_test ? kMinNormalCosine : -1.f;
  return k;
}

namespace {
void validate_settings(const ReprojectorSettings& s) {
  if (!(std::isfinite(s.epsilon) && s.epsilon >= 0))
    throw std::invalid_argument(fmt::format("reprojection epsilon {} must be finite and >= 0 (metres)", s.epsilon));
  if (s.batch_points < 1024 || s.batch_points > (size_t(1) << 24))
    throw std::invalid_argument(fmt::format("batch_points {} outside [1024, 2^24]", s.batch_points));
  if (s.workgroup_size < 1 || s.workgroup_size > 1024 || s.workgroups < 1 || s.workgroups > 65535)
    throw std::invalid_argument("workgroup_size must be in [1, 1024] and workgroups in [1, 65535]");
}
}  // namespace

void validate_reprojector_inputs(const Camera& camera, const DeepFramebuffer& dfb, const ReprojectorSettings& s) {
  validate_settings(s);
  if (dfb.subpixels < 1 || dfb.width != camera.width() * dfb.subpixels || dfb.height != camera.height() * dfb.subpixels)
    throw std::invalid_argument(fmt::format("deep framebuffer {}x{} (S={}) does not match the {}x{} camera", dfb.width,
                                            dfb.height, dfb.subpixels, camera.width(), camera.height()));
  const size_t n = dfb.texel_count();
  if (dfb.covered.size() != n || dfb.normal.size() != 3 * n || dfb.plane_offset.size() != n)
    throw std::invalid_argument("deep framebuffer arrays do not match its size");
}

void validate_reprojector_inputs(const Camera& camera, const PlaneGrid& grid, const ReprojectorSettings& s) {
  validate_settings(s);
  if (grid.subpixels < 1 || grid.width != camera.width() * grid.subpixels ||
      grid.height != camera.height() * grid.subpixels)
    throw std::invalid_argument(fmt::format("plane grid {}x{} (S={}) does not match the {}x{} camera", grid.width,
                                            grid.height, grid.subpixels, camera.width(), camera.height()));
  if (grid.texel_plane.size() != size_t(grid.width) * size_t(grid.height))
    throw std::invalid_argument("plane grid arrays do not match its size");
  const float tolerance = s.epsilon * kCreaseToleranceFraction;
  if (grid.has_creases != s.joint_test || (s.joint_test && grid.crease_tolerance != tolerance))
    throw std::invalid_argument(
        fmt::format("plane grid built with creases {} at tolerance {}, the reprojector wants {} at {}",
                    grid.has_creases, grid.crease_tolerance, s.joint_test, tolerance));
}

PlaneGrid plane_grid_for(const Camera& camera, const DeepFramebuffer& dfb, const ReprojectorSettings& settings) {
  validate_reprojector_inputs(camera, dfb, settings);
  return make_plane_grid(dfb, camera.eye(), settings.epsilon * kCreaseToleranceFraction, settings.joint_test);
}

}  // namespace detail

}  // namespace epr
