// Light from outside (worker/sky_light.h) against answers known in closed form.
//
// White furnace: under a constant environment of radiance L, a scene whose every surface has albedo
// 1 leaves radiance L everywhere, whatever its shape: every pixel, and every recorded vertex (the
// value reprojection shows elsewhere), must converge to L. A horizontal plane of albedo a under an
// environment image reflects a / pi x the image's cosine-weighted integral over the upper hemisphere,
// which a sum over the texels gives exactly; a plane under a sun reflects a E cos / pi. Both MIS and
// next event estimation only must reach these values, and the image's sampling density must integrate
// to 1 and agree with the density of the directions it draws.
#include "worker/sky_light.h"

#include <gtest/gtest.h>

#include <cmath>
#include <utility>

#include "common/limits.h"
#include "common/rng.h"
#include "tests/worker/floor_scene.h"
#include "tests/worker/image_means.h"
#include "worker/path_tracer.h"

namespace epr {
namespace {

// A box open at the top (floor and four walls, 2 m), albedo `a`: concave, so paths bounce inside it.
Scene open_box(float a) {
  Scene s;
  s.name = "open-box";
  Material m;
  m.name = "white";
  m.kd = Vec3(a);
  const uint32_t id = add_material(s, m);
  const Vec3 p[8] = {{-1, 0, -1}, {1, 0, -1}, {1, 2, -1}, {-1, 2, -1}, {-1, 0, 1}, {1, 0, 1}, {1, 2, 1}, {-1, 2, 1}};
  add_tessellated_quad(s, p[0], p[4], p[5], p[1], id, 2);  // floor
  add_tessellated_quad(s, p[0], p[1], p[2], p[3], id, 2);  // z = -1
  add_tessellated_quad(s, p[5], p[4], p[7], p[6], id, 2);  // z = +1
  add_tessellated_quad(s, p[4], p[0], p[3], p[7], id, 2);  // x = -1
  add_tessellated_quad(s, p[1], p[5], p[6], p[2], id, 2);  // x = +1
  // Looks into the box from above a corner, so that some pixels see the sky.
  s.camera = {Vec3(2.5f, 3.5f, 2.5f), Vec3(0, 0.5f, 0), Vec3(0, 1, 0), 60.f};
  return s;
}

// A 200 m floor at y = 0, albedo a, seen from 1 m above: every pixel is a point of the floor.
Scene floor_plane(float a) {
  return diffuse_floor("floor", 100, a, {Vec3(0, 1, 0), Vec3(0.01f, 0, 0), Vec3(0, 0, 1), 40.f});
}

// An 8 x 4 .. image with a bright patch near the horizon and a dimmer coloured sky.
std::shared_ptr<Image> test_sky(int w, int h) {
  auto img = std::make_shared<Image>(w, h, 3);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      Vec3 c(0.2f + 0.6f * float(y) / float(h), 0.4f, 0.9f - 0.5f * float(x) / float(w));
      if (x >= w / 8 && x < w / 8 + w / 16 + 1 && y >= h / 4 && y < h / 4 + h / 8 + 1) c = Vec3(40.f, 30.f, 20.f);
      img->set_rgb(x, y, c);
    }
  return img;
}

// The open box with a 0.5 x 0.5 m emitting square (radiance `ke`, both sides) hanging 1.5 m above
// its floor.
Scene open_box_with_lamp(float a, float ke) {
  Scene s = open_box(a);
  Material m;
  m.name = "lamp";
  m.kd = Vec3(0.f);
  m.ke = Vec3(ke);
  const uint32_t id = add_material(s, m);
  add_quad(s, {-0.25f, 1.5f, -0.25f}, {0.25f, 1.5f, -0.25f}, {0.25f, 1.5f, 0.25f}, {-0.25f, 1.5f, 0.25f}, id);
  return s;
}

ImageMeans render(const Scene& scene, const SkyLight& sky, bool mis, int size, int spp) {
  EmbreeScene es(scene);
  const Camera cam(scene.camera, size, size);
  const PathTracer tracer(es, cam, 7, RussianRoulette::paper(), mis, SamplerKind::kSobolBurley, &sky);
  return render_image_means(tracer, size, spp);
}

TEST(SkyLight, EquirectMappingMatchesBlender) {
  // Blender's Environment Texture, measured with Cycles in Blender 3.4 (Z-up, a direction
  // (x, y, z) ours is (x, -z, y) there): +X reads the image's centre column, Blender's +Y (our -Z)
  // a quarter from the left, its -Y (our +Z) three quarters, straight up the top row.
  const auto ut = [](Vec3 d) { return direction_to_equirect(normalize(d), 0.f); };
  EXPECT_NEAR(ut({1, 0, 0}).x, 0.5f, 1e-6f);
  EXPECT_NEAR(ut({1, 0, 0}).y, 0.5f, 1e-6f);
  EXPECT_NEAR(ut({0, 0, -1}).x, 0.25f, 1e-6f);
  EXPECT_NEAR(ut({0, 0, 1}).x, 0.75f, 1e-6f);
  EXPECT_NEAR(ut({1, 1, 0}).y, 0.25f, 1e-6f);  // 45 degrees up
  EXPECT_NEAR(ut({0, 1, 0}).y, 0.f, 1e-6f);
  // A rotation of r turns the sky like Blender's Mapping node: the centre column moves to phi = r.
  const float r = 0.7f;
  EXPECT_NEAR(direction_to_equirect({std::cos(r), 0, std::sin(r)}, r).x, 0.5f, 1e-6f);
  for (Vec2 u : {Vec2{0.1f, 0.2f}, Vec2{0.6f, 0.9f}, Vec2{0.95f, 0.5f}}) {
    const Vec2 back = direction_to_equirect(equirect_to_direction(u, r), r);
    EXPECT_NEAR(back.x, u.x, 1e-5f);
    EXPECT_NEAR(back.y, u.y, 1e-5f);
  }
}

TEST(SkyLight, ImageDensityIntegratesToOneAndMatchesItsSamples) {
  Lighting l;
  l.environment = EnvironmentLight{};
  l.environment->pixels = test_sky(64, 32);
  l.environment->rotation_deg = 30;
  const SkyLight sky(l, 0.0, 1.f);
  ASSERT_FALSE(sky.empty());
  EXPECT_EQ(sky.triangle_share(), 0.f);
  // Integral over the sphere on a grid finer than the texels, in (u, t) with |J| = 2 pi^2 sin(theta).
  const int n = 512;
  double integral = 0;
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < 2 * n; ++i) {
      const Vec2 ut{(float(i) + 0.5f) / float(2 * n), (float(j) + 0.5f) / float(n)};
      const Vec3 d = equirect_to_direction(ut, 30 * kPi / 180);
      integral += sky.pdf_environment(d, {0, 1, 0}) * 2 * kPi * kPi * std::sin(kPi * ut.y) / (2.0 * n * n);
    }
  EXPECT_NEAR(integral, 1.0, 1e-3);
  // The directions drawn follow the density pdf_environment gives: the estimate of the sky's
  // integral of luminance, mean of lum(L(w)) / p(w), matches the sum over its texels, and the bright
  // patch draws its share of the samples.
  const Image& img = *l.environment->pixels;
  double bright = 0, all = 0, integral_l = 0;
  for (int y = 0; y < img.height; ++y)
    for (int x = 0; x < img.width; ++x) {
      const double l_texel = luminance(img.rgb(x, y));
      const double w = l_texel * std::sin(kPi * (y + 0.5) / img.height);
      all += w;
      if (img.rgb(x, y).x > 10) bright += w;
      integral_l +=
          l_texel * (2 * kPi / img.width) * (std::cos(kPi * y / img.height) - std::cos(kPi * (y + 1) / img.height));
    }
  SampleStream rng(3, 0, 0);
  const int samples = 200000;
  int in_bright = 0;
  double estimate = 0;
  for (int k = 0; k < samples; ++k) {
    const SkyLight::Sample s = sky.sample(rng.next(), rng.next2(), {0, 1, 0});
    ASSERT_GT(s.pdf, 0.f);
    estimate += luminance(s.radiance) / s.pdf;
    in_bright += s.radiance.x > 10;
  }
  EXPECT_NEAR(estimate / samples, integral_l, 0.01 * integral_l);
  const double expected = bright / all;
  EXPECT_NEAR(double(in_bright) / samples, expected, 5 * std::sqrt(expected * (1 - expected) / samples));
}

