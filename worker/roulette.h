// Russian roulette along one eye path: the probability q_n that the path continues from vertex x_n
// (common/roulette.h names the policies; DESIGN.md "Russian roulette" gives the math). q_n depends
// only on the path up to x_n, never on the roulette's own random number, so dividing the
// continuation's weight by q_n keeps every estimate unbiased: the pixel sample and the radiance
// record of every vertex, Le(x_n) + R_n.
//
//   paper       q = 1 - termination once n > start_depth
//   albedo      q = a_n, the surface's largest albedo, clamped to [0.05, 1]
//   throughput  q = max_c(beta_n) a_n, clamped to [0.05, 1]: beta_n is the product of the
//               continuation weights f cos / pdf / q of x_1 .. x_{n-1}, what x_n's light is worth to
//               the pixel
//   reuse       as throughput, but beta restarts at 1 on every vertex reprojection can show (n >= 2,
//               diffuse, inside the image and facing the eye): the record of such a vertex is a
//               sample of its own, worth 1 to the pixels it lands in, and R_n estimates it with the
//               same continuation. A path keeps going through reprojectable surfaces at q = a_n
//               and ends quickly behind the camera or on glossy surfaces no pixel reuses.
// All but paper and off start once n > start_depth; every policy ends the path at max_depth.
#pragma once

#include <algorithm>

#include "common/camera.h"
#include "common/math.h"
#include "common/roulette.h"

namespace epr {

class PathRoulette {
 public:
  PathRoulette(const RussianRoulette& rr, const Camera& camera) : rr_(rr), camera_(camera) {}

  /// q for vertex x_depth (depth 1 is the camera ray's hit) of largest albedo `albedo`, at `position`
  /// with geometric normal `normal` (towards the previous vertex); `diffuse`: reprojection keeps it.
  float survival(int depth, float albedo, const Vec3& position, const Vec3& normal, bool diffuse) {
    using M = RussianRoulette::Mode;
    if (depth >= rr_.max_depth) return 0;
    if (rr_.mode == M::kReuse && depth >= 2 && diffuse && in_view(position, normal)) beta_ = Vec3(1.f);
    if (depth <= rr_.start_depth || rr_.mode == M::kOff) return 1;
    switch (rr_.mode) {
      case M::kPaper:
        return 1 - rr_.termination;
      case M::kAlbedo:
        return std::clamp(albedo, kMinSurvival, 1.f);
      default:
        return std::clamp(std::max({beta_.x, beta_.y, beta_.z}) * albedo, kMinSurvival, 1.f);
    }
  }
  /// The path continued from the vertex with weight f cos / pdf / q.
  void continued(const Vec3& weight) { beta_ = beta_ * weight; }

 private:
  static constexpr float kMinSurvival = 0.05f;

  // What worker/tile_renderer.cpp's filter keeps: inside the image, in front of the eye, facing it.
  bool in_view(const Vec3& p, const Vec3& n) const {
    float rx, ry;
    if (!camera_.project(p, &rx, &ry)) return false;
    if (!(rx >= 0 && rx < float(camera_.width()) && ry >= 0 && ry < float(camera_.height()))) return false;
    return dot(n, camera_.eye() - p) > 0;
  }

  const RussianRoulette& rr_;
  const Camera& camera_;
  Vec3 beta_{1.f};
};

}  // namespace epr
