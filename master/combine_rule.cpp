// See combine_rule.h.
#include "master/combine_rule.h"

#include <algorithm>
#include <cmath>

namespace epr {

double add_batch(double m2, double sum, uint32_t count, double batch, uint32_t k) {
  if (k == 0 || count == 0) return m2;
  const double n = count, kk = k;
  const double delta = batch / kk - sum / n;
  return m2 + delta * delta * n * kk / (n + kk);
}

double path_sample_variance(double m2, uint32_t rounds) {
  if (rounds < kMinRounds) return -1;
  return std::max(0.0, m2) / double(rounds - 1);
}

double reprojected_worth(double path_variance, double reprojection_variance, double fallback, double discount) {
  if (!(path_variance >= 0) || !(reprojection_variance >= 0)) return fallback;
  if (path_variance == 0 && reprojection_variance == 0) return fallback;
  if (reprojection_variance == 0) return kWorthLimit;
  return std::min(discount * path_variance / reprojection_variance, kWorthLimit);
}

Vec3 combine_weighted(const Vec3& path_sum, uint32_t path_count, double worth, const Vec3& lrp) {
  const double m = path_count;
  if (m + worth <= 0) return Vec3(0.f);
  return Vec3(float((path_sum.x + worth * lrp.x) / (m + worth)), float((path_sum.y + worth * lrp.y) / (m + worth)),
              float((path_sum.z + worth * lrp.z) / (m + worth)));
}

}  // namespace epr
