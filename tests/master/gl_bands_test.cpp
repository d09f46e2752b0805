// The GL reprojector on a subpixel grid split into bands (gl_reprojector.h, Limits): with
// ReprojectorSettings::gl_max_band_cells forcing 2, 3 and many bands on a small frame, decisions,
// counts and per-subpixel sample counts are those of the CPU back-end bit for bit (radiance sums to
// float rounding), for reproject, reproject_packed and add_exact, with vertices on every pixel-row
// boundary (so on both sides of every band border); downsampling, read, restore and reset agree across
// bands. And a real 1920 x 1080, S = 4 frame, which no single GL buffer of llvmpipe holds.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <string>

#include "common/vertex_codec.h"
#include "master/cpu_reprojector.h"
#include "master/deep_framebuffer.h"
#include "master/gl_context.h"
#include "master/gl_reprojector.h"
#include "master/reprojection_image.h"
#include "master/reprojection_kernel.h"
#include "test_scenes.h"

namespace epr {
namespace {

void expect_same_counts(const ReprojectionCounts& cg, const ReprojectionCounts& cc) {
  EXPECT_EQ(cg.accepted, cc.accepted);
  EXPECT_EQ(cg.occluded, cc.occluded);
  EXPECT_EQ(cg.backfacing, cc.backfacing);
  EXPECT_EQ(cg.culled, cc.culled);
  EXPECT_EQ(cg.not_diffuse, cc.not_diffuse);
  EXPECT_EQ(cg.invalid, cc.invalid);
  EXPECT_EQ(cg.exact, cc.exact);
}

void expect_same_accumulation(const SubpixelAccumulation& ag, const SubpixelAccumulation& ac) {
  ASSERT_EQ(ag.width, ac.width);
  ASSERT_EQ(ag.height, ac.height);
  ASSERT_EQ(ag.size(), ac.size());
  size_t count_diff = 0, sum_diff = 0;
  for (size_t i = 0; i < ag.size(); ++i) {
    count_diff += ag.count[i] != ac.count[i];
    for (int c = 0; c < 3; ++c) {
      const float g = ag.sum[3 * i + c], r = ac.sum[3 * i + c];
      sum_diff += !(g == r || std::fabs(g - r) <= 1e-5f * std::max(std::fabs(r), 1e-3f));
    }
  }
  EXPECT_EQ(count_diff, 0u) << "subpixels whose counts differ";
  EXPECT_EQ(sum_diff, 0u) << "radiance sums differing by more than float rounding";
}

void expect_same_pixels(const PixelReprojection& a, const PixelReprojection& b) {
  ASSERT_EQ(a.count, b.count);
  ASSERT_EQ(a.radiance.data.size(), b.radiance.data.size());
  size_t diff = 0;
  for (size_t i = 0; i < a.radiance.data.size(); ++i)
    diff +=
        !(std::fabs(a.radiance.data[i] - b.radiance.data[i]) <= 1e-5f * std::max(1.f, std::fabs(b.radiance.data[i])));
  EXPECT_EQ(diff, 0u) << "pixels whose L_rp differs by more than float rounding";
}

// Points on the visible plane of texel row `gy` or `gy - 1` whose projection lands on or within a
// texel of the boundary between grid rows gy - 1 and gy, for every gy that is a multiple of S (every
// possible band border): which side they fall on depends on the last bit of the projection.
void add_row_border_points(const DeepFramebuffer& dfb, const Camera& cam, size_t n, std::mt19937& rng,
                           std::vector<VertexRecord>& out) {
  const int S = dfb.subpixels;
  std::uniform_int_distribution<int> pixel_row(1, dfb.height / S - 1);
  std::uniform_real_distribution<float> u(0, 1), rad(0, 4);
  for (size_t i = 0, tries = 0; i < n && tries < 20 * n; ++tries) {
    const float x = u(rng) * float(dfb.width);
    const float r = u(rng);
    const float y = float(pixel_row(rng) * S) + (r < 0.5f ? 0.f : 2.f * (r - 0.75f));  // on it, or within half a texel
    const size_t t = dfb.index(std::min(dfb.width - 1, int(x)), std::min(dfb.height - 1, int(y)));
    if (!dfb.covered[t]) continue;
    const Ray ray = cam.generate_ray(x / float(S), y / float(S));
    Vec3 nn = dfb.normal_at(t);
    const float denom = dot(nn, ray.dir);
    if (std::fabs(denom) < 1e-3f) continue;
    const float dist = (dfb.plane_offset[t] - dot(nn, ray.origin)) / denom;
    VertexRecord rec;
    rec.position = ray.origin + ray.dir * dist;
    if (dot(nn, cam.eye() - rec.position) < 0) nn = -nn;
    rec.normal = nn;
    rec.radiance = {rad(rng), rad(rng), rad(rng)};
    rec.flags = VertexRecord::kDiffuse;
    out.push_back(rec);
    ++i;
  }
}

class GlBands : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_TRUE(gl_available()) << "OSMesa unavailable: run scripts/setup.sh (libosmesa6)";
    ctx_ = std::make_unique<GlContext>();
  }
  std::unique_ptr<GlContext> ctx_;
};

