// Sampling math: sample-then-invert round trips, densities that integrate to one, and the
// counter-based generator's determinism and uniformity.
#include "common/sampling.h"

#include <gtest/gtest.h>

#include <cmath>
#include <set>

#include "common/rng.h"

namespace epr {
namespace {

Vec2 grid_point(int i, int j, int n) { return {(float(i) + 0.5f) / float(n), (float(j) + 0.5f) / float(n)}; }

TEST(Sampling, ConcentricDiskRoundTrip) {
  const int n = 64;
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) {
      const Vec2 u = grid_point(i, j, n);
      const Vec2 p = sample_uniform_disk_concentric(u);
      EXPECT_LE(p.x * p.x + p.y * p.y, 1.0f + 1e-5f);
      const Vec2 back = invert_uniform_disk_concentric(p);
      EXPECT_NEAR(back.x, u.x, 1e-4f) << i << "," << j;
      EXPECT_NEAR(back.y, u.y, 1e-4f) << i << "," << j;
    }
}

TEST(Sampling, CosineHemisphereRoundTripAndPdf) {
  const int n = 64;
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) {
      const Vec2 u = grid_point(i, j, n);
      const Vec3 w = sample_cosine_hemisphere(u);
      EXPECT_NEAR(length(w), 1.f, 1e-5f);
      EXPECT_GE(w.z, 0.f);
      const Vec2 back = invert_cosine_hemisphere(w);
      EXPECT_NEAR(back.x, u.x, 1e-4f);
      EXPECT_NEAR(back.y, u.y, 1e-4f);
    }
  // The pdf integrates to one over the hemisphere (midpoint rule in spherical coordinates).
  const int m = 400;
  double integral = 0;
  for (int a = 0; a < m; ++a) {
    const double theta = (a + 0.5) * (kPi / 2) / m;
    integral += cosine_hemisphere_pdf(float(std::cos(theta))) * std::sin(theta) * (kPi / 2 / m) * 2 * kPi;
  }
  EXPECT_NEAR(integral, 1.0, 1e-3);
}

TEST(Sampling, CosineHemisphereMatchesPdfInHistogram) {
  // Fraction of samples with cos(theta) > c must be 1 - c^2 for the cosine density.
  const int n = 256;
  int above = 0;
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) above += sample_cosine_hemisphere(grid_point(i, j, n)).z > 0.5f;
  EXPECT_NEAR(double(above) / (n * n), 1 - 0.25, 0.01);
}

TEST(Sampling, TriangleRoundTripAndUniformity) {
  const int n = 64;
  int below_half = 0;
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) {
      const Vec2 u = grid_point(i, j, n);
      const Vec2 b = sample_uniform_triangle(u);
      EXPECT_GE(b.x, 0.f);
      EXPECT_GE(b.y, 0.f);
      EXPECT_LE(b.x + b.y, 1.f + 1e-6f);
      const Vec2 back = invert_uniform_triangle(b);
      EXPECT_NEAR(back.x, u.x, 1e-5f);
      EXPECT_NEAR(back.y, u.y, 1e-5f);
      below_half += (1 - b.x - b.y) > 0.5f;  // corner-2 region b2 > 1/2 has a quarter of the area
    }
  EXPECT_NEAR(double(below_half) / (n * n), 0.25, 0.01);
}

TEST(Sampling, PhongLobeRoundTripAndPdf) {
  for (float e : {1.f, 10.f, 200.f}) {
    const int n = 48;
    for (int i = 0; i < n; ++i)
      for (int j = 0; j < n; ++j) {
        const Vec2 u = grid_point(i, j, n);
        const Vec3 w = sample_phong_lobe(u, e);
        EXPECT_NEAR(length(w), 1.f, 1e-5f);
        const Vec2 back = invert_phong_lobe(w, e);
        EXPECT_NEAR(back.x, u.x, 2e-3f) << e;
        EXPECT_NEAR(back.y, u.y, 1e-4f) << e;
      }
    const int m = 20000;
    double integral = 0;
    for (int a = 0; a < m; ++a) {
      const double theta = (a + 0.5) * (kPi / 2) / m;
      integral += phong_lobe_pdf(float(std::cos(theta)), e) * std::sin(theta) * (kPi / 2 / m) * 2 * kPi;
    }
    EXPECT_NEAR(integral, 1.0, 2e-3) << e;
  }
}

