// Spherical triangle sampling: directions land in the triangle, the solid angle agrees with an
// area-sampled estimate of the same integral, and integrals estimated with uniform directions in
// the solid angle agree with those estimated by uniform points on the triangle.
#include "common/spherical_triangle.h"

#include <gtest/gtest.h>

#include <cmath>

#include "common/rng.h"
#include "common/sampling.h"

namespace epr {
namespace {

struct Config {
  const char* name;
  Vec3 p, v0, v1, v2;
};

// A point close under a triangle, far from it, near its plane, beside it, and seeing its back.
const Config kConfigs[] = {
    {"close", {0.1f, -0.05f, 0.f}, {-1.f, -1.f, 0.2f}, {1.f, -1.f, 0.2f}, {0.f, 1.f, 0.2f}},
    {"far", {0.f, 0.f, -20.f}, {-1.f, -1.f, 0.f}, {1.f, -1.f, 0.f}, {0.f, 1.f, 0.f}},
    {"near_plane", {2.f, 0.f, 0.05f}, {-1.f, -1.f, 0.f}, {1.f, -1.f, 0.f}, {0.f, 1.f, 0.f}},
    {"beside", {0.4f, 0.3f, 0.5f}, {0.f, 0.f, 0.f}, {0.f, 2.f, 0.f}, {0.f, 0.f, 2.f}},
    {"back", {0.f, 0.f, 1.f}, {-1.f, -1.f, 0.f}, {0.f, 1.f, 0.f}, {1.f, -1.f, 0.f}},
};

// Distance along the unit direction w from p to the triangle, or -1 if the ray misses it
// (barycentrics outside [-tol, 1 + tol]).
float hit_distance(const Config& c, const Vec3& w, float tol) {
  const Vec3 e1 = c.v1 - c.v0, e2 = c.v2 - c.v0;
  const Vec3 s1 = cross(w, e2);
  const float div = dot(s1, e1);
  if (div == 0) return -1;
  const Vec3 d = c.p - c.v0;
  const float b1 = dot(d, s1) / div;
  const Vec3 s2 = cross(d, e1);
  const float b2 = dot(w, s2) / div;
  const float t = dot(e2, s2) / div;
  if (b1 < -tol || b2 < -tol || b1 + b2 > 1 + tol || t <= 0) return -1;
  return t;
}

// A smooth integrand over directions.
double g(const Vec3& w) { return 1.0 + 0.8 * w.x * w.x + 0.5 * w.y + 0.3 * w.z * w.y; }

TEST(SphericalTriangle, SampledDirectionsHitTheTriangle) {
  for (const Config& c : kConfigs) {
    SampleStream rng(7, 0, 0);
    for (int i = 0; i < 20000; ++i) {
      const SphericalTriangleSample s = sample_spherical_triangle(c.p, c.v0, c.v1, c.v2, rng.next2());
      ASSERT_TRUE(s.valid) << c.name;
      // Bit for bit the density's solid angle: whoever evaluates the density decides as the sampler.
      EXPECT_EQ(s.solid_angle, triangle_solid_angle(c.p, c.v0, c.v1, c.v2)) << c.name;
      EXPECT_NEAR(length(s.dir), 1.f, 1e-5f);
      EXPECT_GT(hit_distance(c, s.dir, 2e-3f), 0.f) << c.name << " sample " << i;
    }
  }
}

TEST(SphericalTriangle, SolidAngleMatchesAnAreaSampledEstimate) {
  // Solid angle = integral over the triangle of cos_y / d^2 dA, estimated with uniform points.
  for (const Config& c : kConfigs) {
    const Vec3 n = normalize(cross(c.v1 - c.v0, c.v2 - c.v0));
    const double area = 0.5 * length(cross(c.v1 - c.v0, c.v2 - c.v0));
    const int n_samples = 400000;
    double sum = 0;
    for (int i = 0; i < n_samples; ++i) {
      const Vec2 u{(float(i % 632) + 0.5f) / 632.f, (float(i / 632) + 0.5f) / 633.f};
      const Vec2 b = sample_uniform_triangle(u);
      const Vec3 y = c.v0 * b.x + c.v1 * b.y + c.v2 * (1 - b.x - b.y);
      const Vec3 d = y - c.p;
      const double d2 = dot(d, d);
      sum += std::abs(dot(n, d)) / std::sqrt(d2) / d2;
    }
    const double estimate = sum / n_samples * area;
    const double omega = triangle_solid_angle(c.p, c.v0, c.v1, c.v2);
    EXPECT_NEAR(omega, estimate, 2e-3 * estimate) << c.name;
  }
  // The whole sphere's worth: an octahedron's face seen from its centre is 4 pi / 8.
  EXPECT_NEAR(triangle_solid_angle({0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}), 0.5 * kPi, 1e-5);
}

TEST(SphericalTriangle, DirectionsAreUniformInTheSolidAngle) {
  // The same integral of g over the triangle's directions two ways: directions from the sampler
  // weighted by its density 1 / solid angle, and uniform points on the triangle weighted by cos_y / d^2.
  for (const Config& c : kConfigs) {
    const Vec3 n = normalize(cross(c.v1 - c.v0, c.v2 - c.v0));
    const double area = 0.5 * length(cross(c.v1 - c.v0, c.v2 - c.v0));
    const int n_samples = 200000;
    double by_direction = 0, by_area = 0, by_direction_sq = 0;
    SampleStream rng(11, 1, 0);
    for (int i = 0; i < n_samples; ++i) {
      const SphericalTriangleSample s = sample_spherical_triangle(c.p, c.v0, c.v1, c.v2, rng.next2());
      const double f = g(s.dir) * s.solid_angle;
      by_direction += f;
      by_direction_sq += f * f;
      const Vec2 b = sample_uniform_triangle(rng.next2());
      const Vec3 d = c.v0 * b.x + c.v1 * b.y + c.v2 * (1 - b.x - b.y) - c.p;
      const double d2 = dot(d, d);
      by_area += g(normalize(d)) * std::abs(dot(n, d)) / std::sqrt(d2) / d2 * area;
    }
    by_direction /= n_samples;
    by_area /= n_samples;
    const double sd = std::sqrt((by_direction_sq / n_samples - by_direction * by_direction) / n_samples);
    // Area sampling's own noise is larger close to the triangle: allow a relative 1 % as well.
    EXPECT_NEAR(by_direction, by_area, 5 * sd + 1e-2 * by_area) << c.name;
    // Uniform in solid angle: the share of directions in the sub-triangle (v0, v1, m), m the
    // midpoint of v1 v2, is its solid angle over the whole one.
    const Config half{c.name, c.p, c.v0, c.v1, (c.v1 + c.v2) * 0.5f};
    const double expected =
        triangle_solid_angle(c.p, half.v0, half.v1, half.v2) / triangle_solid_angle(c.p, c.v0, c.v1, c.v2);
    int inside = 0;
    SampleStream rng2(13, 2, 0);
    for (int i = 0; i < n_samples; ++i) {
      const SphericalTriangleSample s = sample_spherical_triangle(c.p, c.v0, c.v1, c.v2, rng2.next2());
      inside += hit_distance(half, s.dir, 0.f) > 0 ? 1 : 0;
    }
    const double share = double(inside) / n_samples;
    EXPECT_NEAR(share, expected, 5 * std::sqrt(expected * (1 - expected) / n_samples)) << c.name;
  }
}

TEST(SphericalTriangle, DegenerateTrianglesAreRejected) {
  // The point in the triangle's plane: the spherical triangle is a great-circle arc.
  EXPECT_FALSE(sample_spherical_triangle({3, 0, 0}, {-1, -1, 0}, {1, -1, 0}, {0, 1, 0}, {0.5f, 0.5f}).valid);
  // Two corners in one direction.
  EXPECT_FALSE(sample_spherical_triangle({0, 0, 0}, {1, 0, 0}, {2, 0, 0}, {0, 1, 1}, {0.5f, 0.5f}).valid);
}

}  // namespace
}  // namespace epr
