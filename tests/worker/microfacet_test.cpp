// The GGX metallic-roughness BSDF (worker/bsdf_ggx.h) and its use by the path tracer: the sampling
// density against eval() and against what sample() returns, the white furnaces of a conductor and of a
// dielectric over an unweighted diffuse base,
// smooth glass, metallic-roughness textures per texel, emission textures, and which vertices are
// recorded as reprojectable.
#include "worker/microfacet.h"

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <random>
#include <vector>

#include "common/scene.h"
#include "tests/worker/glowing_box.h"
#include "worker/bsdf.h"
#include "worker/path_tracer.h"
#include "worker/surface_inputs.h"

namespace epr {
namespace {

struct GgxCase {
  const char* name;
  MicrofacetInputs in;
};

// Rough lobes of every kind (perfectly smooth ones are deltas: no density to integrate).
const GgxCase kGgxCases[] = {
    {"conductor r0.3", {Vec3(0.9f, 0.6f, 0.3f), 1, 0.3f, 0, 1.5f, true}},
    {"conductor r0.8", {Vec3(1.f), 1, 0.8f, 0, 1.5f, true}},
    {"dielectric r0.5", {Vec3(0.7f, 0.5f, 0.2f), 0, 0.5f, 0, 1.5f, true}},
    {"half metal r0.4", {Vec3(0.8f), 0.5f, 0.4f, 0, 1.5f, true}},
    {"rough glass entering r0.3", {Vec3(1.f), 0, 0.3f, 1, 1.5f, true}},
    {"rough glass leaving r0.5", {Vec3(1.f), 0, 0.5f, 1, 1.5f, false}},
    {"dielectric smooth layer", {Vec3(0.6f), 0, 0.f, 0, 1.5f, true}},
};

Vec3 ggx_uniform_sphere(float u1, float u2) {
  const float z = 1 - 2 * u1, r = std::sqrt(std::max(0.f, 1 - z * z)), phi = 2 * kPi * u2;
  return {r * std::cos(phi), r * std::sin(phi), z};
}

Vec3 ggx_view(float cos_o) { return {std::sqrt(1 - cos_o * cos_o), 0, cos_o}; }

// The density's integral over the sphere (uniform directions, N = 400k) equals the probability that
// sample() returns a direction (a reflection below the horizon or a refraction above it is
// refused; a delta lobe's samples have no density and are left out): within 5 combined standard
// errors. Without a delta lobe both are above 0.6 in these cases (the samples reflected below the
// horizon, refused, are the energy single scattering loses: ~30 % at roughness 0.8).
TEST(MicrofacetBsdf, PdfIntegratesToTheShareOfValidSamples) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> U(0.f, 1.f);
  const Vec3 n(0, 0, 1);
  for (const GgxCase& c : kGgxCases)
    for (const float cos_o : {0.95f, 0.6f, 0.25f}) {
      SCOPED_TRACE(testing::Message() << c.name << " cos_o " << cos_o);
      const MicrofacetBsdf b(c.in, n, ggx_view(cos_o));
      const int N = 400000;
      double s = 0, s2 = 0;
      for (int i = 0; i < N; ++i) {
        const double p = b.pdf(ggx_uniform_sphere(U(rng), U(rng))) * 4 * kPi;
        s += p, s2 += p * p;
      }
      const double integral = s / N, var_i = (s2 / N - integral * integral) / N;
      int valid = 0;
      for (int i = 0; i < N; ++i) {
        const BsdfSample smp = b.sample(U(rng), {U(rng), U(rng)});
        valid += smp.valid && !smp.delta;  // a delta lobe's samples have no density
      }
      const double share = double(valid) / N, var_s = share * (1 - share) / N;
      EXPECT_NEAR(integral, share, 5 * std::sqrt(var_i + var_s) + 1e-4);
      if (c.in.roughness > 0) {
        EXPECT_GT(share, 0.6);
      }
    }
}

// Every sample's pdf and weight are pdf(wi) and eval(wi) |cos| / pdf(wi), and the mean weight (the
// albedo by sampling) matches the integral of eval |cos| over uniform directions within 5 sigma.
TEST(MicrofacetBsdf, SamplesAgreeWithEvalAndPdf) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> U(0.f, 1.f);
  const Vec3 n(0, 0, 1);
  for (const GgxCase& c : kGgxCases)
    for (const float cos_o : {0.9f, 0.4f}) {
      SCOPED_TRACE(testing::Message() << c.name << " cos_o " << cos_o);
      const MicrofacetBsdf b(c.in, n, ggx_view(cos_o));
      const int N = 200000;
      double ws = 0, ws2 = 0;
      int mismatches = 0;
      for (int i = 0; i < N; ++i) {
        const BsdfSample s = b.sample(U(rng), {U(rng), U(rng)});
        if (!s.valid) continue;
        const double w = luminance(s.weight);
        ws += w, ws2 += w * w;
        if (s.delta) continue;
        const float p = b.pdf(s.wi);
        const Vec3 expect = b.eval(s.wi) * (std::abs(s.wi.z) / p);
        if (std::abs(p - s.pdf) > 1e-3f * p || std::abs(luminance(expect) - float(w)) > 1e-3f * float(w) + 1e-6f)
          ++mismatches;
      }
      EXPECT_EQ(mismatches, 0);
      const double sampled = ws / N, var_a = (ws2 / N - sampled * sampled) / N;
      if (c.in.roughness == 0) continue;  // eval() leaves the delta lobe out
      double es = 0, es2 = 0;
      for (int i = 0; i < N; ++i) {
        const Vec3 wi = ggx_uniform_sphere(U(rng), U(rng));
        const double f = luminance(b.eval(wi)) * std::abs(wi.z) * 4 * kPi;
        es += f, es2 += f * f;
      }
      const double integrated = es / N, var_b = (es2 / N - integrated * integrated) / N;
      EXPECT_NEAR(sampled, integrated, 5 * std::sqrt(var_a + var_b) + 1e-4);
    }
}

