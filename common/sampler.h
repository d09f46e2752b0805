// The random numbers of one eye path, a pure function of (seed, pixel, sample index, dimension).
//
// Two samplers (RenderOptions::sampler, `--sampler`):
//   * kSobolBurley (default): Owen-scrambled Sobol points with hash-based scrambling (Burley 2020,
//     "Practical Hash-based Owen Scrambling", JCGT 9(4); what Cycles calls Sobol-Burley). A path's
//     dimensions are grouped into dimension sets of 2 or 3; set j of pixel p takes point number
//     shuffle(s) of the first 2 or 3 Sobol dimensions, where s is the pixel's global sample number,
//     shuffle a nested uniform (Owen) scramble of the index seeded by hash(seed, p, j), and every
//     coordinate is then Owen-scrambled by its own hash(seed, p, j, coordinate). The sets are
//     "padded": each has its own index shuffle and scrambles, so sets are independent of each other
//     while each one is a well-distributed sequence on its own, at any depth of the path. The first
//     2^k samples of a pixel's 2-D set are a (0,k,2)-net (one point in every elementary interval of
//     area 2^-k); samples 2^k .. 2^(k+1)-1 complete them to a (0,k+1,2)-net, so progressive rounds
//     that continue a pixel's sample numbers continue its sequence, and a skipped pixel just stops.
//   * kIndependent: common/rng.h's SampleStream, every dimension an independent hash: the random
//     numbers of the tracer before the Sobol-Burley sampler existed, in the same order.
//
// Dimension layout of a path (both samplers consume it in this order):
//   film:            set 0, 2-D             jitter within the pixel
//   bounce b >= 0 (vertex x_{b+1}):
//     light:         set 1 + 3b, 3-D        (point on the triangle: 2-D, emitter selection: 1-D)
//     roulette/lobe: set 2 + 3b, 2-D        (Russian roulette, BSDF lobe selection)
//     direction:     set 3 + 3b, 2-D        BSDF direction
// The independent sampler draws film next2(), then per bounce next() (selection), next2() (point),
// next2() (roulette, lobe), next2() (direction) from one SampleStream.
#pragma once

#include <array>
#include <bit>
#include <cstdint>
#include <optional>
#include <string_view>

#include "common/math.h"
#include "common/rng.h"

