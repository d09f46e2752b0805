// The eye-path samplers (common/sampler.h): Sobol-Burley's (0,2)-net structure, unscrambled and
// scrambled, at every dimension set; determinism and range; the independent sampler's bit identity
// with SampleStream; and convergence rates on analytic integrands, Sobol-Burley against independent.
#include "common/sampler.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <functional>
#include <numbers>
#include <set>
#include <vector>

namespace epr {
namespace {

// True if the 2^k points (x[i], y[i]) (32-bit fractions) put exactly one point in every elementary
// interval [a 2^-j, (a+1) 2^-j) x [b 2^-(k-j), (b+1) 2^-(k-j)), j = 0..k: a (0,k,2)-net.
bool is_02_net(const std::vector<uint32_t>& x, const std::vector<uint32_t>& y, int k) {
  const size_t n = size_t(1) << k;
  if (x.size() != n || y.size() != n) return false;
  for (int j = 0; j <= k; ++j) {
    std::vector<int> count(n, 0);
    for (size_t i = 0; i < n; ++i) {
      const uint64_t cx = j == 0 ? 0 : x[i] >> (32 - j);
      const uint64_t cy = k - j == 0 ? 0 : y[i] >> (32 - (k - j));
      ++count[size_t((cx << (k - j)) | cy)];
    }
    for (int c : count)
      if (c != 1) return false;
  }
  return true;
}

// True if the 2^k values put one in every interval [a 2^-k, (a+1) 2^-k).
bool is_stratified_1d(const std::vector<uint32_t>& x, int k) {
  std::vector<int> count(size_t(1) << k, 0);
  for (uint32_t v : x) ++count[k == 0 ? 0 : v >> (32 - k)];
  for (int c : count)
    if (c != 1) return false;
  return true;
}

TEST(Sobol, MatricesAreTheKnownFirstColumns) {
  // Dimension 1 (x + 1): 1, 0.75, 0.625, 0.9375 as the first direction numbers' leading bits.
  EXPECT_EQ(sobol::kMatrices[1][0], 0x80000000u);
  EXPECT_EQ(sobol::kMatrices[1][1], 0xc0000000u);
  EXPECT_EQ(sobol::kMatrices[1][2], 0xa0000000u);
  EXPECT_EQ(sobol::kMatrices[1][3], 0xf0000000u);
  // Dimension 2 (x^2 + x + 1, m = 1, 3): v_2 = v_0 ^ (v_0 >> 2) ^ v_1.
  EXPECT_EQ(sobol::kMatrices[2][0], 0x80000000u);
  EXPECT_EQ(sobol::kMatrices[2][1], 0xc0000000u);
  EXPECT_EQ(sobol::kMatrices[2][2], 0x60000000u);
  // Every matrix is upper triangular with a unit diagonal (column k's lowest set bit is bit k from
  // the top): each coordinate on its own is a (0,1)-sequence.
  for (int d = 0; d < sobol::kDimensions; ++d)
    for (int k = 0; k < 32; ++k) {
      const uint32_t v = sobol::kMatrices[size_t(d)][size_t(k)];
      EXPECT_EQ((v >> (31 - k)) & 1u, 1u) << d << " " << k;
      EXPECT_EQ(v & ((1u << (31 - k)) - 1u), 0u) << d << " " << k;
    }
}

TEST(Sobol, UnscrambledFirstTwoDimensionsAreA02Sequence) {
  for (int k = 0; k <= 12; ++k)
    for (uint32_t block : {0u, 1u, 5u, 1000u}) {
      std::vector<uint32_t> x, y;
      for (uint32_t i = 0; i < (1u << k); ++i) {
        x.push_back(sobol::sample((block << k) + i, 0));
        y.push_back(sobol::sample((block << k) + i, 1));
      }
      EXPECT_TRUE(is_02_net(x, y, k)) << "k " << k << " block " << block;
    }
}

TEST(Sobol, OwenScrambleIsABijectionThatKeepsPrefixes) {
  // A nested uniform scramble permutes the 2^j intervals of width 2^-j for every j, and points
  // sharing their top j bits still share their top j bits after it.
  for (uint32_t seed : {0u, 1u, 0xdeadbeefu}) {
    std::set<uint32_t> prefixes;
    for (uint32_t i = 0; i < 4096; ++i) prefixes.insert(sobol::owen_scramble(i << 20, seed) >> 20);
    EXPECT_EQ(prefixes.size(), 4096u);
    for (uint32_t a : {0x12345678u, 0x9abcdef0u}) {
      const uint32_t b = a ^ 0x0000ffffu;  // same top 16 bits
      EXPECT_EQ(sobol::owen_scramble(a, seed) >> 16, sobol::owen_scramble(b, seed) >> 16);
      EXPECT_NE(sobol::owen_scramble(a, seed), sobol::owen_scramble(b, seed));
    }
  }
}

TEST(SobolBurley, EverySetsFirstSamplesAreNetsAndContinue) {
  // Scrambled and shuffled: the first 2^k samples of any pixel's 2-D set, and the first two
  // coordinates of a 3-D set, are (0,k,2)-nets for every k, so a pixel's sequence stays stratified as
  // progressive rounds add samples; each coordinate of a 3-D set is stratified on its own.
  for (uint64_t seed : {1ull, 77ull})
    for (uint32_t pixel : {0u, 1u, 511u, 262143u})
      for (uint32_t set : {0u, 1u, 2u, 3u, 31u, 94u, 3000u}) {
        const SobolBurleyPixel p(seed, pixel);
        for (int k = 0; k <= 10; ++k) {
          std::vector<uint32_t> c[3];
          for (uint32_t i = 0; i < (1u << k); ++i) {
            uint32_t v[3];
            p.sample(set, i, 3, v);
            for (int d = 0; d < 3; ++d) c[d].push_back(v[d]);
          }
          EXPECT_TRUE(is_02_net(c[0], c[1], k)) << seed << " " << pixel << " " << set << " k " << k;
          for (int d = 0; d < 3; ++d) EXPECT_TRUE(is_stratified_1d(c[d], k)) << d;
        }
      }
}

TEST(SobolBurley, PointsAreTheScrambledSobolPointsOfTheDefinition) {
  // sample() leaves out the bit reversals that cancel; its values must be those of the definition:
  // the index Owen-scrambled (the shuffle), its Sobol point, each coordinate Owen-scrambled, with
  // owen_scramble written out bit by bit (bit k flipped by a hash of the bits above it).
  auto reverse = [](uint32_t x) {
    uint32_t r = 0;
    for (int k = 0; k < 32; ++k) r |= ((x >> k) & 1u) << (31 - k);
    return r;
  };
  auto owen = [&](uint32_t x, uint32_t seed) {
    uint32_t y = reverse(x);
    y ^= y * 0x3d20adeau;
    y += seed;
    y *= (seed >> 16) | 1u;
    y ^= y * 0x05526c56u;
    y ^= y * 0x53a22864u;
    return reverse(y);
  };
  auto sobol_point = [](uint32_t index, int d) {
    uint32_t x = 0;
    for (int k = 0; k < 32; ++k)
      if ((index >> k) & 1u) x ^= sobol::kMatrices[size_t(d)][size_t(k)];
    return x;
  };
  for (uint32_t x : {0u, 1u, 0x80000000u, 0x12345678u, 0xffffffffu}) EXPECT_EQ(sobol::reverse_bits(x), reverse(x));
  for (uint64_t seed : {2ull, 991ull})
    for (uint32_t pixel : {0u, 77u, 262143u}) {
      const SobolBurleyPixel p(seed, pixel);
      const uint64_t key = mix64(mix64(seed ^ 0x2545f4914f6cdd1dULL) + (uint64_t(pixel) + 1) * 0x9e3779b97f4a7c15ULL);
      for (uint32_t set : {0u, 1u, 5u, 3000u})
        for (uint32_t index : {0u, 1u, 2u, 3u, 100u, 65535u, 65536u, 0x7fffffffu, 0xfffffffeu}) {
          const uint64_t h = hash_dimension(key, set);
          const uint32_t shuffled = owen(index, uint32_t(h));
          uint32_t v[3];
          p.sample(set, index, 3, v);
          for (int d = 0; d < 3; ++d) {
            EXPECT_EQ(sobol::sample_reversed(index, d), reverse(sobol::sample(index, d))) << d;
            EXPECT_EQ(v[d], owen(sobol_point(shuffled, d), uint32_t(mix64(h + uint64_t(d + 1)) >> 32)))
                << seed << " " << pixel << " " << set << " " << index << " " << d;
          }
        }
    }
}

TEST(SobolBurley, InUnitIntervalDeterministicAndPixelsDiffer) {
  std::set<uint64_t> firsts;
  for (uint32_t pixel = 0; pixel < 2000; ++pixel) {
    const SobolBurleyPixel p(3, pixel), again(3, pixel);
    for (uint32_t set = 0; set < 8; ++set)
      for (uint32_t i = 0; i < 16; ++i) {
        const Vec3 a = p.sample3(set, i), b = again.sample3(set, i);
        for (float v : {a.x, a.y, a.z}) {
          EXPECT_GE(v, 0.f);
          EXPECT_LT(v, 1.f);
        }
        EXPECT_EQ(a.x, b.x);
        EXPECT_EQ(a.y, b.y);
        EXPECT_EQ(a.z, b.z);
      }
    uint32_t v[2];
    p.sample(0, 0, 2, v);
    firsts.insert((uint64_t(v[0]) << 32) | v[1]);
  }
  EXPECT_EQ(firsts.size(), 2000u);  // every pixel's first film sample differs
  // Another seed gives other points; sets of one pixel are decorrelated (different points).
  EXPECT_NE(SobolBurleyPixel(3, 7).sample2(0, 5).x, SobolBurleyPixel(4, 7).sample2(0, 5).x);
  EXPECT_NE(SobolBurleyPixel(3, 7).sample2(0, 5).x, SobolBurleyPixel(3, 7).sample2(4, 5).x);
}

TEST(PathSampler, IndependentIsTheSampleStreamOrder) {
  for (uint32_t pixel : {0u, 9u, 4000u})
    for (uint32_t sample : {0u, 1u, 63u}) {
      PathSampler ps(SamplerKind::kIndependent, 5, pixel, sample);
      SampleStream s(5, pixel, sample);
      const Vec2 f = ps.film(), g = s.next2();
      EXPECT_EQ(f.x, g.x);
      EXPECT_EQ(f.y, g.y);
      for (int bounce = 0; bounce < 12; ++bounce) {
        const PathSampler::Bounce b = ps.bounce();
        EXPECT_EQ(b.light_select, s.next());
        const Vec2 point = s.next2(), rr_lobe = s.next2(), dir = s.next2();
        EXPECT_EQ(b.light_point.x, point.x);
        EXPECT_EQ(b.light_point.y, point.y);
        EXPECT_EQ(b.rr, rr_lobe.x);
        EXPECT_EQ(b.lobe, rr_lobe.y);
        EXPECT_EQ(b.dir.x, dir.x);
        EXPECT_EQ(b.dir.y, dir.y);
      }
    }
}

TEST(PathSampler, SobolBurleyFollowsTheDimensionLayout) {
  const SobolBurleyPixel p(8, 1234);
  PathSampler ps(SamplerKind::kSobolBurley, 8, 1234, 77);
  const Vec2 f = ps.film();
  EXPECT_EQ(f.x, p.sample2(0, 77).x);
  EXPECT_EQ(f.y, p.sample2(0, 77).y);
  for (uint32_t bounce = 0; bounce < 5; ++bounce) {
    const PathSampler::Bounce b = ps.bounce();
    const Vec3 light = p.sample3(1 + 3 * bounce, 77);
    EXPECT_EQ(b.light_point.x, light.x);
    EXPECT_EQ(b.light_point.y, light.y);
    EXPECT_EQ(b.light_select, light.z);
    EXPECT_EQ(b.rr, p.sample2(2 + 3 * bounce, 77).x);
    EXPECT_EQ(b.lobe, p.sample2(2 + 3 * bounce, 77).y);
    EXPECT_EQ(b.dir.x, p.sample2(3 + 3 * bounce, 77).x);
    EXPECT_EQ(b.dir.y, p.sample2(3 + 3 * bounce, 77).y);
  }
}

// ---- convergence rates ------------------------------------------------------------------------------

using Integrand = std::function<double(Vec2)>;
using Draw = std::function<Vec2(PathSampler&)>;

// Least-squares slope of log(RMS error) against log(N), N = 16, 32, ..., 1024; the RMS over `pixels`
// pixels, each estimating the integral with its own first N samples of `draw`.
struct Rate {
  double slope;
  double rms_at_1024;
};
Rate convergence(SamplerKind kind, const Integrand& f, double exact, const Draw& draw, uint32_t pixels) {
  const std::vector<int> ns{16, 32, 64, 128, 256, 512, 1024};
  std::vector<double> sq(ns.size(), 0.0);
  for (uint32_t pixel = 0; pixel < pixels; ++pixel) {
    double sum = 0;
    size_t next = 0;
    for (int i = 0; i < ns.back(); ++i) {
      PathSampler ps(kind, 11, pixel, uint32_t(i));
      sum += f(draw(ps));
      if (i + 1 == ns[next]) {
        const double e = sum / ns[next] - exact;
        sq[next++] += e * e;
      }
    }
  }
  double sx = 0, sy = 0, sxx = 0, sxy = 0;
  for (size_t j = 0; j < ns.size(); ++j) {
    const double x = std::log(double(ns[j])), y = 0.5 * std::log(sq[j] / pixels);
    sx += x;
    sy += y;
    sxx += x * x;
    sxy += x * y;
  }
  const double n = double(ns.size());
  const Rate r{(n * sxy - sx * sy) / (n * sxx - sx * sx), std::sqrt(sq.back() / pixels)};
  std::printf("%s: slope %.3f, RMS at N = 1024 %.3g\n", to_string(kind), r.slope, r.rms_at_1024);
  return r;
}

const Integrand kSmooth = [](Vec2 u) { return std::exp(double(u.x)) * std::sin(std::numbers::pi * double(u.y)); };
const double kSmoothExact = (std::numbers::e - 1) * 2 / std::numbers::pi;
const Integrand kDisc = [](Vec2 u) {
  const double dx = u.x - 0.5, dy = u.y - 0.5;
  return dx * dx + dy * dy < 0.16 ? 1.0 : 0.0;
};
const double kDiscExact = std::numbers::pi * 0.16;

const Draw kFilm = [](PathSampler& ps) { return ps.film(); };
// The BSDF direction pair at the 20th bounce: padding keeps deep dimensions as well distributed.
const Draw kDeepDirection = [](PathSampler& ps) {
  ps.film();
  for (int b = 0; b < 19; ++b) ps.bounce();
  return ps.bounce().dir;
};
// The light point pair of the 3rd bounce (the first two coordinates of a 3-D set).
const Draw kLightPoint = [](PathSampler& ps) {
  ps.film();
  ps.bounce();
  ps.bounce();
  return ps.bounce().light_point;
};

TEST(SamplerConvergence, IndependentFallsAsOneOverSqrtN) {
  for (const auto& [f, exact] : {std::pair{kSmooth, kSmoothExact}, std::pair{kDisc, kDiscExact}}) {
    const Rate r = convergence(SamplerKind::kIndependent, f, exact, kFilm, 512);
    EXPECT_GT(r.slope, -0.6);
    EXPECT_LT(r.slope, -0.4);
  }
}

TEST(SamplerConvergence, SobolBurleySmoothFallsFasterThanIndependent) {
  const Rate indep = convergence(SamplerKind::kIndependent, kSmooth, kSmoothExact, kFilm, 512);
  for (const Draw& draw : {kFilm, kDeepDirection, kLightPoint}) {
    const Rate r = convergence(SamplerKind::kSobolBurley, kSmooth, kSmoothExact, draw, 512);
    // Owen-scrambled nets: RMS ~ N^-1.5 for a smooth integrand.
    EXPECT_LT(r.slope, -1.2);
    EXPECT_LT(r.slope, indep.slope - 0.6);
    EXPECT_LT(r.rms_at_1024, indep.rms_at_1024 / 20);
  }
}

TEST(SamplerConvergence, SobolBurleyDiscontinuityFallsFasterThanIndependent) {
  const Rate indep = convergence(SamplerKind::kIndependent, kDisc, kDiscExact, kFilm, 512);
  for (const Draw& draw : {kFilm, kDeepDirection, kLightPoint}) {
    const Rate r = convergence(SamplerKind::kSobolBurley, kDisc, kDiscExact, draw, 512);
    // A discontinuity along a curve: RMS ~ N^-0.75 for scrambled nets.
    EXPECT_LT(r.slope, -0.65);
    EXPECT_LT(r.slope, indep.slope - 0.15);
    EXPECT_LT(r.rms_at_1024, indep.rms_at_1024 / 3);
  }
}

}  // namespace
}  // namespace epr
