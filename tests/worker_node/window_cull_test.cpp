// A frame window's leases (TileLease.window_cameras): the worker keeps the vertices its own camera
// culls when another frame of the window would show them, and refuses an unusable window camera.
#include <gtest/gtest.h>

#include "common/builtin_scenes.h"
#include "wire/convert.h"
#include "worker/tile_lease.h"
#include "worker/view_test.h"

namespace epr {
namespace window_cull_test {
namespace {

// A 32 x 32 skip-mode lease of the Cornell box, its whole image one tile.
v1::TileLease cornell_lease(const Scene& scene) {
  RenderOptions o;
  o.width = o.height = 32;
  o.mode = RenderMode::kSkip;
  o.reproject = ReprojectMethod::kCpu;
  v1::TileLease lease;
  lease.set_lease_id(1);
  lease.set_job_id("job-w");
  auto* r = lease.mutable_rect();
  r->set_x1(32);
  r->set_y1(32);
  lease.set_paths_per_pixel(4);
  lease.set_seed(3);
  to_render_settings(o, scene.camera, scene.bounds(), lease.mutable_settings());
  lease.mutable_scene()->set_builtin("builtin:cornell");
  return lease;
}

TEST(WindowCull, VerticesAnotherFrameShowsAreKept) {
  const Scene scene = make_builtin_scene("cornell");
  const EmbreeScene embree(scene);
  v1::TileLease lease = cornell_lease(scene);
  // The other frame: by the back wall, looking out of the box -- at the blocks' back faces and the
  // walls' fronts, which the own camera sees from behind or not at all.
  CameraSpec other;
  other.eye = Vec3(0.f, 1.f, -0.8f);
  other.look = Vec3(0.f, 0.8f, 2.f);
  LeasedTile alone, window;
  ASSERT_FALSE(unpack_tile_lease(lease, &alone));
  to_proto(other, lease.add_window_cameras());
  ASSERT_FALSE(unpack_tile_lease(lease, &window));
  ASSERT_EQ(window.filter.window_cameras.size(), 1u);
  const Camera own(from_proto(lease.settings().camera()), 32, 32), theirs(other, 32, 32);
  const PathTracer tracer(embree, own, lease.seed(), from_proto(lease.settings().russian_roulette()));
  const TileResult a = TileRenderer(tracer, alone.filter).render(alone.request());
  const TileResult w = TileRenderer(tracer, window.filter).render(window.request());
  // The same paths; the window keeps every vertex the frame alone keeps, and more.
  EXPECT_EQ(a.stats.vertices_recorded, w.stats.vertices_recorded);
  EXPECT_GT(w.vertices.size(), a.vertices.size());
  EXPECT_LT(w.stats.culled_frustum + w.stats.culled_facing, a.stats.culled_frustum + a.stats.culled_facing);
  size_t shown = 0;
  for (const VertexRecord& v : w.vertices) {
    float x, y;
    shown += view_test(own, v.position, v.normal, 2, &x, &y) == ViewTest::kVisible ||
             view_test(theirs, v.position, v.normal, 2, &x, &y) == ViewTest::kVisible;
  }
  EXPECT_EQ(shown, w.vertices.size()) << "every kept vertex is shown by one of the cameras";
}

TEST(WindowCull, AnUnusableWindowCameraIsRefused) {
  const Scene scene = make_builtin_scene("cornell");
  v1::TileLease lease = cornell_lease(scene);
  CameraSpec degenerate;
  degenerate.look = degenerate.eye;
  to_proto(scene.camera, lease.add_window_cameras());
  to_proto(degenerate, lease.add_window_cameras());
  LeasedTile t;
  const auto err = unpack_tile_lease(lease, &t);
  ASSERT_TRUE(err);
  EXPECT_NE(err->find("window camera 1"), std::string::npos) << *err;
  v1::TileLease many = cornell_lease(scene);
  for (int i = 0; i < 33; ++i) to_proto(scene.camera, many.add_window_cameras());
  const auto too_many = unpack_tile_lease(many, &t);
  ASSERT_TRUE(too_many);
  EXPECT_NE(too_many->find("33 window cameras, at most 32"), std::string::npos) << *too_many;
}

}  // namespace
}  // namespace window_cull_test
}  // namespace epr