TEST(SkyLight, SelectionSharesAndTheSunCone) {
  Lighting l;
  l.environment = EnvironmentLight{};
  l.environment->color = Vec3(1.f);
  l.sun = SunLight{};
  l.sun->direction = normalize(Vec3(1, 2, 0.5f));
  l.sun->angle_deg = 5;
  l.sun->irradiance = Vec3(3 * kPi);
  const SkyLight sky(l, 1.0, 1.f, 0.5f);  // a fixed half for the triangles
  EXPECT_EQ(sky.triangle_share(), 0.5f);
  // Environment pi x 1 against sun 3 pi: the sky's half splits 1 : 3.
  float u;
  EXPECT_FALSE(sky.picks_sky(0.25f, &u));
  EXPECT_NEAR(u, 0.5f, 1e-6f);
  EXPECT_TRUE(sky.picks_sky(0.75f, &u));
  EXPECT_NEAR(u, 0.5f, 1e-6f);
  SampleStream rng(5, 0, 0);
  const Vec3 n = normalize(Vec3(1, 2, 0.5f));
  double irradiance = 0;
  int sun_samples = 0;
  const int samples = 100000;
  for (int k = 0; k < samples; ++k) {
    const SkyLight::Sample s = sky.sample(0.3f + 0.7f * rng.next(), rng.next2(), n);  // > 1/4: the sun
    ASSERT_GE(dot(s.wi, l.sun->direction), l.sun->cos_half_angle() - 1e-6f);
    ASSERT_NEAR(s.pdf, 0.375 / (2 * kPi * (1 - std::cos(2.5 * kPi / 180))), 1e-3 * s.pdf);
    irradiance += s.radiance.x * dot(s.wi, n) / (s.pdf / 0.375);  // 0.375: the sun's selection
    ++sun_samples;
  }
  EXPECT_NEAR(irradiance / sun_samples, 3 * kPi, 1e-3 * 3 * kPi);
}

