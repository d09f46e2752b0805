// Stability where eye path reprojection fails (docs/FAILURE_MODES.md; DESIGN.md section 5): one test
// per failure case. Every image of every render must be free of NaN and infinity; reprojection's
// error must not exceed plain path tracing's at the same path count by more than a stated margin;
// the artefacts a protection exists for must appear when the protection is defeated.
//
// Method: 64 x 64 images, P = 16 paths per pixel, single-process renders (render_local) with the CPU
// reprojector (its accept / occlude / cull decisions are bit-identical to the GL back-end's, see
// master/reprojector.h). "rp" = reprojection without skipping: it traces exactly the paths "pt" traces
// (same seed, same P), so their errors compare at equal path count. Errors are the relative MSE
//     rMSE = mean over pixels of mean_c (x_c - r_c)^2 / (r_c^2 + 0.01)
// without the largest 1 % of pixel terms (NEE fireflies next to emitters dominate the full mean),
// against a path-traced reference rendered here with 128 paths per pixel (8 P; its own noise adds
// about 1/8 of pt's error to both sides, which moves every ratio a little towards 1) and a different
// seed -- 256 for the glossy scene, the noisiest -- or against the analytic radiance (furnace).
// Seeds are fixed. The figures quoted in comments were measured over seeds 1 - 3 against 256-path
// references at aaede10 (independent sampler, W = 1, the Cornell box's light two-sided); against the
// 128-path ones the seed-1 ratios move by at most 0.05 towards 1 (grazing floor 0.10 -> 0.15), and
// every margin leaves room for the seed-to-seed spread. docs/FAILURE_MODES.md has today's figures.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <limits>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "client/local_render.h"
#include "common/builtin_scenes.h"
#include "common/scene_loader.h"
#include "master/frame_state.h"
#include "tests/study/image_error.h"
#include "tests/study/unfiltered_render.h"
#include "worker/embree_scene.h"
#include "worker/tile_renderer.h"

namespace epr {
namespace {

constexpr int kSize = 64;
constexpr int kSpp = 16;
constexpr int kRefSpp = 128;

// The seed and the direct-light estimator come from the environment so that the figures quoted
// below can be measured again over seeds (EPR_STUDY_SEED=2 ...) and for either estimator
// (EPR_STUDY_MIS=0: next event estimation only, DESIGN.md section 1). The defaults are what ctest
// runs: seed 1 and MIS, the renderer's default.
uint64_t study_seed() {
  const char* s = std::getenv("EPR_STUDY_SEED");
  return s ? std::strtoull(s, nullptr, 10) : 1;
}
bool study_mis() {
  const char* s = std::getenv("EPR_STUDY_MIS");
  return !s || std::string(s) != "0";
}

RenderOptions options(const std::string& scene, RenderMode mode, uint64_t seed = study_seed()) {
  RenderOptions o;
  o.scene = scene;
  o.width = o.height = kSize;
  o.spp = kSpp;
  o.mode = mode;
  o.reproject = ReprojectMethod::kCpu;
  o.seed = seed;
  o.mis = study_mis();
  o.edge_pixels = false;  // the study measures the deep framebuffer's discretisation at edges
  return o;
}

RenderOptions rp(const std::string& scene, uint64_t seed = study_seed()) {
  return options(scene, RenderMode::kReproject, seed);
}
RenderOptions pt(const std::string& scene, uint64_t seed = study_seed()) {
  return options(scene, RenderMode::kPathTrace, seed);
}

uint64_t nonfinite(const Image& img) {
  uint64_t n = 0;
  for (float v : img.data) n += !std::isfinite(v);
  return n;
}

/// Renders and checks that no image holds a NaN or an infinity.
RenderOutputs render(const RenderOptions& o) {
  RenderOutputs out = render_local(o);
  EXPECT_EQ(nonfinite(out.combined), 0u) << o.scene << " combined";
  EXPECT_EQ(nonfinite(out.pathtrace), 0u) << o.scene << " pathtrace";
  EXPECT_EQ(nonfinite(out.reprojection), 0u) << o.scene << " reprojection";
  return out;
}

/// Converged path tracing of o.scene (`spp` paths per pixel, the paper's roulette, its own seed),
/// rendered once per scene and kept for the other tests of the process.
const Image& reference(const RenderOptions& opts, int spp = kRefSpp) {
  static std::map<std::pair<std::string, int>, Image> cache;
  const auto key = std::make_pair(opts.scene, spp);
  auto it = cache.find(key);
  if (it != cache.end()) return it->second;
  RenderOptions o = options(opts.scene, RenderMode::kPathTrace);
  o.spp = spp;
  o.paths_per_round = 32;
  o.seed = 9001;
  return cache.emplace(key, render(o).combined).first->second;
}

size_t count(const Mask& m) {
  return size_t(std::count_if(m.begin(), m.end(), [](uint8_t v) { return v != 0; }));
}

/// What a camera ray through a raster position hits.
struct Probe {
  bool hit = false;
  float t = 0;
  uint32_t prim = 0;
  const Material* material = nullptr;
  Vec3 position;
};

/// Pixels whose centre and four corner rays (inset by 0.02 px) all satisfy `all`, or, with
/// `any_differ`, pixels whose five rays disagree according to `differ`.
class PixelProbe {
 public:
  explicit PixelProbe(const std::string& scene_spec)
      : scene_(load_scene(scene_spec)), embree_(scene_), camera_(scene_.camera, kSize, kSize) {}

