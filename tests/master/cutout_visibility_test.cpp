// Cut-outs and the deep framebuffer: a texel whose centre ray meets a hole sees the surface behind it
// (as the tracer's rays do), the GL and CPU builders store the same triangle and point there, and
// the reprojectors accept no vertex on a hole and every vertex on the wall seen through one.
#include <gtest/gtest.h>

#include <random>

#include "master/deep_framebuffer.h"
#include "master/gl_context.h"
#include "master/make_reprojector.h"
#include "master/reprojector.h"
#include "tests/common/cutout_scenes.h"

namespace epr {
namespace {

constexpr int kCells = 8;
constexpr uint32_t kWall = 0, kScreen = 2;  // material indices (wall, light, screen)

// The checker cell (i, r) the point (x, y) of the screen plane lies in, and how far inside it (as a
// fraction of the cell: 0.5 at the centre, 0 on its border); false outside the screen.
bool cell_of(float x, float y, int* i, int* r, float* inside) {
  const float u = (x + 0.5f) * kCells, v = (0.5f - y) * kCells;
  if (!(u >= 0 && u < kCells && v >= 0 && v < kCells)) return false;
  *i = int(u), *r = int(v);
  *inside = std::min({u - float(*i), float(*i) + 1 - u, v - float(*r), float(*r) + 1 - v});
  return true;
}

// What the ray through texel (x, y) sees first: the screen, or (through a hole or beside it) the
// wall; -1 where that is uncertain (within 10 % of a cell of its border).
int expected_material(const Camera& cam, int S, int x, int y) {
  const Ray ray = cam.generate_ray((float(x) + 0.5f) / float(S), (float(y) + 0.5f) / float(S));
  const float t = -ray.origin.z / ray.dir.z;
  const Vec3 p = ray.origin + ray.dir * t;
  int i, r;
  float inside;
  if (!cell_of(p.x, p.y, &i, &r, &inside)) {
    if (std::fabs(p.x) < 0.55f && std::fabs(p.y) < 0.55f) return -1;  // the screen's own border
    return int(kWall);
  }
  if (inside < 0.1f) return -1;
  return test::checker_opaque(i, r) ? int(kScreen) : int(kWall);
}

void expect_sees_through_holes(const Scene& scene, const DeepFramebuffer& dfb, const Camera& cam, const char* who) {
  size_t holes = 0, solid = 0, wrong = 0;
  for (int y = 0; y < dfb.height; ++y)
    for (int x = 0; x < dfb.width; ++x) {
      const int want = expected_material(cam, dfb.subpixels, x, y);
      if (want < 0) continue;
      const size_t k = dfb.index(x, y);
      if (dfb.triangle[k] == DeepFramebuffer::kNoTriangle) continue;  // beyond the wall
      const uint32_t got = scene.material_of[dfb.triangle[k]];
      wrong += got != uint32_t(want);
      holes += want == int(kWall) && dfb.position_at(k).z < -0.5f && std::fabs(dfb.position_at(k).x) < 0.5f;
      solid += want == int(kScreen);
    }
  EXPECT_EQ(wrong, 0u) << who;
  EXPECT_GT(holes, 1000u) << who << ": texels that see the wall through a hole";
  EXPECT_GT(solid, 1000u) << who;
}

class CutoutVisibility : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_TRUE(gl_available()) << "OSMesa unavailable: run scripts/setup.sh (libosmesa6)";
    ctx_ = std::make_unique<GlContext>();
  }
  std::unique_ptr<GlContext> ctx_;
  const Scene scene_ = test::cutout_screen_scene(kCells);
  const Camera cam_{scene_.camera, 96, 96};
};