TEST(SkyLight, TriangleShareFollowsPowerWithinItsFloor) {
  EXPECT_EQ(triangle_share_for_power(0, 5), 0.f);
  EXPECT_EQ(triangle_share_for_power(5, 0), 1.f);
  EXPECT_FLOAT_EQ(triangle_share_for_power(3, 1), 0.75f);
  EXPECT_FLOAT_EQ(triangle_share_for_power(1, 3), 0.25f);
  EXPECT_FLOAT_EQ(triangle_share_for_power(1000, 1), 1 - kMinLightShare);
  EXPECT_FLOAT_EQ(triangle_share_for_power(1, 1000), kMinLightShare);

  // The powers from a scene: the lamp emits 2 pi x 0.25 m^2 x 8 (two sides); a sky of radiance 0.1
  // and a sun of 0.5 W/m^2 give (pi 0.1 + 0.5) x pi R^2, R = sqrt(2^2 + 2^2 + 2^2) / 2.
  const Scene scene = open_box_with_lamp(0.5f, 8.f);
  EmbreeScene es(scene);
  EXPECT_NEAR(es.emitted_power(), 2 * kPi * 0.25 * 8, 1e-4);
  Lighting l;
  l.environment = EnvironmentLight{};
  l.environment->color = Vec3(0.1f);
  l.sun = SunLight{};
  l.sun->irradiance = Vec3(0.5f);
  const SkyLight sky(l, es);
  EXPECT_NEAR(SkyLight::scene_radius(scene), std::sqrt(3.0), 1e-5);
  const double sky_power = (kPi * 0.1 + 0.5) * kPi * 3;
  EXPECT_NEAR(sky.sky_power(), sky_power, 1e-4 * sky_power);
  EXPECT_NEAR(sky.triangle_share(), 4 * kPi / (4 * kPi + sky_power), 1e-5);
  // Brighter sky, dimmer lamp: the sky takes over, never beyond the floor.
  l.environment->color = Vec3(50.f);
  EXPECT_FLOAT_EQ(SkyLight(l, es).triangle_share(), kMinLightShare);
}

