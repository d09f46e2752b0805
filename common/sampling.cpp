#include "common/sampling.h"

#include <algorithm>

namespace epr {

Vec2 sample_uniform_disk_concentric(Vec2 u) {
  const float ox = 2 * u.x - 1, oy = 2 * u.y - 1;
  if (ox == 0 && oy == 0) return {0, 0};
  float r, theta;
  if (std::abs(ox) > std::abs(oy)) {
    r = ox;
    theta = (kPi / 4) * (oy / ox);
  } else {
    r = oy;
    theta = kPi / 2 - (kPi / 4) * (ox / oy);
  }
  return {r * std::cos(theta), r * std::sin(theta)};
}

Vec2 invert_uniform_disk_concentric(Vec2 p) {
  const float theta = std::atan2(p.y, p.x);  // in [-pi, pi]
  const float r = std::sqrt(p.x * p.x + p.y * p.y);
  float ox, oy;
  // Which of the four wedges (|ox| > |oy| or not, and the sign of r) produced p.
  if (std::abs(theta) < kPi / 4 || std::abs(theta) > 3 * kPi / 4) {
    ox = r * (std::abs(theta) < kPi / 4 ? 1.f : -1.f);
    float t = theta;
    if (ox < 0) t = theta > 0 ? theta - kPi : theta + kPi;
    oy = ox * t / (kPi / 4);
  } else {
    oy = r * (theta > 0 ? 1.f : -1.f);
    float t = theta;
    if (oy < 0) t = theta + kPi;
    ox = oy * (kPi / 2 - t) / (kPi / 4);
  }
  return {(ox + 1) * 0.5f, (oy + 1) * 0.5f};
}

Vec3 sample_cosine_hemisphere(Vec2 u) {
  const Vec2 d = sample_uniform_disk_concentric(u);
  const float z = std::sqrt(std::max(0.f, 1 - d.x * d.x - d.y * d.y));
  return {d.x, d.y, z};
}

Vec2 invert_cosine_hemisphere(const Vec3& w) { return invert_uniform_disk_concentric({w.x, w.y}); }

Vec2 sample_uniform_triangle(Vec2 u) {
  float b0, b1;
  if (u.x < u.y) {
    b0 = u.x / 2;
    b1 = u.y - b0;
  } else {
    b1 = u.y / 2;
    b0 = u.x - b1;
  }
  return {b0, b1};
}

Vec2 invert_uniform_triangle(Vec2 b) {
  if (b.x > b.y) {
    // b1 = u1/2, b0 = u0 - b1
    return {b.x + b.y, 2 * b.y};
  }
  return {2 * b.x, b.y + b.x};
}

Vec3 sample_phong_lobe(Vec2 u, float exponent) {
  const float cos_theta = std::pow(1 - u.x, 1 / (exponent + 1));
  const float sin_theta = std::sqrt(std::max(0.f, 1 - cos_theta * cos_theta));
  const float phi = 2 * kPi * u.y;
  return {sin_theta * std::cos(phi), sin_theta * std::sin(phi), cos_theta};
}

Vec2 invert_phong_lobe(const Vec3& w, float exponent) {
  float phi = std::atan2(w.y, w.x);
  if (phi < 0) phi += 2 * kPi;
  return {1 - std::pow(w.z, exponent + 1), phi / (2 * kPi)};
}

DiscreteDistribution::DiscreteDistribution(std::span<const float> weights)
    : weights_(weights.begin(), weights.end()), cdf_(weights.size() + 1, 0.0) {
  for (size_t i = 0; i < weights_.size(); ++i) cdf_[i + 1] = cdf_[i] + std::max(0.0, weights_[i]);
  total_ = cdf_.back();
}

size_t DiscreteDistribution::sample(float u, float* pmf_out, float* remapped) const {
  const double target = double(u) * total_;
  // First index whose upper edge exceeds target; skip zero-weight items.
  size_t i = size_t(std::upper_bound(cdf_.begin() + 1, cdf_.end(), target) - (cdf_.begin() + 1));
  i = std::min(i, weights_.size() - 1);
  while (weights_[i] <= 0 && i > 0) --i;
  if (pmf_out) *pmf_out = pmf(i);
  if (remapped) {
    const double w = weights_[i];
    *remapped = w > 0 ? float(std::clamp((target - cdf_[i]) / w, 0.0, 0.99999994)) : 0.f;
  }
  return i;
}

}  // namespace epr
