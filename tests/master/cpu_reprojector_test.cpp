// The CPU back-end's parallel accumulation (each task owns the subpixels of every T-th stripe of
// 2^k >= 64 subpixels, cpu_reprojector.h) gives the serial loop's sums bit for bit, whatever the
// thread count: every subpixel still receives its samples in input order.
#include "master/cpu_reprojector.h"

#include <gtest/gtest.h>
#include <tbb/global_control.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <random>
#include <span>

#include "test_scenes.h"

namespace epr {
namespace {

struct Result {
  ReprojectionCounts counts;
  SubpixelAccumulation acc;
};

bool same_bits(const std::vector<float>& a, const std::vector<float>& b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(float)) == 0;
}

// The point of the visible plane of subpixel (gx, gy) (integer part) on the ray through subpixel
// coordinates (gx, gy), facing the eye; false if that subpixel is uncovered or seen edge-on.
bool on_surface(const DeepFramebuffer& dfb, const Camera& cam, float gx, float gy, VertexRecord* r) {
  const int x = std::min(dfb.width - 1, int(gx)), y = std::min(dfb.height - 1, int(gy));
  const size_t t = dfb.index(x, y);
  if (!dfb.covered[t]) return false;
  const float S = float(dfb.subpixels);
  const Ray ray = cam.generate_ray(gx / S, gy / S);
  Vec3 n = dfb.normal_at(t);
  const float denom = dot(n, ray.dir);
  if (std::fabs(denom) < 1e-3f) return false;
  r->position = ray.origin + ray.dir * ((dfb.plane_offset[t] - dot(n, ray.origin)) / denom);
  if (dot(n, cam.eye() - r->position) < 0) n = -n;
  r->normal = n;
  r->flags = VertexRecord::kDiffuse;
  return true;
}

TEST(CpuReprojector, PartitionedAccumulationEqualsTheSerialLoopBitForBit) {
  const Scene scene = test::scene_named("cornell");
  // 400 x 300 subpixels: rows are not a multiple of 64, so stripe borders fall inside rows.
  const Camera cam(scene.camera, 100, 75);
  const DeepFramebuffer dfb = build_deep_framebuffer_cpu(scene, cam, 4);
  ReprojectorSettings settings;
  settings.epsilon = default_epsilon(scene.bounds());
  std::mt19937 rng(1717);

  std::vector<VertexRecord> pts = test::real_like_points(scene, dfb, cam, 150000, 1717);
  test::add_boundary_points(dfb, cam, 20000, rng, pts);
  // Stripes are 2^k >= 64 subpixels, so every stripe border is at a multiple of 64: points at the
  // centres of the subpixels on both sides of each (three each) and on the edge between them.
  std::uniform_real_distribution<float> u(0, 1);
  size_t border_points = 0;
  for (size_t t = 64; t < dfb.texel_count(); t += 64) {
    const float gy = float(t / size_t(dfb.width)), gx = float(t % size_t(dfb.width));
    VertexRecord r;
    for (int k = 0; k < 3; ++k) {
      if (on_surface(dfb, cam, gx + 0.5f, gy + 0.5f, &r)) pts.push_back(r), ++border_points;
      if (gx > 0 && on_surface(dfb, cam, gx - 0.5f, gy + 0.5f, &r)) pts.push_back(r), ++border_points;
    }
    if (gx > 0 && on_surface(dfb, cam, gx, gy + u(rng), &r)) pts.push_back(r), ++border_points;
  }
  ASSERT_GT(border_points, 2000u);
  std::shuffle(pts.begin(), pts.end(), rng);
  // Radiance over six orders of magnitude: adding a subpixel's samples in another order changes its sum.
  std::uniform_real_distribution<float> exponent(-3, 3);
  auto radiance = [&] {
    return Vec3(std::pow(10.f, exponent(rng)), std::pow(10.f, exponent(rng)), std::pow(10.f, exponent(rng)));
  };
  for (auto& r : pts) r.radiance = radiance();
  const VertexCodec codec(scene.bounds());
  std::string packed;
  codec.encode_batch(pts, &packed);
  // Exact samples: on both sides of every multiple of 64, and anywhere (some outside the grid).
  std::vector<ExactSample> exact;
  std::uniform_int_distribution<uint32_t> any(0, uint32_t(dfb.texel_count() + 100));
  for (int round = 0; round < 8; ++round)
    for (uint32_t t = 64; t < dfb.texel_count(); t += 64) {
      exact.push_back({t - 1, radiance()});
      exact.push_back({t, radiance()});
      exact.push_back({any(rng), radiance()});
    }
  std::shuffle(exact.begin(), exact.end(), rng);
  ASSERT_GT(exact.size(), 32768u) << "large enough for the parallel path";

  auto run = [&](int threads, std::span<const VertexRecord> records) {
    // The reprojector uses the arena's threads up to the global limit (by default the cores).
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, 64);
    tbb::task_arena arena(threads);
    CpuReprojector r(cam, dfb, settings);
    arena.execute([&] {
      r.reproject(records);                                    // parallel (>= 32768 records), several chunks
      r.reproject_packed(packed, codec);                       // the same, decoding in place
      r.reproject_packed(packed.substr(0, 16 * 5000), codec);  // a tile: serial
      r.add_exact(exact);
      r.reproject(std::span(pts).subspan(0, 40000));  // a chunk and a partial one
    });
    return Result{r.counts(), r.read()};
  };
  const Result serial = run(1, pts);
  EXPECT_GT(serial.counts.accepted, 100000u);
  EXPECT_GT(serial.counts.exact, 40000u);
  EXPECT_GT(serial.counts.invalid, 0u);
  for (int threads : {2, 3, 8, 32}) {
    SCOPED_TRACE(threads);
    const Result par = run(threads, pts);
    EXPECT_EQ(par.counts, serial.counts);
    EXPECT_EQ(par.acc.count, serial.acc.count);
    EXPECT_TRUE(same_bits(par.acc.sum, serial.acc.sum)) << "radiance sums differ from the serial loop's";
  }