// A dim sky and a bright lamp: the lamp gets most of next event estimation's picks, and the image
// is the same as with the triangles' fixed half (the share changes the noise, not the mean).
TEST(SkyLight, DimSkyBrightLampGivesTheLampMostPicksAndTheSameImage) {
  const Scene scene = open_box_with_lamp(0.6f, 20.f);
  EmbreeScene es(scene);
  Lighting l;
  l.environment = EnvironmentLight{};
  l.environment->color = Vec3(0.05f);
  const SkyLight power(l, es);
  const SkyLight half(l, es.emitted_power(), SkyLight::scene_radius(scene), 0.5f);
  EXPECT_EQ(power.triangle_share(), 1 - kMinLightShare);  // 31 W against 1.5 W: clamped
  int lamp = 0;
  const int picks = 10000;
  for (int k = 0; k < picks; ++k) {
    float u;
    lamp += !power.picks_sky((float(k) + 0.5f) / picks, &u);
  }
  EXPECT_NEAR(double(lamp) / picks, 1 - kMinLightShare, 1e-3);
  for (bool mis : {true, false}) {
    const ImageMeans a = render(scene, power, mis, 32, 256), b = render(scene, half, mis, 32, 256);
    EXPECT_NEAR(a.pixel, b.pixel, 0.01 * b.pixel) << "mis " << mis;
    EXPECT_NEAR(a.vertex, b.vertex, 0.015 * b.vertex) << "mis " << mis;
  }
}

class WhiteFurnace : public ::testing::TestWithParam<std::tuple<bool, bool>> {};

TEST_P(WhiteFurnace, EverySurfaceOfAlbedoOneShowsTheSky) {
  const auto [image, mis] = GetParam();
  const float L = 0.7f;
  Lighting l;
  l.environment = EnvironmentLight{};
  if (image) {  // a constant image: the importance-sampled path, with its sin(theta) weights
    auto img = std::make_shared<Image>(16, 8, 3);
    for (int y = 0; y < 8; ++y)
      for (int x = 0; x < 16; ++x) img->set_rgb(x, y, Vec3(L / 2));
    l.environment->pixels = img;
    l.environment->strength = 2;
  } else {
    l.environment->color = Vec3(L);
  }
  const Scene scene = open_box(1.f);
  EmbreeScene es(scene);
  const SkyLight sky(l, es);
  // The vertex mean is a ratio over paths of their records' sum and count, whose records' values
  // are heavy-tailed (long paths in the box carry 1/q factors): an image sampled for next event
  // estimation alone needs about 200k records to come within 1 % (measured: +4.4 % at 64 paths per
  // pixel, +0.8 % at 256).
  const ImageMeans m = render(scene, sky, mis, 48, 256);
  EXPECT_NEAR(m.pixel, L, 0.01 * L) << "image " << image << " mis " << mis;
  EXPECT_GT(m.vertices, 100000u);
  EXPECT_NEAR(m.vertex, L, 0.015 * L) << "image " << image << " mis " << mis;
}

INSTANTIATE_TEST_SUITE_P(ConstantOrImageAndMis, WhiteFurnace, ::testing::Combine(::testing::Bool(), ::testing::Bool()));

TEST(SkyLight, FloorUnderAnImageReflectsTheHemisphereIntegral) {
  const float a = 0.6f;
  Lighting l;
  l.environment = EnvironmentLight{};
  l.environment->pixels = test_sky(64, 32);
  l.environment->rotation_deg = 30;  // a horizontal floor sees the same integral at any rotation
  l.environment->strength = 1.5f;
  // a / pi x sum over the upper rows of L (2 pi / W) (sin^2 theta1 - sin^2 theta0) / 2.
  const Image& img = *l.environment->pixels;
  double e = 0;
  for (int y = 0; y < img.height / 2; ++y) {
    const double t0 = kPi * y / img.height, t1 = kPi * (y + 1) / img.height;
    const double band = (std::sin(t1) * std::sin(t1) - std::sin(t0) * std::sin(t0)) / 2 * (2 * kPi / img.width);
    for (int x = 0; x < img.width; ++x) {
      const Vec3 c = img.rgb(x, y);
      e += (c.x + c.y + c.z) / 3 * band;
    }
  }
  const double expected = a / kPi * 1.5 * e;
  const Scene scene = floor_plane(a);
  EmbreeScene es(scene);
  const SkyLight sky(l, 0.0, 1.f);
  for (bool mis : {true, false}) {
    const ImageMeans m = render(scene, sky, mis, 16, 1024);
    EXPECT_NEAR(m.pixel, expected, 0.01 * expected) << "mis " << mis;
  }
}

