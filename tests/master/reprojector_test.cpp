// Reprojectors: known answers for the geometric cases on both back-ends, and bit-identical decisions
// and per-subpixel counts between "gl" and "cpu" on large random and real-like vertex sets.
#include "master/reprojector.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>

#include "master/cpu_reprojector.h"
#include "master/gl_context.h"
#include "master/gl_reprojector.h"
#include "master/make_reprojector.h"
#include "master/reprojection_kernel.h"
#include "test_scenes.h"

namespace epr {
namespace {

CameraSpec head_on() {
  CameraSpec c;
  c.eye = {0, 0, 3};
  c.look = {0, 0, 0};
  c.up = {0, 1, 0};
  c.fov_y_degrees = 40;
  return c;
}

Scene quads(std::initializer_list<float> depths, float half = 1) {
  Scene s;
  const uint32_t m = add_material(s, Material{});
  for (float z : depths) add_quad(s, {-half, -half, z}, {half, -half, z}, {half, half, z}, {-half, half, z}, m);
  return s;
}

VertexRecord rec(Vec3 p, Vec3 n, Vec3 L = Vec3(1, 2, 3), uint32_t flags = VertexRecord::kDiffuse) {
  VertexRecord r;
  r.position = p;
  r.normal = n;
  r.radiance = L;
  r.flags = flags;
  return r;
}

// ---- both back-ends: known answers ---------------------------------------------------------------

class ReprojectorCase : public ::testing::TestWithParam<std::string> {
 protected:
  void SetUp() override {
    if (GetParam() == "gl") {
      ASSERT_TRUE(gl_available()) << "OSMesa unavailable: run scripts/setup.sh (libosmesa6)";
      ctx_ = std::make_unique<GlContext>();
    }
  }
  std::unique_ptr<Reprojector> make(const Scene& scene, const Camera& cam, float eps, int S = 4,
                                    ReprojectorSettings settings = {}) {
    dfb_ = build_deep_framebuffer_cpu(scene, cam, S);
    settings.epsilon = eps;
    return make_reprojector(GetParam(), cam, dfb_, settings, ctx_.get());
  }
  std::unique_ptr<GlContext> ctx_;
  DeepFramebuffer dfb_;
};

TEST_P(ReprojectorCase, PlaneSeenHeadOnAcceptsAllItsPointsEvenWithZeroEpsilon) {
  const Scene scene = quads({0.f});
  const Camera cam(head_on(), 64, 64);
  for (float eps : {default_epsilon(scene.bounds()), 0.f}) {
    auto r = make(scene, cam, eps);
    std::mt19937 rng(7);
    std::uniform_real_distribution<float> u(-0.9f, 0.9f);
    std::vector<VertexRecord> pts;
    for (int i = 0; i < 20000; ++i) pts.push_back(rec({u(rng), u(rng), 0.f}, {0, 0, 1}));
    r->reproject(pts);
    const ReprojectionCounts c = r->counts();
    EXPECT_EQ(c.accepted, pts.size()) << "epsilon " << eps;
    EXPECT_EQ(c.occluded + c.culled, 0u);
    const SubpixelAccumulation a = r->read();
    uint64_t total = 0;
    double red = 0;
    for (size_t i = 0; i < a.size(); ++i) total += a.count[i], red += a.sum[3 * i];
    EXPECT_EQ(total, pts.size());
    EXPECT_NEAR(red, double(pts.size()), 1e-3);
  }
}

TEST_P(ReprojectorCase, PointBehindAWallIsOccluded) {
  const Scene scene = quads({0.f, -1.f}, 2);  // wall at z = 0 hides the plane at z = -1
  const Camera cam(head_on(), 64, 64);
  auto r = make(scene, cam, default_epsilon(scene.bounds()));
  const std::vector<VertexRecord> pts = {rec({0.1f, 0.2f, -1.f}, {0, 0, 1}), rec({0.1f, 0.2f, 0.f}, {0, 0, 1})};
  r->reproject(pts);
  const ReprojectionCounts c = r->counts();
  EXPECT_EQ(c.occluded, 1u);
  EXPECT_EQ(c.backfacing, 0u);
  EXPECT_EQ(c.accepted, 1u);
}

TEST_P(ReprojectorCase, PointsOutsideTheFrustumOrBehindTheCameraAreCulled) {
  const Scene scene = quads({0.f});
  const Camera cam(head_on(), 64, 64);
  auto r = make(scene, cam, 0.01f);
  const std::vector<VertexRecord> pts = {
      rec({0, 0, 5}, {0, 0, 1}),    // behind the eye
      rec({0, 0, 3}, {0, 0, 1}),    // at the eye plane: not strictly in front
      rec({10, 0, 0}, {0, 0, 1}),   // right of the frustum
      rec({0, -10, 0}, {0, 0, 1}),  // below
      rec({0, 0, 0}, {0, 0, 1}),    // visible: accepted
  };
  r->reproject(pts);
  EXPECT_EQ(r->counts().culled, 4u);
  EXPECT_EQ(r->counts().accepted, 1u);
}

TEST_P(ReprojectorCase, BackFacingPointOnThinTwoSidedWallDoesNotLeak) {
  const Scene scene = quads({0.f});  // one quad, no thickness
  const Camera cam(head_on(), 64, 64);
  auto r = make(scene, cam, default_epsilon(scene.bounds()));
  // Lit from behind the wall (normal towards -z, away from the eye) but exactly on the visible plane.
  const std::vector<VertexRecord> pts = {rec({0.3f, 0.3f, 0.f}, {0, 0, -1}), rec({0.3f, 0.3f, 0.f}, {0, 0, 1})};
  r->reproject(pts);
  const ReprojectionCounts c = r->counts();
  EXPECT_EQ(c.backfacing, 1u);
  EXPECT_EQ(c.occluded, 1u);
  EXPECT_EQ(c.accepted, 1u);
  // Grazing: normal perpendicular to the view ray counts as back-facing (dot <= 0).
  const Vec3 to_eye = cam.eye() - Vec3(0.3f, 0.3f, 0.f);
  r->reproject(std::vector<VertexRecord>{rec({0.3f, 0.3f, 0.f}, normalize(Vec3(to_eye.z, 0, -to_eye.x)))});
  EXPECT_EQ(r->counts().backfacing, 2u);
}

TEST_P(ReprojectorCase, EpsilonIsAbsolutePlaneDistance) {
  const Scene scene = quads({0.f});
  const Camera cam(head_on(), 64, 64);
  const float eps = 1e-3f;
  auto r = make(scene, cam, eps);
  r->reproject(
      std::vector<VertexRecord>{rec({0.2f, 0.1f, 0.5f * eps}, {0, 0, 1}), rec({0.2f, 0.1f, -0.9f * eps}, {0, 0, 1}),
                                rec({0.2f, 0.1f, 2.f * eps}, {0, 0, 1}), rec({0.2f, 0.1f, -2.f * eps}, {0, 0, 1})});
  EXPECT_EQ(r->counts().accepted, 2u);
  EXPECT_EQ(r->counts().occluded, 2u);
}

TEST_P(ReprojectorCase, UncoveredTexelOccludes) {
  const Scene scene = quads({0.f}, 0.5f);
  const Camera cam(head_on(), 64, 64);
  auto r = make(scene, cam, 1.f);  // huge epsilon: only coverage can reject
  r->reproject(std::vector<VertexRecord>{rec({0.8f, 0.8f, 0.f}, {0, 0, 1})});
  EXPECT_EQ(r->counts().occluded, 1u);
}

// The joint test (reprojection_kernel.h), part 1: a point within epsilon of the texel's plane but on a
// surface more than 60 degrees from it is not on that surface.
TEST_P(ReprojectorCase, PointOnAPlaneWithADifferentNormalIsOccluded) {
  const Scene scene = quads({0.f});
  const Camera cam(head_on(), 64, 64);
  const Vec3 p(-0.3f, 0.2f, 0.f);  // normals tilted towards +x still face the eye at (0, 0, 3)
  auto tilted = [](float degrees) {
    const float a = degrees * 3.14159265f / 180.f;
    return Vec3(std::sin(a), 0.f, std::cos(a));
  };
  const std::vector<VertexRecord> pts = {rec(p, {0, 0, 1}), rec(p, tilted(50)), rec(p, tilted(70)), rec(p, {1, 0, 0})};
  for (bool joint : {true, false}) {
    ReprojectorSettings s;
    s.joint_test = joint;
    auto r = make(scene, cam, default_epsilon(scene.bounds()), 4, s);
    r->reproject(pts);
    EXPECT_EQ(r->counts().accepted, joint ? 2u : 4u) << "joint test " << joint;
    EXPECT_EQ(r->counts().backfacing, 0u);
  }
}

// Part 2, the thin-wall joint: two floor quads meet under a zero-thickness partition at x = 0; the
// camera, on the +x side and at the partition's height, sees the right floor and the partition's face
// but nothing of the left floor. Points of the left floor next to the joint project onto the right
// floor's and the partition's texels near the joint; the plane test alone takes some of them.
TEST_P(ReprojectorCase, FloorRunningOnUnderAThinPartitionDoesNotLeak) {
  Scene scene;
  const uint32_t m = add_material(scene, Material{});
  add_quad(scene, {-1, 0, 1}, {0, 0, 1}, {0, 0, -1}, {-1, 0, -1}, m);  // left floor, faces +y
  add_quad(scene, {0, 0, 1}, {1, 0, 1}, {1, 0, -1}, {0, 0, -1}, m);    // right floor
  add_quad(scene, {0, 0, 1}, {0, 0, -1}, {0, 1, -1}, {0, 1, 1}, m);    // partition, faces +x
  CameraSpec spec;
  spec.eye = {1.5f, 1.f, 2.5f};
  spec.look = {-0.2f, 0.3f, 0.f};
  spec.up = {0, 1, 0};
  spec.fov_y_degrees = 50;
  const Camera cam(spec, 64, 64);
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> z(-0.9f, 0.9f), near_joint(1e-4f, 0.02f);
  std::vector<VertexRecord> left, right;
  for (int i = 0; i < 20000; ++i) {
    left.push_back(rec({-near_joint(rng), 0.f, z(rng)}, {0, 1, 0}));
    right.push_back(rec({near_joint(rng), 0.f, z(rng)}, {0, 1, 0}));
  }
  uint64_t accepted[2][2] = {};  // [joint test][left, right]
  for (bool joint : {false, true}) {
    ReprojectorSettings s;
    s.joint_test = joint;
    for (int side = 0; side < 2; ++side) {
      auto r = make(scene, cam, default_epsilon(scene.bounds()), 4, s);
      r->reproject(side == 0 ? left : right);
      accepted[joint][side] = r->counts().accepted;
    }
  }
  std::printf("  accepted left / right: plane test alone %llu / %llu, with the joint test %llu / %llu\n",
              (unsigned long long)accepted[0][0], (unsigned long long)accepted[0][1],
              (unsigned long long)accepted[1][0], (unsigned long long)accepted[1][1]);
  EXPECT_GT(accepted[0][0], 100u) << "the plane test alone must leak here, or the case tests nothing";
  EXPECT_EQ(accepted[1][0], 0u);
  // The visible floor next to the joint keeps its samples.
  EXPECT_GT(accepted[1][1], 0.9 * double(accepted[0][1]));
}

// Part 3: creases must not cut convex edges. A step (top at y = 0.5, front face at z = 0.5) seen from
// above and in front: points on the top and on the front face next to their shared edge.
TEST_P(ReprojectorCase, ConvexEdgeKeepsItsSamples) {
  Scene scene;
  const uint32_t m = add_material(scene, Material{});
  add_quad(scene, {-1, 0.5f, 0.5f}, {1, 0.5f, 0.5f}, {1, 0.5f, -1}, {-1, 0.5f, -1}, m);  // top, faces +y
  add_quad(scene, {-1, 0, 0.5f}, {1, 0, 0.5f}, {1, 0.5f, 0.5f}, {-1, 0.5f, 0.5f}, m);    // front, faces +z
  add_quad(scene, {-1, 0, 2}, {1, 0, 2}, {1, 0, 0.5f}, {-1, 0, 0.5f}, m);                // floor in front
  CameraSpec spec;
  spec.eye = {0.3f, 1.6f, 2.5f};
  spec.look = {0.f, 0.4f, 0.3f};
  spec.up = {0, 1, 0};
  spec.fov_y_degrees = 45;
  const Camera cam(spec, 64, 64);
  std::mt19937 rng(6);
  std::uniform_real_distribution<float> x(-0.9f, 0.9f), near_edge(1e-4f, 0.03f);
  std::vector<VertexRecord> pts;
  for (int i = 0; i < 20000; ++i) {
    pts.push_back(rec({x(rng), 0.5f, 0.5f - near_edge(rng)}, {0, 1, 0}));  // top
    pts.push_back(rec({x(rng), 0.5f - near_edge(rng), 0.5f}, {0, 0, 1}));  // front
  }
  uint64_t accepted[2] = {};
  for (bool joint : {false, true}) {
    ReprojectorSettings s;
    s.joint_test = joint;
    auto r = make(scene, cam, default_epsilon(scene.bounds()), 4, s);
    r->reproject(pts);
    accepted[joint] = r->counts().accepted;
  }
  std::printf("  accepted at the convex edge: plane test alone %llu, with the joint test %llu of %zu\n",
              (unsigned long long)accepted[0], (unsigned long long)accepted[1], pts.size());
  EXPECT_GT(accepted[1], 0.9 * double(pts.size()));
  EXPECT_GT(accepted[1], 0.97 * double(accepted[0]));
}

// Found by tests/fuzz (regressions/tile_result/plane-grid-without-creases): a PlaneGrid filled by
// hand, without make_plane_grid, has no creased entries -- its planes are plain, and the kernel must
// not look for crease ranges it does not have.
TEST(ReprojectionKernel, HandMadePlaneGridHasNoCreases) {
  detail::PlaneGrid g;
  g.width = g.height = 4;
  g.texel_plane.assign(16, 0);
  g.planes = {0.f, 0.f, 1.f, 0.f};
  ASSERT_TRUE(g.crease_range.empty());
  detail::KernelParams k;
  k.epsilon = 1e-3f;
  EXPECT_EQ(detail::plane_test(k, g, Vec3(0.1f, 0.2f, 0.f), Vec3(0, 0, 1), 5), detail::Decision::kAccepted);
  EXPECT_EQ(detail::plane_test(k, g, Vec3(0.1f, 0.2f, 0.5f), Vec3(0, 0, 1), 5), detail::Decision::kOccluded);
}

TEST_P(ReprojectorCase, SubpixelIndexIsRowMajorWithYDown) {
  const Scene scene = quads({0.f}, 2);
  const Camera cam(head_on(), 40, 30);
  const int S = 4;
  auto r = make(scene, cam, 1e-3f, S);
  // The surface point under raster position (10.3, 20.7): bottom-left part of the image.
  const Ray ray = cam.generate_ray(10.3f, 20.7f);
  const Vec3 p = ray.origin + ray.dir * (-ray.origin.z / ray.dir.z);
  const Vec3 on_plane(p.x, p.y, 0.f);
  r->reproject(std::vector<VertexRecord>{rec(on_plane, {0, 0, 1}, {5, 6, 7})});
  ASSERT_EQ(r->counts().accepted, 1u);
  float rx, ry;
  ASSERT_TRUE(cam.project(on_plane, &rx, &ry));
  const uint32_t expect = subpixel_index(rx, ry, S, cam.width(), cam.height());
  EXPECT_EQ(expect, uint32_t(std::floor(ry * S)) * uint32_t(S * 40) + uint32_t(std::floor(rx * S)));
  EXPECT_EQ(expect / (S * 40), 82u);  // row floor(20.7 * 4): counted from the top
  const SubpixelAccumulation a = r->read();
  EXPECT_EQ(a.width, 160);
  EXPECT_EQ(a.height, 120);
  EXPECT_EQ(a.count[expect], 1u);
  EXPECT_EQ(a.sum[3 * expect + 2], 7.f);
}

TEST_P(ReprojectorCase, AccumulatesAcrossCallsUntilReset) {
  const Scene scene = quads({0.f});
  const Camera cam(head_on(), 32, 32);
  auto r = make(scene, cam, 1e-3f);
  const std::vector<VertexRecord> pts = {rec({0, 0, 0}, {0, 0, 1}, {1, 1, 1})};
  r->reproject(pts);
  r->reproject(pts);
  r->add_exact(std::vector<ExactSample>{{subpixel_index(16.f, 16.f, 4, 32, 32), {2, 2, 2}}});
  SubpixelAccumulation a = r->read();
  const uint32_t idx = subpixel_index(16.f, 16.f, 4, 32, 32);
  // (0,0,0) projects to the image centre (16, 16): the same subpixel.
  EXPECT_EQ(a.count[idx], 3u);
  EXPECT_EQ(a.sum[3 * idx], 4.f);
  EXPECT_EQ(r->counts().exact, 1u);
  EXPECT_EQ(r->counts().accepted, 2u);
  r->reset();
  a = r->read();
  EXPECT_EQ(a.count[idx], 0u);
  EXPECT_EQ(a.sum[3 * idx], 0.f);
  EXPECT_EQ(r->counts(), ReprojectionCounts{});
}

TEST_P(ReprojectorCase, GlossyInvalidAndOutOfGridInputsAreCountedAndSkipped) {
  const Scene scene = quads({0.f});
  const Camera cam(head_on(), 32, 32);
  const float nan = std::numeric_limits<float>::quiet_NaN(), inf = std::numeric_limits<float>::infinity();
  const std::vector<VertexRecord> pts = {rec({0, 0, 0}, {0, 0, 1}, {1, 1, 1}, 0),  // glossy
                                         rec({0, 0, 0}, {0, 0, 1}, {nan, 1, 1}), rec({inf, 0, 0}, {0, 0, 1}),
                                         rec({0, 0, 0}, {0, nan, 1})};
  const std::vector<ExactSample> ex = {{32 * 4 * 32 * 4, {1, 1, 1}}, {0, {inf, 0, 0}}, {5, {1, 1, 1}}};
  {
    auto r = make(scene, cam, 1e-3f);
    r->reproject(pts);
    r->add_exact(ex);
    const ReprojectionCounts c = r->counts();
    EXPECT_EQ(c.not_diffuse, 1u);
    EXPECT_EQ(c.invalid, 3u + 2u);
    EXPECT_EQ(c.exact, 1u);
    EXPECT_EQ(c.accepted, 0u);
    const SubpixelAccumulation a = r->read();
    for (float v : a.sum) ASSERT_TRUE(std::isfinite(v));
  }
  ReprojectorSettings s;
  s.reproject_glossy = true;
  auto r = make(scene, cam, 1e-3f, 4, s);
  r->reproject(pts);
  EXPECT_EQ(r->counts().accepted, 1u);
  EXPECT_EQ(r->counts().not_diffuse, 0u);
}

TEST_P(ReprojectorCase, ResultsDoNotDependOnBatchSize) {
  const Scene scene = test::scene_named("cornell");
  const Camera cam(scene.camera, 48, 48);
  const DeepFramebuffer dfb = build_deep_framebuffer_cpu(scene, cam, 4);
  const auto pts = test::real_like_points(scene, dfb, cam, 10000, 3);
  ReprojectorSettings small;
  small.batch_points = 1024;
  auto a = make(scene, cam, default_epsilon(scene.bounds()), 4, small);
  a->reproject(pts);
  auto b = make(scene, cam, default_epsilon(scene.bounds()));
  b->reproject(pts);
  EXPECT_EQ(a->counts(), b->counts());
  EXPECT_EQ(a->read().count, b->read().count);
  EXPECT_GT(a->counts().accepted, 1000u);
}

// The master keeps vertices in their 16-byte wire form: reproject_packed must be reproject() of the
// decoded records -- same decisions, counts and per-subpixel counts (CPU: also the same sums, bit for
// bit; GL adds with float atomics in any order).
TEST_P(ReprojectorCase, PackedVerticesGiveTheSameResultAsTheirDecodedRecords) {
  const Scene scene = test::scene_named("cornell");
  const Camera cam(scene.camera, 48, 48);
  const DeepFramebuffer dfb = build_deep_framebuffer_cpu(scene, cam, 4);
  auto pts = test::real_like_points(scene, dfb, cam, 40000, 21);  // more than one 32768-record chunk
  for (size_t i = 0; i < pts.size(); i += 7) pts[i].flags = 0;    // some glossy ones
  const VertexCodec codec(scene.bounds());
  std::string packed;
  codec.encode_batch(pts, &packed);
  std::vector<VertexRecord> decoded;
  ASSERT_TRUE(codec.decode_batch(packed, &decoded));
  ASSERT_GT(decoded.size(), 30000u);
  auto a = make(scene, cam, default_epsilon(scene.bounds()));
  a->reproject(decoded);
  auto b = make(scene, cam, default_epsilon(scene.bounds()));
  b->reproject_packed(packed.substr(0, 16 * 1000), codec);  // in two calls, as tiles arrive
  b->reproject_packed(packed.substr(16 * 1000), codec);
  EXPECT_EQ(a->counts(), b->counts());
  EXPECT_GT(a->counts().not_diffuse, 1000u);
  EXPECT_GT(a->counts().accepted, 10000u);
  const SubpixelAccumulation ra = a->read(), rb = b->read();
  EXPECT_EQ(ra.count, rb.count);
  if (GetParam() == "cpu") {
    EXPECT_EQ(ra.sum, rb.sum);
  }
}

INSTANTIATE_TEST_SUITE_P(Backends, ReprojectorCase, ::testing::Values("cpu", "gl"));

// ---- GL and CPU agree ----------------------------------------------------------------------------

void expect_same(Reprojector& gl, Reprojector& cpu) {
  const ReprojectionCounts cg = gl.counts(), cc = cpu.counts();
  EXPECT_EQ(cg.accepted, cc.accepted);
  EXPECT_EQ(cg.occluded, cc.occluded);
  EXPECT_EQ(cg.backfacing, cc.backfacing);
  EXPECT_EQ(cg.culled, cc.culled);
  EXPECT_EQ(cg.not_diffuse, cc.not_diffuse);
  EXPECT_EQ(cg.invalid, cc.invalid);
  EXPECT_EQ(cg.exact, cc.exact);
  const SubpixelAccumulation ag = gl.read(), ac = cpu.read();
  ASSERT_EQ(ag.size(), ac.size());
  size_t count_diff = 0, sum_diff = 0;
  for (size_t i = 0; i < ag.size(); ++i) {
    count_diff += ag.count[i] != ac.count[i];
    for (int c = 0; c < 3; ++c) {
      const float g = ag.sum[3 * i + c], r = ac.sum[3 * i + c];
      sum_diff += !(std::fabs(g - r) <= 1e-5f * std::max(std::fabs(r), 1e-3f));
    }
  }
  EXPECT_EQ(count_diff, 0u) << "subpixels whose counts differ";
  EXPECT_EQ(sum_diff, 0u) << "radiance sums differing by more than float rounding";
}

class GlVersusCpu : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_TRUE(gl_available()) << "OSMesa unavailable: run scripts/setup.sh (libosmesa6)";
    ctx_ = std::make_unique<GlContext>();
  }
  void run(const std::string& scene_name, int w, int h, size_t n, uint32_t seed, float eps_scale) {
    const Scene scene = test::scene_named(scene_name);
    const Camera cam(scene.camera, w, h);
    const DeepFramebuffer dfb = build_deep_framebuffer_gl(*ctx_, scene, cam, 4);
    ReprojectorSettings s;
    s.epsilon = default_epsilon(scene.bounds()) * eps_scale;
    s.batch_points = 1 << 16;  // several batches and ring-slot reuse
    GlReprojector gl(*ctx_, cam, dfb, s);
    CpuReprojector cpu(cam, dfb, s);
    std::mt19937 rng(seed);
    // Round 1: real-like mix. Round 2: random points and points on subpixel boundaries. Round 3:
    // exact samples.
    const auto real = test::real_like_points(scene, dfb, cam, n, seed);
    std::vector<VertexRecord> random;
    test::add_random_points(scene, n / 2, rng, random);
    test::add_boundary_points(dfb, cam, n / 4, rng, random);
    std::vector<ExactSample> exact(n / 10);
    std::uniform_int_distribution<uint32_t> sub(0, uint32_t(dfb.texel_count() - 1));
    for (auto& e : exact) e = {sub(rng), {1.5f, 0.25f, 3.f}};
    for (Reprojector* r : {static_cast<Reprojector*>(&gl), static_cast<Reprojector*>(&cpu)}) {
      r->reproject(real);
      r->reproject(random);
      r->add_exact(exact);
    }
    const ReprojectionCounts c = cpu.counts();
    EXPECT_GT(c.accepted, n / 4) << "the set must exercise acceptance";
    EXPECT_GT(c.occluded - c.backfacing, n / 50) << "and plane/coverage occlusion";
    EXPECT_GT(c.backfacing, n / 50);
    EXPECT_GT(c.culled, n / 50);
    expect_same(gl, cpu);
  }
  std::unique_ptr<GlContext> ctx_;
};

