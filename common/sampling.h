// Sampling routines as small pure functions: each takes its uniform random numbers as arguments and
// comes with its density and, where it exists, its inverse (as in pbrt-v4's util/sampling.h).
#pragma once

#include <cmath>
#include <span>
#include <vector>

#include "common/math.h"

namespace epr {

// ---- cosine-weighted hemisphere (local frame, +z is the normal) ---------------------------------

/// Malley's method: a concentric disk sample lifted onto the hemisphere. pdf = cos(theta) / pi.
Vec3 sample_cosine_hemisphere(Vec2 u);
inline float cosine_hemisphere_pdf(float cos_theta) { return cos_theta > 0 ? cos_theta * kInvPi : 0.f; }
Vec2 invert_cosine_hemisphere(const Vec3& w);

/// Shirley-Chiu concentric mapping of [0,1)^2 onto the unit disk, and its inverse.
Vec2 sample_uniform_disk_concentric(Vec2 u);
Vec2 invert_uniform_disk_concentric(Vec2 p);

// ---- uniform point on a triangle ------------------------------------------------------------------

/// Barycentric coordinates (b0, b1) of a uniform point; b2 = 1 - b0 - b1. pdf = 1 / area.
/// Heitz's low-distortion mapping (2019), which is invertible.
Vec2 sample_uniform_triangle(Vec2 u);
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

}  // namespace epr