TEST(SkyLight, SunOnAFloorGivesItsIrradianceTimesTheCosine) {
  const float a = 0.5f;
  const Scene scene = floor_plane(a);
  EmbreeScene es(scene);
  // A wide disc, and the smallest one of the strongest sun (radiance ~4e18).
  for (const auto& [angle, irradiance] : {std::pair{3.f, 4.f}, std::pair{limits::kMinSunAngleDeg, 1e9f}}) {
    Lighting l;
    l.sun = SunLight{};
    l.sun->direction = normalize(Vec3(1, 2, 0.5f));
    l.sun->angle_deg = angle;
    l.sun->irradiance = Vec3(irradiance);
    const double expected = a * irradiance * l.sun->direction.y / kPi;
    const SkyLight sky(l, 0.0, 1.f);
    for (bool mis : {true, false}) {
      const ImageMeans m = render(scene, sky, mis, 16, 64);
      EXPECT_NEAR(m.pixel, expected, 0.005 * expected) << "mis " << mis << " angle " << angle;
    }
  }
}

// The disc is as wide as its angle, also where float's cosine of the half angle rounds to 1 (below
// ~0.02 degrees): a direction 1e-4 rad off the sun is outside a disc of 0.001 degrees (8.7e-6 rad).
TEST(SkyLight, TheSmallestSunIsAsWideAsItsAngle) {
  Lighting l;
  l.sun = SunLight{};
  l.sun->direction = Vec3(0, 1, 0);
  l.sun->angle_deg = limits::kMinSunAngleDeg;
  const SkyLight sky(l, 0.0, 1.f);
  const auto at = [](double off) { return Vec3(float(std::sin(off)), float(std::cos(off)), 0.f); };
  const float h = 0.5f * limits::kMinSunAngleDeg * kPi / 180;
  EXPECT_EQ(sky.radiance(at(0.5 * h)), l.sun->radiance());
  EXPECT_EQ(sky.radiance(at(0.9 * h)), l.sun->radiance());
  EXPECT_EQ(sky.radiance(at(1.2 * h)), Vec3(0.f));
  EXPECT_EQ(sky.radiance(at(1e-4)), Vec3(0.f));
  EXPECT_EQ(sky.pdf_sun(at(1e-4)), 0.f);
  EXPECT_GT(sky.pdf_sun(at(0.5 * h)), 0.f);
}

// The default roulette (`auto`) follows where the light comes from: under a sky the paths it traces
// are reuse's, bit for bit; lit by a lamp alone they are albedo's (and the two differ, so the test
// sees which one ran).
TEST(SkyLight, AutoRouletteIsReuseUnderASkyAndAlbedoUnderALamp) {
  const Scene scene = open_box_with_lamp(0.7f, 8.f);
  EmbreeScene es(scene);
  const Camera cam(scene.camera, 16, 16);
  const auto means = [&](const SkyLight& sky, const RussianRoulette& rr) {
    const PathTracer tracer(es, cam, 5, rr, true, SamplerKind::kSobolBurley, &sky);
    return render_image_means(tracer, 16, 8);
  };
  const auto same = [](const ImageMeans& a, const ImageMeans& b) {
    return a.pixel == b.pixel && a.vertex == b.vertex && a.vertices == b.vertices;
  };
  Lighting outside;
  outside.environment = EnvironmentLight{};
  outside.environment->color = Vec3(0.5f);
  const SkyLight sky(outside, es);
  ASSERT_TRUE(sky.from_outside());
  const ImageMeans auto_sky = means(sky, RussianRoulette::standard());
  EXPECT_TRUE(same(auto_sky, means(sky, RussianRoulette::reuse())));
  EXPECT_FALSE(same(auto_sky, means(sky, RussianRoulette::albedo())));

  const SkyLight lamp(Lighting{}, es);
  ASSERT_FALSE(lamp.from_outside());
  const ImageMeans auto_lamp = means(lamp, RussianRoulette::standard());
  EXPECT_TRUE(same(auto_lamp, means(lamp, RussianRoulette::albedo())));
  EXPECT_FALSE(same(auto_lamp, means(lamp, RussianRoulette::reuse())));
}

}  // namespace
}  // namespace epr
