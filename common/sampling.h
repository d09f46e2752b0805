// Sampling routines as small pure functions: each takes its uniform random numbers as arguments and
// comes with its density and, where it exists, its inverse (as in pbrt-v4's util/sampling.h).
#pragma once

#include <cmath>
#include <cstdint>
#include <span>
#include <vector>

#include "common/math.h"

namespace epr {

// The samplers a path calls at every vertex are defined here, inline: they are a few dozen
// instructions each, and the call and the lost scheduling across it cost a measurable share.

// ---- cosine-weighted hemisphere (local frame, +z is the normal) ---------------------------------

/// sin and cos for |x| <= pi/4 (Cephes' sinf/cosf minimax polynomials, within 2 ulp there): all
/// the concentric mapping needs, without libm's range reduction.
inline float sin_quarter_pi(float x) {
  const float z = x * x;
  return ((-1.9515295891e-4f * z + 8.3321608736e-3f) * z - 1.6666654611e-1f) * z * x + x;
}
inline float cos_quarter_pi(float x) {
  const float z = x * x;
  return ((2.443315711809948e-5f * z - 1.388731625493765e-3f) * z + 4.166664568298827e-2f) * z * z - 0.5f * z + 1.f;
}

/// Shirley-Chiu concentric mapping of [0,1)^2 onto the unit disk, and its inverse.
inline Vec2 sample_uniform_disk_concentric(Vec2 u) {
  const float ox = 2 * u.x - 1, oy = 2 * u.y - 1;
  if (ox == 0 && oy == 0) return {0, 0};
  // |ox| > |oy|: r = ox, theta = pi/4 (oy/ox) in [-pi/4, pi/4].
  // Otherwise:   r = oy, theta = pi/2 - t with t = pi/4 (ox/oy): cos(theta) = sin(t), sin(theta) = cos(t).
  // Selected rather than branched on (the wedge is a coin toss).
  const bool x_major = std::abs(ox) > std::abs(oy);
  const float r = x_major ? ox : oy;
  const float t = (kPi / 4) * ((x_major ? oy : ox) / r);
  const float c = cos_quarter_pi(t), s = sin_quarter_pi(t);
  return {r * (x_major ? c : s), r * (x_major ? s : c)};
}
Vec2 invert_uniform_disk_concentric(Vec2 p);

/// Malley's method: a concentric disk sample lifted onto the hemisphere. pdf = cos(theta) / pi.
inline Vec3 sample_cosine_hemisphere(Vec2 u) {
  const Vec2 d = sample_uniform_disk_concentric(u);
  const float z = std::sqrt(std::max(0.f, 1 - d.x * d.x - d.y * d.y));
  return {d.x, d.y, z};
}
inline float cosine_hemisphere_pdf(float cos_theta) { return cos_theta > 0 ? cos_theta * kInvPi : 0.f; }
Vec2 invert_cosine_hemisphere(const Vec3& w);

// ---- uniform point on a triangle ------------------------------------------------------------------

/// Barycentric coordinates (b0, b1) of a uniform point; b2 = 1 - b0 - b1. pdf = 1 / area.
/// Heitz's low-distortion mapping (2019), which is invertible.
inline Vec2 sample_uniform_triangle(Vec2 u) {
  // Both halves computed and one selected: which applies is a coin toss, so a branch would be
  // mispredicted half the time.
  const float h0 = u.x * 0.5f, h1 = u.y * 0.5f;
  const bool lower = u.x < u.y;
  return {lower ? h0 : u.x - h1, lower ? u.y - h0 : h1};
}
Vec2 invert_uniform_triangle(Vec2 b);

// ---- Phong lobe around +z: pdf = (n + 1) / (2 pi) cos^n(theta) ------------------------------------

Vec3 sample_phong_lobe(Vec2 u, float exponent);
inline float phong_lobe_pdf(float cos_theta, float exponent) {
  return cos_theta > 0 ? (exponent + 1) * (0.5f * kInvPi) * std::pow(cos_theta, exponent) : 0.f;
}
Vec2 invert_phong_lobe(const Vec3& w, float exponent);

// ---- discrete distribution --------------------------------------------------------------------------

/// Piecewise-constant 1D distribution over n items with non-negative weights.
class DiscreteDistribution {
 public:
  DiscreteDistribution() = default;
  explicit DiscreteDistribution(std::span<const float> weights);

  /// Index of the sampled item; u in [0,1). `remapped` gets a fresh uniform in [0,1) for reuse.
  size_t sample(float u, float* pmf = nullptr, float* remapped = nullptr) const;
  float pmf(size_t i) const { return total_ > 0 ? float(weights_[i] / total_) : 0.f; }
  size_t size() const { return weights_.size(); }
  double total() const { return total_; }

 private:
  std::vector<double> weights_;
  std::vector<double> cdf_;  // cdf_[i] = sum of weights_[0..i), cdf_[n] = total_
  double total_ = 0;
};

/// Walker's alias method, built with Vose's algorithm: O(1) sampling of n items with non-negative
/// weights from one uniform number. The table is built in double precision and deterministically,
/// so the same weights always give the same item for the same u.
class AliasTable {
 public:
  AliasTable() = default;
  /// Throws std::invalid_argument if a weight is negative or not finite, or if none is positive.
  explicit AliasTable(std::span<const float> weights);

  /// Index of the sampled item; u in [0,1). Its bin is floor(u n); the fraction of u n within the
  /// bin chooses between the bin's own item and its alias.
  size_t sample(float u) const {
    const double x = double(u) * double(bins_.size());
    const size_t i = std::min(size_t(x), bins_.size() - 1);
    const Bin& b = bins_[i];
    return x - double(i) < b.threshold ? i : b.alias;
  }
  /// Probability of item i (weight / sum of weights).
  float pmf(size_t i) const { return pmf_[i]; }
  size_t size() const { return bins_.size(); }

 private:
  struct Bin {
    double threshold = 1;  // keep item i when the in-bin fraction is below this
    uint32_t alias = 0;
  };
  std::vector<Bin> bins_;
  std::vector<float> pmf_;
};

}  // namespace epr
