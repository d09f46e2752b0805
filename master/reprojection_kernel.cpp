// The plane grid, kernel parameters and input checks the CPU and GL reprojectors share. See
// reprojection_kernel.h.
#include "master/reprojection_kernel.h"

#include <fmt/format.h>
#include <tbb/blocked_range.h>
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

size_t PlaneGridBuilder::KeyHash::operator()(const Key& k) const {
  uint64_t h = 0x9e3779b97f4a7c15ull;
  for (uint32_t v : k.b) h = (h ^ v) * 0xbf58476d1ce4e5b9ull;
  return size_t(h ^ (h >> 31));
}

size_t PlaneGridBuilder::SetHash::operator()(const std::vector<uint32_t>& v) const {
  uint64_t h = 0x9e3779b97f4a7c15ull;
  for (uint32_t x : v) h = (h ^ x) * 0xbf58476d1ce4e5b9ull;
  return size_t(h ^ (h >> 31));
}

PlaneGridBuilder::PlaneGridBuilder(int width, int height, int subpixels, const Vec3& eye, float crease_tolerance,
                                   bool creases)
    : eye_(eye) {
  if (width < 0 || height < 0 || int64_t(width) * height >= int64_t(kCreasedBit))
    throw std::invalid_argument(fmt::format("plane grid {}x{} too large", width, height));
  g_.width = width;
  g_.height = height;
  g_.subpixels = subpixels;
  g_.crease_tolerance = crease_tolerance;
  g_.has_creases = creases;
  g_.texel_plane.assign(size_t(width) * size_t(height), PlaneGrid::kUncovered);
}

