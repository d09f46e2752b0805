// The variance combination of a pixel's two estimates and its effective sample count (DESIGN.md
// "Combining the two estimates", RenderOptions::combine = kVariance). Pure functions.
//
// Pixel p has M path samples (sum Σ_M, mean x̄) and a reprojected estimate L_rp (the average of its n
// non-empty subpixels' means m_s, s with c_s samples each). On luminance Y:
//   path:        σ̂² = B / (R − 1), B = Σ_r k_r (x̄_r − x̄)²  over the R rounds (batches of k_r paths)
//                the pixel traced in: the batch-means estimate of one path's variance, unbiased for
//                any batch sizes; Var(x̄) ≈ σ̂² / M. Undefined for R < kMinRounds.
//   reprojected: v_rp = Σ_s (Y(m_s) − Y(L_rp))² / (n (n − 1)), the variance of the mean of n subpixel
//                means estimated from their spread. One subpixel counts as one sample, whatever the
//                number of (correlated) reprojected samples in it: a conservative effective count
//                (n ≤ S²), and any variation of the radiance inside the pixel counts as noise too.
//                Undefined for n < min_subpixels(S).
// Inverse-variance weights 1/Var(x̄) and 1/v_rp give
//   L = (Σ_M + M'_eq L_rp) / (M + M'_eq),   M'_eq = W σ̂² / v_rp  (the paths L_rp is worth),
// the same form as the fixed rule with W M' replaced by M'_eq; W discounts σ̂² / M for the
// stratification of the pixel's own paths (W = 1: plain inverse-variance weights), so that a pixel
// whose v_rp is what M'_eff independent samples give weighs L_rp as the fixed rule does. Where σ̂² or v_rp is undefined
// (too few rounds or subpixels: their estimates would be too noisy to weigh by) or both are 0, M'_eq falls back to W
// M'_eff; v_rp = 0 < σ̂² gives L_rp alone.
//
// M'_eff = n² / Σ_s (1 / c_s): the samples of equal variance that the average of subpixel means is
// worth (M' when the counts are even, fewer when they are not). The skip rule counts N_eff =
// M + W M'_eff, which uses only counts: M and the subpixel counts are integers, the same in a
// cluster as in one process, so the decisions are too (radiance sums agree only to float rounding).
#pragma once

#include <algorithm>
#include <cstdint>

#include "common/math.h"

namespace epr {

/// Subpixels with samples a pixel of S x S subpixels needs before its v_rp is estimated: 8 (at
/// least 7 degrees of freedom), or all of them when S x S < 8 (at least 2).
inline int min_subpixels(int subpixels) { return subpixels * subpixels < 8 ? std::max(2, subpixels * subpixels) : 8; }
/// Rounds a pixel needs before its path variance is estimated (at least 3 degrees of freedom).
inline constexpr uint32_t kMinRounds = 4;

/// B after one more batch: k paths of luminance sum `batch` added to `count` paths of luminance sum
/// `sum` (Chan et al.'s pairwise update of the batch means' scatter). Unchanged for k = 0.
double add_batch(double m2, double sum, uint32_t count, double batch, uint32_t k);

/// σ̂² = B / (R − 1): one path's variance from the batch scatter of R batches; -1 for R < kMinRounds.
double path_sample_variance(double m2, uint32_t rounds);

/// M'_eq, the paths the reprojected estimate is worth: discount σ̂² / v_rp (kWorthLimit if v_rp = 0 <
/// σ̂²); `fallback` (W M'_eff) when σ̂² < 0 or v_rp < 0 (undefined) or both are 0. `discount` is 1 for
/// independent path samples; the render passes W (a pixel's own Sobol-Burley paths are stratified,
/// so their mean's error is below σ̂² / M, which the batch moments of single-path rounds cannot see).
inline constexpr double kWorthLimit = 1e30;
double reprojected_worth(double path_variance, double reprojection_variance, double fallback, double discount = 1);

/// (Σ_M + worth L_rp) / (M + worth) per channel, in double; 0 if M + worth = 0.
Vec3 combine_weighted(const Vec3& path_sum, uint32_t path_count, double worth, const Vec3& lrp);

/// The skip rule's effective sample count N_eff = M + W M'_eff.
inline double effective_samples(uint64_t path_count, double reprojected_effective, float reprojected_weight) {
  return double(path_count) + double(reprojected_weight) * reprojected_effective;
}

}  // namespace epr
