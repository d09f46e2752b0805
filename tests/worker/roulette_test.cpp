// worker/roulette.h's survival probability on hand-made vertices: what each policy makes of the
// path's throughput and of vertices that reprojection can or cannot show, and the policies' names
// (common/roulette.h). The furnace tests (path_tracer_test.cpp, tests/client/local_render_test.cpp)
// check that every policy keeps pixels and records unbiased.
#include "worker/roulette.h"

#include <gtest/gtest.h>

namespace epr {
namespace {

// Eye at the origin looking down -z; a 64 x 64 image.
const Camera kCamera(CameraSpec{Vec3(0, 0, 0), Vec3(0, 0, -1), Vec3(0, 1, 0), 60.f}, 64, 64);
const Vec3 kInView(0, 0, -3), kFacing(0, 0, 1);  // in the image's centre, facing the eye
const Vec3 kBehind(0, 0, 3);                     // behind the eye

TEST(PathRoulette, PaperAndAlbedoIgnoreThroughput) {
  const RussianRoulette paper = RussianRoulette::paper(), albedo = RussianRoulette::albedo();
  PathRoulette p(paper, kCamera), a(albedo, kCamera);
  for (int depth = 1; depth <= 12; ++depth) {
    EXPECT_FLOAT_EQ(p.survival(depth, 0.5f, kBehind, kFacing, true), depth > 8 ? 0.9f : 1.f) << depth;
    EXPECT_FLOAT_EQ(a.survival(depth, 0.5f, kBehind, kFacing, true), depth > 3 ? 0.5f : 1.f) << depth;
    p.continued(Vec3(0.1f));
    a.continued(Vec3(0.1f));
  }
  EXPECT_FLOAT_EQ(a.survival(13, 0.01f, kBehind, kFacing, true), 0.05f);  // the floor
}

TEST(PathRoulette, ThroughputFollowsTheLargestChannel) {
  const RussianRoulette rr = RussianRoulette::throughput();
  PathRoulette t(rr, kCamera);
  EXPECT_FLOAT_EQ(t.survival(1, 0.5f, kInView, kFacing, true), 1.f);
  t.continued(Vec3(0.8f, 0.4f, 0.2f));
  EXPECT_FLOAT_EQ(t.survival(2, 0.5f, kInView, kFacing, true), 1.f);  // start depth 2
  t.continued(Vec3(0.5f));
  // beta = (0.4, 0.2, 0.1): q = 0.4 x albedo 0.5, whether reprojection shows the vertex or not.
  EXPECT_FLOAT_EQ(t.survival(3, 0.5f, kInView, kFacing, true), 0.2f);
  EXPECT_FLOAT_EQ(t.survival(3, 0.5f, kBehind, kFacing, true), 0.2f);
  t.continued(Vec3(0.01f));
  EXPECT_FLOAT_EQ(t.survival(4, 0.5f, kInView, kFacing, true), 0.05f);  // the floor
  EXPECT_FLOAT_EQ(t.survival(rr.max_depth, 1.f, kInView, kFacing, true), 0.f);
}

TEST(PathRoulette, ReuseRestartsTheThroughputOnVerticesReprojectionShows) {
  const RussianRoulette rr = RussianRoulette::reuse();
  const auto q_after = [&](const Vec3& position, const Vec3& normal, bool diffuse) {
    PathRoulette r(rr, kCamera);
    r.survival(1, 0.5f, kBehind, kFacing, true);
    r.continued(Vec3(0.2f));
    r.survival(2, 0.5f, kBehind, kFacing, true);
    r.continued(Vec3(0.5f));  // beta = 0.1
    return r.survival(3, 0.5f, position, normal, diffuse);
  };
  EXPECT_FLOAT_EQ(q_after(kInView, kFacing, true), 0.5f);           // beta restarts: q = albedo
  EXPECT_FLOAT_EQ(q_after(kBehind, kFacing, true), 0.05f);          // behind the eye: 0.1 x 0.5
  EXPECT_FLOAT_EQ(q_after(kInView, -kFacing, true), 0.05f);         // facing away from the eye
  EXPECT_FLOAT_EQ(q_after(kInView, kFacing, false), 0.05f);         // glossy: not reprojected
  EXPECT_FLOAT_EQ(q_after(Vec3(50, 0, -3), kFacing, true), 0.05f);  // outside the image
}

TEST(RouletteNames, EveryPolicyByNameAndBack) {
  for (const NamedRoulette& n : named_roulettes()) {
    EXPECT_EQ(roulette_named(n.name), n.rr) << n.name;
    EXPECT_EQ(roulette_name(n.rr.mode), n.name);
  }
  EXPECT_EQ(roulette_named("REUSE"), RussianRoulette::reuse());
  EXPECT_FALSE(roulette_named("russian"));
  EXPECT_FALSE(roulette_named(""));
  EXPECT_EQ(roulette_names(), "paper, albedo, off, throughput, reuse, auto");
}

TEST(RouletteAuto, IsReuseUnderASkyOrSunAndAlbedoInsideKeepingTheDepthsGiven) {
  EXPECT_EQ(RussianRoulette::standard(), RussianRoulette::automatic());
  EXPECT_EQ(RussianRoulette::automatic().resolved(true), RussianRoulette::reuse());
  EXPECT_EQ(RussianRoulette::automatic().resolved(false), RussianRoulette::albedo());
  RussianRoulette capped = RussianRoulette::automatic();
  capped.max_depth = 12;
  capped.start_depth = 5;
  const RussianRoulette inside = capped.resolved(false);
  EXPECT_EQ(inside.mode, RussianRoulette::Mode::kAlbedo);
  EXPECT_EQ(inside.max_depth, 12);
  EXPECT_EQ(inside.start_depth, 5);
  // Every other policy is itself, wherever the light comes from.
  for (const NamedRoulette& n : named_roulettes())
    if (n.rr.mode != RussianRoulette::Mode::kAuto) {
      EXPECT_EQ(n.rr.resolved(true), n.rr) << n.name;
      EXPECT_EQ(n.rr.resolved(false), n.rr) << n.name;
    }
}

}  // namespace
}  // namespace epr
