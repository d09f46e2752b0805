// The cut measurement's view share (master/view_overlap.h): rays from each camera, traced with the
// scene's BVH, and the other camera's rays towards their hits.
#include "master/view_overlap.h"

#include <gtest/gtest.h>

#include <cstdio>
#include <optional>
#include <string>
#include <utility>

#include "common/builtin_scenes.h"
#include "common/camera_animation.h"
#include "common/scene_loader.h"
#include "tests/common/cutout_scenes.h"

namespace epr {
namespace view_overlap_test {
namespace {

// A wall in the plane z = 0 (x, y in [-4, 4]) facing +z, and, with `blocker`, a panel at z = 4.5
// covering x in [-5, blocker] (y in [-5, 5]).
Scene wall_scene(std::optional<float> blocker = std::nullopt) {
  Scene s;
  s.name = "test-wall";
  const uint32_t m = add_material(s, Material{});
  add_quad(s, {-4, -4, 0}, {4, -4, 0}, {4, 4, 0}, {-4, 4, 0}, m);
  if (blocker) add_quad(s, {-5, -5, 4.5f}, {*blocker, -5, 4.5f}, {*blocker, 5, 4.5f}, {-5, 5, 4.5f}, m);
  return s;
}

CameraSpec looking(Vec3 eye, Vec3 look, float fov) {
  CameraSpec c;
  c.eye = eye;
  c.look = look;
  c.fov_y_degrees = fov;
  return c;
}

// Camera a close to the wall (its view all wall), camera b further back with a wider view holding
// all of a's: the panel stands between b and the wall, behind a.
const CameraSpec kNear = looking({0, 0, 3}, {0, 0, 0}, 40), kFar = looking({0, 0, 6}, {0, 0, 0}, 60);

TEST(ViewShare, IdenticalCamerasShareEverything) {
  const Scene scene = make_builtin_scene("cornell");
  const SceneBvh bvh(scene);
  const ViewProbe a = view_probe(bvh, scene.camera, 64, 48), b = view_probe(bvh, scene.camera, 64, 48);
  ASSERT_FALSE(a.points.empty());
  EXPECT_EQ(view_share(a, b, bvh), 1.0);
  EXPECT_EQ(mutual_view_share(a, b, bvh), 1.0);
}

TEST(ViewShare, ACameraLookingAwaySharesNothing) {
  const Scene scene = wall_scene();
  const SceneBvh bvh(scene);
  const ViewProbe a = view_probe(bvh, kNear, 32, 32);
  const ViewProbe away = view_probe(bvh, looking({0, 0, 3}, {0, 0, 6}, 40), 32, 32);
  ASSERT_EQ(a.points.size(), size_t(kViewProbeSide) * size_t(kViewProbeSide)) << "a sees the wall only";
  EXPECT_EQ(view_share(a, away, bvh), 0.0);
  EXPECT_EQ(view_share(away, a, bvh), 1.0) << "a camera that sees nothing shares all it sees";
}

TEST(ViewShare, AWallBetweenHidesWhatItCovers) {
  // No panel: b sees all a sees. The panel over x < 0: b sees a's right half (64 of 128 columns).
  // The panel over everything: b sees none of it.
  const std::pair<std::optional<float>, double> cases[] = {{std::nullopt, 1.0}, {0.f, 0.5}, {5.f, 0.0}};
  for (const auto& [blocker, expected] : cases) {
    SCOPED_TRACE("panel up to x = " + (blocker ? std::to_string(*blocker) : std::string("none")));
    const Scene scene = wall_scene(blocker);
    const SceneBvh bvh(scene);
    const ViewProbe a = view_probe(bvh, kNear, 32, 32), b = view_probe(bvh, kFar, 32, 32);
    ASSERT_EQ(a.points.size(), size_t(kViewProbeSide) * size_t(kViewProbeSide)) << "the panel is behind a";
    EXPECT_EQ(view_share(a, b, bvh), expected);
  }
}

TEST(ViewShare, BackFacesAndPointsBehindTheOtherEyeAreNotShared) {
  // b behind the wall looking at its back: every point of a's view projects into b's image, none faces b.
  const Scene scene = wall_scene();
  const SceneBvh bvh(scene);
  const ViewProbe a = view_probe(bvh, kNear, 32, 32);
  EXPECT_EQ(view_share(a, view_probe(bvh, looking({0, 0, -6}, {0, 0, 0}, 60), 32, 32), bvh), 0.0);
  // b between a and the wall, looking at a: the wall is behind b.
  EXPECT_EQ(view_share(a, view_probe(bvh, looking({0, 0, 1}, {0, 0, 3}, 60), 32, 32), bvh), 0.0);
}

TEST(ViewShare, TheOtherEyeSeesThroughTheHolesOfACutOut) {
  // a, between the cut-out screen and the wall, sees only the wall; b sees the wall through the
  // screen, whose checker mask hides about half of it: the share is what b sees through the holes,
  // as with the holes modelled as geometry; with an opaque screen nothing.
  const CameraSpec between = looking({0, 0, -0.2f}, {0, 0, -1}, 60), front = looking({0, 0, 2}, {0, 0, -1}, 30);
  auto share = [&](const Scene& scene) {
    const SceneBvh bvh(scene);
    return view_share(view_probe(bvh, between, 32, 32), view_probe(bvh, front, 32, 32), bvh);
  };
  const double masked = share(test::cutout_screen_scene(4)), modelled = share(test::cutout_screen_scene(4, true));
  EXPECT_NEAR(masked, modelled, 0.01);
  EXPECT_GT(masked, 0.3);
  EXPECT_LT(masked, 0.7);
  EXPECT_EQ(share(test::cutout_screen_scene(4, false, true)), 0.0);
}

double pair_share(const std::string& file, uint32_t f0, uint32_t f1) {
  const std::string path = std::string(EPR_SOURCE_DIR) + "/scenes/" + file;
  CameraSpec still;
  const CameraAnimation anim = load_camera_animation(path, {}, &still);
  const Scene scene = load_scene(path);
  const SceneBvh bvh(scene);
  return mutual_view_share(view_probe(bvh, anim.at(f0, still), 160, 90), view_probe(bvh, anim.at(f1, still), 160, 90),
                           bvh);
}

TEST(ViewShare, TheConferenceRoomsCutSharesLittleAndItsFlyThroughMuch) {
  // BENCHMARKS.md section 18: the fly-through's pairs 88-91 %, the two shots of the cut scene 27 %.
  const double smooth = pair_share("conference-flythrough.json", 10, 11);
  const double cut = pair_share("conference-cut.json", 24, 25);
  const double within = pair_share("conference-cut.json", 22, 23);
  EXPECT_GT(smooth, 0.8);
  EXPECT_GT(within, 0.8);
  EXPECT_LT(cut, 0.4);
  EXPECT_GT(cut, 0.1) << "the default threshold does not cut the conference room's two shots";
  std::printf("conference fly-through 10-11 %.3f, cut scene 22-23 %.3f, 24-25 %.3f\n", smooth, within, cut);
}

}  // namespace
}  // namespace view_overlap_test
}  // namespace epr
