// Next event estimation's point on an emitting triangle (worker/emitter_sampling.h): both techniques
// give points on the triangle, the density integrates to the triangle's probability, and the
// estimate of a receiver's irradiance agrees with a dense quadrature close to the light (solid-angle
// sampling) and far from it (area sampling).
#include "worker/emitter_sampling.h"

#include <gtest/gtest.h>

#include <cmath>

#include "common/rng.h"

namespace epr {
namespace {

// A 1 x 0.8 m triangle at y = 2 facing down, chosen with probability 0.5.
Emitter test_emitter() {
  Emitter e;
  e.p0 = {-0.5f, 2.f, -0.4f};
  e.p1 = {0.5f, 2.f, -0.4f};
  e.p2 = {0.f, 2.f, 0.4f};
  e.normal = {0.f, -1.f, 0.f};
  e.le = Vec3(1.f);
  e.pdf_area = 0.5f / triangle_area(e.p0, e.p1, e.p2);
  return e;
}

struct Receiver {
  const char* name;
  Vec3 p, n;
  bool solid_angle;  // the technique the rule must choose
};

const Receiver kReceivers[] = {
    {"floor_far", {0.1f, 0.f, 0.f}, {0, 1, 0}, false},
    {"below_close", {0.1f, 1.9f, 0.05f}, {0, 1, 0}, true},
    {"wall_beside", {0.7f, 1.95f, 0.f}, {-1, 0, 0}, true},
    {"tilted_mid", {-0.3f, 1.4f, 0.2f}, {0.6f, 0.8f, 0.f}, true},
};

// Irradiance from the triangle at r (Le = 1): the integral of cos_x cos_y / d^2 over its area, by
// the midpoint rule on a fine grid of the unit square mapped to the triangle.
double quadrature_irradiance(const Emitter& e, const Receiver& r) {
  const int n = 1000;
  const double area = triangle_area(e.p0, e.p1, e.p2);
  double sum = 0;
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) {
      const Vec2 b = sample_uniform_triangle({(float(i) + 0.5f) / n, (float(j) + 0.5f) / n});
      const Vec3 y = e.p0 * b.x + e.p1 * b.y + e.p2 * (1 - b.x - b.y);
      const Vec3 d = y - r.p;
      const double d2 = dot(d, d), dist = std::sqrt(d2);
      const double cos_x = std::max(0.0, double(dot(r.n, d)) / dist), cos_y = std::abs(dot(e.normal, d)) / dist;
      sum += cos_x * cos_y / d2;
    }
  return sum / (double(n) * n) * area;
}

TEST(EmitterSampling, TheRuleChoosesSolidAngleCloseToTheLight) {
  const Emitter e = test_emitter();
  for (const Receiver& r : kReceivers)
    EXPECT_EQ(emitter_solid_angle(r.p, e.p0, e.p1, e.p2, e.normal) > 0, r.solid_angle) << r.name;
}

TEST(EmitterSampling, PointsLieOnTheTriangle) {
  const Emitter e = test_emitter();
  for (const Receiver& r : kReceivers) {
    SampleStream rng(3, 0, 0);
    for (int i = 0; i < 5000; ++i) {
      const EmitterPoint s = sample_emitter_point(e, r.p, rng.next2());
      ASSERT_TRUE(s.valid) << r.name;
      EXPECT_EQ(s.solid_angle > 0, r.solid_angle) << r.name;
      EXPECT_NEAR(s.pos.y, 2.f, 1e-5f) << r.name;
      // Inside the triangle: on the inner side of each edge (2-D, in x z), up to rounding.
      const auto edge = [&](const Vec3& a, const Vec3& b) {
        return (b.x - a.x) * (s.pos.z - a.z) - (b.z - a.z) * (s.pos.x - a.x);
      };
      const float side = edge(e.p0, e.p1);
      EXPECT_GE(side * edge(e.p1, e.p2), -1e-5f) << r.name;
      EXPECT_GE(side * edge(e.p2, e.p0), -1e-5f) << r.name;
    }
  }
}

TEST(EmitterSampling, DensityIntegratesToTheTrianglesProbability) {
  // The integral over the triangle's directions of the density, by uniform points on the triangle:
  // mean of pdf(y) cos_y / d^2 x area = pmf = 0.5.
  const Emitter e = test_emitter();
  const float area = triangle_area(e.p0, e.p1, e.p2);
  for (const Receiver& r : kReceivers) {
    SampleStream rng(5, 0, 0);
    const int n = 400000;
    double sum = 0;
    for (int i = 0; i < n; ++i) {
      const Vec2 b = sample_uniform_triangle(rng.next2());
      const Vec3 y = e.p0 * b.x + e.p1 * b.y + e.p2 * (1 - b.x - b.y);
      const Vec3 d = y - r.p;
      const float d2 = dot(d, d), cos_y = std::abs(dot(e.normal, d)) / std::sqrt(d2);
      sum += double(emitter_direction_pdf(r.p, e.p0, e.p1, e.p2, e.normal, e.pdf_area, d2, cos_y)) * cos_y / d2;
    }
    EXPECT_NEAR(sum / n * area, 0.5, 0.01) << r.name;
  }
}

TEST(EmitterSampling, IrradianceEstimateIsUnbiased) {
  // E[cos_x / pdf] over sampled points (pdf including the triangle's probability 0.5, hence x 0.5)
  // against the quadrature; the density is the one MIS evaluates for the same point.
  const Emitter e = test_emitter();
  for (const Receiver& r : kReceivers) {
    const double expected = quadrature_irradiance(e, r);
    SampleStream rng(9, 0, 0);
    const int n = 200000;
    double sum = 0, sum_sq = 0;
    for (int i = 0; i < n; ++i) {
      const EmitterPoint s = sample_emitter_point(e, r.p, rng.next2());
      ASSERT_TRUE(s.valid);
      const Vec3 d = s.pos - r.p;
      const float d2 = dot(d, d), dist = std::sqrt(d2);
      const float cos_x = std::max(0.f, dot(r.n, d) / dist), cos_y = std::abs(dot(e.normal, d)) / dist;
      const float pdf = emitter_direction_pdf(r.p, e.p0, e.p1, e.p2, e.normal, e.pdf_area, d2, cos_y);
      if (s.solid_angle > 0) {
        EXPECT_NEAR(pdf, e.pdf_area * triangle_area(e.p0, e.p1, e.p2) / s.solid_angle, 1e-6f * pdf);
      }
      const double f = 0.5 * cos_x / pdf;
      sum += f;
      sum_sq += f * f;
    }
    const double mean = sum / n, sd = std::sqrt((sum_sq / n - mean * mean) / n);
    EXPECT_NEAR(mean, expected, 5 * sd + 1e-4 * expected) << r.name << " sd " << sd;
  }
}

}  // namespace
}  // namespace epr
