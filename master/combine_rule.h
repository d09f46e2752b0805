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
// Inverse-variance weights would give L = (Σ_M + M'_eq L_rp) / (M + M'_eq), M'_eq = W σ̂² / v_rp, but
// weights estimated from the samples they weigh are correlated with them (a low set of samples has a
// small spread and gets more weight) and bias the image low. So the samples are split in two halves
// h = 0, 1 -- the path samples by the parity of the round they were traced in, the reprojected ones by
// subpixel checkerboard ((sx + sy) & 1) -- and each half is weighed by the OTHER half's variances only
// (cross-weighting, combine_halves):
//   Q_h = W σ̂²_o / (v_rp,o n_o / n_h)    (o the other half, n its non-empty subpixels)
//   L_h = (Σ_h + Q_h L_rp,h) / (M_h + Q_h),   L = Σ_h c_h L_h / Σ_h c_h,   c_h = M_h + W M'_eff,h,
// so every weight is independent of the values it multiplies and E[L] is the estimates' common
// mean. W discounts σ̂² for the stratification of the pixel's own paths (W = 1: plain inverse-variance
// weights), so that a pixel whose v_rp is what M'_eff independent samples give weighs L_rp as the fixed
// rule does. Where the other half's σ̂² or v_rp is undefined (too few rounds or subpixels: too noisy to
// weigh by) or both are 0, Q_h falls back to W M'_eff,h; v_rp = 0 < σ̂² gives L_rp,h alone. (σ̂² and
// v_rp above are then those of one half: its rounds, its subpixels.) Unbiased, but weights from half
// the samples are noisy: measured, it has more error than the fixed rule (BENCHMARKS.md 20).
// M'_eff = n² / Σ_s (1 / c_s): the samples of equal variance that the average of subpixel means is
// worth (M' when the counts are even, fewer when they are not). The skip rule counts N_eff =
// M + W M'_eff, which uses only counts: M and the subpixel counts are integers, the same in a
// cluster as in one process, so the decisions are too (radiance sums agree only to float rounding).
#pragma once

#include <algorithm>
#include <cstdint>

#include "common/math.h"

namespace epr {

/// Subpixels with samples a half of a pixel of S x S subpixels needs before its v_rp is estimated: 4
/// (at least 3 degrees of freedom), or the whole half when it has fewer (at least 2).
inline int min_subpixels(int subpixels) { return std::clamp(subpixels * subpixels / 2, 2, 4); }
/// Rounds a half needs before its path variance is estimated (at least 3 degrees of freedom).
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

/// One half of a pixel's samples (see above): its diffuse path sum Σ_h over M_h paths and their
/// variance σ̂²_h (-1: undefined), and its reprojected estimate L_rp,h, the average of n_h non-empty
/// subpixel means, with M'_eff,h and v_rp,h (-1: undefined).
struct CombineHalf {
  Vec3 path_sum{0.f};
  double paths = 0;
  double path_variance = -1;
  Vec3 lrp{0.f};
  int subpixels = 0;
  double effective = 0;
  double rp_variance = -1;
};

/// The cross-weighted combination Σ_h c_h L_h / Σ_h c_h of two halves, per channel; `weight` W per
/// unit of M'_eff (the fallback's), `discount` W (reprojected_worth). 0 if both halves are empty.
Vec3 combine_halves(const CombineHalf& a, const CombineHalf& b, double weight, double discount);

/// The skip rule's effective sample count N_eff = M + W M'_eff.
inline double effective_samples(uint64_t path_count, double reprojected_effective, float reprojected_weight) {
  return double(path_count) + double(reprojected_weight) * reprojected_effective;
}

}  // namespace epr
