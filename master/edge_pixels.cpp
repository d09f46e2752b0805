// See edge_pixels.h.
#include "master/edge_pixels.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>

namespace epr::detail {

namespace {

// Whether two plane-table entries hold the same plane (a creased entry copies its own plane; the
// opposite winding of one plane is the same plane).
bool same_plane(const PlaneGrid& g, uint32_t a, uint32_t b) {
  if (a == b) return true;
  if (a == PlaneGrid::kUncovered || b == PlaneGrid::kUncovered) return false;
  const float* x = &g.planes[4 * size_t(a)];
  const float* y = &g.planes[4 * size_t(b)];
  const bool same = x[0] == y[0] && x[1] == y[1] && x[2] == y[2] && x[3] == y[3];
  const bool opposite = x[0] == -y[0] && x[1] == -y[1] && x[2] == -y[2] && x[3] == -y[3];
  return same || opposite;
}

}  // namespace

EdgePixels::EdgePixels(const PlaneGrid& g) {
  const int S = g.subpixels;
  width_ = S > 0 ? g.width / S : 0;
  height_ = S > 0 ? g.height / S : 0;
  const size_t pixels = size_t(width_) * size_t(height_);
  bits_.assign((pixels + 63) / 64, 0);
  // Is pixel p an edge pixel? A pixel that sees no surface at all is not (it gets no samples anyway).
  const auto edge = [&](size_t p) {
    const int x = int(p % size_t(width_)), y = int(p / size_t(width_));
    const int gx0 = std::max(0, x * S - 1), gx1 = std::min(g.width, (x + 1) * S + 1);
    const int gy0 = std::max(0, y * S - 1), gy1 = std::min(g.height, (y + 1) * S + 1);
    const uint32_t first = g.texel_plane[size_t(gy0) * size_t(g.width) + size_t(gx0)];
    for (int gy = gy0; gy < gy1; ++gy)
      for (int gx = gx0; gx < gx1; ++gx)
        if (!same_plane(g, first, g.texel_plane[size_t(gy) * size_t(g.width) + size_t(gx)])) return true;
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