  Probe probe(float rx, float ry) const {
    const Ray ray = camera_.generate_ray(rx, ry);
    Hit hit;
    Probe p;
    if (!embree_.intersect(ray, 0.f, std::numeric_limits<float>::infinity(), &hit)) return p;
    p.hit = true;
    p.t = hit.t;
    p.prim = hit.prim;
    p.material = &scene_.materials[scene_.material_of[hit.prim]];
    p.position = ray.origin + ray.dir * hit.t;
    return p;
  }

  Mask where_all(const std::function<bool(const Probe&)>& pred) const {
    return build([&](const std::array<Probe, 5>& ps) {
      return std::all_of(ps.begin(), ps.end(), [&](const Probe& p) { return pred(p); });
    });
  }

  Mask where(const std::function<bool(const std::array<Probe, 5>&)>& pred) const { return build(pred); }
  const Scene& scene() const { return scene_; }
  const Camera& camera() const { return camera_; }

 private:
  Mask build(const std::function<bool(const std::array<Probe, 5>&)>& pred) const {
    Mask m(size_t(kSize) * kSize, 0);
    constexpr float kIn = 0.02f;
    for (int y = 0; y < kSize; ++y)
      for (int x = 0; x < kSize; ++x) {
        const float fx = float(x), fy = float(y);
        const std::array<Probe, 5> ps = {probe(fx + 0.5f, fy + 0.5f), probe(fx + kIn, fy + kIn),
                                         probe(fx + 1 - kIn, fy + kIn), probe(fx + kIn, fy + 1 - kIn),
                                         probe(fx + 1 - kIn, fy + 1 - kIn)};
        m[size_t(y) * kSize + size_t(x)] = pred(ps);
      }
    return m;
  }