void PlaneGridBuilder::add_band(const DeepFramebuffer& band, int row0, int row1) {
  const int W = g_.width, H = g_.height;
  const int b0 = band.first_row, b1 = band.first_row + band.height;
  if (band.width != W || band.subpixels != g_.subpixels || row0 != next_row_ || row1 < row0 || row1 > H ||
      b0 > std::max(0, row0 - 1) || b1 < std::min(H, row1 + 1) || b0 < 0 || b1 > H)
    throw std::invalid_argument(fmt::format(
        "deep framebuffer band of rows [{}, {}) ({} wide, S={}) cannot give rows [{}, {}) of a {}x{} grid (S={}) "
        "after row {}",
        b0, b1, band.width, band.subpixels, row0, row1, W, H, g_.subpixels, next_row_));
  if (row0 == row1) return;
  // Plain entries: one per distinct plane, numbered in texel order. The band's rows come in grid order
  // and rows seen before (the halo above) find their planes already numbered, so the numbering is the
  // full frame's.
  band_plain_.assign(band.texel_count(), PlaneGrid::kUncovered);
  Key last{};
  uint32_t last_plane = PlaneGrid::kUncovered;
  for (size_t t = 0; t < band.texel_count(); ++t) {
    if (!band.covered[t]) continue;
    const float v[4] = {band.normal[3 * t], band.normal[3 * t + 1], band.normal[3 * t + 2], band.plane_offset[t]};
    Key key;
    std::memcpy(key.b, v, 16);
    if (last_plane == PlaneGrid::kUncovered || !(key == last)) {
      auto [it, inserted] = plain_.try_emplace(key, uint32_t(plain_.size()));
      if (inserted) g_.planes.insert(g_.planes.end(), v, v + 4);
      last = key;
      last_plane = it->second;
    }
    band_plain_[t] = last_plane;
  }
  // Band row of grid row y: y - b0.
  std::copy(band_plain_.begin() + ptrdiff_t(size_t(row0 - b0) * W),
            band_plain_.begin() + ptrdiff_t(size_t(row1 - b0) * W),
            g_.texel_plane.begin() + ptrdiff_t(size_t(row0) * W));
  next_row_ = row1;
  if (!g_.has_creases) return;

  // Crease sets: per texel, the other planes its 8 neighbours see, each as 2 * plane + (1 if flipped),
  // sorted. Rows in parallel; the sets are interned below in texel order (deterministic indices).
  const int n = row1 - row0;
  row_sets_.resize(size_t(n));    // concatenated sets of a row
  row_texels_.resize(size_t(n));  // (texel x, set begin, set size) per creased texel
  const float crease_tolerance = g_.crease_tolerance;
  const std::vector<float>& planes = g_.planes;
  // Another entry of the same plane (a zero of the other sign, or the opposite winding): not a crease;
  // oriented by the eye it would cut the far half of the texel's own epsilon band.
  auto same_entry_plane = [&](uint32_t a, uint32_t b) {
    return same_plane(&planes[4 * size_t(a)], &planes[4 * size_t(b)]);
  };
  auto oriented = [&](uint32_t q, const Vec3& point, double* side) {
    const float* pl = &planes[4 * size_t(q)];
    *side = double(pl[0]) * point.x + double(pl[1]) * point.y + double(pl[2]) * point.z - double(pl[3]);
    return std::fabs(*side) > double(crease_tolerance);
  };
  tbb::parallel_for(row0, row1, [&](int y) {
    auto& rs = row_sets_[size_t(y - row0)];
    auto& rt = row_texels_[size_t(y - row0)];
    rs.clear();
    rt.clear();
    std::vector<uint32_t> set;
    for (int x = 0; x < W; ++x) {
      const size_t t = band.index(x, y - b0);
      const uint32_t own = band_plain_[t];
      if (own == PlaneGrid::kUncovered) continue;
      set.clear();
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          const int nx = x + dx, ny = y + dy;
          if ((dx == 0 && dy == 0) || nx < 0 || ny < 0 || nx >= W || ny >= H) continue;
          const uint32_t q = band_plain_[band.index(nx, ny - b0)];
          if (q == PlaneGrid::kUncovered || q == own || same_entry_plane(own, q)) continue;
          double side = 0;
          if (!oriented(q, band.position_at(t), &side) && !oriented(q, eye_, &side)) continue;
          const uint32_t code = 2 * q + (side < 0 ? 1u : 0u);
          if (std::find(set.begin(), set.end(), code) == set.end()) set.push_back(code);
        }
      if (set.empty()) continue;
      std::sort(set.begin(), set.end());
      rt.insert(rt.end(), {uint32_t(x), uint32_t(rs.size()), uint32_t(set.size())});
      rs.insert(rs.end(), set.begin(), set.end());
    }
  });
  // Creased entries, numbered in texel order from 0 (finish() moves them after the plain ones).
  std::vector<uint32_t> key;
  for (int y = row0; y < row1; ++y) {
    const auto& rt = row_texels_[size_t(y - row0)];
    const auto& rs = row_sets_[size_t(y - row0)];
    for (size_t i = 0; i < rt.size(); i += 3) {
      const uint32_t own = band_plain_[band.index(int(rt[i]), y - b0)];
      key.assign(1, own);
      key.insert(key.end(), rs.begin() + rt[i + 1], rs.begin() + rt[i + 1] + rt[i + 2]);
      auto [it, inserted] = creased_.try_emplace(key, uint32_t(creased_planes_.size() / 4));
      if (inserted) {
        const std::array<float, 4> plane{g_.planes[4 * size_t(own)], g_.planes[4 * size_t(own) + 1],
                                         g_.planes[4 * size_t(own) + 2], g_.planes[4 * size_t(own) + 3]};
        creased_planes_.insert(creased_planes_.end(), plane.begin(), plane.end());
        g_.crease_range.push_back(uint32_t(g_.creases.size() / 4));
        g_.crease_range.push_back(uint32_t(key.size() - 1));
        for (size_t c = 1; c < key.size(); ++c) {
          const float s = (key[c] & 1u) ? -1.f : 1.f;
          const float* pl = &g_.planes[4 * size_t(key[c] >> 1)];
          g_.creases.insert(g_.creases.end(), {s * pl[0], s * pl[1], s * pl[2], s * pl[3]});
        }
      }
      g_.texel_plane[size_t(y) * W + rt[i]] = kCreasedBit | it->second;
    }
  }
}

PlaneGrid PlaneGridBuilder::finish() {
  if (next_row_ != g_.height)
    throw std::logic_error(fmt::format("plane grid: {} of {} rows added", next_row_, g_.height));
  g_.first_creased = uint32_t(g_.planes.size() / 4);
  if (!creased_planes_.empty()) {
    g_.planes.insert(g_.planes.end(), creased_planes_.begin(), creased_planes_.end());
    const uint32_t first = g_.first_creased;
    std::vector<uint32_t>& tp = g_.texel_plane;
    tbb::parallel_for(tbb::blocked_range<size_t>(0, tp.size(), size_t(1) << 16), [&](const auto& r) {
      for (size_t t = r.begin(); t != r.end(); ++t)
        if (tp[t] != PlaneGrid::kUncovered && (tp[t] & kCreasedBit)) tp[t] = first + (tp[t] & ~kCreasedBit);
    });
  }
  plain_.clear();
  creased_.clear();
  creased_planes_ = {};
  band_plain_ = {};
  row_sets_ = {};
  row_texels_ = {};
  next_row_ = 0;
  return std::move(g_);
}

PlaneGrid make_plane_grid(const DeepFramebuffer& dfb, const Vec3& eye, float crease_tolerance, bool creases) {
  PlaneGridBuilder b(dfb.width, dfb.height, dfb.subpixels, eye, crease_tolerance, creases);
  b.add_band(dfb, 0, dfb.height);
  return b.finish();
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
