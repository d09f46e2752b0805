// What a path tracer hands to a reprojector for each eye-path vertex x_n, n >= 2 (DESIGN.md section 1).
#pragma once

#include <cstdint>

#include "common/math.h"

namespace epr {

struct VertexRecord {
  Vec3 position;  // x_n, world space, metres
  Vec3 normal;    // unit geometric normal at x_n, flipped to face x_{n-1} (the side it was lit from)
  Vec3 radiance;  // Le(x_n) + R_n, linear RGB radiance leaving x_n (W / (m^2 sr)); view-independent if diffuse
  uint32_t flags = 0;

  static constexpr uint32_t kDiffuse = 1u << 0;  // Lambertian: valid as a sample for any viewer
  bool diffuse() const { return (flags & kDiffuse) != 0; }
};

}  // namespace epr
