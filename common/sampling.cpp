#include "common/sampling.h"

#include <algorithm>
#include <stdexcept>

namespace epr {

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

Vec2 invert_cosine_hemisphere(const Vec3& w) { return invert_uniform_disk_concentric({w.x, w.y}); }

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

AliasTable::AliasTable(std::span<const float> weights) : bins_(weights.size()), pmf_(weights.size()) {
  if (weights.size() > UINT32_MAX) throw std::invalid_argument("alias table: too many items");
  double total = 0;
  for (const float w : weights) {
    if (!(w >= 0) || !std::isfinite(w)) throw std::invalid_argument("alias table: weights must be finite and >= 0");
    total += w;
  }
  if (!(total > 0)) throw std::invalid_argument("alias table: no positive weight");

  // Vose: scaled probabilities n p_i; items below 1 ("small") are topped up by one item above 1.
  const size_t n = weights.size();
  std::vector<double> scaled(n);
  std::vector<uint32_t> small, large;
  for (size_t i = 0; i < n; ++i) {
    pmf_[i] = float(double(weights[i]) / total);
    scaled[i] = double(weights[i]) / total * double(n);
    (scaled[i] < 1 ? small : large).push_back(uint32_t(i));
  }
  while (!small.empty() && !large.empty()) {
    const uint32_t s = small.back(), l = large.back();
    small.pop_back();
    bins_[s] = {scaled[s], l};
    scaled[l] -= 1 - scaled[s];
    if (scaled[l] < 1) {
      large.pop_back();
      small.push_back(l);
    }
  }
  // What is left is 1 up to rounding: those bins keep their own item.
  for (const uint32_t i : large) bins_[i] = {1.0, i};
  for (const uint32_t i : small) bins_[i] = {1.0, i};
}

}  // namespace epr