TEST_F(GlVersusCpu, CornellRealLikeAndRandomSets) { run("cornell", 128, 128, 400000, 11, 1.f); }
TEST_F(GlVersusCpu, HallRealLikeAndRandomSets) { run("hall", 160, 90, 300000, 12, 1.f); }
TEST_F(GlVersusCpu, CornellWithTinyEpsilon) { run("cornell", 96, 96, 200000, 13, 1e-3f); }

TEST_F(GlVersusCpu, PrefetchAndWorkgroupShapeDoNotChangeResults) {
  const Scene scene = test::scene_named("cornell");
  const Camera cam(scene.camera, 64, 64);
  const DeepFramebuffer dfb = build_deep_framebuffer_cpu(scene, cam, 4);
  const auto pts = test::real_like_points(scene, dfb, cam, 100000, 5);
  ReprojectorSettings a;
  a.epsilon = default_epsilon(scene.bounds());
  ReprojectorSettings b = a;
  b.prefetch = false;
  b.workgroup_size = 64;
  b.workgroups = 3;
  GlReprojector ga(*ctx_, cam, dfb, a), gb(*ctx_, cam, dfb, b);
  ga.reproject(pts);
  gb.reproject(pts);
  expect_same(ga, gb);
}

TEST_F(GlVersusCpu, CountsSurviveFoldingIntoHostTotals) {
  const Scene scene = test::scene_named("cornell");
  const Camera cam(scene.camera, 64, 64);
  const DeepFramebuffer dfb = build_deep_framebuffer_cpu(scene, cam, 4);
  const auto pts = test::real_like_points(scene, dfb, cam, 50000, 8);
  ReprojectorSettings s;
  s.epsilon = default_epsilon(scene.bounds());
  s.batch_points = 4096;
  s.counter_fold_points = 5000;  // fold after every second batch
  GlReprojector gl(*ctx_, cam, dfb, s);
  CpuReprojector cpu(cam, dfb, s);
  for (int round = 0; round < 3; ++round) {
    gl.reproject(pts);
    cpu.reproject(pts);
  }
  expect_same(gl, cpu);
  EXPECT_EQ(gl.counts().total(), 3 * pts.size());
  gl.reset();
  EXPECT_EQ(gl.counts(), ReprojectionCounts{});
}

