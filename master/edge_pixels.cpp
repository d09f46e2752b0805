// See edge_pixels.h.
#include "master/edge_pixels.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>

namespace epr::detail {

namespace {

// Whether two plane-table entries hold the same plane (a creased entry copies its own plane).
bool same_entry_plane(const PlaneGrid& g, uint32_t a, uint32_t b) {
  if (a == b) return true;
  if (a == PlaneGrid::kUncovered || b == PlaneGrid::kUncovered) return false;
  return same_plane(&g.planes[4 * size_t(a)], &g.planes[4 * size_t(b)]);
}

}  // namespace

EdgePixels::EdgePixels(const PlaneGrid& g, const Camera& camera, float epsilon) {
  const int S = g.subpixels;
  width_ = S > 0 ? g.width / S : 0;
  height_ = S > 0 ? g.height / S : 0;
  const size_t pixels = size_t(width_) * size_t(height_);
  bits_.assign((pixels + 63) / 64, 0);
  // The point of entry e's plane on the ray through texel (gx, gy)'s centre, false if parallel.
  const auto point_on = [&](uint32_t e, int gx, int gy, Vec3* x) {
    const float* q = &g.planes[4 * size_t(e)];
    const Ray r = camera.generate_ray((float(gx) + 0.5f) / float(S), (float(gy) + 0.5f) / float(S));
    const Vec3 n{q[0], q[1], q[2]};
    const float along = dot(n, r.dir);
    if (!(std::fabs(along) > 0)) return false;
    *x = r.origin + r.dir * ((q[3] - dot(n, r.origin)) / along);
    return true;
  };
  const auto within = [&](uint32_t e, const Vec3& x) {
    const float* q = &g.planes[4 * size_t(e)];
    return std::fabs(q[0] * x.x + q[1] * x.y + q[2] * x.z - q[3]) <= epsilon;
  };
  // Is pixel p an edge pixel? A pixel that sees no surface at all is not (it gets no samples anyway).
  const auto edge = [&](size_t p) {
    const int x = int(p % size_t(width_)), y = int(p / size_t(width_));
    const int gx0 = std::max(0, x * S - 1), gx1 = std::min(g.width, (x + 1) * S + 1);
    const int gy0 = std::max(0, y * S - 1), gy1 = std::min(g.height, (y + 1) * S + 1);
    const uint32_t first = g.texel_plane[size_t(gy0) * size_t(g.width) + size_t(gx0)];
    Vec3 first_point;
    bool have_first_point = false;
    for (int gy = gy0; gy < gy1; ++gy)
      for (int gx = gx0; gx < gx1; ++gx) {
        const uint32_t e = g.texel_plane[size_t(gy) * size_t(g.width) + size_t(gx)];
        if (same_entry_plane(g, first, e)) continue;
        if (first == PlaneGrid::kUncovered || e == PlaneGrid::kUncovered) return true;
        // Another plane: one surface only if each texel's point lies within epsilon of the other's
        // plane (facets of one flat or gently curved surface), as the plane test would accept it.
        if (!have_first_point && !point_on(first, gx0, gy0, &first_point)) return true;
        have_first_point = true;
        Vec3 point;
        if (!point_on(e, gx, gy, &point) || !within(first, point) || !within(e, first_point)) return true;
      }
    return false;
  };
  // One task per run of 64-pixel words: each word is written by one task only.
  tbb::parallel_for(tbb::blocked_range<size_t>(0, bits_.size(), 64), [&](const tbb::blocked_range<size_t>& r) {
    for (size_t w = r.begin(); w != r.end(); ++w)
      for (size_t p = w * 64; p < std::min(pixels, w * 64 + 64); ++p)
        if (edge(p)) bits_[w] |= uint64_t(1) << (p & 63);
  });
  for (uint64_t word : bits_) count_ += size_t(__builtin_popcountll(word));
}

void EdgePixels::drop(PixelReprojection* out) const {
  if (count_ == 0) return;
  const size_t pixels = size_t(width_) * size_t(height_);
  const bool radiance = out->radiance.width == width_ && out->radiance.height == height_;
  for (size_t w = 0; w < bits_.size(); ++w) {
    uint64_t word = bits_[w];
    while (word) {
      const size_t p = w * 64 + size_t(__builtin_ctzll(word));
      word &= word - 1;
      if (p >= pixels) break;
      if (out->count.size() == pixels) out->count[p] = 0;
      if (out->effective.size() == pixels) out->effective[p] = 0.f;
      if (out->variance.size() == pixels) out->variance[p] = -1.f;
      if (radiance) out->radiance.set_rgb(int(p % size_t(width_)), int(p / size_t(width_)), Vec3(0.f));
    }
  }
}

}  // namespace epr::detail