  // The test can see an order change: the same records in reverse order give other sums.
  std::vector<VertexRecord> reversed(pts.rbegin(), pts.rend());
  const Result rev = run(1, reversed);
  EXPECT_EQ(rev.acc.count, serial.acc.count);
  EXPECT_FALSE(same_bits(rev.acc.sum, serial.acc.sum));
}

}  // namespace
}  // namespace epr

namespace epr {
namespace {

// The CPU back-end holds the plane index in 16 bits when the plane table has fewer than 65535
// entries, else in 32: the same plane grid padded past 65535 entries (unused ones) decides and sums
// every record alike, packed or not.
TEST(CpuReprojector, NarrowAndWidePlaneIndicesDecideAlike) {
  const Scene scene = test::scene_named("cornell");
  const Camera cam(scene.camera, 80, 60);
  const DeepFramebuffer dfb = build_deep_framebuffer_cpu(scene, cam, 4);
  ReprojectorSettings settings;
  settings.epsilon = default_epsilon(scene.bounds());
  const detail::PlaneGrid narrow = detail::plane_grid_for(cam, dfb, settings);
  ASSERT_LT(narrow.planes.size() / 4, 0xffffu);
  detail::PlaneGrid wide = narrow;
  wide.planes.resize(wide.planes.size() + 4 * 70000, 0.f);  // entries no texel refers to
  std::mt19937 rng(99);
  std::vector<VertexRecord> pts = test::real_like_points(scene, dfb, cam, 60000, 99);
  test::add_boundary_points(dfb, cam, 5000, rng, pts);
  const VertexCodec codec(scene.bounds());
  std::string packed;
  codec.encode_batch(pts, &packed);
  CpuReprojector a(cam, narrow, settings), b(cam, std::move(wide), settings);
  for (CpuReprojector* r : {&a, &b}) {
    r->reproject(pts);
    r->reproject_packed(packed, codec);
  }
  EXPECT_EQ(a.counts(), b.counts());
  EXPECT_GT(a.counts().accepted, 10000u) << "too few accepted points to compare";
  EXPECT_GT(a.counts().occluded, 100u) << "no occluded points: the plane test's rejections are not compared";
  const SubpixelAccumulation x = a.read(), y = b.read();
  EXPECT_EQ(x.count, y.count);
  EXPECT_TRUE(same_bits(x.sum, y.sum));
}

}  // namespace
}  // namespace epr
