// Cut-outs in the tracer (worker/embree_scene.cpp): closest-hit and shadow rays pass through the
// holes of an alpha mask, and a render of a checker-cut screen in front of a lit wall matches the
// same scene with the holes modelled as geometry (the holes show the wall, the shadow has holes).
#include <gtest/gtest.h>
#include <tbb/parallel_for.h>

#include <cmath>
#include <vector>

#include "tests/common/cutout_scenes.h"
#include "worker/embree_scene.h"
#include "worker/path_tracer.h"

namespace epr {
namespace {

// The centre of checker cell (i, r) of the screen (n x n cells), on the screen plane z = 0.
Vec3 cell_centre(int n, int i, int r) {
  const float c = 1.f / float(n);
  return {-0.5f + (float(i) + 0.5f) * c, 0.5f - (float(r) + 0.5f) * c, 0.f};
}

TEST(Cutout, ClosestHitAndShadowRaysPassThroughHolesOnly) {
  const int n = 4;
  const Scene scene = test::cutout_screen_scene(n);
  ASSERT_NO_THROW(scene.validate());
  ASSERT_TRUE(scene.has_cut_outs());
  EmbreeScene es(scene);
  const uint32_t screen = 2;  // material index of the screen (wall, light, screen)
  int holes = 0, solid = 0;
  for (int r = 0; r < n; ++r)
    for (int i = 0; i < n; ++i) {
      const Vec3 target = cell_centre(n, i, r);
      const Ray ray{{target.x, target.y, 2.f}, {0, 0, -1}};
      Hit h;
      ASSERT_TRUE(es.intersect(ray, 0.f, 1e30f, &h));
      const bool opaque = test::checker_opaque(i, r);
      if (opaque) {
        ++solid;
        EXPECT_EQ(scene.material_of[h.prim], screen) << "cell " << i << ", " << r;
        EXPECT_NEAR(h.t, 2.f, 1e-5f);
      } else {
        ++holes;
        EXPECT_EQ(scene.material_of[h.prim], 0u) << "cell " << i << ", " << r << ": the wall behind the hole";
        EXPECT_NEAR(h.t, 3.f, 1e-5f);
      }
      // A shadow ray from the wall to the front crosses the screen at the cell's centre.
      const Vec3 from{target.x, target.y, -1.f};
      EXPECT_EQ(es.occluded(from, {0, 0, 1}, 1e-3f, 2.f), opaque) << "cell " << i << ", " << r;
    }
  EXPECT_EQ(holes, 8);
  EXPECT_EQ(solid, 8);
}

TEST(Cutout, SceneWithoutCutOutsHasNoFilterAndTheSameHits) {
  // The opaque screen: every ray stops on it, and triangle indices are the scene's own.
  const Scene scene = test::cutout_screen_scene(4, false, true);
  EXPECT_FALSE(scene.has_cut_outs());
  EmbreeScene es(scene);
  for (int r = 0; r < 4; ++r)
    for (int i = 0; i < 4; ++i) {
      const Vec3 target = cell_centre(4, i, r);
      Hit h;
      ASSERT_TRUE(es.intersect({{target.x, target.y, 2.f}, {0, 0, -1}}, 0.f, 1e30f, &h));
      EXPECT_GE(h.prim, 4u);  // the screen's triangles come after the wall's and the light's
      EXPECT_NEAR(h.t, 2.f, 1e-5f);
    }
}

struct Rendered {
  std::vector<double> sum, sum_sq;  // per pixel: luminance of the path samples, and its square
  int spp = 0;
};

Rendered render(const Scene& scene, int size, int spp, uint64_t seed) {
  EmbreeScene es(scene);
  const Camera cam(scene.camera, size, size);
  PathTracer tracer(es, cam, seed, RussianRoulette::paper(), true);
  Rendered out;
  out.spp = spp;
  out.sum.assign(size_t(size) * size_t(size), 0);
  out.sum_sq = out.sum;
  tbb::parallel_for(0, size, [&](int y) {
    for (int x = 0; x < size; ++x)
      for (int s = 0; s < spp; ++s) {
        const double l = luminance(tracer.trace(x, y, uint32_t(s), nullptr, nullptr));
        out.sum[size_t(y) * size_t(size) + size_t(x)] += l;
        out.sum_sq[size_t(y) * size_t(size) + size_t(x)] += l * l;
      }
  });
  return out;
}

// Blocks of b x b pixels whose means differ by more than 5 standard errors (plus 1 % of the mean).
int differing_blocks(const Rendered& a, const Rendered& c, int size, int b, int* blocks) {
  int differ = 0;
  *blocks = 0;
  for (int by = 0; by < size; by += b)
    for (int bx = 0; bx < size; bx += b) {
      double ma = 0, mc = 0, va = 0, vc = 0;
      const double n = double(b) * double(b) * a.spp;
      for (int y = by; y < by + b; ++y)
        for (int x = bx; x < bx + b; ++x) {
          const size_t p = size_t(y) * size_t(size) + size_t(x);
          ma += a.sum[p], mc += c.sum[p], va += a.sum_sq[p], vc += c.sum_sq[p];
        }
      ma /= n, mc /= n;
      va = va / n - ma * ma, vc = vc / n - mc * mc;
      const double se = std::sqrt(std::max(va, 0.0) / n + std::max(vc, 0.0) / n);
      ++*blocks;
      differ += std::fabs(ma - mc) > 5 * se + 0.01 * std::max(ma, mc);
    }
  return differ;
}

TEST(Cutout, RenderMatchesTheHolesModelledAsGeometry) {
  const int size = 48, spp = 48, block = 4;
  const Rendered cut = render(test::cutout_screen_scene(8), size, spp, 7);
  const Rendered modelled = render(test::cutout_screen_scene(8, true), size, spp, 8);
  const Rendered opaque = render(test::cutout_screen_scene(8, false, true), size, spp, 9);
  int blocks = 0;
  EXPECT_EQ(differing_blocks(cut, modelled, size, block, &blocks), 0) << "of " << blocks << " blocks";
  // The comparison can tell: without the holes, the screen's and its shadow's blocks differ.
  EXPECT_GT(differing_blocks(opaque, modelled, size, block, &blocks), blocks / 10);
}

}  // namespace
}  // namespace epr