  Scene scene_;
  EmbreeScene embree_;
  Camera camera_;
};

/// Edge pixels: the five rays hit different materials, or depths more than 5 % apart.
Mask edge_mask(const PixelProbe& probe) {
  return probe.where([](const std::array<Probe, 5>& ps) {
    for (const Probe& p : ps) {
      if (p.hit != ps[0].hit) return true;
      if (!p.hit) continue;
      if (p.material != ps[0].material || std::abs(p.t - ps[0].t) > 0.05f * ps[0].t) return true;
    }
    return false;
  });
}

double num(const nlohmann::json& j, const char* key) { return j.contains(key) ? j.at(key).get<double>() : 0.0; }

/// Share of the recorded vertices x_n, n >= 2, culled by the worker or the master, in %.
double culled_percent(const nlohmann::json& s) {
  const double culled = num(s, "culled_master") + num(s, "culled_frustum_worker") + num(s, "culled_facing_worker") +
                        num(s, "culled_glossy_worker");
  return 100 * culled / std::max(1.0, num(s, "vertices_recorded"));
}

double max_on(const Image& img, const Mask& mask) {
  double m = 0;
  for (size_t p = 0; p < mask.size(); ++p)
    if (mask[p])
      for (int c = 0; c < 3; ++c) m = std::max(m, double(img.data[p * size_t(img.channels) + size_t(c)]));
  return m;
}

void report(const char* what, double rp_err, double pt_err) {
  std::printf("  %-40s rp %.5f  pt %.5f  rp/pt %.3f\n", what, rp_err, pt_err, rp_err / pt_err);
}

}  // namespace

// The study's scenes: parsed by name, valid, lit, deterministic.
TEST(FailureModes, StudyScenesBuildValidAndDeterministic) {
  for (const std::string& name : study_scene_names()) {
    SCOPED_TRACE(name);
    const Scene a = load_scene("builtin:" + name), b = make_builtin_scene(name);
    EXPECT_NO_THROW(a.validate());
    EXPECT_EQ(a.name, "builtin:" + name);
    EXPECT_FALSE(a.camera.validate().has_value());
    EXPECT_TRUE(std::any_of(a.materials.begin(), a.materials.end(), [](const Material& m) { return m.emissive(); }));
    EXPECT_EQ(a.positions.size(), b.positions.size());
    EXPECT_EQ(a.triangles, b.triangles);
    EXPECT_EQ(make_builtin_scene(name, 3).triangle_count(), 9 * a.triangle_count());
  }
  const auto six = builtin_scene_names();  // the design's six stay six
  EXPECT_EQ(std::find(six.begin(), six.end(), "thinwall"), six.end());
}

// ---------------------------------------------------------------------------------------------------
// Glossy surfaces: not reprojected by default; forcing them in biases the glossy pixels.
// ---------------------------------------------------------------------------------------------------

TEST(FailureModes, GlossyVerticesAreCulledByDefaultAndForcingThemBiasesTheGlossyBox) {
  const std::string scene = "builtin:glossy";
  const PixelProbe probe(scene);
  const Mask glossy = probe.where_all([](const Probe& p) { return p.hit && !p.material->diffuse(); });
  ASSERT_GT(count(glossy), 200u) << "the tall glossy box must fill a region of the image";
  const Image& ref = reference(rp(scene), 256);
  const RenderOutputs ptr = render(pt(scene));
  const RenderOutputs def = render(rp(scene));
  RenderOptions forced_opts = rp(scene);
  forced_opts.reproject_glossy = true;
  const RenderOutputs forced = render(forced_opts);

  EXPECT_GT(num(def.stats, "culled_glossy_worker"), 0) << "glossy vertices must be culled by default";
  EXPECT_EQ(num(forced.stats, "culled_glossy_worker"), 0);
  const double e_pt = rmse(ptr.combined, ref), e_def = rmse(def.combined, ref);
  const double g_pt = rmse(ptr.combined, ref, glossy), g_def = rmse(def.combined, ref, glossy),
               g_forced = rmse(forced.combined, ref, glossy);
  report("glossy scene, whole image, default", e_def, e_pt);
  report("glossy box pixels, default", g_def, g_pt);
  report("glossy box pixels, glossy forced", g_forced, g_pt);
  // By default the glossy pixels get no reprojected sample (their first vertex is glossy and what
  // lies behind is occluded), so they keep path tracing's error: measured rp/pt 1.000 (seeds 1-3, MIS and NEE).
  EXPECT_LE(g_def, 1.02 * g_pt);
  // Whole image: measured rp/pt 0.68, 0.70, 0.64 (MIS, seeds 1-3; 1.002, 1.024, 0.852 with NEE only,
  // whose diffuse vertices lit through the glossy box were the noisy ones): 10 % margin.
  EXPECT_LE(e_def, 1.10 * e_pt);
  // The failure mode, made visible: view-dependent radiance reprojected as if it were diffuse.
  // Measured forced / default on the glossy pixels: 1.74, 2.41, 1.96 (MIS; 1.60-1.85 with NEE only).
  EXPECT_GT(g_forced, 1.3 * g_def);
}

// ---------------------------------------------------------------------------------------------------
// Epsilon: 0 rejects almost everything (tilted planes) and biases edges; 100x lets hidden points
// through (the paper's Fig. 10 transparency); the default does neither.
// ---------------------------------------------------------------------------------------------------

TEST(FailureModes, EpsilonZeroAndHundredfoldShowTheirArtefactsTheDefaultDoesNot) {
  const std::string scene = "builtin:cornell";
  const Mask edges = edge_mask(PixelProbe(scene));
  const Image& ref = reference(rp(scene));
  const RenderOutputs ptr = render(pt(scene));
  std::vector<RenderOutputs> outs;  // epsilon 0, default, 100x; then default and 100x without the joint test
  for (auto [f, joint] : {std::pair{0.f, true}, {1.f, true}, {100.f, true}, {1.f, false}, {100.f, false}}) {
    RenderOptions o = rp(scene);
    o.epsilon = 3e-4f * f;
    o.joint_test = joint;
    outs.push_back(render(o));
  }
  RenderOptions ex = rp(scene);
  ex.reproject = ReprojectMethod::kExact;
  const RenderOutputs exact = render(ex);
  const double e_pt = rmse(ptr.combined, ref);
  const double e0 = rmse(outs[0].combined, ref), e1 = rmse(outs[1].combined, ref), e100 = rmse(outs[2].combined, ref);
  const double ex_err = rmse(exact.combined, ref);
  report("epsilon 0", e0, e_pt);
  report("epsilon default", e1, e_pt);
  report("epsilon 100x", e100, e_pt);
  report("exact", ex_err, e_pt);
  const double a0 = num(outs[0].stats, "accepted"), a1 = num(outs[1].stats, "accepted"),
               a100 = num(outs[2].stats, "accepted");
  const double a1_off = num(outs[3].stats, "accepted"), a100_off = num(outs[4].stats, "accepted");
  std::printf("  accepted: eps 0 %.0f, default %.0f, 100x %.0f; without the joint test: default %.0f, 100x %.0f\n", a0,
              a1, a100, a1_off, a100_off);
  std::printf("  mean: ref %.4f eps0 %.4f def %.4f 100x %.4f\n", mean(ref), mean(outs[0].combined),
              mean(outs[1].combined), mean(outs[2].combined));
  report("epsilon default, no joint test", rmse(outs[3].combined, ref), e_pt);
  report("epsilon 100x, no joint test", rmse(outs[4].combined, ref), e_pt);
  report("edges: default, no joint test", rmse(outs[3].combined, ref, edges), rmse(ptr.combined, ref, edges));
  report("edges: 100x, no joint test", rmse(outs[4].combined, ref, edges), rmse(ptr.combined, ref, edges));
  report("edges: epsilon default", rmse(outs[1].combined, ref, edges), rmse(ptr.combined, ref, edges));
  report("edges: epsilon 100x", rmse(outs[2].combined, ref, edges), rmse(ptr.combined, ref, edges));
  report("edges: exact", rmse(exact.combined, ref, edges), rmse(ptr.combined, ref, edges));

  // Default: the discretisation costs nothing measurable. Measured (MIS, seeds 1-3) rp/pt 0.78, 0.88,
  // 0.83 and rp/exact 0.99, 1.00, 1.00: no margin over pt, 10 % over exact.
  EXPECT_LE(e1, 1.0 * e_pt);
  EXPECT_LE(e1, 1.10 * ex_err);
  // Epsilon 0: only points on axis-aligned planes survive the plane test (4 % of the default's),
  // so pixels mix a few surfaces' samples: the image measurably differs. Measured eps0 / default
  // rMSE 1.28, 1.22, 1.27 (MIS; 1.62-1.68 with NEE only, whose noise hid less of it... its fireflies
  // sit where eps 0 rejects); mean radiance +10.1 %, +9.5 %, +9.9 % above the default's (the
  // reference: +0.4 %).
  EXPECT_LT(a0, 0.1 * a1);
  EXPECT_GT(e0, 1.12 * e1);
  EXPECT_GT(mean(outs[0].combined), 1.05 * mean(outs[1].combined));
  // 100 x epsilon (3 % of the diagonal, ~10 cm here) with the plane test alone (the paper's; the joint
  // test off): occluded points near visible planes pass (transparency, Fig. 10) -- 2.3 % more vertices
  // accepted -- and they land at occlusion edges. Both renders trace the same paths, so their
  // difference is exactly what the extra acceptances did: measured per edge pixel 23x, 16x, 14x the
  // mean change elsewhere (seeds 1-3). In rMSE the artefact is small at 16 paths: 100x / default on
  // the edge pixels 1.11, 1.03, 1.02 (MIS; 1.29 with NEE).
  EXPECT_GT(a100_off, 1.01 * a1_off);
  const auto mean_change = [&](const Image& a, const Image& b, bool on_edges) {
    double sum = 0;
    size_t n = 0;
    for (size_t p = 0; p < edges.size(); ++p) {
      if ((edges[p] != 0) != on_edges) continue;
      for (int c = 0; c < 3; ++c)
        sum += std::fabs(double(a.data[p * 3 + size_t(c)]) - double(b.data[p * 3 + size_t(c)]));
      ++n;
    }
    return sum / double(std::max<size_t>(1, n));
  };
  const double change_edges = mean_change(outs[4].combined, outs[3].combined, true),
               change_rest = mean_change(outs[4].combined, outs[3].combined, false);
  std::printf("  100x - default without the joint test, mean |change| per pixel: edges %.5f, elsewhere %.5f (%.1fx)\n",
              change_edges, change_rest, change_edges / std::max(1e-12, change_rest));
  EXPECT_GT(change_edges, 3.0 * change_rest);
  EXPECT_GE(rmse(outs[4].combined, ref, edges), 1.0 * rmse(outs[3].combined, ref, edges));
  // The joint test (the default) rejects most of those points: they lie on surfaces crossing the
  // visible plane (the floor under a box's side, a wall behind a box's edge), whose normals differ
  // from the plane's. Measured extra acceptances at 100x: +0.45 %, +0.45 %, +0.47 % with it against
  // +2.3 % without, and the 100x edge error 1.00, 0.98, 1.21 x pt against 1.10, 0.99, 1.22 without
  // (seeds 1-3). At the default epsilon it rejects 0.12 % of the accepted vertices and leaves the
  // error where it was (0.780, 0.882, 0.828 x pt against 0.778, 0.882, 0.829).
  EXPECT_LT(a100 - a1, 0.5 * (a100_off - a1_off));
  EXPECT_LE(rmse(outs[2].combined, ref, edges), rmse(outs[4].combined, ref, edges));
  EXPECT_GT(a1, 0.99 * a1_off);
  EXPECT_LE(e1, 1.02 * rmse(outs[3].combined, ref));
}

// ---------------------------------------------------------------------------------------------------
// Subpixels: with S = 1 the reprojected samples of a pixel are averaged with their uneven density
// inside it, which biases edge pixels (Fig. 7-8); S = 4 normalises per subpixel.
// ---------------------------------------------------------------------------------------------------

TEST(FailureModes, OneSubpixelAliasesEdgesFourDoesNot) {
  const std::string scene = "builtin:cornell";
  const PixelProbe probe(scene);
  const Mask edges = edge_mask(probe);
  ASSERT_GT(count(edges), 300u);
  const Image& ref = reference(rp(scene));
  const RenderOutputs ptr = render(pt(scene));
  RenderOptions ex = rp(scene);
  ex.reproject = ReprojectMethod::kExact;
  const double exact_edges = rmse(render(ex).combined, ref, edges);
  std::vector<double> edge_err, all_err;
  for (int s : {1, 2, 4}) {
    RenderOptions o = rp(scene);
    o.subpixels = s;
    const RenderOutputs out = render(o);
    edge_err.push_back(rmse(out.combined, ref, edges));
    all_err.push_back(rmse(out.combined, ref));
    report(("S=" + std::to_string(s) + " edges").c_str(), edge_err.back(), rmse(ptr.combined, ref, edges));
    report(("S=" + std::to_string(s) + " whole").c_str(), all_err.back(), rmse(ptr.combined, ref));
  }
  const double pt_edges = rmse(ptr.combined, ref, edges), pt_all = rmse(ptr.combined, ref);
  // S = 1 aliases edges: measured (MIS, seeds 1-3) S=1 / S=4 on the edge pixels 1.38, 1.49, 1.48
  // (2.0-2.4 with NEE only), and S=1 is worse than path tracing there (rp/pt 1.36, 1.43, 1.78).
  EXPECT_GT(edge_err[0], 1.25 * edge_err[2]);
  EXPECT_GT(edge_err[0], pt_edges);
  // S = 4 (the default) does not: on the edges it matches exact visibility (rp/exact 0.97, 1.02,
  // 0.99) -- where both are above pt (seed 3: 1.20 and 1.22), reprojected samples of the neighbouring
  // surfaces are what exact visibility also admits, not discretisation -- and on the whole image it
  // beats pt (0.78, 0.88, 0.83).
  EXPECT_LE(edge_err[2], 1.05 * exact_edges);
  EXPECT_LE(edge_err[2], 1.3 * pt_edges);
  EXPECT_LE(all_err[2], 1.0 * pt_all);
}

// ---------------------------------------------------------------------------------------------------
// The wall: almost every vertex is culled; reprojection must cost no accuracy.
// ---------------------------------------------------------------------------------------------------

TEST(FailureModes, FacingAWallAlmostEverythingIsCulledAndErrorStaysPathTracings) {
  const std::string scene = "builtin:wall";
  const Image& ref = reference(rp(scene));
  const RenderOutputs ptr = render(pt(scene));
  const RenderOutputs out = render(rp(scene));
  const double culled = culled_percent(out.stats);
  const double e_rp = rmse(out.combined, ref), e_pt = rmse(ptr.combined, ref);
  report("wall", e_rp, e_pt);
  std::printf("  culled %.2f%%, accepted %.0f\n", culled, num(out.stats, "accepted"));
  // Measured 99.90 / 99.91 / 99.90 % culled and rp/pt 0.995, 0.993, 0.995 (MIS, seeds 1-3): the few
  // accepted samples change nothing; 2 % margin.
  EXPECT_GT(culled, 99.0);
  EXPECT_GT(num(out.stats, "accepted"), 0);
  EXPECT_LE(e_rp, 1.02 * e_pt);
}

// ---------------------------------------------------------------------------------------------------
// Thin two-sided walls: no light through the partition.
// ---------------------------------------------------------------------------------------------------

TEST(FailureModes, ThinWallLeaksNoLightThroughItsFaceOrItsJoints) {
  const std::string scene = "builtin:thinwall";
  const PixelProbe probe(scene);
  // The partition's face, seen from the dark room, at least 10 cm from its joints with the floor,
  // the ceiling and the back wall.
  const Mask face = probe.where_all([](const Probe& p) {
    return p.hit && p.material->name == "partition" && p.position.y > 0.1f && p.position.y < 1.9f &&
           p.position.z > -0.9f;
  });
  // Everything seen in the dark room, the partition (x = 0) included.
  const Mask dark = probe.where_all([](const Probe& p) { return p.hit && p.position.x > -1e-4f; });
  const Mask lit = probe.where_all([](const Probe& p) { return p.hit && p.position.x < -1e-3f; });
  ASSERT_GT(count(face), 150u);
  ASSERT_GT(count(dark), 500u);
  ASSERT_GT(count(lit), 500u);

  const RenderOutputs ptr = render(pt(scene));
  const RenderOutputs out = render(rp(scene));
  RenderOptions ex = rp(scene);
  ex.reproject = ReprojectMethod::kExact;
  const RenderOutputs exact = render(ex);
  RenderOptions no_joint = rp(scene);
  no_joint.joint_test = false;
  const RenderOutputs plane_only = render(no_joint);
  const UnfilteredRender master_only = render_unfiltered(rp(scene), false);
  const UnfilteredRender defeated = render_unfiltered(rp(scene), true);
  EXPECT_GT(master_only.counts.accepted, 0u);
  EXPECT_GT(defeated.counts.accepted, 0u);
  std::printf(
      "  pt max on dark %.4g; rp max on face %.4g, on dark %.4g; without the joint test %.4g; exact max on dark %.4g; "
      "master-only face %.4g dark %.4g; defeated face max %.4g mean %.4g; lit mean %.4f; backfacing %llu\n",
      max_on(ptr.combined, dark), max_on(out.combined, face), max_on(out.combined, dark),
      max_on(plane_only.combined, dark), max_on(exact.combined, dark), max_on(master_only.images.combined, face),
      max_on(master_only.images.combined, dark), max_on(defeated.images.combined, face),
      mean(defeated.images.combined, face), mean(ptr.combined, lit), (unsigned long long)master_only.counts.backfacing);

  // Path tracing: no light at all in the dark room (the scene's premise).
  EXPECT_EQ(max_on(ptr.combined, dark), 0.0);
  // Through the partition's face: nothing, to the bit -- the worker culls the far side's vertices
  // (culled_facing) and, without the worker's filter, the master's back-facing test does.
  EXPECT_GT(num(out.stats, "culled_facing_worker"), 1000);
  EXPECT_EQ(max_on(out.combined, face), 0.0);
  EXPECT_GT(master_only.counts.backfacing, 1000u);
  EXPECT_EQ(max_on(master_only.images.combined, face), 0.0);
  // At the joints, the plane test alone (the paper's) leaks: the lit room's floor, ceiling and back
  // wall lie in the dark room's planes, and near the partition their points also lie within epsilon of
  // the partition's plane. Points landing on the dark room's joint texels pass: measured 3.7 %, 2.0 %,
  // 6.0 % of the lit room's mean radiance on one pixel (MIS, seeds 1-3; 5 % with NEE only), confined
  // to pixels within 10 cm of the joints.
  const Mask away_from_joints = probe.where_all([](const Probe& p) {
    return p.hit && p.position.x > -1e-4f &&
           !(p.position.x < 0.1f && (p.position.y < 0.1f || p.position.y > 1.9f || p.position.z < -0.9f));
  });
  ASSERT_GT(count(away_from_joints), 500u);
  EXPECT_EQ(max_on(plane_only.combined, away_from_joints), 0.0);
  EXPECT_GT(max_on(plane_only.combined, dark), 0.01 * mean(ptr.combined, lit));
  // The joint test (the default) stops both: a lit floor point on a partition texel has a normal 90
  // degrees from the partition's, and one on a dark floor texel lies past that texel's crease (the
  // partition's plane, seen by its neighbours). The whole dark room, joints included, stays exactly
  // black (seeds 1-3, MIS and NEE), also with the worker's filter off.
  EXPECT_EQ(max_on(out.combined, dark), 0.0);
  EXPECT_EQ(max_on(master_only.images.combined, dark), 0.0);
  // Exact mode (visibility rays): nothing in the dark room away from its edges. Measured max on the
  // whole dark mask 0, 0, 0.012 (MIS, seeds 1-3; 0 with NEE only): the 0.012 is the pixel whose left
  // border lies exactly on the partition's free front edge (z = 1). The mask's probe rays are inset
  // by 0.02 px, so they all hit the partition, but the pixel's footprint also covers a sliver of the
  // lit room seen past the edge, and exact visibility rightly admits the vertices there (pt at 16
  // paths just never sampled the sliver). Away from the joints and the front edge: 0 in all seeds.
  const Mask inside_dark = probe.where_all([](const Probe& p) {
    return p.hit && p.position.x > -1e-4f && p.position.z < 0.9f &&
           !(p.position.x < 0.1f && (p.position.y < 0.1f || p.position.y > 1.9f || p.position.z < -0.9f));
  });
  ASSERT_GT(count(inside_dark), 400u);
  EXPECT_EQ(max_on(exact.combined, inside_dark), 0.0);
  EXPECT_LE(max_on(exact.combined, dark), 0.03 * mean(ptr.combined, lit));
  // What the back-facing test protects: defeated, the lit side's radiance lands on the partition's
  // dark face (measured mean 0.21, 21 % of the lit room's).
  EXPECT_GT(mean(defeated.images.combined, face), 0.05 * mean(ptr.combined, lit));
}

// The worker's half of the protection: its vertex filter sends no vertex that faces away from the
// camera (the master's half is checked by render_unfiltered above).
TEST(FailureModes, ThinWallWorkerSendsNoVertexFacingAwayFromTheCamera) {
  const Scene scene = load_scene("builtin:thinwall");
  const Camera camera(scene.camera, kSize, kSize);
  EmbreeScene embree(scene);
  PathTracer tracer(embree, camera, 1, RussianRoulette::paper());
  const TileRect all{0, 0, kSize, kSize};
  const TileResult culled =
      TileRenderer(tracer, VertexFilter{VertexFilter::Mode::kCull, 4, false}).render({all, {}, {}, 4});
  const TileResult raw =
      TileRenderer(tracer, VertexFilter{VertexFilter::Mode::kAll, 4, false}).render({all, {}, {}, 4});
  size_t facing_away_raw = 0;
  for (const VertexRecord& v : raw.vertices) facing_away_raw += dot(v.normal, camera.eye() - v.position) <= 0;
  ASSERT_GT(facing_away_raw, 1000u) << "the scene must produce vertices lit from the partition's far side";
  EXPECT_GT(culled.stats.culled_facing, 1000u);  // (those outside the view count as culled_frustum)
  EXPECT_LE(culled.stats.culled_facing, facing_away_raw);
  ASSERT_FALSE(culled.vertices.empty());
  for (const VertexRecord& v : culled.vertices) ASSERT_GT(dot(v.normal, camera.eye() - v.position), 0.f);
}

// ---------------------------------------------------------------------------------------------------
// Russian roulette off: paths stop at a fixed depth, and reprojected samples -- the shorter tails of
// those paths -- come out darker than path samples (Fig. 11). Analytic furnace.
// ---------------------------------------------------------------------------------------------------

TEST(FailureModes, RouletteOffDarkensReprojectedSamplesRouletteOnDoesNot) {
  // Closed box, albedo a = 0.8, emission 1: radiance 1 / (1 - a) = 5 everywhere. A path cut after
  // d = 8 vertices gathers sum_{k=0}^{d} a^k = (1 - a^9) / (1 - a) = 4.329; a vertex x_n keeps only
  // d - n + 1 of them, so every reprojected sample is darker than that.
  const std::string scene = "builtin:furnace?albedo=0.8";
  const double analytic = 5.0, truncated = (1 - std::pow(0.8, 9)) / 0.2;
  RenderOptions off = rp(scene), paper = rp(scene);
  off.spp = paper.spp = 64;  // the furnace's NEE has heavy tails near the box's edges: 64 paths
  off.rr = RussianRoulette::off(8);
  const RenderOutputs o = render(off);
  const RenderOutputs p = render(paper);
  std::printf("  off: pt %.4f rp-only %.4f combined %.4f; paper: pt %.4f rp-only %.4f combined %.4f\n",
              mean(o.pathtrace), mean(o.reprojection), mean(o.combined), mean(p.pathtrace), mean(p.reprojection),
              mean(p.combined));
  // Means over 64 x 64 pixels x 64 paths; at 16 paths they spread by +-1.5 % over seeds 1-3: 3 %.
  EXPECT_NEAR(mean(p.pathtrace), analytic, 0.03 * analytic);
  EXPECT_NEAR(mean(p.combined), analytic, 0.03 * analytic);
  EXPECT_NEAR(mean(p.reprojection), mean(p.pathtrace), 0.03 * mean(p.pathtrace));
  EXPECT_NEAR(mean(o.pathtrace), truncated, 0.03 * truncated);
  // Without roulette: measured (16 paths, seeds 1-3) reprojection / pt 0.76, 0.77, 0.77 and
  // combined / pt 0.87, 0.87, 0.87 (MIS; NEE only: 0.75-0.80 and 0.86-0.90).
  EXPECT_LT(mean(o.reprojection), 0.9 * mean(o.pathtrace));
  EXPECT_LT(mean(o.combined), 0.95 * mean(o.pathtrace));
  EXPECT_LT(mean(o.combined), 0.9 * mean(p.combined)) << "rp without roulette must be darker than rp with it";
}

// ---------------------------------------------------------------------------------------------------
// A light no camera ray can reach: everything visible is lit indirectly.
// ---------------------------------------------------------------------------------------------------

TEST(FailureModes, HiddenLightStaysStableAndNoWorseThanPathTracing) {
  const std::string scene = "builtin:hiddenlight";
  const PixelProbe probe(scene);
  const Mask sees_emitter = probe.where([](const std::array<Probe, 5>& ps) {
    return std::any_of(ps.begin(), ps.end(), [](const Probe& p) { return p.hit && p.material->emissive(); });
  });
  EXPECT_EQ(count(sees_emitter), 0u) << "the emitter must be hidden from the camera";
  const Image& ref = reference(rp(scene));
  const RenderOutputs ptr = render(pt(scene));
  const RenderOutputs out = render(rp(scene));
  const double e_rp = rmse(out.combined, ref), e_pt = rmse(ptr.combined, ref);
  report("hidden light", e_rp, e_pt);
  // Measured rp/pt 0.37, 0.36, 0.35 (MIS, seeds 1-3; 0.33-0.37 with NEE only): no margin over pt.
  EXPECT_LE(e_rp, 1.0 * e_pt);
  EXPECT_EQ(num(out.stats, "nonfinite_dropped"), 0);
}

// ---------------------------------------------------------------------------------------------------
// Grazing angles: the corridor floor far from the camera is seen at under 1.5 degrees.
// ---------------------------------------------------------------------------------------------------

TEST(FailureModes, GrazingFloorAndSilhouettesNoWorseThanPathTracing) {
  const std::string scene = "builtin:grazing";
  const PixelProbe probe(scene);
  const Mask grazing =
      probe.where_all([](const Probe& p) { return p.hit && p.material->name == "floor" && p.t > 5.f; });
  ASSERT_GT(count(grazing), 100u);
  const Image& ref = reference(rp(scene));
  const RenderOutputs ptr = render(pt(scene));
  for (int s : {1, 4}) {
    RenderOptions o = rp(scene);
    o.subpixels = s;
    const RenderOutputs out = render(o);
    const double e_floor = rmse(out.combined, ref, grazing), e_all = rmse(out.combined, ref);
    report(("grazing floor S=" + std::to_string(s)).c_str(), e_floor, rmse(ptr.combined, ref, grazing));
    report(("grazing whole S=" + std::to_string(s)).c_str(), e_all, rmse(ptr.combined, ref));
    // Measured (MIS, seeds 1-3) rp/pt on the grazing floor 0.19, 0.17, 0.17 (S=1) and 0.20, 0.17,
    // 0.19 (S=4), on the whole image 0.47-0.49 and 0.45-0.48: no margin over pt.
    EXPECT_LE(e_floor, 1.0 * rmse(ptr.combined, ref, grazing));
    EXPECT_LE(e_all, 1.0 * rmse(ptr.combined, ref));
  }
}

}  // namespace epr
