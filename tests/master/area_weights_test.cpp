// Area-weighted edge pixels (master/edge_pixels.h, AreaWeights in master/reprojection_image.h): a
// pixel covered by two surfaces gets the area-weighted mean of their subpixel means, not the mean
// over its subpixel centres; a surface covering area but no centre leaves the pixel an edge pixel.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <span>

#include "common/builtin_scenes.h"
#include "common/embree_bvh.h"
#include "common/render_options.h"
#include "common/scene_loader.h"
#include "master/deep_framebuffer.h"
#include "master/edge_pixels.h"
#include "master/plane_grid_builder.h"
#include "master/reprojection_image.h"
#include "tests/common/cutout_scenes.h"

namespace epr {
namespace {

// One pixel at S = 4: the left column of texels (class 1) sees a surface of radiance 3 over half the
// pixel's area, the other 12 texels (class 0) one of radiance 1 over the other half; 2 samples each.
TEST(AreaWeights, HalfCoveredPixelGetsTheAreaWeightedMeanNotTheCentreCountMean) {
  std::vector<AccumulationCell> cells(16);
  AreaWeights w;
  w.pixels = {0};
  for (int s = 0; s < 16; ++s) {
    const bool left = s % 4 == 0;
    cells[size_t(s)] = left ? AccumulationCell{6, 6, 6, 2} : AccumulationCell{2, 2, 2, 2};
    w.cells.push_back(AreaWeights::pack(left ? 1 : 0, 128));
  }
  PixelReprojection plain;
  downsample_cells(cells, 4, 4, 4, {}, &plain);
  EXPECT_FLOAT_EQ(plain.radiance.rgb(0, 0).x, 1.5f);  // by centres: (4 * 3 + 12 * 1) / 16
  EXPECT_EQ(plain.count[0], 32u);
  PixelReprojection weighted;
  weighted.statistics = true;
  weighted.area_weights = &w;
  downsample_cells(cells, 4, 4, 4, {}, &weighted);
  EXPECT_FLOAT_EQ(weighted.radiance.rgb(0, 0).x, 2.f);  // by area: (3 + 1) / 2
  // M' = 1 / sum_k a_k^2 / C_k = 1 / (1/4 / 8 + 1/4 / 24) = 24 (a stratified mean's count), M'_eff
  // = 1 / sum_k a_k^2 sum_s 1 / (n_k^2 c(s)) = 1 / (1/4 * 2/16 + 1/4 * 6/144).
  EXPECT_EQ(weighted.count[0], 24u);
  const double spread = 0.25 * (4 * 0.5) / 16 + 0.25 * (12 * 0.5) / 144;
  EXPECT_FLOAT_EQ(weighted.effective[0], float(1 / spread));
  EXPECT_EQ(weighted.half_variance[0], -1.f);  // not split: the count-based combination
  EXPECT_EQ(weighted.half_subpixels[0] + weighted.half_subpixels[1], 0);
  // The counts alone agree with the full downsampling.
  PixelReprojection counts;
  counts.area_weights = &w;
  downsample_cells(cells, 4, 4, 4, {}, &counts, DownsampleParts::kCounts);
  EXPECT_EQ(counts.count[0], weighted.count[0]);
  // A surface of non-zero area without samples: L_rp from the other, M' 0 (the pixel is not yet
  // estimated, so the skip rule and the combination ignore L_rp).
  for (int s = 0; s < 16; s += 4) cells[size_t(s)] = {};
  downsample_cells(cells, 4, 4, 4, {}, &weighted);
  EXPECT_FLOAT_EQ(weighted.radiance.rgb(0, 0).x, 1.f);
  EXPECT_EQ(weighted.count[0], 0u);
  // Weights of the wrong size are refused.
  w.cells.pop_back();
  EXPECT_THROW(downsample_cells(cells, 4, 4, 4, {}, &weighted), std::invalid_argument);
}

// A wall at z = 0 and, 1 m in front of it, a panel covering x < bx, with bx where the ray through
// raster x = 3 + `fraction` (pixel column 3) meets the panel's plane: a vertical outline there.
Scene panel_scene(const Camera& cam, float fraction) {
  const Ray r = cam.generate_ray(3 + fraction, 4);
  const float bx = r.origin.x + r.dir.x * ((1 - r.origin.z) / r.dir.z);
  Scene s;
  const uint32_t m = add_material(s, Material{});
  add_quad(s, {-20, -20, 0}, {20, -20, 0}, {20, 20, 0}, {-20, 20, 0}, m);
  add_quad(s, {-20, -20, 1}, {bx, -20, 1}, {bx, 20, 1}, {-20, 20, 1}, m);
  return s;
}

const Camera kPanelCamera(CameraSpec{}, 8, 8);
constexpr float kPanelEpsilon = 1e-3f;

detail::PlaneGrid panel_grid(const Scene& s) {
  return detail::build_plane_grid_any(s, kPanelCamera, 4, kPanelEpsilon * detail::kCreaseToleranceFraction, true);
}

// The outline at 5/16 of column 3: its texel centres see the panel in one column of 4 (1/4), the
// panel covers 5/16 of the pixel (80 of its 16 x 16 rays). With the panel's subpixels at radiance 4
// and the wall's at 0, L_rp is 4 * 5/16 = 1.25, not the centres' 1.0.
TEST(AreaWeights, OutlineThroughAPixelWeighsItsSurfacesByTheAreaTheyCover) {
  const Scene scene = panel_scene(kPanelCamera, 5.f / 16.f);
  const detail::PlaneGrid g = panel_grid(scene);
  const detail::EdgePixels centres(g, kPanelCamera, kPanelEpsilon);
  EXPECT_EQ(centres.count(), 8u);  // column 3
  const detail::EdgePixels e(g, kPanelCamera, kPanelEpsilon, &scene);
  EXPECT_EQ(e.count(), 0u);
  ASSERT_EQ(e.weighted(), 8u);
  for (size_t i = 0; i < 8; ++i) EXPECT_EQ(e.weights().pixels[i], 8 * i + 3);
  std::vector<AccumulationCell> cells(g.texel_plane.size());
  for (size_t t = 0; t < cells.size(); ++t) {
    const float z = g.planes[4 * size_t(g.texel_plane[t]) + 3] * g.planes[4 * size_t(g.texel_plane[t]) + 2];
    cells[t] = z > 0.5f ? AccumulationCell{8, 8, 8, 2} : AccumulationCell{0, 0, 0, 2};
  }
  PixelReprojection plain, weighted;
  downsample_cells(cells, g.width, g.height, 4, {}, &plain);
  weighted.area_weights = &e.weights();
  downsample_cells(cells, g.width, g.height, 4, {}, &weighted);
  for (int y = 0; y < 8; ++y) {
    EXPECT_FLOAT_EQ(plain.radiance.rgb(3, y).x, 1.f);
    EXPECT_FLOAT_EQ(weighted.radiance.rgb(3, y).x, 1.25f);
    EXPECT_FLOAT_EQ(weighted.radiance.rgb(2, y).x, 4.f);
    EXPECT_FLOAT_EQ(weighted.radiance.rgb(4, y).x, 0.f);
  }
}

// The outline at 1/10 of column 3, between the pixel's border and its first texel centres: the
// panel covers area but no centre there, so column 3 stays an edge pixel; column 2, whose ring saw
// the wall, is all panel and no edge pixel.
TEST(AreaWeights, ASurfaceCoveringAreaButNoCentreLeavesAnEdgePixel) {
  const Scene scene = panel_scene(kPanelCamera, 0.1f);
  const detail::PlaneGrid g = panel_grid(scene);
  EXPECT_EQ(detail::EdgePixels(g, kPanelCamera, kPanelEpsilon).count(), 16u);  // columns 2 and 3
  const detail::EdgePixels e(g, kPanelCamera, kPanelEpsilon, &scene);
  EXPECT_EQ(e.weighted(), 0u);
  ASSERT_EQ(e.count(), 8u);
  for (int y = 0; y < 8; ++y) EXPECT_TRUE(e[size_t(8 * y + 3)]);
}

// The reference for the edge pixels' rays: every triangle, Moller-Trumbore with inclusive edges,
// from tnear on, not in a hole, the nearest.
void brute_force_rays(const Scene& s, std::span<const Ray> rays, std::span<const float> tnear, std::span<Hit> hits) {
  for (size_t i = 0; i < rays.size(); ++i) {
    hits[i] = Hit{};
    hits[i].prim = EmbreeBvh::kMissed;
    float best = INFINITY;
    for (uint32_t t = 0; t < uint32_t(s.triangle_count()); ++t) {
      const Vec3 a = s.positions[s.triangles[t][0]];
      float u, v, tt;
      if (!detail::ray_triangle(rays[i], a, s.positions[s.triangles[t][1]] - a, s.positions[s.triangles[t][2]] - a, &u,
                                &v, &tt))
        continue;
      if (!(u >= 0 && v >= 0 && u + v <= 1) || !(tt >= tnear[i]) || !(tt < best)) continue;
      if (s.materials[s.material_of[t]].cut_out() && s.cut_out_at(t, u, v)) continue;
      best = tt, hits[i].prim = t, hits[i].t = tt;
    }
  }
}

// The edge pixels of the Cornell box and of a checker-cut screen in front of a wall (its holes
// outline surfaces too), resolved with the Embree BVH and with the brute-force reference: the same
// edge pixels, area-weighted pixels and weights.
TEST(AreaWeights, EmbreeVisibilityGivesTheBruteForceReferencesWeights) {
  for (const Scene& scene : {make_builtin_scene("cornell"), test::cutout_screen_scene(8)}) {
    SCOPED_TRACE(scene.name);
    const Camera cam(scene.camera, 40, 40);
    const float epsilon = RenderOptions{}.epsilon * scene.bounds().diagonal_length();
    const detail::PlaneGrid g =
        detail::build_plane_grid_any(scene, cam, 4, epsilon * detail::kCreaseToleranceFraction, true);
    const detail::EdgePixels embree(g, cam, epsilon, &scene);
    const detail::EdgePixels reference(
        g, cam, epsilon, &scene, [&scene](std::span<const Ray> r, std::span<const float> tnear, std::span<Hit> h) {
          brute_force_rays(scene, r, tnear, h);
        });
    std::printf("%s 40 x 40: %zu edge pixels, %zu area-weighted\n", scene.name.c_str(), reference.count(),
                reference.weighted());
    EXPECT_GT(reference.weighted(), 20u);
    EXPECT_GT(reference.count(), 0u);
    EXPECT_EQ(embree.count(), reference.count());
    for (size_t p = 0; p < 40 * 40; ++p) EXPECT_EQ(embree[p], reference[p]) << "pixel " << p;
    EXPECT_EQ(embree.weights().pixels, reference.weights().pixels);
    EXPECT_EQ(embree.weights().cells, reference.weights().cells);
  }
}

// Crytek Sponza at 64 x 64 (its camera, S = 4, the default epsilon): most of the pixels that took no
// reprojected samples by the centres' test keep them, area-weighted or found to see one surface.
TEST(AreaWeights, SponzaKeepsReprojectedSamplesInMostFormerEdgePixels) {
  const Scene scene = load_scene((std::filesystem::path(EPR_SOURCE_DIR) / "scenes/crytek-sponza/sponza.json").string());
  const Camera cam(scene.camera, 64, 64);
  const float epsilon = RenderOptions{}.epsilon * scene.bounds().diagonal_length();
  const detail::PlaneGrid g =
      detail::build_plane_grid_any(scene, cam, 4, epsilon * detail::kCreaseToleranceFraction, true);
  const detail::EdgePixels before(g, cam, epsilon);
  const detail::EdgePixels after(g, cam, epsilon, &scene);
  size_t kept = 0;
  for (size_t p = 0; p < 64 * 64; ++p) kept += before[p] && !after[p];
  std::printf("Sponza 64 x 64: %zu edge pixels by centres, %zu kept (%zu area-weighted), %zu left\n", before.count(),
              kept, after.weighted(), after.count());
  EXPECT_GT(before.count(), 64u * 64u / 2);
  EXPECT_GT(kept, before.count() / 2);
  EXPECT_EQ(before.count(), kept + after.count());
}

}  // namespace
}  // namespace epr
