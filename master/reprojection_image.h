// From the subpixel accumulation to pixels (DESIGN.md section 1, paper 4.2 and 3.4). Pure functions.
//
// Downsampling: for pixel p with subpixels s (S x S of them),
//   mean(s)  = sum(s) / count(s)                      (subpixels with count 0 are skipped)
//   L_rp(p)  = average of mean(s) over p's non-empty subpixels   (0 if all are empty)
//   M'(p)    = sum of count(s)
// Averaging per-subpixel means (not pooling all samples) is the paper's normalisation: a subpixel
// hit by many reprojected points does not dominate its pixel.
// Combination with the M path-traced samples of p (their radiance sum and count), a reprojected
// sample counting for W in (0, 1] of a path (RenderOptions::reprojected_weight, default 1):
//   L(p) = (path_sum(p) + W M'(p) L_rp(p)) / (M(p) + W M'(p)),   0 if M + W M' = 0.
// Skip mask: pixel p traces no new path next round if M + W M' >= P and M >= min_paths.
// (With W = 1, both are the paper's, bit for bit.)
//
// Images are epr::Image (row 0 at the top, 3 channels, linear RGB radiance); counts are row-major
// vectors of width * height pixels. Sizes are checked (std::invalid_argument).
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "common/image.h"

namespace epr {

/// Per-subpixel accumulation, read back from a Reprojector.
struct SubpixelAccumulation {
  int width = 0, height = 0;    // subpixels: S * image width, S * image height
  int subpixels = 4;            // S
  std::vector<float> sum;       // 3 per subpixel: RGB radiance sum
  std::vector<uint32_t> count;  // 1 per subpixel: number of samples
  size_t size() const { return size_t(width) * size_t(height); }
};

/// Area-weighted pixels (DESIGN.md "Edge pixels"; made by detail::EdgePixels): per listed pixel and
/// per subpixel, the surface class its centre sees and the area that class covers in the pixel, in
/// fine samples (at most 511). Such a pixel's L_rp is sum_k A_k R_k / sum_k A_k over its classes k
/// with samples, R_k the mean of the subpixel means of class k; its M' is the count of a stratified
/// mean, 1 / sum_k a_k^2 / C_k (a_k = A_k / sum A, C_k the samples of k's subpixels), its M'_eff
/// 1 / sum_k a_k^2 sum_{s in k} 1 / (n_k^2 c(s)) (n_k of k's subpixels with samples, c(s) their
/// counts), both 0 until every class of non-zero area has samples.
struct AreaWeights {
  static constexpr int kAreaBits = 10;
  std::vector<uint32_t> pixels;  // ascending pixel indices
  std::vector<uint16_t> cells;   // S * S per listed pixel, its subpixels row by row: class << 10 | area
  static uint16_t pack(int cls, int area) { return uint16_t((cls << kAreaBits) | area); }
  static int class_of(uint16_t c) { return c >> kAreaBits; }
  static int area_of(uint16_t c) { return c & ((1 << kAreaBits) - 1); }
};

struct PixelReprojection {
  Image radiance;               // L_rp, 3 channels, width x height pixels
  std::vector<uint32_t> count;  // M', per pixel (saturating at 2^32 - 1)
  // With `statistics` set (master/combine_rule.h): M'_eff per pixel, written with the counts, and
  // per pixel and half h = 0, 1 (its subpixels with (sx + sy) & 1 == h), written with the radiance:
  // L_rp,h (RGB), M'_eff,h, v_rp,h (the variance of L_rp,h's luminance; -1 where undefined) and n_h,
  // the half's non-empty subpixels (0 in both halves of an area-weighted pixel: it is not split).
  bool statistics = false;
  std::vector<float> effective;
  std::vector<float> half_radiance;     // 6 per pixel
  std::vector<float> half_effective;    // 2 per pixel
  std::vector<float> half_variance;     // 2 per pixel
  std::vector<uint8_t> half_subpixels;  // 2 per pixel
  // Pixels downsampled by area (null: none); not owned, set by the caller of a downsampling.
  const AreaWeights* area_weights = nullptr;
};

/// Downsamples an S*W x S*H subpixel accumulation to W x H pixels.
PixelReprojection downsample(const SubpixelAccumulation& acc);

/// What a downsampling computes: both M' and L_rp, M' alone (a skip round's decision needs no
/// radiance, and the sum of counts costs no divisions), or L_rp alone (a preview that keeps M' as it
/// was: no per-pixel count array is made).
enum class DownsampleParts { kBoth, kCounts, kRadiance };

/// One subpixel of an accumulation as the back-ends store it: RGB radiance sum and sample count.
struct AccumulationCell {
  float r = 0, g = 0, b = 0;
  uint32_t n = 0;
};
static_assert(sizeof(AccumulationCell) == 16);

/// The same downsampling straight from a back-end's cells (grid_w x grid_h subpixels, S per axis),
/// without copying the grid first, into *out: only the pixels p with skip[p] == 0 are computed, the
/// others keep their values (every pixel if `skip` is empty or what is written is not of the image's
/// size, in which case it is reallocated). Only the `parts` asked for are written (and allocated);
/// the other member of *out is left as it was, also when empty.
void downsample_cells(std::span<const AccumulationCell> cells, int grid_w, int grid_h, int subpixels,
                      std::span<const uint8_t> skip, PixelReprojection* out,
                      DownsampleParts parts = DownsampleParts::kBoth);
/// The same for a grid kept in bands of `band_rows` grid rows (the last may be shorter): bands[b]
/// holds grid rows [b * band_rows, (b + 1) * band_rows), row-major.
void downsample_bands(std::span<const AccumulationCell* const> bands, int band_rows, int grid_w, int grid_h,
                      int subpixels, std::span<const uint8_t> skip, PixelReprojection* out,
                      DownsampleParts parts = DownsampleParts::kBoth);

/// L(p) of one pixel: (path_sum + W M' L_rp) / (M + W M') in double, 0 if M + W M' = 0
/// (combine_weighted() with W M').
Vec3 combine_pixel(const Vec3& path_sum, uint32_t path_count, uint32_t reprojected_count, const Vec3& lrp,
                   float reprojected_weight = 1.f);
/// L(p) = (path_sum + W M' L_rp) / (M + W M'). `path_sum` is the sum (not the mean) of p's M path samples.
Image combine(const Image& path_sum, const std::vector<uint32_t>& path_count, const PixelReprojection& reprojected,
              float reprojected_weight = 1.f);

/// The samples a pixel counts as having: M + W M' (in double: exact for W = 1).
inline double weighted_samples(uint64_t path_count, uint64_t reprojected_count, float reprojected_weight) {
  return double(path_count) + double(reprojected_weight) * double(reprojected_count);
}
/// The skip rule: M + W M' >= target_samples and M >= min_paths.
inline bool skip_pixel(uint64_t path_count, uint64_t reprojected_count, uint64_t target_samples, uint64_t min_paths,
                       float reprojected_weight) {
  return weighted_samples(path_count, reprojected_count, reprojected_weight) >= double(target_samples) &&
         path_count >= min_paths;
}
/// 1 = skip pixel next round (skip_pixel()), else 0.
std::vector<uint8_t> skip_mask(const std::vector<uint32_t>& path_count, const std::vector<uint32_t>& reprojected_count,
                               uint64_t target_samples, uint32_t min_paths = 1, float reprojected_weight = 1.f);

}  // namespace epr