TEST(Sampling, DiscreteDistributionFrequencies) {
  const std::vector<float> w = {1, 0, 3, 4};
  DiscreteDistribution d(w);
  EXPECT_FLOAT_EQ(d.pmf(0) + d.pmf(1) + d.pmf(2) + d.pmf(3), 1.f);
  std::vector<int> hits(4, 0);
  const int n = 80000;
  for (int i = 0; i < n; ++i) {
    float pmf, remapped;
    const size_t k = d.sample((float(i) + 0.5f) / float(n), &pmf, &remapped);
    ASSERT_LT(k, 4u);
    EXPECT_FLOAT_EQ(pmf, d.pmf(k));
    EXPECT_GE(remapped, 0.f);
    EXPECT_LT(remapped, 1.f);
    ++hits[k];
  }
  EXPECT_EQ(hits[1], 0);
  EXPECT_NEAR(hits[0] / double(n), 1 / 8.0, 1e-3);
  EXPECT_NEAR(hits[2] / double(n), 3 / 8.0, 1e-3);
  EXPECT_NEAR(hits[3] / double(n), 4 / 8.0, 1e-3);
}

TEST(Sampling, QuarterPiSinCosMatchLibm) {
  for (int i = -1000; i <= 1000; ++i) {
    const float x = (kPi / 4) * float(i) / 1000;
    EXPECT_NEAR(sin_quarter_pi(x), std::sin(double(x)), 2e-7) << x;
    EXPECT_NEAR(cos_quarter_pi(x), std::cos(double(x)), 2e-7) << x;
  }
}

TEST(Sampling, AliasTableFrequenciesMatchWeights) {
  const std::vector<float> w = {1, 0, 3, 4, 0.5f, 7.5f, 0, 2};
  const AliasTable t(w);
  ASSERT_EQ(t.size(), w.size());
  double total = 0, pmf_sum = 0;
  for (float x : w) total += x;
  for (size_t i = 0; i < w.size(); ++i) {
    EXPECT_NEAR(t.pmf(i), w[i] / total, 1e-7);
    pmf_sum += t.pmf(i);
  }
  EXPECT_NEAR(pmf_sum, 1.0, 1e-6);
  // Stratified u: each item's share of [0,1) must be its pmf, up to the grid's resolution.
  std::vector<int> hits(w.size(), 0);
  const int n = 1 << 20;
  for (int i = 0; i < n; ++i) {
    const size_t k = t.sample((float(i) + 0.5f) / float(n));
    ASSERT_LT(k, w.size());
    ++hits[k];
  }
  for (size_t i = 0; i < w.size(); ++i) {
    if (w[i] == 0) {
      EXPECT_EQ(hits[i], 0) << i;
    }
    EXPECT_NEAR(hits[i] / double(n), w[i] / total, 2e-5) << i;
  }
}

TEST(Sampling, AliasTableManyUnequalWeights) {
  // 1000 weights spanning four decades, as an emitter table of mixed lights would.
  std::vector<float> w(1000);
  for (size_t i = 0; i < w.size(); ++i) w[i] = std::pow(10.f, 4 * bits_to_unit_float(hash_key(3, uint32_t(i), 0, 0)));
  const AliasTable t(w);
  double total = 0, pmf_sum = 0;
  for (float x : w) total += x;
  for (size_t i = 0; i < w.size(); ++i) pmf_sum += t.pmf(i);
  EXPECT_NEAR(pmf_sum, 1.0, 1e-5);
  std::vector<int> hits(w.size(), 0);
  const int n = 1 << 22;
  for (int i = 0; i < n; ++i) ++hits[t.sample((float(i) + 0.5f) / float(n))];
  double max_error = 0;
  for (size_t i = 0; i < w.size(); ++i) max_error = std::max(max_error, std::abs(hits[i] / double(n) - w[i] / total));
  EXPECT_LT(max_error, 5e-6);  // a few grid cells of 1 / 2^22 (the mean pmf is 1e-3)
}