namespace epr {

enum class SamplerKind : uint8_t { kSobolBurley, kIndependent };

const char* to_string(SamplerKind k);  // "sobol-burley", "independent"
std::optional<SamplerKind> parse_sampler(std::string_view name);

namespace sobol {

inline constexpr int kDimensions = 3;

// Generator matrices of the first three Sobol dimensions as 32 direction numbers each (column k:
// the bits contributed by bit k of the index, most significant output bit first). Dimension 0 is
// the van der Corput sequence; dimensions 1 and 2 use the primitive polynomials x + 1 and
// x^2 + x + 1 with initial numbers m = {1} and m = {1, 3}: the first two entries of S. Joe and
// F. Y. Kuo's new-joe-kuo-6.21201 table (web.maths.unsw.edu.au/~fkuo/sobol/), recurrence of
// Bratley and Fox (ACM TOMS 14(1), 1988).
constexpr std::array<std::array<uint32_t, 32>, kDimensions> make_matrices() {
  struct Poly {
    int s;
    uint32_t a;
    uint32_t m[2];
  };
  constexpr Poly polys[2] = {{1, 0, {1, 0}}, {2, 1, {1, 3}}};
  std::array<std::array<uint32_t, 32>, kDimensions> v{};
  for (int k = 0; k < 32; ++k) v[0][size_t(k)] = 1u << (31 - k);
  for (int d = 1; d < kDimensions; ++d) {
    const Poly& p = polys[d - 1];
    auto& vd = v[size_t(d)];
    for (int k = 0; k < 32; ++k) {
      if (k < p.s) {
        vd[size_t(k)] = p.m[k] << (31 - k);
        continue;
      }
      uint32_t x = vd[size_t(k - p.s)] ^ (vd[size_t(k - p.s)] >> p.s);
      for (int j = 1; j < p.s; ++j)
        if ((p.a >> (p.s - 1 - j)) & 1u) x ^= vd[size_t(k - j)];
      vd[size_t(k)] = x;
    }
  }
  return v;
}
inline constexpr auto kMatrices = make_matrices();

// The matrices by bytes of the index: kByteTables[dim][b][v] is the XOR of the columns that byte b
// of the index selects when it holds v, so that a point takes four table reads (12 KiB in all).
constexpr std::array<std::array<std::array<uint32_t, 256>, 4>, kDimensions> make_byte_tables() {
  std::array<std::array<std::array<uint32_t, 256>, 4>, kDimensions> t{};
  for (size_t d = 0; d < size_t(kDimensions); ++d)
    for (size_t b = 0; b < 4; ++b)
      for (uint32_t v = 0; v < 256; ++v) {
        uint32_t x = 0;
        for (size_t bit = 0; bit < 8; ++bit)
          if ((v >> bit) & 1u) x ^= kMatrices[d][b * 8 + bit];
        t[d][b][v] = x;
      }
  return t;
}
inline constexpr auto kByteTables = make_byte_tables();

/// Unscrambled Sobol point `index`, dimension `dim` < kDimensions, as a 32-bit fraction.
constexpr uint32_t sample(uint32_t index, int dim) {
  const auto& t = kByteTables[size_t(dim)];
  return t[0][index & 0xffu] ^ t[1][(index >> 8) & 0xffu] ^ t[2][(index >> 16) & 0xffu] ^ t[3][index >> 24];
}

constexpr uint32_t reverse_bits(uint32_t x) {
  x = ((x & 0xaaaaaaaau) >> 1) | ((x & 0x55555555u) << 1);
  x = ((x & 0xccccccccu) >> 2) | ((x & 0x33333333u) << 2);
  x = ((x & 0xf0f0f0f0u) >> 4) | ((x & 0x0f0f0f0fu) << 4);
  return __builtin_bswap32(x);
}

// reverse_bits(sample(index, dim)) by bytes of the index, as kByteTables: the bit order in which
// Owen scrambling works, so that a scrambled coordinate takes one bit reversal instead of two.
constexpr std::array<std::array<std::array<uint32_t, 256>, 4>, kDimensions> make_reversed_byte_tables() {
  std::array<std::array<std::array<uint32_t, 256>, 4>, kDimensions> t{};
  for (size_t d = 0; d < size_t(kDimensions); ++d)
    for (size_t b = 0; b < 4; ++b)
      for (uint32_t v = 0; v < 256; ++v) t[d][b][v] = reverse_bits(kByteTables[d][b][v]);
  return t;
}
inline constexpr auto kReversedByteTables = make_reversed_byte_tables();

/// reverse_bits(sample(index, dim)). Dimension 0 (van der Corput) is the index itself.
constexpr uint32_t sample_reversed(uint32_t index, int dim) {
  if (dim == 0) return index;
  const auto& t = kReversedByteTables[size_t(dim)];
  return t[0][index & 0xffu] ^ t[1][(index >> 8) & 0xffu] ^ t[2][(index >> 16) & 0xffu] ^ t[3][index >> 24];
}

/// Nested uniform (Owen) scramble of a 32-bit fraction: bit k (from the top) is flipped by a hash of
/// the seed and the bits above it. laine_karras() works on the reversed bits: Burley's Laine-Karras-style hash on the
/// reversed bits, with N. Vegdahl's better-mixing constants ("Building a better LK hash", psychopath.io, 2021), which
/// keep the property that each reversed bit depends only on the reversed bits below it.
constexpr uint32_t laine_karras(uint32_t x, uint32_t seed) {
  x ^= x * 0x3d20adeau;
  x += seed;
  x *= (seed >> 16) | 1u;
  x ^= x * 0x05526c56u;
  x ^= x * 0x53a22864u;
  return x;
}
constexpr uint32_t owen_scramble(uint32_t x, uint32_t seed) {
  return reverse_bits(laine_karras(reverse_bits(x), seed));
}

/// A 32-bit fraction to a float in [0, 1) (its top 24 bits).
constexpr float to_unit_float(uint32_t x) { return float(x >> 8) * 0x1p-24f; }

}  // namespace sobol

/// Sobol-Burley points of one pixel: set `set`'s sample number `index` (see the file comment).
class SobolBurleyPixel {
 public:
  SobolBurleyPixel(uint64_t seed, uint32_t pixel)
      : key_(mix64(mix64(seed ^ 0x2545f4914f6cdd1dULL) + (uint64_t(pixel) + 1) * 0x9e3779b97f4a7c15ULL)) {}