// White furnace: a conductor with F0 = 1 under a uniform sky of radiance 1 reflects its albedo,
// the mean sampled weight. With visible-normal sampling each weight is G2 / G1(wo) <= 1, so the
// albedo is at most 1 (bound: every weight <= 1 + 1e-4, the mean <= 1). Single scattering loses
// energy that grows with roughness (no multiple-scattering compensation): at roughness <= 0.2 and
// cos_o >= 0.5 the albedo stays above 0.98; at roughness 1 (alpha 1: D = 1 / pi, G2 = 2 cos_i /
// (1 + cos_i) seen from the normal) it is exactly 1 - ln 2 = 0.307 at normal incidence, checked
// within 5 standard errors (100k samples).
TEST(MicrofacetBsdf, WhiteFurnaceConductorReflectsAtMostOne) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> U(0.f, 1.f);
  for (const float rough : {0.05f, 0.2f, 0.5f, 1.f})
    for (const float cos_o : {1.f, 0.5f, 0.15f}) {
      SCOPED_TRACE(testing::Message() << "roughness " << rough << " cos_o " << cos_o);
      const MicrofacetBsdf b({Vec3(1.f), 1, rough, 0, 1.5f, true}, Vec3(0, 0, 1), ggx_view(cos_o));
      const int N = 100000;
      double sum = 0, sum2 = 0;
      float largest = 0;
      for (int i = 0; i < N; ++i) {
        const BsdfSample s = b.sample(U(rng), {U(rng), U(rng)});
        if (!s.valid) continue;
        sum += s.weight.y, sum2 += double(s.weight.y) * s.weight.y;
        largest = std::max(largest, max_component(s.weight));
      }
      const double albedo = sum / N, se = std::sqrt((sum2 / N - albedo * albedo) / N);
      EXPECT_LE(largest, 1.f + 1e-4f);
      EXPECT_LE(albedo, 1.0);
      if (rough <= 0.2f && cos_o >= 0.5f) {
        EXPECT_GT(albedo, 0.98);
      }
      if (rough == 1.f && cos_o == 1.f) {
        EXPECT_NEAR(albedo, 1 - std::log(2.0), 5 * se + 1e-4);
      }
      EXPECT_GT(albedo, 0.25);
    }
}