TEST(Sampling, AliasTableIsDeterministicAndRejectsBadWeights) {
  const std::vector<float> w = {2, 5, 1, 1, 9};
  const AliasTable a(w), b(w);
  for (int i = 0; i < 1000; ++i) {
    const float u = bits_to_unit_float(hash_key(11, uint32_t(i), 0, 0));
    EXPECT_EQ(a.sample(u), b.sample(u));
  }
  EXPECT_LT(a.sample(0.f), w.size());
  EXPECT_LT(a.sample(0.99999994f), w.size());
  const std::vector<float> zeros = {0, 0}, negative = {1, -1}, nan = {1, std::nanf("")};
  EXPECT_THROW(AliasTable{zeros}, std::invalid_argument);
  EXPECT_THROW(AliasTable{negative}, std::invalid_argument);
  EXPECT_THROW(AliasTable{nan}, std::invalid_argument);
  EXPECT_THROW(AliasTable{std::span<const float>{}}, std::invalid_argument);
}

TEST(Rng, CounterBasedIsDeterministicAndKeyed) {
  SampleStream a(7, 100, 3), b(7, 100, 3), c(7, 100, 4), d(8, 100, 3), e(7, 101, 3);
  const float va = a.next();
  EXPECT_EQ(va, b.next());
  EXPECT_NE(va, c.next());
  EXPECT_NE(va, d.next());
  EXPECT_NE(va, e.next());
  EXPECT_NE(a.next(), va);  // the next dimension differs
  // The stream is the keyed hash, dimension after dimension.
  SampleStream f(123456789, 77, 5);
  for (uint32_t d = 0; d < 40; ++d) EXPECT_EQ(f.next(), bits_to_unit_float(hash_key(123456789, 77, 5, d))) << d;
  const uint64_t bits = hash_key(123456789, 77, 5, 40);
  const Vec2 pair = f.next2();
  EXPECT_EQ(pair.x, bits_to_unit_float(bits));
  EXPECT_EQ(pair.y, bits_to_unit_float(bits << 24));
  EXPECT_EQ(f.dimension(), 41u);
}

TEST(Rng, PairsAreUniformAndUncorrelated) {
  double sx = 0, sy = 0, sxy = 0, syy = 0;
  const int n = 200000;
  for (int i = 0; i < n; ++i) {
    SampleStream s(5, uint32_t(i), 0);
    const Vec2 p = s.next2();
    ASSERT_GE(p.y, 0.f);
    ASSERT_LT(p.y, 1.f);
    sx += p.x;
    sy += p.y;
    sxy += double(p.x) * p.y;
    syy += double(p.y) * p.y;
  }
  sx /= n, sy /= n, sxy /= n, syy /= n;
  EXPECT_NEAR(sy, 0.5, 3e-3);
  EXPECT_NEAR(syy - sy * sy, 1.0 / 12, 2e-3);
  EXPECT_NEAR((sxy - sx * sy) * 12, 0.0, 0.01);  // correlation coefficient
}

TEST(Rng, UniformMoments) {
  double sum = 0, sum2 = 0;
  const int n = 200000;
  for (int i = 0; i < n; ++i) {
    const float u = bits_to_unit_float(hash_key(1, uint32_t(i), 0, 0));
    ASSERT_GE(u, 0.f);
    ASSERT_LT(u, 1.f);
    sum += u;
    sum2 += double(u) * u;
  }
  EXPECT_NEAR(sum / n, 0.5, 3e-3);
  EXPECT_NEAR(sum2 / n - (sum / n) * (sum / n), 1.0 / 12, 2e-3);
}

}  // namespace
}  // namespace epr