  Vec2 sample2(uint32_t set, uint32_t index) const {
    uint32_t x[2];
    sample(set, index, 2, x);
    return {sobol::to_unit_float(x[0]), sobol::to_unit_float(x[1])};
  }
  Vec3 sample3(uint32_t set, uint32_t index) const {
    uint32_t x[3];
    sample(set, index, 3, x);
    return {sobol::to_unit_float(x[0]), sobol::to_unit_float(x[1]), sobol::to_unit_float(x[2])};
  }
  /// The 32-bit fractions of the first n <= sobol::kDimensions coordinates.
  void sample(uint32_t set, uint32_t index, int n, uint32_t* out) const {
    sample_reversed_index(set, sobol::reverse_bits(index), n, out);
  }
  /// sample() from reverse_bits(index), which a path computes once for all its sets. Every value is
  /// owen_scramble(sobol::sample(owen_scramble(index, seed), d), seed_d), written with the
  /// reversals that cancel left out.
  void sample_reversed_index(uint32_t set, uint32_t reversed_index, int n, uint32_t* out) const {
    const uint64_t h = hash_dimension(key_, set);
    const uint32_t shuffled = sobol::reverse_bits(sobol::laine_karras(reversed_index, uint32_t(h)));
    for (int d = 0; d < n; ++d)
      out[d] = sobol::reverse_bits(
          sobol::laine_karras(sobol::sample_reversed(shuffled, d), uint32_t(mix64(h + uint64_t(d + 1)) >> 32)));
  }

 private:
  uint64_t key_;
};

/// The random numbers of path number `sample` of one pixel, in the layout of the file comment.
class PathSampler {
 public:
  struct Bounce {
    float light_select;  // emitter selection
    Vec2 light_point;    // point on the emitter triangle
    float rr, lobe;      // Russian roulette, BSDF lobe
    Vec2 dir;            // BSDF direction
  };

  PathSampler(SamplerKind kind, uint64_t seed, uint32_t pixel, uint32_t sample)
      : kind_(kind), stream_(seed, pixel, sample), sobol_(seed, pixel), reversed_sample_(sobol::reverse_bits(sample)) {}

  Vec2 film() { return kind_ == SamplerKind::kIndependent ? stream_.next2() : sobol2(0); }
  /// The next bounce's numbers (the first call: vertex x_1).
  Bounce bounce() {
    Bounce b;
    if (kind_ == SamplerKind::kIndependent) {
      b.light_select = stream_.next();
      b.light_point = stream_.next2();
      const Vec2 rr_lobe = stream_.next2();
      b.rr = rr_lobe.x;
      b.lobe = rr_lobe.y;
      b.dir = stream_.next2();
    } else {
      const uint32_t set = 1 + 3 * bounce_++;
      uint32_t light[3];
      sobol_.sample_reversed_index(set, reversed_sample_, 3, light);
      b.light_point = {sobol::to_unit_float(light[0]), sobol::to_unit_float(light[1])};
      b.light_select = sobol::to_unit_float(light[2]);
      const Vec2 rr_lobe = sobol2(set + 1);
      b.rr = rr_lobe.x;
      b.lobe = rr_lobe.y;
      b.dir = sobol2(set + 2);
    }
    return b;
  }

 private:
  // SobolBurleyPixel::sample2(set, sample) for this path's sample number.
  Vec2 sobol2(uint32_t set) const {
    uint32_t x[2];
    sobol_.sample_reversed_index(set, reversed_sample_, 2, x);
    return {sobol::to_unit_float(x[0]), sobol::to_unit_float(x[1])};
  }

  SamplerKind kind_;
  SampleStream stream_;
  SobolBurleyPixel sobol_;
  uint32_t reversed_sample_;  // sobol::reverse_bits(sample number)
  uint32_t bounce_ = 0;
};

}  // namespace epr
