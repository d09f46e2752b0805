// The method end to end in one process (DESIGN.md section 1; issue "Step 2"): path tracing,
// reprojection into the OSMesa deep framebuffer, normalisation, combination and pixel skipping,
// checked against answers known in closed form and against path tracing itself.
#include "client/local_render.h"

#include <gtest/gtest.h>

#include <cmath>

#include "common/scene_loader.h"
#include "worker/embree_scene.h"

namespace epr {
namespace {

double channel_mean(const Image& img) {
  double s = 0;
  for (float v : img.data) s += v;
  return s / double(img.data.size());
}

// A square render of `scene` at `spp` samples per pixel, the other options at their defaults.
RenderOptions square_job(const std::string& scene, int size, int spp) {
  RenderOptions o;
  o.scene = scene;
  o.width = o.height = size;
  o.spp = spp;
  return o;
}

// The mean of L_rp over the pixels that have reprojected samples (edge pixels have none:
// master/edge_pixels.h).
double reprojected_mean(const RenderOutputs& out) {
  double s = 0;
  size_t n = 0;
  for (size_t p = 0; p < out.mprime.data.size(); ++p)
    if (out.mprime.data[p] > 0) {
      for (int c = 0; c < 3; ++c) s += out.reprojection.data[3 * p + size_t(c)];
      n += 3;
    }
  return n ? s / double(n) : 0;
}

RenderOptions furnace_options(RenderMode mode, RussianRoulette rr) {
  RenderOptions o = square_job("builtin:furnace?albedo=0.5&emission=1", 64, 256);
  o.paths_per_round = 64;
  o.mode = mode;
  o.rr = rr;
  o.seed = 5;
  return o;
}

// Closed box, albedo 0.5, Le 1: radiance 2 everywhere. Every reprojected sample Le + R_n is an
// unbiased estimate of it, so the reprojection image and the combined image must show it too.
TEST(LocalRender, FurnaceReprojectionAndCombinedMatchAnalyticRadiance) {
  const RenderOutputs out = render_local(furnace_options(RenderMode::kReproject, RussianRoulette::paper()));
  const double expected = 2.0;
  EXPECT_NEAR(channel_mean(out.pathtrace), expected, 0.01 * expected);
  EXPECT_NEAR(reprojected_mean(out), expected, 0.01 * expected);
  EXPECT_NEAR(channel_mean(out.combined), expected, 0.01 * expected);
  EXPECT_GT(channel_mean(out.mprime), 100.0);  // most vertices of a closed box are visible
}

// Paper Fig. 11: truncating paths at a fixed depth makes reprojected samples (the shorter tails of
// paths) darker than path samples; with Russian roulette they agree.
TEST(LocalRender, RussianRouletteKeepsReprojectionUnbiased) {
  const RenderOutputs fixed = render_local(furnace_options(RenderMode::kReproject, RussianRoulette::off(3)));
  const double pt_fixed = channel_mean(fixed.pathtrace), rp_fixed = reprojected_mean(fixed);
  // Depth 3: path samples 1 + a + a^2 + a^3 = 1.875; vertices at depth 2 and 3 carry 1.75 and 1.5.
  EXPECT_NEAR(pt_fixed, 1.875, 0.02);
  EXPECT_LT(rp_fixed, 0.95 * pt_fixed) << "without roulette the reprojection image must be darker";

  // Every unbiased policy, the ones whose survival follows the path's throughput included: the
  // records (Le + R_n of vertices other pixels see) and the pixels both show the analytic 2.
  for (const char* name : {"paper", "throughput", "reuse"}) {
    SCOPED_TRACE(name);
    const RenderOutputs rr = render_local(furnace_options(RenderMode::kReproject, roulette_named(name).value()));
    EXPECT_NEAR(reprojected_mean(rr), channel_mean(rr.pathtrace), 0.01 * channel_mean(rr.pathtrace));
    EXPECT_NEAR(reprojected_mean(rr), 2.0, 0.02);
    EXPECT_NEAR(channel_mean(rr.pathtrace), 2.0, 0.02);
  }
}

TEST(LocalRender, SkippingTracesFewerPathsAndEveryPixelReachesTarget) {
  RenderOptions o = square_job("builtin:cornell", 64, 16);
  o.mode = RenderMode::kSkip;
  const RenderOutputs out = render_local(o);
  uint64_t traced = 0;
  for (int y = 0; y < o.height; ++y)
    for (int x = 0; x < o.width; ++x) {
      const float m = out.path_count.at(x, y)[0], mp = out.mprime.at(x, y)[0];
      ASSERT_GE(m + mp, float(o.spp)) << x << "," << y;
      ASSERT_GE(m, 1.f);
      traced += uint64_t(m);
    }
  const uint64_t full = uint64_t(o.spp) * o.width * o.height;
  // Edge pixels (21 % of the image here, master/edge_pixels.h) trace all their paths.
  EXPECT_LT(traced, full * 17 / 20) << "skipping must save paths on the Cornell box";
  EXPECT_EQ(out.stats.at("paths_traced").get<uint64_t>(), traced);
  EXPECT_EQ(out.stats.at("paths_skipped").get<uint64_t>(), full - traced);
}

// Skip mode refreshes M' only for the pixels still active at a round's end; a preview keeps the
// skipped pixels as they were, the images for results bring them up to date (they keep receiving
// reprojected samples from their neighbours' paths).
TEST(LocalRender, SkipModePreviewKeepsSkippedPixelsResultImagesRefreshThem) {
  RenderOptions o = square_job("builtin:cornell", 64, 32);
  o.round_growth = 0;
  o.mode = RenderMode::kSkip;
  o.reproject = ReprojectMethod::kCpu;
  bool checked = false;
  render_local(o, [&](const RoundProgress& p) {
    if (checked || p.pixels_active > 0.8 || p.pixels_active < 0.05) return;
    std::vector<uint8_t> skip;
    std::vector<uint32_t> first_sample;
    p.frame->tile_inputs(0, 0, o.width, o.height, &skip, &first_sample);
    const FrameImages preview = p.frame->images(/*preview=*/true);
    const FrameImages current = p.frame->images();
    size_t skipped = 0, grew = 0;
    for (size_t i = 0; i < skip.size(); ++i) {
      const float before = preview.reprojected.data[i], now = current.reprojected.data[i];
      if (skip[i]) {
        ++skipped;
        ASSERT_GE(now, before) << i;
        grew += now > before;
      } else {
        ASSERT_EQ(now, before) << "an active pixel is refreshed every round: " << i;
        // The round refreshed M' alone; the preview brings the active pixels' L_rp up to date.
        for (size_t c = 0; c < 3; ++c)
          ASSERT_EQ(preview.reprojection.data[3 * i + c], current.reprojection.data[3 * i + c]) << i;
      }
    }
    EXPECT_GT(skipped, 100u);
    EXPECT_GT(grew, skipped / 10) << "skipped pixels keep receiving reprojected samples";
    checked = true;
  });
  EXPECT_TRUE(checked) << "no round had between 5 % and 80 % of the pixels active";
}

TEST(LocalRender, NoSkippingInPathTraceMode) {
  RenderOptions o = square_job("builtin:cornell", 32, 4);
  const RenderOutputs out = render_local(o);
  for (float m : out.path_count.data) ASSERT_EQ(m, 4.f);
  EXPECT_EQ(out.mprime.width, 0);  // no reprojection ran
}

// Pixels whose footprint spans more than one plane: casting rays through the pixel's corners and
// centre, the hit triangles' planes differ (or some ray misses).
std::vector<uint8_t> edge_pixels(const Scene& scene, const Camera& cam) {
  EmbreeScene es(scene);
  std::vector<uint8_t> edge(size_t(cam.width()) * size_t(cam.height()), 0);
  for (int y = 0; y < cam.height(); ++y)
    for (int x = 0; x < cam.width(); ++x) {
      Vec3 first_n;
      float first_d = 0;
      bool first = true, differs = false;
      const float offs[5][2] = {{0.01f, 0.01f}, {0.99f, 0.01f}, {0.01f, 0.99f}, {0.99f, 0.99f}, {0.5f, 0.5f}};
      for (const auto& o : offs) {
        Hit h;
        const Ray r = cam.generate_ray(float(x) + o[0], float(y) + o[1]);
        if (!es.intersect(r, 0, 1e30f, &h)) {
          differs = true;
          break;
        }
        const Vec3 n = scene.geometric_normal(h.prim);
        const float d = dot(n, scene.positions[scene.triangles[h.prim][0]]);
        if (first) {
          first_n = n;
          first_d = d;
          first = false;
        } else if (dot(n, first_n) < 0.9999f || std::abs(d - first_d) > 1e-4f) {
          differs = true;
        }
      }
      edge[size_t(y) * size_t(cam.width()) + size_t(x)] = differs;
    }
  return edge;
}

struct EdgeSplit {
  double interior_signed = 0, edge_abs = 0, interior_abs = 0;  // relative to the reference's mean
};

EdgeSplit split_difference(const Image& a, const Image& ref, const std::vector<uint8_t>& edge) {
  double sum_ref = 0, n_int = 0, n_edge = 0;
  EdgeSplit s;
  for (size_t p = 0; p < edge.size(); ++p) {
    const double va = (a.data[3 * p] + a.data[3 * p + 1] + a.data[3 * p + 2]) / 3;
    const double vr = (ref.data[3 * p] + ref.data[3 * p + 1] + ref.data[3 * p + 2]) / 3;
    sum_ref += vr;
    if (edge[p]) {
      s.edge_abs += std::abs(va - vr);
      ++n_edge;
    } else {
      s.interior_abs += std::abs(va - vr);
      s.interior_signed += va - vr;
      ++n_int;
    }
  }
  const double mean_ref = sum_ref / double(edge.size());
  s.interior_signed /= n_int * mean_ref;
  s.interior_abs /= n_int * mean_ref;
  s.edge_abs /= n_edge * mean_ref;
  return s;
}

// Paper Fig. 9: the deep framebuffer and exact visibility part at edges only. GL and exact renders
// with the same seed share every path and every vertex, so their difference is free of path noise:
// inside surfaces it is the deep framebuffer's discretisation (the epsilon plane test), tiny; at edges
// the GL render's edge pixels take no reprojected samples (master/edge_pixels.h, their bias is
// EdgeBias.*'s) while exact's keep theirs. Path tracing with another seed is the unbiased reference
// for the exact mode's bias check.
TEST(LocalRender, ConvergedCornellBiasIsConcentratedAtEdgesAndExactModeHasNone) {
  RenderOptions o = square_job("builtin:cornell", 96, 256);
  o.paths_per_round = 64;
  o.seed = 1;
  const RenderOutputs pt = render_local(o);
  o.mode = RenderMode::kReproject;
  o.seed = 2;
  const RenderOutputs gl = render_local(o);
  o.reproject = ReprojectMethod::kExact;
  const RenderOutputs exact = render_local(o);

  const Scene scene = load_scene(o.scene);
  const Camera cam(scene.camera, o.width, o.height);
  const auto edge = edge_pixels(scene, cam);
  const EdgeSplit disc = split_difference(gl.combined, exact.combined, edge);
  const EdgeSplit bias = split_difference(exact.combined, pt.pathtrace, edge);
  std::printf("gl vs exact: interior signed %.5f |.| %.5f  edge |.| %.5f\n", disc.interior_signed, disc.interior_abs,
              disc.edge_abs);
  std::printf("exact vs pt: interior signed %.5f |.| %.5f  edge |.| %.5f\n", bias.interior_signed, bias.interior_abs,
              bias.edge_abs);
  // Tiny inside surfaces, far larger at edges. Measured at 96x96, 256 spp, S = 4: interior mean
  // |gl - exact| = 0.056 % of the image mean, edges 2.5 % (44x; 7.3 % before edge pixels took no
  // reprojected samples). An epsilon or projection bug breaks the interior bound.
  EXPECT_LT(disc.interior_abs, 0.002);
  EXPECT_GT(disc.edge_abs, 20 * disc.interior_abs);
  // Exact mode: no bias beyond noise against independent path tracing (interior mean within 2 %).
  EXPECT_NEAR(bias.interior_signed, 0.0, 0.02);
}

// The statistics name the roulette that ran: `auto` (the default) as what it resolved to from the
// scene's lights, the same paths as that roulette named outright; any other by its own name.
TEST(LocalRender, StatisticsNameTheRouletteThatRan) {
  RenderOptions lamp = square_job("builtin:cornell", 16, 4);
  RenderOptions sky = lamp;
  sky.lighting.environment = EnvironmentLight{};
  sky.lighting.environment->color = Vec3(0.5f);
  for (const auto& [opts, name] : {std::pair{lamp, "albedo"}, std::pair{sky, "reuse"}}) {
    const RenderOutputs automatic = render_local(opts);
    EXPECT_EQ(automatic.stats.at("roulette"), name);
    RenderOptions named = opts;
    named.rr = *roulette_named(name);
    const RenderOutputs outright = render_local(named);
    EXPECT_EQ(outright.stats.at("roulette"), name);
    EXPECT_EQ(automatic.pathtrace.data, outright.pathtrace.data) << name;
  }
  RenderOptions paper = sky;
  paper.rr = RussianRoulette::paper();
  const RenderOutputs out = render_local(paper);
  EXPECT_EQ(out.stats.at("roulette"), "paper");
  EXPECT_NE(out.pathtrace.data, render_local(sky).pathtrace.data);
}

}  // namespace
}  // namespace epr