// White furnace of a dielectric with a white base (Blender's Principled BSDF v1, the reference): the
// diffuse base is c (1 - metallic) / pi for every wo, not weighted by 1 - F(cos_o), so it alone
// reflects exactly 1 and the specular layer adds its own albedo on top: above 1 everywhere (about
// 1.04 head-on at roughness 0.3, 1.01 at roughness 1, single scattering), most at grazing wo (1.29 at
// cos_o 0.15, roughness 0.3; asserted above 1.2). eval_diffuse is the same
// from every wo.
TEST(MicrofacetBsdf, WhiteFurnaceDielectricAddsItsSpecularToAnUnweightedDiffuseBase) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> U(0.f, 1.f);
  const Vec3 n(0, 0, 1), wi = normalize(Vec3(0.2f, 0.4f, 1));
  const float head_on = MicrofacetBsdf({Vec3(1.f), 0, 0.3f, 0, 1.5f, true}, n, n).eval_diffuse(wi).x;
  EXPECT_FLOAT_EQ(head_on, kInvPi);
  for (const float rough : {0.3f, 1.f})
    for (const float cos_o : {1.f, 0.5f, 0.15f}) {
      SCOPED_TRACE(testing::Message() << "roughness " << rough << " cos_o " << cos_o);
      const MicrofacetBsdf b({Vec3(1.f), 0, rough, 0, 1.5f, true}, n, ggx_view(cos_o));
      EXPECT_FLOAT_EQ(b.eval_diffuse(wi).x, head_on);
      const int N = 100000;
      double sum = 0, sum2 = 0;
      for (int i = 0; i < N; ++i) {
        const BsdfSample s = b.sample(U(rng), {U(rng), U(rng)});
        if (s.valid) sum += s.weight.y, sum2 += double(s.weight.y) * s.weight.y;
      }
      const double albedo = sum / N, se = std::sqrt((sum2 / N - albedo * albedo) / N);
      RecordProperty("albedo_r" + std::to_string(int(rough * 10)) + "_c" + std::to_string(int(cos_o * 100)),
                     std::to_string(albedo));
      EXPECT_GT(albedo, 1.0 + 5 * se);
      EXPECT_LT(albedo, 2.0);
      if (rough == 0.3f && cos_o == 0.15f) {
        EXPECT_GT(albedo, 1.2);
      }
    }
}

// A smooth glass slab (ior 1.5, faces 0.1 m apart) in front of a uniform emitter of radiance 1: a
// camera looking through it at normal incidence sees (1 - F)^2 (1 + F^2 + F^4 + ...) = (1 - F) /
// (1 + F) = 0.9231 for F = 0.04 (the two interfaces and the light bouncing between them; (1 - F)^2
// alone is 0.9216). Each path scores 0 or 1 here: 128k paths give a standard error of 0.0008;
// the bound is 0.003. Also without MIS: a delta lobe's continuation must still see the emitter.
TEST(MicrofacetBsdf, SmoothGlassSlabTransmitsOneMinusFSquared) {
  Scene s;
  s.name = "test-slab";
  Material glass;
  glass.name = "glass";
  glass.type = MaterialType::kMicrofacet;
  glass.kd = Vec3(1.f);
  glass.roughness = 0;
  glass.transmission = 1;
  glass.ior = 1.5f;
  const uint32_t g = add_material(s, glass);
  Material lamp;
  lamp.name = "lamp";
  lamp.kd = Vec3(0.f);
  lamp.ke = Vec3(1.f);
  const uint32_t l = add_material(s, lamp);
  const float h = 10;
  add_quad(s, {-h, -h, 0}, {h, -h, 0}, {h, h, 0}, {-h, h, 0}, g);                  // front, facing +z
  add_quad(s, {-h, -h, -0.1f}, {-h, h, -0.1f}, {h, h, -0.1f}, {h, -h, -0.1f}, g);  // back, facing -z
  add_quad(s, {-h, -h, -1}, {h, -h, -1}, {h, h, -1}, {-h, h, -1}, l);              // the emitter
  s.camera = {Vec3(0, 0, 5), Vec3(0, 0, 0), Vec3(0, 1, 0), 2.f};
  const EmbreeScene es(s);
  const float f = ggx::fresnel_dielectric(1, 1.5f);
  ASSERT_NEAR(f, 0.04f, 1e-4f);
  const double expected = (1 - f) / (1 + f);
  for (const bool mis : {true, false}) {
    SCOPED_TRACE(mis ? "mis" : "nee only");
    const Camera cam(s.camera, 8, 8);
    const PathTracer tracer(es, cam, 5, RussianRoulette::paper(), mis);
    double sum = 0;
    int n = 0;
    for (int y = 0; y < 8; ++y)
      for (int x = 0; x < 8; ++x)
        for (uint32_t k = 0; k < 2000; ++k, ++n) sum += tracer.trace(x, y, k, nullptr, nullptr).y;
    EXPECT_NEAR(sum / n, expected, 0.003);
  }
}