// Cornell box, 96 x 80 pixels, S = 4: 384 x 320 subpixels, 1536 per pixel row.
struct BandCase {
  size_t max_band_cells;
  size_t bands;
};

TEST_F(GlBands, DecisionsCountsAndSumsMatchTheCpuBackendOnEveryBanding) {
  const Scene scene = test::scene_named("cornell");
  CameraSpec narrow = scene.camera;
  narrow.fov_y_degrees *= 0.7f;  // part of the box outside the frustum: culled vertices
  const Camera cam(narrow, 96, 80);
  const DeepFramebuffer dfb = build_deep_framebuffer_cpu(scene, cam, 4);
  const size_t row_cells = size_t(dfb.width) * 4;
  std::mt19937 rng(21);
  std::vector<VertexRecord> pts = test::real_like_points(scene, dfb, cam, 150000, 22);
  add_row_border_points(dfb, cam, 60000, rng, pts);
  test::add_boundary_points(dfb, cam, 20000, rng, pts);
  std::shuffle(pts.begin(), pts.end(), rng);
  for (size_t i = 0; i < pts.size(); i += 13) pts[i].flags = 0;  // glossy
  pts[5].position.x = std::numeric_limits<float>::quiet_NaN();   // invalid
  const VertexCodec codec(scene.bounds());
  Bounds3 wider = scene.bounds();
  wider.extend(wider.hi + Vec3(0.01f, 0.02f, 0.f));
  const VertexCodec other_codec(wider);
  std::string words;
  codec.encode_batch(pts, &words);
  std::vector<ExactSample> exact;
  std::uniform_int_distribution<uint32_t> sub(0, uint32_t(dfb.texel_count() - 1));
  std::uniform_int_distribution<uint32_t> border(1, uint32_t(dfb.height / 4 - 1));
  for (int i = 0; i < 30000; ++i) {
    // Half at random, half in the last row of a band or the first of the next (every pixel row boundary).
    const uint32_t row = i % 2 ? sub(rng) / uint32_t(dfb.width) : border(rng) * 4 - uint32_t(i % 4 == 0);
    exact.push_back({row * uint32_t(dfb.width) + sub(rng) % uint32_t(dfb.width), {0.5f, 1.f, float(i % 7)}});
  }
  exact.push_back({uint32_t(dfb.texel_count()), {1, 1, 1}});  // outside the grid: invalid

  for (const BandCase bc : {BandCase{40 * row_cells, 2}, BandCase{27 * row_cells, 3}, BandCase{7 * row_cells, 12},
                            BandCase{row_cells + 5, 80}}) {
    SCOPED_TRACE(testing::Message() << bc.bands << " bands");
    ReprojectorSettings s;
    s.epsilon = default_epsilon(scene.bounds());
    s.batch_points = 1 << 14;  // several slots per call, slots reused
    s.gl_max_band_cells = bc.max_band_cells;
    GlReprojector gl(*ctx_, cam, dfb, s);
    ASSERT_EQ(gl.band_count(), bc.bands);
    CpuReprojector cpu(cam, dfb, s);
    {
      SCOPED_TRACE("reproject");
      for (size_t off = 0; off < pts.size(); off += 40000) {
        const std::span<const VertexRecord> call(pts.data() + off, std::min<size_t>(40000, pts.size() - off));
        gl.reproject(call);
        cpu.reproject(call);
      }
      const ReprojectionCounts c = cpu.counts();
      EXPECT_GT(c.accepted, 60000u);
      EXPECT_GT(c.culled, 5000u);
      EXPECT_GT(c.backfacing, 5000u);
      EXPECT_GT(c.occluded - c.backfacing, 5000u);
      EXPECT_GT(c.not_diffuse, 5000u);
      EXPECT_EQ(c.invalid, 1u);
      expect_same_counts(gl.counts(), c);
      expect_same_accumulation(gl.read(), cpu.read());
    }
    {
      SCOPED_TRACE("reproject_packed");
      // Tile-sized calls; every third with another quantisation (records still waiting for their
      // dispatch are decoded with the parameters they came with).
      const size_t call = 15000 * VertexCodec::kPackedBytes;
      for (size_t off = 0, k = 0; off < words.size(); off += call, ++k) {
        const VertexCodec& c = k % 3 == 2 ? other_codec : codec;
        gl.reproject_packed(std::string_view(words).substr(off, call), c);
        cpu.reproject_packed(std::string_view(words).substr(off, call), c);
      }
      expect_same_counts(gl.counts(), cpu.counts());
      expect_same_accumulation(gl.read(), cpu.read());
    }
    {
      SCOPED_TRACE("add_exact");
      gl.add_exact(exact);
      cpu.add_exact(exact);
      expect_same_counts(gl.counts(), cpu.counts());
      EXPECT_EQ(cpu.counts().exact, exact.size() - 1);
      expect_same_accumulation(gl.read(), cpu.read());
    }
    const SubpixelAccumulation ref = cpu.read();
    {
      SCOPED_TRACE("downsample");
      const PixelReprojection want = downsample(ref);
      expect_same_pixels(gl.downsample_pixels(), want);
      // With a skip mask (the skipped pixels keep their values) and counts only.
      std::vector<uint8_t> skip(size_t(cam.width()) * size_t(cam.height()));
      for (size_t p = 0; p < skip.size(); ++p) skip[p] = (p * 7 + p / 96) % 3 == 0;
      PixelReprojection partial = want, counts = want;
      for (size_t p = 0; p < skip.size(); ++p)
        if (skip[p]) {
          partial.count[p] = counts.count[p] = 12345;
          partial.radiance.set_rgb(int(p % 96), int(p / 96), Vec3(-1.f));
        }
      for (float& v : counts.radiance.data) v = -2.f;
      PixelReprojection got_partial = partial, got_counts = counts;
      gl.downsample_pixels_into(&got_partial, skip);
      gl.downsample_pixels_into(&got_counts, skip, DownsampleParts::kCounts);
      for (size_t p = 0; p < skip.size(); ++p) {
        ASSERT_EQ(got_partial.count[p], skip[p] ? 12345u : want.count[p]) << p;
        ASSERT_EQ(got_counts.count[p], skip[p] ? 12345u : want.count[p]) << p;
        for (int c = 0; c < 3; ++c) {
          const float g = got_partial.radiance.data[3 * p + size_t(c)];
          if (skip[p])
            ASSERT_EQ(g, -1.f);
          else
            ASSERT_NEAR(g, want.radiance.data[3 * p + size_t(c)], 1e-5f * std::max(1.f, want.radiance.data[3 * p]));
          ASSERT_EQ(got_counts.radiance.data[3 * p + size_t(c)], -2.f);
        }
      }
      // The compute-shader path, band by band.
      ReprojectorSettings cs = s;
      cs.gl_map_downsample = false;
      GlReprojector computed(*ctx_, cam, dfb, cs);
      computed.restore(ref, cpu.counts());
      expect_same_pixels(computed.downsample_pixels(), want);
    }
    {
      SCOPED_TRACE("restore, read, reset");
      GlReprojector restored(*ctx_, cam, dfb, s);
      restored.restore(ref, cpu.counts());
      const SubpixelAccumulation back = restored.read();
      EXPECT_EQ(back.count, ref.count);
      EXPECT_EQ(back.sum, ref.sum) << "restore then read gives the accumulation bit for bit";
      expect_same_counts(restored.counts(), cpu.counts());
      // Reprojection continues as if the samples had been added to it.
      const std::span<const VertexRecord> more(pts.data(), 50000);
      restored.reproject(more);
      cpu.reproject(more);
      expect_same_counts(restored.counts(), cpu.counts());
      expect_same_accumulation(restored.read(), cpu.read());
      restored.reproject(more);  // still waiting for its dispatch when reset() drops it
      restored.reset();
      EXPECT_EQ(restored.counts(), ReprojectionCounts{});
      const SubpixelAccumulation zero = restored.read();
      EXPECT_EQ(std::count(zero.count.begin(), zero.count.end(), 0u), std::ptrdiff_t(zero.count.size()));
    }
  }
}

