// The variance combination (master/combine_rule.h) on synthetic pixels with known variances: the
// batch moments of the path samples, v_rp from the spread of subpixel means (downsample_cells with
// statistics) and the combined estimate, against the two estimates alone and the fixed rule; and the
// skip rule's effective count M'_eff on hand-made subpixel counts.
#include "master/combine_rule.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <random>
#include <span>
#include <vector>

#include "common/render_options.h"
#include "master/reprojection_image.h"

namespace epr {
namespace {

// One synthetic pixel of true value `mu`: P = 64 path samples in the default round schedule, and
// kS x kS subpixels of `per_subpixel` reprojected samples each. Samples are mu plus noise
// of the given per-sample standard deviation (normal), or, with `skew`, mu times an exponential variate
// (standard deviation mu: rare bright samples, as in light transport) or a lognormal one (exp(Z - 1/2),
// standard deviation 1.31 mu, rarer and brighter ones).
enum class Skew { kNone, kExponential, kLognormal };
struct SyntheticPixel {
  double mu = 1, sigma_path = 1, sigma_rp = 1;
  uint32_t per_subpixel = 12;
  Skew skew = Skew::kNone;
};

struct Estimates {
  double path, rp, variance_rule, fixed_rule;
  double same_sample;  // inverse-variance weights estimated from the very samples they weigh
};

constexpr int kS = 4;

// The weighting the cross-weighted rule replaced: M'_eq = σ̂² / v_rp from all the pixel's samples.
double same_sample_worth(double m2, uint32_t rounds, std::span<const AccumulationCell> cells, double fallback) {
  std::vector<double> means;
  for (const AccumulationCell& c : cells)
    if (c.n > 0) means.push_back(double(c.r) / double(c.n));
  double avg = 0, scatter = 0;
  for (double m : means) avg += m / double(means.size());
  for (double m : means) scatter += (m - avg) * (m - avg);
  const double n = double(means.size());
  return reprojected_worth(path_sample_variance(m2, rounds), n >= 8 ? scatter / (n * (n - 1)) : -1, fallback);
}

Estimates estimate(const SyntheticPixel& px, std::mt19937_64& rng) {
  std::normal_distribution<double> normal(0, 1);
  std::exponential_distribution<double> expo(1);
  const auto sample = [&](double sigma) {
    switch (px.skew) {
      case Skew::kExponential:
        return px.mu * expo(rng);
      case Skew::kLognormal:
        return px.mu * std::exp(normal(rng) - 0.5);
      default:
        return px.mu + sigma * normal(rng);
    }
  };
  RenderOptions o;
  o.spp = 64;
  // All paths (the same-sample rule) and per half: rounds of even and odd index.
  double sum = 0, m2 = 0, half_sum[2] = {}, half_m2[2] = {};
  uint32_t m = 0, rounds = 0, half_m[2] = {}, half_rounds[2] = {};
  for (int done = 0, k; (k = round_paths(o, done)) > 0; done += k) {
    double batch = 0;
    for (int i = 0; i < k; ++i) batch += sample(px.sigma_path);
    m2 = add_batch(m2, sum, m, batch, uint32_t(k));
    sum += batch;
    m += uint32_t(k);
    const int h = int(rounds++ & 1);
    half_m2[h] = add_batch(half_m2[h], half_sum[h], half_m[h], batch, uint32_t(k));
    half_sum[h] += batch;
    half_m[h] += uint32_t(k);
    ++half_rounds[h];
  }
  std::vector<AccumulationCell> cells(kS * kS);
  for (AccumulationCell& c : cells) {
    double s = 0;
    for (uint32_t i = 0; i < px.per_subpixel; ++i) s += sample(px.sigma_rp);
    c = {float(s), float(s), float(s), px.per_subpixel};
  }
  PixelReprojection rp;
  rp.statistics = true;
  downsample_cells(cells, kS, kS, kS, {}, &rp);
  const Vec3 lrp = rp.radiance.rgb(0, 0);
  const Vec3 path_sum{float(sum), float(sum), float(sum)};
  const float w = RenderOptions{}.reprojected_weight;
  CombineHalf half[2];
  for (int h = 0; h < 2; ++h) {
    half[h].path_sum = Vec3(float(half_sum[h]));
    half[h].paths = half_m[h];
    half[h].path_variance = path_sample_variance(half_m2[h], half_rounds[h]);
    half[h].lrp = Vec3(rp.half_radiance[3 * size_t(h)]);
    half[h].subpixels = rp.half_subpixels[size_t(h)];
    half[h].effective = rp.half_effective[size_t(h)];
    half[h].rp_variance = rp.half_variance[size_t(h)];
  }
  const double same = same_sample_worth(m2, rounds, cells, double(w) * double(rp.effective[0]));
  return {sum / m, lrp.x, combine_halves(half[0], half[1], w, 1).x, combine_pixel(path_sum, m, rp.count[0], lrp, w).x,
          combine_weighted(path_sum, m, same, lrp).x};
}

struct Errors {
  double path = 0, rp = 0, variance_rule = 0, fixed_rule = 0, same_sample = 0;  // mean squared errors
  double bias = 0, bias_sigma = 0;            // the variance rule's mean error and its sigma
  double same_bias = 0, same_bias_sigma = 0;  // the same for the same-sample weights
};

Errors errors(const SyntheticPixel& px, int trials, uint64_t seed) {
  std::mt19937_64 rng(seed);
  Errors e;
  double sum_err = 0, sum_err2 = 0, same_err = 0, same_err2 = 0;
  for (int t = 0; t < trials; ++t) {
    const Estimates x = estimate(px, rng);
    e.path += (x.path - px.mu) * (x.path - px.mu);
    e.rp += (x.rp - px.mu) * (x.rp - px.mu);
    e.variance_rule += (x.variance_rule - px.mu) * (x.variance_rule - px.mu);
    e.fixed_rule += (x.fixed_rule - px.mu) * (x.fixed_rule - px.mu);
    e.same_sample += (x.same_sample - px.mu) * (x.same_sample - px.mu);
    sum_err += x.variance_rule - px.mu;
    sum_err2 += (x.variance_rule - px.mu) * (x.variance_rule - px.mu);
    same_err += x.same_sample - px.mu;
    same_err2 += (x.same_sample - px.mu) * (x.same_sample - px.mu);
  }
  for (double* v : {&e.path, &e.rp, &e.variance_rule, &e.fixed_rule, &e.same_sample}) *v /= trials;
  e.bias = sum_err / trials;
  e.bias_sigma = std::sqrt((sum_err2 / trials - e.bias * e.bias) / trials);
  e.same_bias = same_err / trials;
  e.same_bias_sigma = std::sqrt((same_err2 / trials - e.same_bias * e.same_bias) / trials);
  return e;
}

// 4000 trials: each mean squared error is within about 2.2 % (one sigma, sqrt(2 / 4000) for normal
// errors) of its expectation; the estimates share their trials, so their ratios are sharper still.
// The bound "never worse than the better part" is checked as MSE <= 1.15 x the better part's, which
// leaves the loss of weights estimated from one half's 3 to 8 degrees of freedom (several per cent)
// and more than 3 sigma of sampling error.
constexpr int kTrials = 4000;

TEST(VarianceCombination, ReprojectionMuchWorseThanPathsIsLeftOut) {
  // Var(path mean) = 1 / 64; Var(L_rp) = 100 / 192: L_rp is 33x worse.
  const Errors e = errors({1, 1, 10, 12}, kTrials, 1);
  EXPECT_LT(e.path, e.rp / 10);
  EXPECT_LE(e.variance_rule, 1.15 * std::min(e.path, e.rp)) << "path " << e.path << " rp " << e.rp;
  EXPECT_GT(e.fixed_rule, 4 * e.path);  // W = 0.5 counts every reprojected sample, whatever its variance
}

TEST(VarianceCombination, ReprojectionMuchBetterThanPathsDominates) {
  // Var(path mean) = 1 / 64; Var(L_rp) = 0.01 / 192: L_rp is 300x better.
  const Errors e = errors({1, 1, 0.1, 12}, kTrials, 2);
  EXPECT_LT(e.rp, e.path / 10);
  EXPECT_LE(e.variance_rule, 1.15 * std::min(e.path, e.rp)) << "path " << e.path << " rp " << e.rp;
  EXPECT_GT(e.fixed_rule, 4 * e.rp);
}

TEST(VarianceCombination, EqualQualityBeatsBothParts) {
  // Equal per-sample variance: Var(path mean) = 1 / 64, Var(L_rp) = 1 / 192; the optimum is
  // 1 / 256, 0.75 x the better part.
  const Errors e = errors({1, 1, 1, 12}, kTrials, 3);
  EXPECT_LE(e.variance_rule, 0.85 * std::min(e.path, e.rp)) << "path " << e.path << " rp " << e.rp;
}

// Skewed samples: weights estimated from the samples they weigh are correlated with them (a low
// sample set has a low spread and gets more weight), which biases that weighting low; the same
// generator shows it (more than 4 sigma below 0), and the cross-weighted rule within 3 sigma of 0.
// 40000 trials: sigma of the mean error about 0.03 % of the value.
void expect_unbiased(const SyntheticPixel& px, uint64_t seed) {
  const Errors e = errors(px, 10 * kTrials, seed);
  EXPECT_LT(e.same_bias, -4 * e.same_bias_sigma) << "same-sample bias " << e.same_bias << " +- " << e.same_bias_sigma;
  EXPECT_LT(std::abs(e.bias), 3 * e.bias_sigma) << "bias " << e.bias << " +- " << e.bias_sigma;
  EXPECT_LE(e.variance_rule, 1.15 * std::min(e.path, e.rp)) << "path " << e.path << " rp " << e.rp;
  std::printf(
      "bias %+.3f %% +- %.3f %% (same-sample weights %+.3f %% +- %.3f %%); MSE %.5f (same-sample %.5f), path %.5f, rp "
      "%.5f\n",
      100 * e.bias / px.mu, 100 * e.bias_sigma / px.mu, 100 * e.same_bias / px.mu, 100 * e.same_bias_sigma / px.mu,
      e.variance_rule, e.same_sample, e.path, e.rp);
}

TEST(VarianceCombination, ExponentialSamplesAreUnbiased) { expect_unbiased({1, 1, 1, 12, Skew::kExponential}, 4); }

TEST(VarianceCombination, LognormalSamplesAreUnbiased) { expect_unbiased({1, 1, 1, 12, Skew::kLognormal}, 5); }

TEST(VarianceCombination, UndefinedVariancesFallBack) {
  EXPECT_EQ(path_sample_variance(5, kMinRounds - 1), -1);
  EXPECT_DOUBLE_EQ(path_sample_variance(6, 4), 2);
  EXPECT_EQ(reprojected_worth(-1, 0.5, 7), 7);  // σ̂² undefined
  EXPECT_EQ(reprojected_worth(1, -1, 7), 7);    // v_rp undefined
  EXPECT_EQ(reprojected_worth(0, 0, 7), 7);     // both exact: the fixed rule
  EXPECT_EQ(reprojected_worth(1, 0, 7), kWorthLimit);
  EXPECT_DOUBLE_EQ(reprojected_worth(2, 0.5, 7), 4);
}

TEST(VarianceCombination, BatchMomentsEqualTheDirectScatter) {
  // Batches {1}, {3}, {2, 4}: batch means 1, 3, 3 of sizes 1, 1, 2; overall mean 2.5;
  // B = 1 * 1.5^2 + 1 * 0.5^2 + 2 * 0.5^2 = 3.
  double m2 = 0;
  m2 = add_batch(m2, 0, 0, 1, 1);
  m2 = add_batch(m2, 1, 1, 3, 1);
  m2 = add_batch(m2, 4, 2, 6, 2);
  EXPECT_DOUBLE_EQ(m2, 3);
}

// M'_eff = n^2 / sum 1/c_s: the skip rule's count of the reprojected samples.
TEST(EffectiveCount, EvenSubpixelsCountEverySampleUnevenOnesFewer) {
  std::vector<AccumulationCell> cells(16, AccumulationCell{1, 1, 1, 4});
  PixelReprojection rp;
  rp.statistics = true;
  downsample_cells(cells, 4, 4, 4, {}, &rp, DownsampleParts::kCounts);
  EXPECT_EQ(rp.count[0], 64u);
  EXPECT_FLOAT_EQ(rp.effective[0], 64.f);
  // One subpixel with 100 samples, 15 with one: M' = 115 but the average of subpixel means has the
  // variance of 256 / (1/100 + 15) = 17.06 samples.
  for (AccumulationCell& c : cells) c.n = 1;
  cells[5].n = 100;
  downsample_cells(cells, 4, 4, 4, {}, &rp, DownsampleParts::kBoth);
  EXPECT_EQ(rp.count[0], 115u);
  EXPECT_NEAR(rp.effective[0], 256.0 / (0.01 + 15), 1e-3);
  EXPECT_NEAR(effective_samples(10, rp.effective[0], 0.5f), 10 + 0.5 * 256.0 / 15.01, 1e-3);
  // Empty subpixels do not count; none at all: 0.
  for (AccumulationCell& c : cells) c.n = 0;
  cells[0].n = 9;
  downsample_cells(cells, 4, 4, 4, {}, &rp, DownsampleParts::kCounts);
  EXPECT_FLOAT_EQ(rp.effective[0], 9.f);
  cells[0].n = 0;
  downsample_cells(cells, 4, 4, 4, {}, &rp, DownsampleParts::kCounts);
  EXPECT_FLOAT_EQ(rp.effective[0], 0.f);
}

// v_rp,h: the spread of a half's subpixel means' luminance over n_h (n_h - 1), the halves the
// checkerboard (sx + sy) & 1; undefined under 4 subpixels in the half.
TEST(EffectiveCount, ReprojectionVarianceFromEachHalfsSubpixelSpread) {
  std::vector<AccumulationCell> cells(16);
  for (int i = 0; i < 16; ++i) cells[size_t(i)] = {float(i % 2) * 2, float(i % 2) * 2, float(i % 2) * 2, 2};
  PixelReprojection rp;
  rp.statistics = true;
  downsample_cells(cells, 4, 4, 4, {}, &rp);
  // Means alternate 0 and 1 along a row: each half holds four of each, scatter 8 * 0.25 = 2, v = 2 / (8 * 7).
  for (int h = 0; h < 2; ++h) {
    EXPECT_EQ(rp.half_subpixels[size_t(h)], 8);
    EXPECT_NEAR(rp.half_variance[size_t(h)], 2.0 / 56.0, 1e-6);
    EXPECT_FLOAT_EQ(rp.half_effective[size_t(h)], 16.f);  // 8^2 / (8 / 2)
    EXPECT_FLOAT_EQ(rp.half_radiance[3 * size_t(h)], 0.5f);
  }
  // Seven subpixels left: half 0 has (0,0), (2,0), (1,1): undefined; half 1 (1,0), (3,0), (0,1), (2,1)
  // of means 1, 1, 0, 0: scatter 1, v = 1 / 12.
  for (int i = 7; i < 16; ++i) cells[size_t(i)].n = 0;
  downsample_cells(cells, 4, 4, 4, {}, &rp);
  EXPECT_EQ(rp.half_subpixels[0], 3);
  EXPECT_EQ(rp.half_variance[0], -1.f);
  EXPECT_NEAR(rp.half_radiance[0], 1.0 / 3.0, 1e-6);
  EXPECT_EQ(rp.half_subpixels[1], 4);
  EXPECT_NEAR(rp.half_variance[1], 1.0 / 12.0, 1e-6);
}

// Each half is weighed by the other half's variances: values in half 0 do not change half 0's weight.
TEST(VarianceCombination, AHalfsWeightComesFromTheOtherHalf) {
  CombineHalf a, b;
  a.path_sum = Vec3(8.f);  // 8 paths of mean 1
  a.paths = 8;
  a.path_variance = 1;
  a.lrp = Vec3(2.f);
  a.subpixels = 8;
  a.effective = 16;
  a.rp_variance = 0.5;
  b = a;
  b.path_sum = Vec3(24.f);  // 24 paths of mean 1
  b.paths = 24;
  // c_a = 8 + 0.5 * 16 = 16, c_b = 24 + 8 = 32.
  const auto mix = [](double la, double lb) { return (16 * la + 32 * lb) / 48; };
  // Q_a = σ̂²_b / v_b = 1 / 0.5 = 2: L_a = (8 + 2 * 2) / (8 + 2) = 1.2; Q_b = 2: L_b = 28 / 26.
  EXPECT_NEAR(combine_halves(a, b, 0.5, 1).x, mix(1.2, 28.0 / 26.0), 1e-6);
  // Half b's variances weigh a's L_rp: σ̂²_b = 4 gives Q_a = 8, L_a = (8 + 16) / 16 = 1.5; b's own
  // weight stays Q_b = σ̂²_a / v_a = 2 (weights from the own half would give L_a = 1.2, L_b = 1.25).
  b.path_variance = 4;
  EXPECT_NEAR(combine_halves(a, b, 0.5, 1).x, mix(1.5, 28.0 / 26.0), 1e-6);
  // Half a's variances change only L_b: σ̂²_a = 100 gives Q_b = 200, L_b = (24 + 400) / 224; L_a stays 1.5.
  a.path_variance = 100;
  EXPECT_NEAR(combine_halves(a, b, 0.5, 1).x, mix(1.5, 424.0 / 224.0), 1e-6);
  // Undefined variances: each half falls back to W M'_eff of its own, 8: L_a = 1.5, L_b = 40 / 32.
  b.rp_variance = -1;
  a.path_variance = -1;
  EXPECT_NEAR(combine_halves(a, b, 0.5, 1).x, mix(1.5, 1.25), 1e-6);
}

}  // namespace
}  // namespace epr
