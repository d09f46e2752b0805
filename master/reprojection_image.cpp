// See reprojection_image.h.
#include "master/reprojection_image.h"

#include <fmt/format.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "master/combine_rule.h"

namespace epr {

namespace {

uint32_t saturate_count(uint64_t n) { return uint32_t(std::min<uint64_t>(n, UINT32_MAX)); }

constexpr int kMaxSubpixelsPerPixel = 64;  // S <= 8

// What the downsampling writes for one pixel.
struct PixelValue {
  Vec3 radiance{0.f};
  uint64_t total = 0;   // M' (the effective count for an area-weighted pixel)
  float effective = 0;  // M'_eff
};

// An area-weighted pixel (AreaWeights): `codes` are its S * S subpixels' class and area.
template <class CellAt>
PixelValue weighted_pixel(const CellAt& cell, int x, int y, int S, const uint16_t* codes) {
  double sum[kMaxSubpixelsPerPixel][3] = {}, inverse[kMaxSubpixelsPerPixel] = {}, samples[kMaxSubpixelsPerPixel] = {};
  int area[kMaxSubpixelsPerPixel] = {}, with_samples[kMaxSubpixelsPerPixel] = {};
  int classes = 0;
  for (int j = 0; j < S; ++j)
    for (int i = 0; i < S; ++i) {
      const uint16_t code = codes[j * S + i];
      const int k = AreaWeights::class_of(code);
      area[k] = AreaWeights::area_of(code);
      classes = std::max(classes, k + 1);
      const AccumulationCell c = cell(y * S + j, x * S + i);
      if (c.n == 0) continue;
      sum[k][0] += double(c.r) / double(c.n);
      sum[k][1] += double(c.g) / double(c.n);
      sum[k][2] += double(c.b) / double(c.n);
      inverse[k] += 1.0 / double(c.n);
      samples[k] += double(c.n);
      ++with_samples[k];
    }
  double rgb[3] = {0, 0, 0}, covered = 0, all = 0;
  bool complete = true;
  for (int k = 0; k < classes; ++k) {
    all += area[k];
    if (with_samples[k] == 0) {
      complete = complete && area[k] == 0;
      continue;
    }
    covered += area[k];
    for (int c = 0; c < 3; ++c) rgb[c] += area[k] * sum[k][c] / with_samples[k];
  }
  PixelValue v;
  if (covered > 0) v.radiance = Vec3(float(rgb[0] / covered), float(rgb[1] / covered), float(rgb[2] / covered));
  if (complete && all > 0) {
    // Per unit variance of one sample: the variance of L_rp (M'_eff), and that of a stratified mean
    // of the classes' samples pooled (M': it grows with every sample).
    double spread = 0, pooled = 0;
    for (int k = 0; k < classes; ++k)
      if (with_samples[k] > 0) {
        const double a = area[k] / all;
        spread += a * a * inverse[k] / (double(with_samples[k]) * double(with_samples[k]));
        pooled += a * a / samples[k];
      }
    if (spread > 0) v.effective = float(1.0 / spread);
    if (pooled > 0) v.total = uint64_t(std::floor(1.0 / pooled + 1e-9));
  }
  return v;
}

// The downsampling, for any storage of the cells: `cell(gy, gx)` returns the subpixel of grid row gy
// and column gx. Only pixels p with skip[p] == 0 (every pixel if `skip` is empty, or if what is
// written is not W x H: it is then reallocated); only the `parts` asked for are written or
// reallocated.
template <class CellAt>
void downsample_impl(int grid_w, int grid_h, int S, const CellAt& cell, std::span<const uint8_t> skip,
                     PixelReprojection* outp, DownsampleParts parts = DownsampleParts::kBoth) {
  const int W = grid_w / S, H = grid_h / S;
  const size_t pixels = size_t(W) * size_t(H);
  PixelReprojection& out = *outp;
  const bool counts_only = parts == DownsampleParts::kCounts, with_counts = parts != DownsampleParts::kRadiance;
  if (with_counts && out.count.size() != pixels) {
    out.count.assign(pixels, 0);
    skip = {};
  }
  if (!counts_only && (out.radiance.width != W || out.radiance.height != H || out.radiance.channels != 3)) {
    out.radiance = Image(W, H, 3);
    skip = {};
  }
  const bool stats = out.statistics;
  if (stats && with_counts && out.effective.size() != pixels) {
    out.effective.assign(pixels, 0.f);
    skip = {};
  }
  if (stats && !counts_only && out.half_variance.size() != 2 * pixels) {
    out.half_radiance.assign(6 * pixels, 0.f);
    out.half_effective.assign(2 * pixels, 0.f);
    out.half_variance.assign(2 * pixels, -1.f);
    out.half_subpixels.assign(2 * pixels, 0);
    skip = {};
  }
  if (S * S > kMaxSubpixelsPerPixel) throw std::invalid_argument("downsample: more than 8 x 8 subpixels");
  if (!skip.empty() && skip.size() != pixels) throw std::invalid_argument("downsample: skip mask of the wrong size");
  const AreaWeights* weights = out.area_weights;
  if (weights && weights->cells.size() != weights->pixels.size() * size_t(S) * size_t(S))
    throw std::invalid_argument("downsample: area weights of the wrong size");
  tbb::parallel_for(0, H, [&](int y) {
    // The next area-weighted pixel at or after this row's first.
    size_t next =
        weights
            ? size_t(std::lower_bound(weights->pixels.begin(), weights->pixels.end(), uint32_t(size_t(y) * size_t(W))) -
                     weights->pixels.begin())
            : 0;
    for (int x = 0; x < W; ++x) {
      const size_t p = size_t(y) * size_t(W) + size_t(x);
      const bool weighted = weights && next < weights->pixels.size() && weights->pixels[next] == p;
      if (weighted) ++next;
      if (!skip.empty() && skip[p]) continue;
      if (weighted) {
        const PixelValue v = weighted_pixel(cell, x, y, S, &weights->cells[(next - 1) * size_t(S) * size_t(S)]);
        if (!counts_only) out.radiance.set_rgb(x, y, v.radiance);
        if (with_counts) out.count[p] = saturate_count(v.total);
        if (stats && with_counts) out.effective[p] = v.effective;
        if (stats && !counts_only) {
          for (int h = 0; h < 2; ++h) {
            for (int c = 0; c < 3; ++c) out.half_radiance[6 * p + 3 * size_t(h) + size_t(c)] = 0.f;
            out.half_effective[2 * p + size_t(h)] = 0.f;
            out.half_variance[2 * p + size_t(h)] = -1.f;
            out.half_subpixels[2 * p + size_t(h)] = 0;
          }
        }
        continue;
      }
      if (counts_only) {
        uint64_t total = 0;
        double inverse = 0;  // Σ 1 / c_s over the non-empty subpixels (M'_eff)
        int non_empty = 0;
        for (int j = 0; j < S; ++j)
          for (int i = 0; i < S; ++i) {
            const uint32_t n = cell(y * S + j, x * S + i).n;
            total += n;
            if (stats && n > 0) {
              inverse += 1.0 / double(n);
              ++non_empty;
            }
          }
        out.count[p] = saturate_count(total);
        if (stats) out.effective[p] = non_empty ? float(double(non_empty) * double(non_empty) / inverse) : 0.f;
        continue;
      }
      double mean[3] = {0, 0, 0};
      // Per half h ((sx + sy) & 1): the non-empty subpixels' mean RGB and luminances, Σ 1 / c_s.
      double half_mean[2][3] = {}, half_inverse[2] = {};
      double lum[2][kMaxSubpixelsPerPixel];
      int half_n[2] = {0, 0};
      double inverse = 0;
      uint64_t total = 0;
      int non_empty = 0;
      for (int j = 0; j < S; ++j)
        for (int i = 0; i < S; ++i) {
          const AccumulationCell c = cell(y * S + j, x * S + i);
          if (c.n == 0) continue;
          const double r = double(c.r) / double(c.n), g = double(c.g) / double(c.n), b = double(c.b) / double(c.n);
          mean[0] += r;
          mean[1] += g;
          mean[2] += b;
          inverse += 1.0 / double(c.n);
          total += c.n;
          ++non_empty;
          if (stats) {
            const int h = (x * S + i + y * S + j) & 1;
            half_mean[h][0] += r;
            half_mean[h][1] += g;
            half_mean[h][2] += b;
            half_inverse[h] += 1.0 / double(c.n);
            lum[h][half_n[h]++] = 0.2126 * r + 0.7152 * g + 0.0722 * b;
          }
        }
      out.radiance.set_rgb(
          x, y,
          non_empty ? Vec3(float(mean[0] / non_empty), float(mean[1] / non_empty), float(mean[2] / non_empty))
                    : Vec3(0.f));
      if (with_counts) out.count[p] = saturate_count(total);
      if (stats) {
        if (with_counts) out.effective[p] = non_empty ? float(double(non_empty) * double(non_empty) / inverse) : 0.f;
        for (int h = 0; h < 2; ++h) {
          const int n = half_n[h];
          for (int c = 0; c < 3; ++c)
            out.half_radiance[6 * p + 3 * size_t(h) + size_t(c)] = n ? float(half_mean[h][c] / n) : 0.f;
          out.half_effective[2 * p + size_t(h)] = n ? float(double(n) * double(n) / half_inverse[h]) : 0.f;
          out.half_subpixels[2 * p + size_t(h)] = uint8_t(n);
          double v = -1;
          if (n >= min_subpixels(S)) {
            double avg = 0, scatter = 0;
            for (int k = 0; k < n; ++k) avg += lum[h][k];
            avg /= n;
            for (int k = 0; k < n; ++k) scatter += (lum[h][k] - avg) * (lum[h][k] - avg);
            v = scatter / (double(n) * double(n - 1));
          }
          out.half_variance[2 * p + size_t(h)] = float(v);
        }
      }
    }
  });
}

}  // namespace

PixelReprojection downsample(const SubpixelAccumulation& acc) {
  const int S = acc.subpixels;
  if (S < 1 || acc.width % S != 0 || acc.height % S != 0 || acc.sum.size() != 3 * acc.size() ||
      acc.count.size() != acc.size())
    throw std::invalid_argument("downsample: malformed subpixel accumulation");
  PixelReprojection out;
  downsample_impl(
      acc.width, acc.height, S,
      [&](int gy, int gx) {
        const size_t s = size_t(gy) * size_t(acc.width) + size_t(gx);
        return AccumulationCell{acc.sum[3 * s], acc.sum[3 * s + 1], acc.sum[3 * s + 2], acc.count[s]};
      },
      {}, &out);
  return out;
}

void downsample_cells(std::span<const AccumulationCell> cells, int grid_w, int grid_h, int S,
                      std::span<const uint8_t> skip, PixelReprojection* out, DownsampleParts parts) {
  if (S < 1 || grid_w % S != 0 || grid_h % S != 0 || cells.size() != size_t(grid_w) * size_t(grid_h))
    throw std::invalid_argument("downsample_cells: malformed subpixel grid");
  downsample_impl(
      grid_w, grid_h, S, [&](int gy, int gx) { return cells[size_t(gy) * size_t(grid_w) + size_t(gx)]; }, skip, out,
      parts);
}

void downsample_bands(std::span<const AccumulationCell* const> bands, int band_rows, int grid_w, int grid_h, int S,
                      std::span<const uint8_t> skip, PixelReprojection* out, DownsampleParts parts) {
  if (S < 1 || grid_w % S != 0 || grid_h % S != 0 || band_rows < 1 ||
      bands.size() != size_t((grid_h + band_rows - 1) / band_rows))
    throw std::invalid_argument("downsample_bands: malformed subpixel grid");
  downsample_impl(
      grid_w, grid_h, S,
      [&](int gy, int gx) {
        return bands[size_t(gy / band_rows)][size_t(gy % band_rows) * size_t(grid_w) + size_t(gx)];
      },
      skip, out, parts);
}

Vec3 combine_pixel(const Vec3& path_sum, uint32_t path_count, uint32_t reprojected_count, const Vec3& lrp,
                   float reprojected_weight) {
  return combine_weighted(path_sum, path_count, double(reprojected_weight) * double(reprojected_count), lrp);
}

Image combine(const Image& path_sum, const std::vector<uint32_t>& path_count, const PixelReprojection& rp,
              float reprojected_weight) {
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
      out.set_rgb(
          x, y,
          combine_pixel(path_sum.rgb(x, y), path_count[p], rp.count[p], rp.radiance.rgb(x, y), reprojected_weight));
    }
  });
  return out;
}

std::vector<uint8_t> skip_mask(const std::vector<uint32_t>& path_count, const std::vector<uint32_t>& reprojected_count,
                               uint64_t target_samples, uint32_t min_paths, float reprojected_weight) {
  if (path_count.size() != reprojected_count.size())
    throw std::invalid_argument(fmt::format("skip_mask: {} path counts but {} reprojected counts", path_count.size(),
                                            reprojected_count.size()));
  std::vector<uint8_t> skip(path_count.size());
  for (size_t p = 0; p < skip.size(); ++p)
    skip[p] = skip_pixel(path_count[p], reprojected_count[p], target_samples, min_paths, reprojected_weight);
  return skip;
}

}  // namespace epr