// metallicRoughnessTexture per texel: the worker's inputs at two points of one triangle differ as
// the texture's G (roughness) and B (metallic) do, read as data (the sRGB curve of the colour
// decoding undone) and multiplied by the factors.
TEST(MicrofacetBsdf, MetallicRoughnessTextureIsReadPerTexel) {
  Scene s;
  Texture t;
  t.width = 2, t.height = 1;
  const auto decoded = [](float v) { return std::pow((v + 0.055f) / 1.055f, 2.4f); };  // as stored v
  t.rgb = {0, decoded(0.2f), 1, 0, decoded(0.9f), 0};
  s.textures.push_back(t);
  Material m;
  m.type = MaterialType::kMicrofacet;
  m.metallic_roughness_texture = 0;
  m.roughness = 0.5f;
  m.metallic = 0.8f;
  const uint32_t id = add_material(s, m);
  add_triangle(s, {0, 0, 0}, {1, 0, 0}, {0, 1, 0}, id);
  s.uvs = {{Vec2{0.25f, 0.5f}, Vec2{0.75f, 0.5f}, Vec2{0.25f, 0.5f}}};
  const MicrofacetInputs left = microfacet_inputs(s, s.materials[id], Vec3(1.f), 0, 0.f, 0.f, true);
  const MicrofacetInputs right = microfacet_inputs(s, s.materials[id], Vec3(1.f), 0, 1.f, 0.f, true);
  EXPECT_NEAR(left.roughness, 0.5f * 0.2f, 1e-5f);
  EXPECT_NEAR(left.metallic, 0.8f, 1e-5f);
  EXPECT_NEAR(right.roughness, 0.5f * 0.9f, 1e-5f);
  EXPECT_NEAR(right.metallic, 0.f, 1e-5f);
}

// A closed box of Lambertian emitting walls whose floor (y = -1) is a rough metal: every recorded
// vertex on the floor is marked not diffuse (the master does not reproject it), every other one
// diffuse.
TEST(MicrofacetBsdf, MetalVerticesProduceNoDiffuseRecords) {
  Material metal;
  metal.type = MaterialType::kMicrofacet;
  metal.kd = Vec3(0.9f);
  metal.metallic = 1;
  metal.roughness = 0.4f;
  Scene s = test::glowing_box(metal, "test-metal-floor");
  s.camera = {Vec3(0.2f, 0.1f, 0.5f), Vec3(-1, -0.8f, -1), Vec3(0, 1, 0), 70.f};
  const EmbreeScene es(s);
  const Camera cam(s.camera, 16, 16);
  const PathTracer tracer(es, cam, 9, RussianRoulette::paper());
  std::vector<VertexRecord> records;
  for (int y = 0; y < 16; ++y)
    for (int x = 0; x < 16; ++x)
      for (uint32_t k = 0; k < 8; ++k) tracer.trace(x, y, k, &records, nullptr);
  size_t on_floor = 0, elsewhere = 0, wrong = 0;
  for (const VertexRecord& r : records) {
    const Vec3 a(std::abs(r.position.x), std::abs(r.position.y), std::abs(r.position.z));
    if (int(a.x > 0.999f) + int(a.y > 0.999f) + int(a.z > 0.999f) > 1) continue;  // at an edge: either face
    const bool floor = r.position.y < -0.999f;
    (floor ? on_floor : elsewhere) += 1;
    if (r.diffuse() == floor) {
      ++wrong;
      ADD_FAILURE() << "record at " << r.position.x << " " << r.position.y << " " << r.position.z << " diffuse "
                    << r.diffuse();
    }
  }
  EXPECT_GT(on_floor, 500u);
  EXPECT_GT(elsewhere, 500u);
  EXPECT_EQ(wrong, 0u);
}

