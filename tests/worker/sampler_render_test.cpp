// The path tracer with each sampler (common/sampler.h): unbiased in the furnace, a path is a pure
// function of (seed, pixel, sample index) so rounds continue a pixel's sequence, and Sobol-Burley's
// pixels are less noisy than independent sampling's on the Cornell box at equal samples.
#include <gtest/gtest.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cstdio>

#include "common/builtin_scenes.h"
#include "common/scene_loader.h"
#include "worker/path_tracer.h"

namespace epr {
namespace {

Scene furnace(float albedo) {
  Scene s;
  s.name = "test-furnace";
  Material m;
  m.name = "furnace";
  m.kd = Vec3(albedo);
  m.ke = Vec3(1.f);
  const uint32_t id = add_material(s, m);
  const Vec3 p[8] = {{-1, -1, -1}, {1, -1, -1}, {1, 1, -1}, {-1, 1, -1},
                     {-1, -1, 1},  {1, -1, 1},  {1, 1, 1},  {-1, 1, 1}};
  add_tessellated_quad(s, p[0], p[1], p[2], p[3], id, 2);
  add_tessellated_quad(s, p[5], p[4], p[7], p[6], id, 2);
  add_tessellated_quad(s, p[4], p[0], p[3], p[7], id, 2);
  add_tessellated_quad(s, p[1], p[5], p[6], p[2], id, 2);
  add_tessellated_quad(s, p[4], p[5], p[1], p[0], id, 2);
  add_tessellated_quad(s, p[3], p[2], p[6], p[7], id, 2);
  s.camera = {Vec3(0.2f, 0.1f, 0.5f), Vec3(-1, -0.8f, -1), Vec3(0, 1, 0), 70.f};
  return s;
}

// Mean pixel value of `size` x `size` pixels with `spp` paths each, rows in parallel.
double mean_pixel(const PathTracer& tracer, int size, int spp) {
  std::vector<double> rows(size_t(size), 0.0);
  tbb::parallel_for(0, size, [&](int y) {
    for (int x = 0; x < size; ++x)
      for (int s = 0; s < spp; ++s) {
        const Vec3 v = tracer.trace(x, y, uint32_t(s), nullptr, nullptr);
        rows[size_t(y)] += (v.x + v.y + v.z) / 3.0;
      }
  });
  double sum = 0;
  for (double r : rows) sum += r;
  return sum / (double(size) * size * spp);
}

class SamplerFurnace : public ::testing::TestWithParam<SamplerKind> {};

TEST_P(SamplerFurnace, MeanMatchesTheAnalyticRadiance) {
  const float albedo = 0.8f;
  const Scene scene = furnace(albedo);
  EmbreeScene es(scene);
  const Camera cam(scene.camera, 64, 64);
  const PathTracer tracer(es, cam, 5, RussianRoulette::paper(), true, GetParam());
  const double expected = 1.0 / (1.0 - albedo);
  EXPECT_NEAR(mean_pixel(tracer, 64, 128), expected, 0.01 * expected) << to_string(GetParam());
}

INSTANTIATE_TEST_SUITE_P(BothSamplers, SamplerFurnace,
                         ::testing::Values(SamplerKind::kSobolBurley, SamplerKind::kIndependent));

TEST(SamplerRender, APathIsAPureFunctionOfItsKeyAndSamplersDiffer) {
  const Scene scene = load_scene("builtin:cornell");
  EmbreeScene es(scene);
  const Camera cam(scene.camera, 16, 16);
  const PathTracer sobol(es, cam, 3, RussianRoulette::paper(), true, SamplerKind::kSobolBurley);
  const PathTracer sobol_again(es, cam, 3, RussianRoulette::paper(), true, SamplerKind::kSobolBurley);
  const PathTracer indep(es, cam, 3, RussianRoulette::paper(), true, SamplerKind::kIndependent);
  int differ = 0;
  // Sample numbers in any order (a later round first) give the same paths.
  for (uint32_t s : {40u, 3u, 17u, 0u})
    for (int y = 0; y < 16; y += 3)
      for (int x = 0; x < 16; x += 3) {
        std::vector<VertexRecord> a, b;
        const Vec3 pa = sobol.trace(x, y, s, &a, nullptr), pb = sobol_again.trace(x, y, s, &b, nullptr);
        ASSERT_EQ(pa, pb);
        ASSERT_EQ(a.size(), b.size());
        for (size_t i = 0; i < a.size(); ++i) ASSERT_EQ(a[i].position, b[i].position);
        differ += !(pa == indep.trace(x, y, s, nullptr, nullptr));
      }
  EXPECT_GT(differ, 100);  // of 144 paths; a few may agree where both are black
}

// Per-pixel variance across seeds of a `size` x `size` crop at `spp` paths per pixel (mean of the
// channels); returns the mean and the median over pixels (the typical pixel a user looks at).
struct Noise {
  double mean, median;
};
Noise noise(const EmbreeScene& es, const Camera& cam, SamplerKind kind, int size, int spp, int seeds) {
  std::vector<double> var(size_t(size) * size_t(size), 0.0);
  tbb::parallel_for(0, size, [&](int y) {
    std::vector<PathTracer> tracers;
    for (int k = 0; k < seeds; ++k)
      tracers.emplace_back(es, cam, uint64_t(100 + k), RussianRoulette::paper(), true, kind);
    for (int x = 0; x < size; ++x) {
      Vec3 sum(0.f), sq(0.f);
      for (const PathTracer& t : tracers) {
        Vec3 est(0.f);
        for (int s = 0; s < spp; ++s) est = est + t.trace(x + 40, y + 40, uint32_t(s), nullptr, nullptr);
        est = est * (1.f / float(spp));
        sum = sum + est;
        sq = sq + est * est;
      }
      const Vec3 mean = sum * (1.f / float(seeds));
      const Vec3 v = (sq * (1.f / float(seeds)) - mean * mean) * (float(seeds) / float(seeds - 1));
      var[size_t(y) * size_t(size) + size_t(x)] = (double(v.x) + v.y + v.z) / 3.0;
    }
  });
  double total = 0;
  for (double v : var) total += v;
  std::nth_element(var.begin(), var.begin() + long(var.size() / 2), var.end());
  return {total / double(var.size()), var[var.size() / 2]};
}

TEST(SamplerRender, SobolBurleyIsLessNoisyOnTheCornellBoxAtEqualSamples) {
  const Scene scene = load_scene("builtin:cornell");
  EmbreeScene es(scene);
  const Camera cam(scene.camera, 128, 128);
  const Noise indep = noise(es, cam, SamplerKind::kIndependent, 24, 32, 8);
  const Noise sobol = noise(es, cam, SamplerKind::kSobolBurley, 24, 32, 8);
  std::printf(
      "Cornell 24x24 crop, 32 spp, 8 seeds: pixel variance mean / median: independent %.4g / %.4g, "
      "sobol-burley %.4g / %.4g (%.2fx / %.2fx)\n",
      indep.mean, indep.median, sobol.mean, sobol.median, sobol.mean / indep.mean, sobol.median / indep.median);
  EXPECT_GT(indep.median, 0);
  EXPECT_LT(sobol.mean, indep.mean);
  EXPECT_LT(sobol.median, 0.85 * indep.median);
}

}  // namespace
}  // namespace epr
