// The scene's Embree BVH (common/embree_bvh.h): a coherent stream of camera rays finds, ray by ray,
// the hit a single ray finds (the same distance; the same triangle but where the ray passes through
// an edge two triangles share) -- through cut-out holes, from each ray's own tnear on, and nothing
// where a ray leaves the scene.
#include "common/embree_bvh.h"

#include <gtest/gtest.h>

#include <cmath>
#include <stdexcept>
#include <vector>

#include "common/builtin_scenes.h"
#include "tests/common/cutout_scenes.h"

namespace epr {
namespace {

// Every ray of a w x h grid of camera rays, 3 x 3 per pixel, with tnear `near` / cos(view direction).
void expect_stream_matches_single_rays(const Scene& scene, int w, int h, float near) {
  const EmbreeBvh bvh(scene);
  const Camera cam(scene.camera, w, h);
  std::vector<Ray> rays;
  std::vector<float> tnear;
  for (int y = 0; y < 3 * h; ++y)
    for (int x = 0; x < 3 * w; ++x) {
      rays.push_back(cam.generate_ray((float(x) + 0.5f) / 3, (float(y) + 0.5f) / 3));
      tnear.push_back(near / dot(rays.back().dir, cam.forward()));
    }
  std::vector<Hit> hits(rays.size());
  bvh.intersect_coherent(rays, tnear, hits);
  size_t hit_count = 0, ties = 0;
  for (size_t i = 0; i < rays.size(); ++i) {
    Hit one;
    const bool found = bvh.intersect(rays[i], tnear[i], INFINITY, &one);
    ASSERT_EQ(found, hits[i].prim != EmbreeBvh::kMissed) << "ray " << i;
    if (!found) continue;
    ++hit_count;
    // Where a ray meets two triangles at one distance (through their common edge) either may be
    // reported: the packets and the single ray may break the tie differently.
    ties += hits[i].prim != one.prim;
    EXPECT_NEAR(hits[i].t, one.t, 1e-5f * one.t) << "ray " << i;
    EXPECT_GE(hits[i].t, tnear[i]);
  }
  EXPECT_GT(hit_count, rays.size() / 4);
  EXPECT_LE(ties, hit_count / 100) << ties << " of " << hit_count << " hits on another triangle";
}

TEST(EmbreeBvh, CoherentStreamFindsWhatSingleRaysFindThroughHoles) {
  const Scene scene = test::cutout_screen_scene(8);
  ASSERT_TRUE(scene.has_cut_outs());
  expect_stream_matches_single_rays(scene, 24, 24, 1e-4f);
  // Without the cut-out filter the screen would hide the wall behind its holes: inside the screen's
  // outline the stream's rays see the wall through the holes and the screen elsewhere.
  const EmbreeBvh bvh(scene);
  const Camera cam(scene.camera, 24, 24);
  int through = 0, on_screen = 0;
  for (int y = 0; y < 24; ++y)
    for (int x = 0; x < 24; ++x) {
      const Ray r = cam.generate_ray(float(x) + 0.5f, float(y) + 0.5f);
      const Vec3 p = r.origin + r.dir * (-r.origin.z / r.dir.z);  // where it crosses the screen's plane
      if (std::fabs(p.x) > 0.45f || std::fabs(p.y) > 0.45f) continue;
      Hit h[1];
      const float near[1] = {0.f};
      bvh.intersect_coherent({&r, 1}, near, h);
      ASSERT_NE(h[0].prim, EmbreeBvh::kMissed);
      (scene.material_of[h[0].prim] == 0 ? through : on_screen)++;
    }
  EXPECT_GT(through, 20);
  EXPECT_GT(on_screen, 20);
}

TEST(EmbreeBvh, CoherentStreamFindsWhatSingleRaysFindInTheBuiltInScenes) {
  for (const char* name : {"cornell", "conference"}) {
    SCOPED_TRACE(name);
    const Scene scene = make_builtin_scene(name);
    expect_stream_matches_single_rays(scene, 33, 17, 1e-5f * scene.bounds().diagonal_length());
  }
}

// tnear starts each ray: a ray from in front of the screen with tnear past it sees the wall, and
// every ray of a stream pointing away from the scene hits nothing.
TEST(EmbreeBvh, CoherentStreamHonoursEachRaysTnearAndReportsMisses) {
  const Scene scene = test::cutout_screen_scene(4, false, true);  // an opaque screen at z = 0
  const EmbreeBvh bvh(scene);
  const std::vector<Ray> rays = {
      {{0.1f, 0.1f, 2.f}, {0, 0, -1}}, {{0.1f, 0.1f, 2.f}, {0, 0, -1}}, {{0.1f, 0.1f, 2.f}, {0, 0, 1}}};
  const std::vector<float> tnear = {0.f, 2.5f, 0.f};
  std::vector<Hit> hits(3);
  bvh.intersect_coherent(rays, tnear, hits);
  EXPECT_NEAR(hits[0].t, 2.f, 1e-5f);
  EXPECT_NE(scene.material_of[hits[0].prim], 0u);
  EXPECT_NEAR(hits[1].t, 3.f, 1e-5f);
  EXPECT_EQ(scene.material_of[hits[1].prim], 0u);
  EXPECT_EQ(hits[2].prim, EmbreeBvh::kMissed);
  EXPECT_THROW(bvh.intersect_coherent(rays, std::vector<float>(2), hits), std::invalid_argument);
}

}  // namespace
}  // namespace epr