// The limits: a band is whole pixel rows; gl_max_band_cells below one pixel row is refused.
TEST_F(GlBands, BandsAreWholePixelRows) {
  const Scene scene = test::scene_named("cornell");
  const Camera cam(scene.camera, 30, 21);
  const DeepFramebuffer dfb = build_deep_framebuffer_cpu(scene, cam, 2);
  ReprojectorSettings s;
  s.epsilon = default_epsilon(scene.bounds());
  s.gl_max_band_cells = 60 * 2 * 5 + 59;  // 5 pixel rows and a bit: 21 rows -> bands of 5, 5, 5, 5, 1
  GlReprojector gl(*ctx_, cam, dfb, s);
  EXPECT_EQ(gl.band_count(), 5u);
  EXPECT_EQ(gl.band_cells() % (60 * 2), 0u);
  EXPECT_LE(gl.band_cells(), s.gl_max_band_cells);
  s.gl_max_band_cells = 60 * 2 - 1;
  EXPECT_THROW(GlReprojector(*ctx_, cam, dfb, s), std::runtime_error);
  s.gl_max_band_cells = 0;
  GlReprojector one(*ctx_, cam, dfb, s);
  EXPECT_EQ(one.band_count(), 1u);
}

// A real 1920 x 1080, S = 4 frame (7680 x 4320 subpixels: 506 MiB of accumulation, more than one
// llvmpipe SSBO holds) on a hand-made plane grid -- a wall seen head-on, tiles of its texels
// assigned to a plane 0.5 m behind it or left uncovered -- and a few million points on and off the
// wall: GL and CPU agree on counts, per-subpixel counts and the downsampled image.
TEST_F(GlBands, FullHdFrameAtFourSubpixels) {
  CameraSpec spec;
  spec.eye = {0, 0, 3};
  spec.look = {0, 0, 0};
  spec.up = {0, 1, 0};
  spec.fov_y_degrees = 40;
  const Camera cam(spec, 1920, 1080);
  ReprojectorSettings s;
  s.epsilon = 1e-3f;
  detail::PlaneGrid grid;
  grid.width = 1920 * 4;
  grid.height = 1080 * 4;
  grid.subpixels = 4;
  grid.has_creases = true;
  grid.crease_tolerance = s.epsilon * detail::kCreaseToleranceFraction;
  grid.planes = {0.f, 0.f, 1.f, 0.f, 0.f, 0.f, 1.f, -0.5f};  // z = 0, z = -0.5
  grid.first_creased = 2;
  grid.texel_plane.resize(size_t(grid.width) * size_t(grid.height));
  for (int y = 0; y < grid.height; ++y)
    for (int x = 0; x < grid.width; ++x) {
      const int tile = (x / 37 + y / 23) % 5;
      grid.texel_plane[size_t(y) * size_t(grid.width) + size_t(x)] = tile == 0   ? detail::PlaneGrid::kUncovered
                                                                     : tile == 1 ? 1u
                                                                                 : 0u;
    }
  GlReprojector gl(*ctx_, cam, grid, s);
  EXPECT_GT(gl.band_count(), 1u) << "the frame should not fit one buffer on llvmpipe";
  CpuReprojector cpu(cam, std::move(grid), s);

  // Points on the wall (most accepted), off it, behind the camera, facing away.
  std::mt19937 rng(77);
  std::uniform_real_distribution<float> u(-1.f, 1.f), rad(0, 4);
  const float half_h = 3.f * std::tan(20.f * 3.14159265f / 180.f), half_w = half_h * 1920.f / 1080.f;
  std::vector<VertexRecord> pts(3'000'000);
  for (size_t i = 0; i < pts.size(); ++i) {
    VertexRecord& r = pts[i];
    const int kind = int(i % 10);
    r.position = {u(rng) * half_w * 1.05f, u(rng) * half_h * 1.05f, kind == 8 ? 0.3f : kind == 9 ? 4.f : 0.f};
    r.normal = {0, 0, i % 17 == 0 ? -1.f : 1.f};
    r.radiance = {rad(rng), rad(rng), rad(rng)};
    r.flags = VertexRecord::kDiffuse;
  }
  gl.reproject(pts);
  cpu.reproject(pts);
  const ReprojectionCounts c = cpu.counts();
  EXPECT_GT(c.accepted, 1'000'000u);
  EXPECT_GT(c.culled, 300'000u);
  expect_same_counts(gl.counts(), c);
  expect_same_pixels(gl.downsample_pixels(), cpu.downsample_pixels());
}

}  // namespace
}  // namespace epr
