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

namespace {

// Q_h: what half h's L_rp is worth, from the other half's variances.
double half_worth(const CombineHalf& h, const CombineHalf& other, double weight, double discount) {
  if (h.subpixels == 0) return 0;
  const double rp_variance =
      other.rp_variance >= 0 && other.subpixels > 0 ? other.rp_variance * other.subpixels / h.subpixels : -1;
  return reprojected_worth(other.path_variance, rp_variance, weight * h.effective, discount);
}

}  // namespace

Vec3 combine_halves(const CombineHalf& a, const CombineHalf& b, double weight, double discount) {
  const double ca = a.paths + weight * a.effective, cb = b.paths + weight * b.effective;
  if (ca + cb <= 0) return Vec3(0.f);
  const Vec3 la = combine_weighted(a.path_sum, uint32_t(a.paths), half_worth(a, b, weight, discount), a.lrp);
  const Vec3 lb = combine_weighted(b.path_sum, uint32_t(b.paths), half_worth(b, a, weight, discount), b.lrp);
  const double wa = ca / (ca + cb), wb = cb / (ca + cb);
  return Vec3(float(wa * la.x + wb * lb.x), float(wa * la.y + wb * lb.y), float(wa * la.z + wb * lb.z));
}

}  // namespace epr
