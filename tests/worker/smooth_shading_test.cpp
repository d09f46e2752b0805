// Shading normals in the path tracer (worker/path_tracer.cpp, worker/bsdf.h): a glTF cylinder with
// NORMAL shows no step between its facets (the flat one does), a normal map tilts the surface
// towards or away from a sun by the expected cosine, no direction below the geometric surface is
// reflected into, and a white furnace still gives the sky's radiance (no energy made or lost beyond
// the facets' small share).
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "common/scene_loader.h"
#include "common/tangents.h"
#include "tests/common/gltf_test_files.h"
#include "tests/common/scene_test_files.h"
#include "tests/worker/image_means.h"
#include "worker/bsdf.h"
#include "worker/path_tracer.h"
#include "worker/sky_light.h"

namespace epr {
namespace {

// A capped-less cylinder of radius 1 about the y axis, y in [-1, 1], `segments` facets, outward
// winding; with `normals` its vertex normals (cos phi, 0, sin phi) as glTF NORMAL.
std::string write_cylinder(const test::TempDir& dir, const std::string& name, int segments, bool normals) {
  test::GltfBuilder g;
  std::vector<float> xyz, nrm;
  std::vector<uint16_t> idx;
  for (int i = 0; i < segments; ++i) {
    const float phi = 2 * kPi * float(i) / float(segments);
    for (const float y : {-1.f, 1.f}) {
      xyz.insert(xyz.end(), {std::cos(phi), y, std::sin(phi)});
      nrm.insert(nrm.end(), {std::cos(phi), 0, std::sin(phi)});
    }
    const auto a = uint16_t(2 * i), b = uint16_t(2 * ((i + 1) % segments));
    idx.insert(idx.end(), {a, uint16_t(a + 1), b, b, uint16_t(a + 1), uint16_t(b + 1)});
  }
  const int mesh = g.mesh(xyz, idx);
  if (normals)
    g.doc["meshes"][mesh]["primitives"][0]["attributes"]["NORMAL"] =
        g.accessor(test::bytes_of(nrm), 5126, nrm.size() / 3, "VEC3");
  g.node({{"mesh", mesh}});
  return g.write_gltf(dir, name);
}

// Every pixel's mean over `spp` paths, row-major.
std::vector<float> render_pixels(const Scene& scene, const Lighting& lighting, int w, int h, int spp) {
  EmbreeScene es(scene);
  const SkyLight sky(lighting, es);
  const Camera cam(scene.camera, w, h);
  const PathTracer tracer(es, cam, 11, RussianRoulette::paper(), true, SamplerKind::kSobolBurley, &sky);
  std::vector<float> out(size_t(w) * size_t(h));
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      double sum = 0;
      for (int s = 0; s < spp; ++s) {
        const Vec3 c = tracer.trace(x, y, uint32_t(s), nullptr, nullptr);
        sum += (c.x + c.y + c.z) / 3;
      }
      out[size_t(y) * size_t(w) + size_t(x)] = float(sum / spp);
    }
  return out;
}

Lighting sun_only(Vec3 direction) {
  Lighting l;
  l.sun = SunLight{};
  l.sun->direction = normalize(direction);
  l.sun->irradiance = Vec3(3.f);
  return l;
}

// The largest difference between horizontal neighbours along the cylinder's middle rows, away
// from its silhouette.
float largest_step(const std::vector<float>& img, int w, int h) {
  float step = 0;
  for (int y = h / 2 - 4; y <= h / 2 + 4; ++y) {
    int first = -1, last = -1;
    for (int x = 0; x < w; ++x)
      if (img[size_t(y * w + x)] > 0) last = x, first = first < 0 ? x : first;
    for (int x = first + 4; x + 1 <= last - 4; ++x)
      step = std::max(step, std::abs(img[size_t(y * w + x + 1)] - img[size_t(y * w + x)]));
  }
  return step;
}

TEST(SmoothShading, GltfCylinderWithNormalsHasNoStepBetweenFacets) {
  test::TempDir dir;
  const int w = 96, h = 96;
  std::vector<float> images[2];
  for (const bool smooth : {false, true}) {
    Scene s = load_scene(write_cylinder(dir, smooth ? "smooth" : "flat", 12, smooth));
    ASSERT_EQ(s.normals.empty(), !smooth);
    s.camera = {Vec3(0, 0, 6), Vec3(0, 0, 0), Vec3(0, 1, 0), 22.f};
    // The sun from the camera's side and a little to the right: the lit half faces the camera.
    images[smooth] = render_pixels(s, sun_only({0.5f, 0.2f, 1.f}), w, h, 8);
  }
  const float flat = largest_step(images[0], w, h), smooth = largest_step(images[1], w, h);
  // Measured: flat 0.33 (a 30-degree turn between facets), smooth 0.028 (the cosine's slope over a
  // pixel where the surface turns away).
  EXPECT_GT(flat, 0.1f);
  EXPECT_LT(smooth, 0.04f);
  EXPECT_GT(flat, 3 * smooth);
}

// A 4 x 4 m floor at z = 0 (normal +z, u along +x) whose 1 x 1 normal map tilts the normal by
// `tilt` radians towards +x, seen from above under a sun 45 degrees from the zenith towards +x.
Scene mapped_floor(float tilt) {
  Scene s;
  s.name = "mapped-floor";
  Texture t;
  t.path = "tilt";
  t.width = t.height = 1;
  t.rgb = {0.5f + 0.5f * std::sin(tilt), 0.5f, 0.5f + 0.5f * std::cos(tilt)};
  s.textures.push_back(t);
  Material m;
  m.kd = Vec3(0.5f);
  m.normal_texture = 0;
  const uint32_t id = add_material(s, m);
  s.positions = {{-2, -2, 0}, {2, -2, 0}, {2, 2, 0}, {-2, 2, 0}};
  s.triangles = {{0, 1, 2}, {0, 2, 3}};
  s.material_of = {id, id};
  s.uvs = {{Vec2{0, 0}, Vec2{1, 0}, Vec2{1, 1}}, {Vec2{0, 0}, Vec2{1, 1}, Vec2{0, 1}}};
  generate_tangents(s, {true, true});
  s.camera = {Vec3(0, 0, 3), Vec3(0, 0, 0), Vec3(0, 1, 0), 30.f};
  return s;
}

TEST(SmoothShading, NormalMapTiltsNextEventEstimationByTheExpectedCosine) {
  const Lighting sun = sun_only({1, 0, 1});
  const auto mean = [&](float tilt) {
    const Scene s = mapped_floor(tilt);
    s.validate();
    const std::vector<float> img = render_pixels(s, sun, 16, 16, 4);
    double sum = 0;
    for (float v : img) sum += v;
    return sum / double(img.size());
  };
  const float a = 0.35f;  // 20 degrees
  const double flat = mean(0.f), towards = mean(a), away = mean(-a);
  // Direct light only (the floor sees nothing else): kd / pi E cos, the cosine to the shading normal,
  // times Cycles' bump shadowing term G(g), g = cos(sun, n) / (cos(sun, ns) cos(n, ns)) with n the
  // smooth normal +z: towards the sun g = 0.83, G = 0.947; away from it g > 1, G = 1.
  EXPECT_NEAR(flat, 0.5 / kPi * 3 * std::cos(kPi / 4), 1e-3);
  const double g = std::cos(kPi / 4) / (std::cos(kPi / 4 - a) * std::cos(a));
  ASSERT_LT(g, 1);
  EXPECT_NEAR(towards / flat, std::cos(kPi / 4 - a) / std::cos(kPi / 4) * (-g * g * g + g * g + g), 5e-3);
  EXPECT_NEAR(away / flat, std::cos(kPi / 4 + a) / std::cos(kPi / 4), 5e-3);
}

// The glTF file of a 2 x 2 m floor at y = 0 (u along +x, glTF v along +z, so the bitangent is -z)
// with NORMAL and a 4 x 4 normal map tilting the normal by `tilt` radians towards +x, a grey
// Lambertian, seen from above: the scene Cycles 3.4 rendered (cycles_reference.py --gltf, a sun of
// irradiance 3 at 40 degrees from the zenith towards +x, 32 x 32, fov 30) as 0.16419 for tilt -30
// degrees, 0.36694 for the flat map (texel 128/255: 0.2 degrees towards +x), 0.40586 for +10 degrees
// and 0.46066 for +30 degrees: kd / pi E cos(sun, ns) G, the 8-bit texel's exact normal.
std::string write_mapped_floor(const test::TempDir& dir, float tilt) {
  test::GltfBuilder g;
  const std::vector<float> xyz{-1, 0, -1, 1, 0, -1, 1, 0, 1, -1, 0, 1}, nrm{0, 1, 0, 0, 1, 0, 0, 1, 0, 0, 1, 0},
      uv{0, 0, 1, 0, 1, 1, 0, 1};
  const int mesh = g.mesh(xyz, {0, 2, 1, 0, 3, 2});
  auto& attributes = g.doc["meshes"][mesh]["primitives"][0]["attributes"];
  attributes["NORMAL"] = g.accessor(test::bytes_of(nrm), 5126, 4, "VEC3");
  attributes["TEXCOORD_0"] = g.accessor(test::bytes_of(uv), 5126, 4, "VEC2");
  g.node({{"mesh", mesh}});
  std::vector<float> texels;
  for (int i = 0; i < 16; ++i)
    texels.insert(texels.end(), {0.5f + 0.5f * std::sin(tilt), 0.5f, 0.5f + 0.5f * std::cos(tilt)});
  test::write_rgb8_png(dir.path("tilt.png"), 4, 4, texels);
  g.doc["images"] = {{{"uri", "tilt.png"}}};
  g.doc["textures"] = {{{"source", 0}}};
  g.doc["materials"] = {{{"name", "grey"}, {"normalTexture", {{"index", 0}}}}};
  g.doc["meshes"][mesh]["primitives"][0]["material"] = 0;
  return g.write_gltf(dir, "floor");
}

TEST(SmoothShading, NormalMappedGltfFloorRendersAsCycles) {
  test::TempDir dir;
  const Lighting sun = sun_only({std::sin(0.6981317f), std::cos(0.6981317f), 0});  // 40 degrees
  const auto mean = [&](float tilt_deg) {
    Scene s = load_scene(write_mapped_floor(dir, tilt_deg * kPi / 180));
    s.materials[0] = Material{.name = "grey", .kd = Vec3(0.5f), .normal_texture = s.materials[0].normal_texture};
    s.camera = {Vec3(0, 3, 0), Vec3(0, 0, 0), Vec3(0, 0, -1), 30.f};
    const std::vector<float> img = render_pixels(s, sun, 16, 16, 4);
    double sum = 0;
    for (float v : img) sum += v;
    return sum / double(img.size());
  };
  EXPECT_NEAR(mean(-30), 0.16419, 2e-4);
  EXPECT_NEAR(mean(0), 0.36694, 2e-4);
  EXPECT_NEAR(mean(10), 0.40586, 2e-4);  // without the bump shadowing term 0.41417
  EXPECT_NEAR(mean(30), 0.46066, 2e-4);  // without it 0.47004
}

// A direction above the shading hemisphere but below the geometric surface carries nothing: no
// value, no density, never sampled.
TEST(SmoothShading, BsdfReflectsNothingBelowTheGeometricSurface) {
  const Vec3 ng{0, 0, 1}, ns = normalize({std::sin(1.f), 0, std::cos(1.f)});  // 57 degrees apart
  Material m;
  m.kd = Vec3(0.8f);
  const Bsdf bsdf(m, m.kd, ng, ns, normalize({0.2f, 0.1f, 1}));
  const Vec3 below = normalize({1, 0, -0.2f});
  ASSERT_GT(dot(below, ns), 0.f);
  EXPECT_TRUE(is_black(bsdf.eval(below)));
  EXPECT_EQ(bsdf.pdf(below), 0.f);
  EXPECT_EQ(bsdf.cosine(below), 0.f);
  int valid = 0, n = 4096;
  for (int i = 0; i < n; ++i) {
    const BsdfSample bs = bsdf.sample(0.5f, {(float(i % 64) + 0.5f) / 64, (float(i / 64) + 0.5f) / 64});
    if (!bs.valid) continue;
    ++valid;
    EXPECT_GT(dot(bs.wi, ng), 0.f);
    EXPECT_EQ(bs.weight.x, 0.8f);  // cosine about the shading normal: f cos / pdf = kd
  }
  // Some of the cosine lobe about ns lies below the plane (those samples are refused), most above.
  EXPECT_GT(valid, n / 2);
  EXPECT_LT(valid, n);
  // Glossy: the same rule.
  m.type = MaterialType::kGlossy;
  m.ks = Vec3(0.2f);
  const Bsdf glossy(m, m.kd, ng, ns, normalize({0.2f, 0.1f, 1}));
  EXPECT_TRUE(is_black(glossy.eval(below)));
  EXPECT_EQ(glossy.pdf(below), 0.f);
}

// With a shading normal tilted from the smooth one, a sampled direction's weight is eval() cos / pdf
// (the bump shadowing term in both), the term lowers the diffuse value towards the tilt and only
// there, and the densities are those of the untilted lobes.
TEST(SmoothShading, BumpShadowingTermWeighsSamplesAsItWeighsEval) {
  const Vec3 n{0, 0, 1}, ns = normalize({std::sin(0.5f), 0, std::cos(0.5f)}), wo = normalize({-0.3f, 0.1f, 1});
  Material m;
  m.kd = Vec3(0.6f);
  const Bsdf lambert(m, m.kd, n, ns, wo, n), lambert_plain(m, m.kd, n, ns, wo);
  const Bsdf ggx(MicrofacetInputs{Vec3(0.6f), 0, 0.5f, 0, 1.5f, true}, n, ns, wo, n);
  const Bsdf ggx_plain(MicrofacetInputs{Vec3(0.6f), 0, 0.5f, 0, 1.5f, true}, n, ns, wo);
  int lowered = 0, checked = 0;
  for (int i = 0; i < 1024; ++i) {
    const Vec2 u{(float(i % 32) + 0.5f) / 32, (float(i / 32) + 0.5f) / 32};
    for (const auto& [b, plain] : {std::pair{&lambert, &lambert_plain}, std::pair{&ggx, &ggx_plain}}) {
      const BsdfSample s = b->sample(float(i % 7) / 7, u);
      if (!s.valid || s.delta) continue;
      ++checked;
      const float c = b->cosine(s.wi);
      EXPECT_NEAR(s.weight.x, b->eval(s.wi).x * c / s.pdf, 1e-4f * (1 + s.weight.x));
      EXPECT_NEAR(s.pdf, plain->pdf(s.wi), 1e-5f * s.pdf);
      const float g = bump_shadowing_term(n, ns, s.wi);
      EXPECT_NEAR(b->eval_diffuse(s.wi).x, plain->eval_diffuse(s.wi).x * g, 1e-6f);
      lowered += g < 0.99f;
    }
  }
  EXPECT_GT(checked, 1500);
  EXPECT_GT(lowered, 100);  // the tilt (towards +x) shadows the directions on its side
}

// A UV sphere of radius 1 (`rings` x 2 `rings` facets) with its exact vertex normals, albedo 1.
Scene smooth_sphere(int rings) {
  Scene s;
  s.name = "smooth-sphere";
  Material m;
  m.kd = Vec3(1.f);
  const uint32_t id = add_material(s, m);
  std::vector<std::array<Vec3, 3>> normals;
  const auto at = [&](int i, int j) {
    const float th = kPi * float(j) / float(rings), ph = kPi * float(i) / float(rings);
    return Vec3(std::sin(th) * std::cos(ph), std::cos(th), std::sin(th) * std::sin(ph));
  };
  for (int j = 0; j < rings; ++j)
    for (int i = 0; i < 2 * rings; ++i) {
      const Vec3 a = at(i, j), b = at(i + 1, j), c = at(i + 1, j + 1), d = at(i, j + 1);
      for (const std::array<Vec3, 3>& t : {std::array<Vec3, 3>{a, b, c}, std::array<Vec3, 3>{a, c, d}}) {
        if (!(length(cross(t[1] - t[0], t[2] - t[0])) > 1e-9f)) continue;  // the poles' slivers
        add_triangle(s, t[0], t[1], t[2], id);
        if (dot(s.geometric_normal(s.triangle_count() - 1), t[0]) < 0)
          std::swap(s.triangles.back()[1], s.triangles.back()[2]);
        const auto& tri = s.triangles.back();
        normals.push_back({s.positions[tri[0]], s.positions[tri[1]], s.positions[tri[2]]});
      }
    }
  s.normals = std::move(normals);
  s.camera = {Vec3(0, 0.3f, 2.2f), Vec3(0, 0, 0), Vec3(0, 1, 0), 50.f};
  return s;
}

// Under a constant sky L every surface of albedo 1 leaves L. Shading normals must not make light
// (the image stays at L); the directions the shading lobe puts below a facet's plane are lost, a
// share of about delta^2 / 4 for a facet delta radians off its vertex normals: under 1 % here.
TEST(SmoothShading, WhiteFurnaceStaysAtTheSkyRadiance) {
  Scene s = smooth_sphere(8);
  add_quad(s, {-3, -1, -3}, {-3, -1, 3}, {3, -1, 3}, {3, -1, -3}, 0);  // a floor: paths bounce
  s.validate();
  EmbreeScene es(s);
  const float L = 0.7f;
  Lighting l;
  l.environment = EnvironmentLight{};
  l.environment->color = Vec3(L);
  const SkyLight sky(l, es);
  const Camera cam(s.camera, 48, 48);
  for (const bool mis : {true, false}) {
    const PathTracer tracer(es, cam, 5, RussianRoulette::paper(), mis, SamplerKind::kSobolBurley, &sky);
    const ImageMeans m = render_image_means(tracer, 48, 128);
    EXPECT_LT(m.pixel, L * 1.005) << "mis " << mis;
    EXPECT_GT(m.pixel, L * 0.985) << "mis " << mis;
    EXPECT_GT(m.vertices, 10000u);
    EXPECT_NEAR(m.vertex, L, 0.02 * L) << "mis " << mis;
  }
}

}  // namespace
}  // namespace epr
