// See reprojection_image.h.
#include "master/reprojection_image.h"

#include <stdexcept>

#include <fmt/format.h>
#include <tbb/parallel_for.h>

namespace epr {

namespace {

// The downsampling of one pixel, for any storage of the cells: `cell(s)` returns subpixel s.
template <class CellAt>
PixelReprojection downsample_impl(int grid_w, int grid_h, int S, const CellAt& cell) {
  const int W = grid_w / S, H = grid_h / S;
  PixelReprojection out{Image(W, H, 3), std::vector<uint64_t>(size_t(W) * size_t(H), 0)};
  tbb::parallel_for(0, H, [&](int y) {
    for (int x = 0; x < W; ++x) {
      double mean[3] = {0, 0, 0};
      uint64_t total = 0;
      int non_empty = 0;
      for (int j = 0; j < S; ++j)
        for (int i = 0; i < S; ++i) {
          const size_t s = size_t(y * S + j) * size_t(grid_w) + size_t(x * S + i);
          const AccumulationCell c = cell(s);
          if (c.n == 0) continue;
          mean[0] += double(c.r) / double(c.n);
          mean[1] += double(c.g) / double(c.n);
          mean[2] += double(c.b) / double(c.n);
          total += c.n;
          ++non_empty;
        }
      if (non_empty) out.radiance.set_rgb(x, y, Vec3(float(mean[0] / non_empty), float(mean[1] / non_empty), float(mean[2] / non_empty)));
      out.count[size_t(y) * size_t(W) + size_t(x)] = total;
    }
  });
  return out;
}

}  // namespace

PixelReprojection downsample(const SubpixelAccumulation& acc) {
  const int S = acc.subpixels;
  if (S < 1 || acc.width % S != 0 || acc.height % S != 0 || acc.sum.size() != 3 * acc.size() ||
      acc.count.size() != acc.size())
    throw std::invalid_argument("downsample: malformed subpixel accumulation");
  return downsample_impl(acc.width, acc.height, S, [&](size_t s) {
    return AccumulationCell{acc.sum[3 * s], acc.sum[3 * s + 1], acc.sum[3 * s + 2], acc.count[s]};
  });
}

PixelReprojection downsample_cells(std::span<const AccumulationCell> cells, int grid_w, int grid_h, int S) {
  if (S < 1 || grid_w % S != 0 || grid_h % S != 0 || cells.size() != size_t(grid_w) * size_t(grid_h))
    throw std::invalid_argument("downsample_cells: malformed subpixel grid");
  return downsample_impl(grid_w, grid_h, S, [&](size_t s) { return cells[s]; });
}

Image combine(const Image& path_sum, const std::vector<uint32_t>& path_count, const PixelReprojection& rp) {
  const size_t n = size_t(path_sum.width) * size_t(path_sum.height);
  if (path_sum.channels < 3 || path_count.size() != n || rp.radiance.width != path_sum.width ||
      rp.radiance.height != path_sum.height || rp.count.size() != n)
    throw std::invalid_argument(fmt::format("combine: sizes differ (path image {}x{}, {} counts, reprojection {}x{})",
                                            path_sum.width, path_sum.height, path_count.size(), rp.radiance.width,
                                            rp.radiance.height));
  Image out(path_sum.width, path_sum.height, 3);
  tbb::parallel_for(0, path_sum.height, [&](int y) {
    for (int x = 0; x < path_sum.width; ++x) {
      const size_t p = size_t(y) * size_t(path_sum.width) + size_t(x);
      const double m = path_count[p], mr = double(rp.count[p]);
      if (m + mr == 0) continue;
      const Vec3 ps = path_sum.rgb(x, y), lr = rp.radiance.rgb(x, y);
      out.set_rgb(x, y, Vec3(float((ps.x + mr * lr.x) / (m + mr)), float((ps.y + mr * lr.y) / (m + mr)),
                             float((ps.z + mr * lr.z) / (m + mr))));
    }
  });
  return out;
}

std::vector<uint8_t> skip_mask(const std::vector<uint32_t>& path_count, const std::vector<uint64_t>& reprojected_count,
                               uint64_t target_samples, uint32_t min_paths) {
  if (path_count.size() != reprojected_count.size())
    throw std::invalid_argument(fmt::format("skip_mask: {} path counts but {} reprojected counts", path_count.size(),
                                            reprojected_count.size()));
  std::vector<uint8_t> skip(path_count.size());
  for (size_t p = 0; p < skip.size(); ++p)
    skip[p] = uint64_t(path_count[p]) + reprojected_count[p] >= target_samples && path_count[p] >= min_paths;
  return skip;
}

}  // namespace epr
