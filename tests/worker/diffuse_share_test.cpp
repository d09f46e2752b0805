// Diffuse-share reprojection in the path tracer (DESIGN.md "Diffuse-share reprojection"): a vertex of
// a microfacet material with a diffuse base records that base's share of its reflected light and is
// marked reprojectable; the pixel's own sample hands back its glossy part; a Lambertian vertex's
// share is its whole radiance (glossy part exactly 0).
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "common/scene.h"
#include "tests/worker/glowing_box.h"
#include "worker/bsdf.h"
#include "worker/path_tracer.h"

namespace epr {
namespace {

// A closed box of Lambertian walls (albedo 0.5) emitting radiance 1 around a floor (y = -1) of
// material `floor`: a nearly uniform field of light, in which the floor reflects c of it through its
// diffuse base plus what its specular layer reflects (F the dielectric Fresnel, 0.04 head-on for
// ior 1.5).
Scene share_box(const Material& floor) {
  Scene s = test::glowing_box(floor, "test-share-box");
  s.camera = {Vec3(0.f, 0.6f, 0.9f), Vec3(0, -1, -0.2f), Vec3(0, 1, 0), 50.f};
  return s;
}

struct ShareStats {
  double pixel = 0, glossy = 0;  // means of the floor pixels' samples and of their glossy parts
  double record = 0;             // mean of the floor records' radiance
  size_t records = 0, not_diffuse = 0, pixels = 0;
  bool exact_zero_glossy = true;
};

ShareStats trace_box(const Scene& s) {
  const EmbreeScene es(s);
  const Camera cam(s.camera, 16, 16);
  const PathTracer tracer(es, cam, 3, RussianRoulette::paper());
  ShareStats st;
  std::vector<VertexRecord> records;
  for (int y = 0; y < 16; ++y)
    for (int x = 0; x < 16; ++x)
      for (uint32_t k = 0; k < 64; ++k) {
        Vec3 glossy(-1.f);
        const Vec3 l = tracer.trace(x, y, k, &records, nullptr, &glossy);
        st.exact_zero_glossy = st.exact_zero_glossy && glossy.x == 0 && glossy.y == 0 && glossy.z == 0;
        if (cam.generate_ray(float(x) + 0.5f, float(y) + 0.5f).dir.y < -0.9f) {  // the floor, seen from above
          st.pixel += l.x;
          st.glossy += glossy.x;
          ++st.pixels;
        }
      }
  for (const VertexRecord& r : records) {
    if (r.position.y > -0.999f || std::abs(r.position.x) > 0.999f || std::abs(r.position.z) > 0.999f) continue;
    st.record += r.radiance.x;
    ++st.records;
    st.not_diffuse += !r.diffuse();
  }
  st.pixel /= double(std::max<size_t>(1, st.pixels));
  st.glossy /= double(std::max<size_t>(1, st.pixels));
  st.record /= double(std::max<size_t>(1, st.records));
  return st;
}

// A Lambertian floor: every sample's glossy part is exactly 0 and its records are its whole
// radiance: their mean is the floor pixels' (within 8 %: the same surface from other angles).
TEST(DiffuseShare, ALambertianVertexSharesItsWholeRadiance) {
  Material lambert;
  lambert.kd = Vec3(0.3f);
  const ShareStats st = trace_box(share_box(lambert));
  ASSERT_GT(st.records, 2000u);
  ASSERT_GT(st.pixels, 2000u);
  EXPECT_TRUE(st.exact_zero_glossy);
  EXPECT_EQ(st.not_diffuse, 0u);
  EXPECT_NEAR(st.record / st.pixel, 1.0, 0.08);
}

// A dielectric floor (specular layer over the diffuse base c = 0.3): its records are reprojectable
// and carry the diffuse base's share only, the same as the floor pixels' samples minus their glossy
// parts (within 10 %: other angles, other Fresnel weights), clearly below the pixels' whole radiance
// (what a record held before); the glossy parts are clearly above 0.
TEST(DiffuseShare, AGlossyOverDiffuseVertexRecordsItsDiffuseShare) {
  Material dielectric;
  dielectric.type = MaterialType::kMicrofacet;
  dielectric.kd = Vec3(0.3f);
  dielectric.metallic = 0;
  dielectric.roughness = 0.3f;
  const ShareStats st = trace_box(share_box(dielectric));
  ASSERT_GT(st.records, 2000u);
  ASSERT_GT(st.pixels, 2000u);
  EXPECT_EQ(st.not_diffuse, 0u) << "a vertex with a diffuse base is reprojectable";
  EXPECT_NEAR(st.record / (st.pixel - st.glossy), 1.0, 0.1);
  EXPECT_LT(st.record, 0.9 * st.pixel) << "a record must not carry the specular layer's light";
  EXPECT_GT(st.glossy, 0.1 * st.pixel);
}

// Bsdf::eval_diffuse: the whole of eval() for Lambertian, Kd / pi beside a Phong lobe, and the
// diffuse base alone (below eval()) for the microfacet material; 0 below the surface.
TEST(DiffuseShare, EvalDiffuseIsTheDiffuseLobe) {
  const Vec3 n(0, 0, 1), wo = normalize(Vec3(0.3f, 0, 1));
  Material lambert;
  lambert.kd = Vec3(0.4f);
  const Bsdf l(lambert, lambert.kd, n, wo);
  const Bsdf m(MicrofacetInputs{Vec3(0.4f), 0, 0.3f, 0, 1.5f, true}, n, n, wo);
  EXPECT_TRUE(l.has_diffuse());
  EXPECT_TRUE(m.has_diffuse());
  for (int i = 0; i < 50; ++i) {
    const Vec3 wi = normalize(Vec3(std::cos(0.37f * float(i)), std::sin(0.37f * float(i)), 0.05f + 0.02f * float(i)));
    EXPECT_EQ(l.eval_diffuse(wi).x, l.eval(wi).x);
    EXPECT_GT(m.eval_diffuse(wi).x, 0.f);
    EXPECT_LT(m.eval_diffuse(wi).x, m.eval(wi).x);
  }
  EXPECT_EQ(m.eval_diffuse(Vec3(0, 0, -1)).x, 0.f);
  const Bsdf metal(MicrofacetInputs{Vec3(0.9f), 1, 0.3f, 0, 1.5f, true}, n, n, wo);
  EXPECT_FALSE(metal.has_diffuse());
}

}  // namespace
}  // namespace epr
