// The path tracer against answers known in closed form, and its determinism.
//
// Furnace: a closed box whose every face has albedo a and emits Le. The radiance leaving any point
// in any direction is Le / (1 - a) (a geometric series of bounces). Each pixel estimate and each
// recorded vertex value Le + R_n is an unbiased estimate of that number, so their means must match
// it within the Monte Carlo error: this checks the back-propagation and roulette weighting that
// reprojection depends on. Both direct-light estimators (MIS and next event estimation only) are
// checked there, and against each other on the Cornell box, where MIS must also lower the noise.
#include "worker/path_tracer.h"

#include <gtest/gtest.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>

#include "common/rng.h"
#include "common/scene_loader.h"
#include "tests/worker/image_means.h"
#include "worker/tile_renderer.h"

namespace epr {
namespace {

Scene furnace_box(float albedo, float emission) {
  Scene s;
  s.name = "test-furnace";
  Material m;
  m.name = "furnace";
  m.kd = Vec3(albedo);
  m.ke = Vec3(emission);
  const uint32_t id = add_material(s, m);
  const Vec3 p[8] = {{-1, -1, -1}, {1, -1, -1}, {1, 1, -1}, {-1, 1, -1},
                     {-1, -1, 1},  {1, -1, 1},  {1, 1, 1},  {-1, 1, 1}};
  // Faces counter-clockwise seen from inside (normals point inwards).
  add_tessellated_quad(s, p[0], p[1], p[2], p[3], id, 2);  // z = -1
  add_tessellated_quad(s, p[5], p[4], p[7], p[6], id, 2);  // z = +1
  add_tessellated_quad(s, p[4], p[0], p[3], p[7], id, 2);  // x = -1
  add_tessellated_quad(s, p[1], p[5], p[6], p[2], id, 2);  // x = +1
  add_tessellated_quad(s, p[4], p[5], p[1], p[0], id, 2);  // y = -1
  add_tessellated_quad(s, p[3], p[2], p[6], p[7], id, 2);  // y = +1
  s.camera = {Vec3(0.2f, 0.1f, 0.5f), Vec3(-1, -0.8f, -1), Vec3(0, 1, 0), 70.f};
  return s;
}

// Renders the furnace at 64x64 in parallel tiles. NEE near the box's edges is heavy-tailed
// (measured per-path standard deviation ~3 at albedo 0.5), so 1 % needs ~10^6 paths to be a
// 5-sigma bound rather than a coin toss.
ImageMeans render_furnace(float albedo, RussianRoulette rr, int spp, bool mis = true) {
  const Scene scene = furnace_box(albedo, 1.f);
  EmbreeScene es(scene);
  const int size = 64;
  const Camera cam(scene.camera, size, size);
  const PathTracer tracer(es, cam, 42, rr, mis);
  return render_image_means(tracer, size, spp);
}

// Every unbiased roulette of common/roulette.h (all but off) by name.
class FurnaceTest : public ::testing::TestWithParam<std::tuple<float, std::string, bool>> {};

TEST_P(FurnaceTest, PixelsAndVerticesMatchAnalyticRadiance) {
  const auto [albedo, rr_mode, mis] = GetParam();
  const RussianRoulette rr = roulette_named(rr_mode).value();
  const double expected = 1.0 / (1.0 - albedo);
  const ImageMeans r = render_furnace(albedo, rr, 256, mis);  // 1M paths
  EXPECT_NEAR(r.pixel, expected, 0.01 * expected) << "albedo " << albedo << " rr " << rr_mode << " mis " << mis;
  EXPECT_GT(r.vertices, 10000u);
  EXPECT_NEAR(r.vertex, expected, 0.01 * expected) << "albedo " << albedo << " rr " << rr_mode << " mis " << mis;
}

INSTANTIATE_TEST_SUITE_P(AlbedoRouletteAndMis, FurnaceTest,
                         ::testing::Combine(::testing::Values(0.5f, 0.8f),
                                            ::testing::Values("paper", "albedo", "throughput", "reuse"),
                                            ::testing::Bool()));

// One-sided emitters: the furnace's faces emit from their front side only. Facing inwards the box
// is the furnace again (Le / (1 - a) everywhere); turned outwards (corners 1 and 2 swapped) the
// inside sees only dark backs and every pixel and vertex is black (but for a few rays stepped off
// the surface through a corner of the box: means of ~1e-10 measured, against 2 were the faces
// two-sided). A wrong side test at a hit, in next event estimation or in MIS's weights moves the
// first case by a third or more.
TEST(PathTracer, OneSidedEmittersLightOnlyTheirFrontSide) {
  for (const bool mis : {true, false}) {
    SCOPED_TRACE(mis ? "mis" : "nee");
    Scene inwards = furnace_box(0.5f, 1.f);
    inwards.materials[0].emits_front_only = true;
    Scene outwards = inwards;
    for (auto& t : outwards.triangles) std::swap(t[1], t[2]);
    const int size = 64;
    const Camera cam(inwards.camera, size, size);
    EmbreeScene in_es(inwards), out_es(outwards);
    const ImageMeans in = render_image_means(PathTracer(in_es, cam, 42, RussianRoulette::paper(), mis), size, 256);
    EXPECT_NEAR(in.pixel, 2.0, 0.02);
    EXPECT_NEAR(in.vertex, 2.0, 0.02);
    const ImageMeans out = render_image_means(PathTracer(out_es, cam, 42, RussianRoulette::paper(), mis), size, 16);
    EXPECT_GT(out.vertices, 1000u);
    EXPECT_LT(out.pixel, 1e-6);
    EXPECT_LT(out.vertex, 1e-6);
  }
}

TEST(EmbreeScene, OneSidedEmittersEmitHalfThePower) {
  Scene scene = furnace_box(0.5f, 1.f);
  const double two_sided = EmbreeScene(scene).emitted_power();
  EXPECT_NEAR(two_sided, 2 * kPi * 24.0, 1e-3);  // 2 pi x area 24 m^2 x luminance 1
  scene.materials[0].emits_front_only = true;
  EXPECT_NEAR(EmbreeScene(scene).emitted_power(), two_sided / 2, 1e-3);
}

TEST(PathTracer, WithoutRouletteAFixedDepthIsDarker) {
  // Truncating at 3 vertices loses the series' tail: expected sum_{k<3} a^k Le plus the NEE of the
  // last vertex, i.e. 1 + a + a^2 + a^3 for Le = 1 — measurably below 1 / (1 - a). With MIS the
  // last vertex keeps next event estimation at full weight (no continuation can be traced there).
  const float a = 0.8f;
  for (bool mis : {true, false}) {
    const ImageMeans r = render_furnace(a, RussianRoulette::off(3), 64, mis);
    const double truncated = 1 + a + a * a + a * a * a;
    EXPECT_NEAR(r.pixel, truncated, 0.01 * truncated) << "mis " << mis;
    EXPECT_LT(r.pixel, 0.8 / (1 - a));
  }
}

// ---- MIS against next event estimation only, on the shared Cornell box ------------------------------
// The light hangs 1 cm below the ceiling: a path vertex in that gap gets a next event estimate with a
// 1/d^2 factor (the fireflies MIS removes), which BSDF sampling finds at a bounded weight.

constexpr int kCornellSize = 64, kCornellSpp = 256, kCornellBlock = 8;

struct PixelMoments {
  std::vector<double> sum, sum2;  // per pixel, luminance of the path samples
  std::vector<Vec3> mean;         // per pixel, per channel
};

PixelMoments render_cornell(const EmbreeScene& es, const Camera& cam, bool mis) {
  PathTracer tracer(es, cam, 77, RussianRoulette::paper(), mis);
  const size_t n = size_t(kCornellSize) * kCornellSize;
  PixelMoments m{std::vector<double>(n), std::vector<double>(n), std::vector<Vec3>(n, Vec3(0.f))};
  tbb::parallel_for(0, kCornellSize, [&](int y) {
    for (int x = 0; x < kCornellSize; ++x) {
      const size_t i = size_t(y) * kCornellSize + size_t(x);
      double c[3] = {0, 0, 0};
      for (int s = 0; s < kCornellSpp; ++s) {
        const Vec3 v = tracer.trace(x, y, uint32_t(s), nullptr, nullptr);
        const double l = luminance(v);
        m.sum[i] += l;
        m.sum2[i] += l * l;
        for (int k = 0; k < 3; ++k) c[k] += v[k];
      }
      m.mean[i] = Vec3(float(c[0] / kCornellSpp), float(c[1] / kCornellSpp), float(c[2] / kCornellSpp));
    }
  });
  return m;
}

TEST(PathTracer, MisAndNextEventEstimationAgreeOnTheCornellBoxAndMisIsLessNoisyNearTheLight) {
  const Scene scene = load_scene(std::string(EPR_SOURCE_DIR) + "/scenes/cornell-box/CornellBox-Original.obj");
  EmbreeScene es(scene);
  const Camera cam(scene.camera, kCornellSize, kCornellSize);
  const PixelMoments on = render_cornell(es, cam, true), off = render_cornell(es, cam, false);

  // Block means within noise: sigma from the spread of the 64 pixel means of each block in each
  // render (which sees realised fireflies, unlike a per-sample variance that has not met them).
  const int blocks = kCornellSize / kCornellBlock;
  int over = 0, comparisons = 0;
  double total_on[3] = {0, 0, 0}, total_off[3] = {0, 0, 0};
  for (int by = 0; by < blocks; ++by)
    for (int bx = 0; bx < blocks; ++bx)
      for (int k = 0; k < 3; ++k) {
        double s_on = 0, s2_on = 0, s_off = 0, s2_off = 0;
        for (int y = by * kCornellBlock; y < (by + 1) * kCornellBlock; ++y)
          for (int x = bx * kCornellBlock; x < (bx + 1) * kCornellBlock; ++x) {
            const size_t i = size_t(y) * kCornellSize + size_t(x);
            s_on += on.mean[i][k], s2_on += double(on.mean[i][k]) * on.mean[i][k];
            s_off += off.mean[i][k], s2_off += double(off.mean[i][k]) * off.mean[i][k];
          }
        const double px = kCornellBlock * kCornellBlock;
        const double m_on = s_on / px, m_off = s_off / px;
        const double se_on = std::sqrt(std::max(0.0, s2_on / px - m_on * m_on) / px);
        const double se_off = std::sqrt(std::max(0.0, s2_off / px - m_off * m_off) / px);
        const double tolerance = 5 * std::sqrt(se_on * se_on + se_off * se_off) + 0.01 * std::max(m_on, m_off);
        ++comparisons;
        if (std::abs(m_on - m_off) > tolerance) {
          ++over;
          std::printf("block (%d,%d) channel %d: mis %.4f nee %.4f tolerance %.4f\n", bx, by, k, m_on, m_off,
                      tolerance);
        }
        total_on[k] += m_on;
        total_off[k] += m_off;
      }
  EXPECT_LE(over, comparisons / 100) << "block/channel comparisons beyond 5 sigma";
  for (int k = 0; k < 3; ++k)
    EXPECT_NEAR(total_on[k], total_off[k], 0.01 * total_off[k]) << "image mean, channel " << k;

  // The ceiling next to the light: pixels whose camera ray hits the (non-emissive) ceiling within
  // 0.6 m of the light's centre. Per-path variance of the luminance, summed over those pixels.
  double var_on = 0, var_off = 0;
  int ceiling = 0;
  for (int y = 0; y < kCornellSize; ++y)
    for (int x = 0; x < kCornellSize; ++x) {
      Hit hit;
      const Ray ray = cam.generate_ray(float(x) + 0.5f, float(y) + 0.5f);
      if (!es.intersect(ray, 0.f, std::numeric_limits<float>::infinity(), &hit)) continue;
      if (scene.materials[es.material(hit.prim)].emissive()) continue;
      const Vec3 p = ray.origin + ray.dir * hit.t;
      if (p.y < 1.985f || std::hypot(p.x, p.z + 0.03f) > 0.6f) continue;
      const size_t i = size_t(y) * kCornellSize + size_t(x);
      const double n = kCornellSpp;
      var_on += on.sum2[i] / n - (on.sum[i] / n) * (on.sum[i] / n);
      var_off += off.sum2[i] / n - (off.sum[i] / n) * (off.sum[i] / n);
      ++ceiling;
    }
  ASSERT_GT(ceiling, 20) << "ceiling pixels next to the light";
  std::printf("ceiling next to the light, %d pixels: per-path variance MIS %.4g, NEE only %.4g (ratio %.2f)\n", ceiling,
              var_on / ceiling, var_off / ceiling, var_off / var_on);
  RecordProperty("ceiling_variance_ratio", std::to_string(var_off / var_on));
  EXPECT_LT(var_on, var_off);
}

TEST(PathTracer, NextEventEstimationOnlyIgnoresEmissionFoundByTheContinuation) {
  // In the furnace every surface emits; MIS changes samples, NEE only must not see the option
  // through anything but the estimator: same seed, same paths, different values; same vertex count.
  const Scene scene = furnace_box(0.5f, 1.f);
  EmbreeScene es(scene);
  const Camera cam(scene.camera, 8, 8);
  const PathTracer mis(es, cam, 3, RussianRoulette::paper(), true), nee(es, cam, 3, RussianRoulette::paper(), false);
  EXPECT_TRUE(mis.mis());
  EXPECT_FALSE(nee.mis());
  int differ = 0;
  for (uint32_t s = 0; s < 64; ++s) {
    std::vector<VertexRecord> a, b;
    const Vec3 pa = mis.trace(4, 4, s, &a, nullptr), pb = nee.trace(4, 4, s, &b, nullptr);
    ASSERT_EQ(a.size(), b.size()) << "the estimator must not change the path";
    for (size_t i = 0; i < a.size(); ++i) ASSERT_EQ(a[i].position, b[i].position);
    differ += !(pa == pb);
  }
  EXPECT_GT(differ, 32);
}

TEST(PathTracer, RecordedNormalsFaceThePreviousVertex) {
  const Scene scene = furnace_box(0.5f, 1.f);
  EmbreeScene es(scene);
  const Camera cam(scene.camera, 8, 8);
  PathTracer tracer(es, cam, 3, RussianRoulette::paper());
  std::vector<VertexRecord> recs;
  for (uint32_t s = 0; s < 64; ++s) tracer.trace(4, 4, s, &recs, nullptr);
  ASSERT_FALSE(recs.empty());
  for (const VertexRecord& v : recs) {
    // Inside the box every normal points inwards: towards the centre.
    EXPECT_GT(dot(v.normal, -v.position), 0.f);
    EXPECT_NEAR(length(v.normal), 1.f, 1e-5f);
    EXPECT_TRUE(v.diffuse());
  }
}

class DeterminismTest : public ::testing::TestWithParam<bool> {};

TEST_P(DeterminismTest, TileIsBitIdenticalWhateverTheThreadOrOrder) {
  const Scene scene = furnace_box(0.7f, 1.f);
  EmbreeScene es(scene);
  const Camera cam(scene.camera, 32, 32);
  PathTracer tracer(es, cam, 9, RussianRoulette::paper(), GetParam());
  TileRenderer tr(tracer, {VertexFilter::Mode::kAll});
  const auto tiles = make_tiles(32, 32, 8);
  auto render_all = [&](bool parallel, bool reversed) {
    std::vector<TileResult> out(tiles.size());
    auto one = [&](size_t i) {
      const size_t t = reversed ? tiles.size() - 1 - i : i;
      TileRequest req;
      req.rect = tiles[t];
      req.paths_per_pixel = 4;
      out[t] = tr.render(req);
    };
    if (parallel)
      tbb::parallel_for(size_t(0), tiles.size(), one);
    else
      for (size_t i = 0; i < tiles.size(); ++i) one(i);
    return out;
  };
  const auto a = render_all(false, false);
  const auto b = render_all(true, true);
  for (size_t t = 0; t < tiles.size(); ++t) {
    ASSERT_EQ(a[t].path_sum.size(), b[t].path_sum.size());
    for (size_t i = 0; i < a[t].path_sum.size(); ++i) ASSERT_EQ(a[t].path_sum[i], b[t].path_sum[i]);
    ASSERT_EQ(a[t].vertices.size(), b[t].vertices.size());
    for (size_t i = 0; i < a[t].vertices.size(); ++i) ASSERT_EQ(a[t].vertices[i].radiance, b[t].vertices[i].radiance);
  }
}

INSTANTIATE_TEST_SUITE_P(MisOnAndOff, DeterminismTest, ::testing::Bool());

TEST(EmbreeScene, HitNormalIsTheTrianglesGeometricNormal) {
  // The tracer takes a hit's normal from Embree; it must be Scene::geometric_normal (right-hand rule).
  Scene scene = furnace_box(0.5f, 0.f);
  add_triangle(scene, {0.3f, -0.2f, 0.1f}, {-0.4f, 0.5f, -0.2f}, {0.1f, 0.2f, 0.6f}, 0);  // oblique, inside
  EmbreeScene es(scene);
  int hits = 0;
  for (uint32_t i = 0; i < 2000; ++i) {
    SampleStream rng(1, i, 0);
    const float z = 1 - 2 * rng.next(), phi = 2 * kPi * rng.next();
    const float r = std::sqrt(std::max(0.f, 1 - z * z));
    const Ray ray{{0.05f, 0.02f, -0.03f}, {r * std::cos(phi), r * std::sin(phi), z}};
    Hit h;
    ASSERT_TRUE(es.intersect(ray, 0.f, 1e30f, &h));  // closed box
    const Vec3 n = normalize(h.ng), expected = scene.geometric_normal(h.prim);
    EXPECT_NEAR(n.x, expected.x, 1e-6f);
    EXPECT_NEAR(n.y, expected.y, 1e-6f);
    EXPECT_NEAR(n.z, expected.z, 1e-6f);
    hits += h.prim == scene.triangle_count() - 1;
  }
  EXPECT_GT(hits, 20);  // the oblique triangle was among them
}

TEST(EmbreeScene, CompactMaterialIndexMatchesTheScene) {
  // 1-byte table up to 256 materials, 2 bytes beyond: both must give Scene::material_of.
  for (int materials : {3, 256, 257, 700}) {
    Scene scene;
    scene.name = "test-materials";
    for (int m = 0; m < materials; ++m) add_material(scene, Material{});
    for (int i = 0; i < 2 * materials; ++i) {
      const float x = float(i);
      add_triangle(scene, {x, 0, 0}, {x + 1, 0, 0}, {x, 1, 0}, uint32_t((i * 7) % materials));
    }
    EmbreeScene es(scene);
    for (uint32_t t = 0; t < scene.triangle_count(); ++t)
      ASSERT_EQ(es.material(t), scene.material_of[t]) << materials << " materials, triangle " << t;
  }
}

TEST(EmbreeScene, EmitterTableSelectsByPowerAndItsPdfIntegratesToOne) {
  // Two lights: a large dim one and a small bright one; selection must follow area x luminance(Ke).
  Scene scene;
  scene.name = "test-lights";
  Material wall, dim, bright;
  dim.ke = Vec3(1.f);
  bright.ke = Vec3(2.f, 8.f, 1.f);
  const uint32_t w = add_material(scene, wall), d = add_material(scene, dim), b = add_material(scene, bright);
  add_quad(scene, {-1, 0, -1}, {1, 0, -1}, {1, 0, 1}, {-1, 0, 1}, w);
  add_tessellated_quad(scene, {-1, 2, -1}, {1, 2, -1}, {1, 2, 1}, {-1, 2, 1}, d, 3);                       // area 4
  add_quad(scene, {-0.1f, 1.9f, -0.1f}, {0.1f, 1.9f, -0.1f}, {0.1f, 1.9f, 0.1f}, {-0.1f, 1.9f, 0.1f}, b);  // 0.04
  EmbreeScene es(scene);
  ASSERT_EQ(es.emitters().size(), 18u + 2u);
  const double power_dim = 4.0 * luminance(dim.ke), power_bright = 0.04 * luminance(bright.ke);
  double integral = 0;
  for (const Emitter& e : es.emitters()) {
    const float area = 0.5f * length(cross(e.p1 - e.p0, e.p2 - e.p0));
    integral += double(e.pdf_area) * area;  // sum of selection probabilities
  }
  EXPECT_NEAR(integral, 1.0, 1e-5);
  int bright_hits = 0;
  const int n = 1 << 16;
  for (int i = 0; i < n; ++i) {
    const Emitter* e = es.sample_emitter((float(i) + 0.5f) / float(n));
    ASSERT_NE(e, nullptr);
    bright_hits += e->le == bright.ke;
  }
  EXPECT_NEAR(bright_hits / double(n), power_bright / (power_dim + power_bright), 1e-3);

  const Scene dark = furnace_box(0.5f, 0.f);
  EXPECT_EQ(EmbreeScene(dark).sample_emitter(0.5f), nullptr);
}

TEST(TileRenderer, SkippedPixelsTraceNothingAndSampleIndicesShiftTheSequence) {
  const Scene scene = furnace_box(0.5f, 1.f);
  EmbreeScene es(scene);
  const Camera cam(scene.camera, 4, 4);
  PathTracer tracer(es, cam, 5, RussianRoulette::paper());
  TileRenderer tr(tracer, {VertexFilter::Mode::kNone});
  std::vector<uint8_t> skip(16, 0);
  skip[3] = 1;
  std::vector<uint32_t> first(16, 0);
  first[5] = 1;
  TileRequest req{{0, 0, 4, 4}, skip, first, 2};
  const TileResult r = tr.render(req);
  EXPECT_EQ(r.path_count[3], 0u);
  EXPECT_EQ(r.path_sum[3], Vec3(0.f));
  EXPECT_EQ(r.stats.paths.paths, 15u * 2);
  // Pixel 5 traced samples 1 and 2; tracing samples 0..2 one by one must reproduce that sum.
  const Vec3 s1 = tracer.trace(1, 1, 1, nullptr, nullptr), s2 = tracer.trace(1, 1, 2, nullptr, nullptr);
  EXPECT_EQ(r.path_sum[5], s1 + s2);
}

TEST(TileRenderer, CullingDropsWhatTheCameraCannotSee) {
  const Scene scene = furnace_box(0.5f, 1.f);
  EmbreeScene es(scene);
  const Camera cam(scene.camera, 16, 16);
  PathTracer tracer(es, cam, 11, RussianRoulette::paper());
  TileRequest req{{0, 0, 16, 16}, {}, {}, 4};
  const TileResult all = TileRenderer(tracer, {VertexFilter::Mode::kAll}).render(req);
  const TileResult culled = TileRenderer(tracer, {VertexFilter::Mode::kCull}).render(req);
  const TileResult exact = TileRenderer(tracer, {VertexFilter::Mode::kExact}).render(req);
  EXPECT_EQ(all.vertices.size(), culled.stats.vertices_recorded);
  EXPECT_EQ(all.vertices.size(), culled.vertices.size() + culled.stats.culled_frustum + culled.stats.culled_facing +
                                     culled.stats.culled_glossy);
  EXPECT_GT(culled.stats.culled_frustum, 0u);
  for (const VertexRecord& v : culled.vertices) {
    float rx, ry;
    ASSERT_TRUE(cam.project(v.position, &rx, &ry));
    EXPECT_GE(rx, 0.f);
    EXPECT_LT(rx, 16.f);
  }
  // Inside a convex box nothing in view is hidden from the eye.
  EXPECT_EQ(exact.stats.exact_occluded, 0u);
  EXPECT_EQ(exact.visible.size(), culled.vertices.size());
}

}  // namespace
}  // namespace epr
