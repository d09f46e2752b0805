// Point, spot and directional lights (common/lights.h, sampled in worker/sky_light.cpp) against
// answers known in closed form: a diffuse floor of albedo a lit by a point light of intensity I at
// height d shows a / pi x I cos^3(theta) / d^2 where a camera at the light sees it at angle theta
// (irradiance I cos / r^2 with r = d / cos). Light reaches the floor only directly (every ray it
// reflects escapes), and next event estimation of a delta light is exact for a given floor point:
// the only spread is the film's jitter within a pixel, so the expected value is the same formula
// averaged over a 16 x 16 grid in each pixel, and the tolerances are that of the grid (1e-3).
#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <vector>

#include "tests/worker/floor_scene.h"
#include "tests/worker/image_means.h"
#include "worker/path_tracer.h"
#include "worker/sky_light.h"

namespace epr {
namespace {

constexpr float kAlbedo = 0.5f, kHeight = 2.f;

// A 4 x 4 m floor at y = 0 seen straight down from (0, kHeight, 0), where the lamps are.
Scene lamp_floor(float fov) {
  return diffuse_floor("lamp-floor", 2, kAlbedo, {Vec3(0, kHeight, 0), Vec3(0, 0, 0), Vec3(0, 0, 1), fov});
}

// Per-pixel means ((r + g + b) / 3) of a size x size render.
std::vector<double> render_pixels(const Scene& scene, const Lighting& lighting, bool mis, int size, int spp) {
  EmbreeScene es(scene);
  const SkyLight sky(lighting, es);
  const Camera cam(scene.camera, size, size);
  const PathTracer tracer(es, cam, 11, RussianRoulette::paper(), mis, SamplerKind::kSobolBurley, &sky);
  TileRenderer tiles(tracer, {VertexFilter::Mode::kAll});
  std::vector<double> out(size_t(size) * size_t(size));
  for (const TileRect& rect : make_tiles(size, size, 16)) {
    TileRequest req;
    req.rect = rect;
    req.paths_per_pixel = spp;
    const TileResult r = tiles.render(req);
    for (int y = rect.y0; y < rect.y1; ++y)
      for (int x = rect.x0; x < rect.x1; ++x) {
        const size_t i = size_t(y - rect.y0) * size_t(rect.width()) + size_t(x - rect.x0);
        out[size_t(y) * size_t(size) + size_t(x)] =
            (r.path_sum[i].x + r.path_sum[i].y + r.path_sum[i].z) / 3.0 / r.path_count[i];
      }
  }
  return out;
}

// The floor's radiance in the pixel, `value` of the unit direction from the camera averaged over a
// 16 x 16 grid of the pixel; also the largest angle (degrees) to straight down within the pixel.
double pixel_mean(const Camera& cam, int x, int y, const std::function<double(Vec3)>& value,
                  double* max_angle = nullptr) {
  double sum = 0, widest = 0;
  for (int j = 0; j < 16; ++j)
    for (int i = 0; i < 16; ++i) {
      const Vec3 d = cam.generate_ray(float(x) + (float(i) + 0.5f) / 16, float(y) + (float(j) + 0.5f) / 16).dir;
      sum += value(d);
      widest = std::max(widest, std::acos(std::min(1.0, double(-d.y))) * 180 / kPi);
    }
  if (max_angle) *max_angle = widest;
  return sum / 256;
}

// a / pi x I(theta) cos^3 / d^2 for a light at the camera with intensity `intensity(cos)` downwards.
std::function<double(Vec3)> floor_radiance(const std::function<double(double)>& intensity) {
  return [intensity](Vec3 d) {
    const double c = -d.y;
    return kAlbedo / kPi * intensity(c) * c * c * c / (kHeight * kHeight);
  };
}

PunctualLight point_light(float intensity) {
  PunctualLight l;
  l.name = "bulb";
  l.type = LightType::kPoint;
  l.position = Vec3(0, kHeight, 0);
  l.intensity = Vec3(intensity);
  return l;
}

TEST(PunctualLight, PointLightGivesIntensityTimesCosineOverDistanceSquared) {
  Scene scene = lamp_floor(50);
  const float intensity = 7;
  scene.lights.push_back(point_light(intensity));
  const int size = 16;
  const Camera cam(scene.camera, size, size);
  for (bool mis : {true, false}) {
    const std::vector<double> px = render_pixels(scene, {}, mis, size, 16);
    for (int y = 0; y < size; ++y)
      for (int x = 0; x < size; ++x) {
        const double expected = pixel_mean(cam, x, y, floor_radiance([&](double) { return intensity; }));
        ASSERT_NEAR(px[size_t(y * size + x)], expected, 1e-3 * expected)
            << "pixel " << x << ", " << y << " mis " << mis;
      }
  }
}

// With a constant sky as well, the selection between the sky and the lamp (by power) leaves the mean
// unbiased: a L (the sky's share) plus the lamp's. Sky sampling has a spread: 256 x 256 paths, the
// tolerance 1.5 % (the Bernoulli spread of picking the sky, about 0.4 %, with margin).
TEST(PunctualLight, PointLightAndSkyAdd) {
  Scene scene = lamp_floor(50);
  scene.lights.push_back(point_light(5));
  Lighting sky;
  sky.environment = EnvironmentLight{};
  sky.environment->color = Vec3(0.5f);
  const int size = 16;
  const Camera cam(scene.camera, size, size);
  double expected = 0;
  for (int y = 0; y < size; ++y)
    for (int x = 0; x < size; ++x) expected += pixel_mean(cam, x, y, floor_radiance([](double) { return 5.0; }));
  expected = expected / (size * size) + kAlbedo * 0.5;
  for (bool mis : {true, false}) {
    const std::vector<double> px = render_pixels(scene, sky, mis, size, 256);
    double mean = 0;
    for (double v : px) mean += v;
    mean /= double(px.size());
    EXPECT_NEAR(mean, expected, 0.015 * expected) << "mis " << mis;
  }
}

// A spot pointing down (outer cone 20 degrees, inner 10): every pixel matches the falloff averaged
// over the pixel, and the floor beyond the outer cone is black.
TEST(PunctualLight, SpotFallsOffToZeroOutsideItsOuterCone) {
  const double inner = 10, outer = 20, rad = kPi / 180;
  const double ci = std::cos(inner * rad), co = std::cos(outer * rad);
  const auto smoothstep = [](double t) { return t * t * (3 - 2 * t); };
  for (SpotFalloff falloff : {SpotFalloff::kGltf, SpotFalloff::kBlender}) {
    Scene scene = lamp_floor(60);
    PunctualLight l = point_light(9);
    l.type = LightType::kSpot;
    l.direction = Vec3(0, -1, 0);
    l.cos_inner = float(ci);
    l.cos_outer = float(co);
    l.falloff = falloff;
    scene.lights.push_back(l);
    const auto intensity = [&](double c) {
      if (c <= co) return 0.0;
      const double t = std::min(1.0, (c - co) / (ci - co));
      return 9 * (falloff == SpotFalloff::kGltf ? t * t : c * smoothstep(t));
    };
    const int size = 32;
    const Camera cam(scene.camera, size, size);
    const std::vector<double> px = render_pixels(scene, {}, true, size, 64);
    int dark = 0, full = 0;
    for (int y = 0; y < size; ++y)
      for (int x = 0; x < size; ++x) {
        double widest = 0;
        const double expected = pixel_mean(cam, x, y, floor_radiance(intensity), &widest);
        const double got = px[size_t(y * size + x)];
        const double peak = kAlbedo / kPi * 9 / (kHeight * kHeight);
        // Where the cone's edge crosses a pixel its 64 jittered samples integrate a steep ramp: within
        // 0.5 % of the peak (measured: 0.3 % at 16 samples).
        EXPECT_NEAR(got, expected, 5e-3 * peak) << "pixel " << x << ", " << y;
        // The pixel's nearest point to the axis is beyond the outer cone: black.
        const Vec3 centre = cam.generate_ray(float(x) + 0.5f, float(y) + 0.5f).dir;
        const double centre_angle = std::acos(double(-centre.y)) / rad;
        if (centre_angle - (widest - centre_angle) > outer + 0.1) {
          EXPECT_EQ(got, 0.0) << "pixel " << x << ", " << y << " at " << centre_angle << " degrees";
          ++dark;
        }
        if (widest < inner) ++full;
      }
    EXPECT_GT(dark, 100);  // the test saw the dark floor and the cone's centre
    EXPECT_GT(full, 10);
  }
}

// Directional lights are suns: a floor under two of them (one a delta, one a 1 degree disc) and the
// lighting's own sun gets a / pi x the sum of E cos.
TEST(PunctualLight, DirectionalLightsAndTheSunAdd) {
  Scene scene = lamp_floor(50);
  PunctualLight a;
  a.name = "key";
  a.type = LightType::kDirectional;
  a.direction = normalize(Vec3(1, 2, 0.5f));
  a.intensity = Vec3(4);
  PunctualLight b = a;
  b.name = "fill";
  b.direction = normalize(Vec3(-1, 1, 0));
  b.intensity = Vec3(2);
  b.angle_deg = 1;
  scene.lights = {a, b};
  Lighting lighting;
  lighting.sun = SunLight{};
  lighting.sun->direction = normalize(Vec3(0, 1, -1));
  lighting.sun->irradiance = Vec3(3);
  const double expected = kAlbedo / kPi * (4 * a.direction.y + 2 * b.direction.y + 3 * lighting.sun->direction.y);
  {
    EmbreeScene es(scene);
    EXPECT_EQ(SkyLight(lighting, es).sun_count(), 3u);
  }
  for (bool mis : {true, false}) {
    const std::vector<double> px = render_pixels(scene, lighting, mis, 16, 64);
    double mean = 0;
    for (double v : px) mean += v;
    mean /= double(px.size());
    // Each sun's pick is a Bernoulli choice among three: 16 x 16 x 64 paths, the spread about 0.5 %.
    EXPECT_NEAR(mean, expected, 0.02 * expected) << "mis " << mis;
  }
  // One directional light alone: every pixel (no choice to make) is exact.
  scene.lights = {a};
  const std::vector<double> px = render_pixels(scene, {}, true, 16, 4);
  for (double v : px) EXPECT_NEAR(v, kAlbedo / kPi * 4 * a.direction.y, 1e-4);
}

}  // namespace
}  // namespace epr