// An emission texture is a texture at hits and in next event estimation: a lamp whose texture is red
// on its left half and blue on its right (Ke = the mean) lights a floor as two separate red and
// blue lamps do. Compared by the mean red and blue of the image's left and right halves, without
// MIS (next event estimation alone lights the floor) and with it; within 4 % (65k paths each:
// measured differences under 1 %). Light sampled at the lamp's mean colour instead puts as much red
// on the right as on the left (differences of 30 % and more).
Scene ggx_lamp_over_floor(bool textured) {
  Scene s;
  s.name = textured ? "test-textured-lamp" : "test-two-lamps";
  Material floor;
  floor.kd = Vec3(0.5f);
  const uint32_t f = add_material(s, floor);
  add_quad(s, {-4, 0, 4}, {4, 0, 4}, {4, 0, -4}, {-4, 0, -4}, f);
  if (textured) {
    Texture t;
    t.width = 2, t.height = 1;
    t.nearest = true;            // two halves (bilinear would blend the two texels across the lamp)
    t.rgb = {2, 0, 0, 0, 0, 2};  // over the mean (1, 0, 1) per channel
    s.textures.push_back(t);
    Material lamp;
    lamp.kd = Vec3(0.f);
    lamp.ke = Vec3(1, 0, 1);
    lamp.ke_texture = 0;
    const uint32_t l = add_material(s, lamp);
    add_quad(s, {-1, 1, -1}, {1, 1, -1}, {1, 1, 1}, {-1, 1, 1}, l);
  } else {
    Material red, blue;
    red.kd = blue.kd = Vec3(0.f);
    red.ke = Vec3(2, 0, 0);
    blue.ke = Vec3(0, 0, 2);
    const uint32_t r = add_material(s, red), b = add_material(s, blue);
    add_quad(s, {-1, 1, -1}, {0, 1, -1}, {0, 1, 1}, {-1, 1, 1}, r);
    add_quad(s, {0, 1, -1}, {1, 1, -1}, {1, 1, 1}, {0, 1, 1}, b);
  }
  // Texture coordinates from x and z: u = (x + 1) / 2 runs across the lamp.
  s.uvs.resize(s.triangles.size());
  for (size_t i = 0; i < s.triangles.size(); ++i)
    for (int k = 0; k < 3; ++k) {
      const Vec3 p = s.positions[s.triangles[i][size_t(k)]];
      s.uvs[i][size_t(k)] = {(p.x + 1) / 2, (p.z + 1) / 2};
    }
  s.camera = {Vec3(0, 0.6f, 0.01f), Vec3(0, 0, 0), Vec3(0, 0, -1), 100.f};
  return s;
}

TEST(MicrofacetBsdf, EmissionTextureLightsAsTheTexelsDo) {
  for (const bool mis : {false, true}) {
    SCOPED_TRACE(mis ? "mis" : "nee only");
    std::array<double, 4> means[2];  // left red, left blue, right red, right blue
    for (const bool textured : {false, true}) {
      const Scene s = ggx_lamp_over_floor(textured);
      const EmbreeScene es(s);
      const int size = 32;
      const Camera cam(s.camera, size, size);
      const PathTracer tracer(es, cam, 21, RussianRoulette::paper(), mis);
      std::array<double, 4> m{};
      for (int y = 0; y < size; ++y)
        for (int x = 0; x < size; ++x)
          for (uint32_t k = 0; k < 64; ++k) {
            const Vec3 c = tracer.trace(x, y, k, nullptr, nullptr);
            const size_t half = x < size / 2 ? 0 : 2;
            m[half] += c.x, m[half + 1] += c.z;
          }
      means[textured] = m;
    }
    for (size_t i = 0; i < 4; ++i) EXPECT_NEAR(means[1][i] / means[0][i], 1.0, 0.04) << "quantity " << i;
    EXPECT_GT(means[0][0], 1.5 * means[0][2]);  // the left half is redder than the right
  }
}

}  // namespace
}  // namespace epr