TEST_F(CutoutVisibility, BothBuildersSeeTheWallThroughTheHolesAndAgree) {
  const DeepFramebuffer gl = build_deep_framebuffer_gl(*ctx_, scene_, cam_, 4);
  const DeepFramebuffer cpu = build_deep_framebuffer_cpu(scene_, cam_, 4);
  expect_sees_through_holes(scene_, gl, cam_, "gl");
  expect_sees_through_holes(scene_, cpu, cam_, "cpu");
  // Where they pick the same triangle they store the same point, holes included.
  size_t same = 0, differ = 0;
  for (size_t k = 0; k < gl.texel_count(); ++k) {
    if (gl.triangle[k] != cpu.triangle[k]) {
      ++differ;
      continue;
    }
    ++same;
    EXPECT_EQ(gl.position_at(k), cpu.position_at(k)) << "texel " << k;
    EXPECT_EQ(gl.plane_offset[k], cpu.plane_offset[k]);
  }
  EXPECT_LT(differ, gl.texel_count() / 100) << "they differ only along edges";
  // Banded, as the master builds it: the same texels.
  auto bands = detail::gl_deep_framebuffer_bands(*ctx_, scene_, cam_, 4, 37);
  for (int r0 = 0; r0 < gl.height; r0 += 37) {
    DeepFramebuffer band;
    bands->build(r0, std::min(gl.height, r0 + 37), &band);
    for (int y = 0; y < band.height; ++y)
      for (int x = 0; x < band.width; ++x)
        ASSERT_EQ(band.triangle[band.index(x, y)], gl.triangle[gl.index(x, y + r0)]) << x << ", " << y + r0;
  }
}

VertexRecord rec(Vec3 p) {
  VertexRecord r;
  r.position = p;
  r.normal = {0, 0, 1};
  r.radiance = {1, 1, 1};
  r.flags = VertexRecord::kDiffuse;
  return r;
}

// Points jittered around the centres of the checker cells (within 30 % of a cell), on the screen
// plane (z = 0) or on the wall behind each cell as seen from the eye (z = -1).
std::vector<VertexRecord> points(const Camera& cam, bool on_screen, bool hole_cells, size_t n, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> jitter(-0.3f, 0.3f);
  std::uniform_int_distribution<int> cell(0, kCells - 1);
  std::vector<VertexRecord> out;
  while (out.size() < n) {
    const int i = cell(rng), r = cell(rng);
    if (test::checker_opaque(i, r) == hole_cells) continue;
    const float c = 1.f / kCells;
    const Vec3 s{-0.5f + (float(i) + 0.5f + jitter(rng)) * c, 0.5f - (float(r) + 0.5f + jitter(rng)) * c, 0.f};
    if (on_screen) {
      out.push_back(rec(s));
    } else {  // the wall point the eye sees through s
      const Vec3 d = s - cam.eye();
      out.push_back(rec(cam.eye() + d * ((-1.f - cam.eye().z) / d.z)));
    }
  }
  return out;
}

TEST_F(CutoutVisibility, NoVertexIsAcceptedOnAHoleAndTheWallBehindOneIsSeen) {
  for (const char* builder : {"gl", "cpu"}) {
    const DeepFramebuffer dfb = std::string(builder) == "gl" ? build_deep_framebuffer_gl(*ctx_, scene_, cam_, 4)
                                                             : build_deep_framebuffer_cpu(scene_, cam_, 4);
    ReprojectorSettings settings;
    settings.epsilon = default_epsilon(scene_.bounds());
    std::vector<ReprojectionCounts> per_backend;
    for (const char* backend : {"gl", "cpu"}) {
      auto rp = make_reprojector(backend, cam_, dfb, settings, ctx_.get());
      const size_t n = 20000;
      const auto count = [&](const std::vector<VertexRecord>& v) {
        const ReprojectionCounts before = rp->counts();
        rp->reproject(v);
        return rp->counts().accepted - before.accepted;
      };
      const std::string at = std::string(builder) + " builder, " + backend + " reprojector";
      EXPECT_EQ(count(points(cam_, true, true, n, 1)), 0u) << at << ": points on the screen's holes";
      EXPECT_EQ(count(points(cam_, false, true, n, 2)), n) << at << ": the wall seen through the holes";
      EXPECT_EQ(count(points(cam_, false, false, n, 3)), 0u) << at << ": the wall behind the screen";
      EXPECT_EQ(count(points(cam_, true, false, n, 4)), n) << at << ": the screen itself";
      per_backend.push_back(rp->counts());
    }
    EXPECT_EQ(per_backend[0].accepted, per_backend[1].accepted) << builder;
    EXPECT_EQ(per_backend[0].occluded, per_backend[1].occluded) << builder;
  }
}

}  // namespace
}  // namespace epr