TEST(Reprojector, FactoryRejectsBadInput) {
  const Scene scene = quads({0.f});
  const Camera cam(head_on(), 16, 16);
  const DeepFramebuffer dfb = build_deep_framebuffer_cpu(scene, cam, 4);
  ReprojectorSettings s;
  s.epsilon = 0.001f;
  EXPECT_THROW(make_reprojector("vulkan", cam, dfb, s), std::invalid_argument);
  s.epsilon = -1;
  EXPECT_THROW(make_reprojector("cpu", cam, dfb, s), std::invalid_argument);
  s.epsilon = 0.001f;
  EXPECT_THROW(make_reprojector("cpu", Camera(head_on(), 17, 16), dfb, s), std::invalid_argument);
  EXPECT_NEAR(default_epsilon(scene.bounds()), 3e-4f * std::sqrt(8.f), 1e-7f);
}

TEST(Reprojector, SubpixelIndexConvention) {
  EXPECT_EQ(subpixel_index(0.f, 0.f, 4, 10, 10), 0u);
  EXPECT_EQ(subpixel_index(0.3f, 0.f, 4, 10, 10), 1u);
  EXPECT_EQ(subpixel_index(0.f, 0.3f, 4, 10, 10), 40u);
  EXPECT_EQ(subpixel_index(9.99f, 9.99f, 4, 10, 10), 40u * 40u - 1);
  EXPECT_EQ(subpixel_index(10.f, 0.f, 4, 10, 10), UINT32_MAX);
  EXPECT_EQ(subpixel_index(-0.01f, 0.f, 4, 10, 10), UINT32_MAX);
}

}  // namespace
}  // namespace epr
