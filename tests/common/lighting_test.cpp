// The sky and the sun as a scene JSON and the flags give them (common/lighting.h): parsing, the
// errors that name the flag or the file and line, the image read inside the scene's folder, and the
// refusal of a scene with no light at all, which now says how to light it from outside.
#include "common/lighting.h"

#include <gtest/gtest.h>

#include <cmath>

#include "common/image.h"
#include "common/scene_loader.h"
#include "tests/common/scene_test_files.h"

namespace epr {
namespace {

using test::load_error;
using test::TempDir;

bool contains(const std::string& s, const std::string& part) { return s.find(part) != std::string::npos; }

std::string env_error(const std::string& v) {
  std::string file;
  try {
    parse_env_flag(v, &file);
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  return "";
}

std::string sun_error(const std::string& v) {
  try {
    parse_sun_flag(v);
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  return "";
}

const std::string kDarkObj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";

void write_sky(const std::string& path, int w, int h, float value) {
  Image img(w, h, 3);
  for (float& v : img.data) v = value;
  write_exr(path, img);
}

TEST(Lighting, EnvFlagIsAColourOrAFile) {
  std::string file;
  EXPECT_EQ(parse_env_flag("1,0.5,2", &file).color, Vec3(1, 0.5f, 2));
  EXPECT_TRUE(file.empty());
  EXPECT_EQ(parse_env_flag("0.25", &file).color, Vec3(0.25f));
  const EnvironmentLight e = parse_env_flag("skies/sky.hdr", &file);
  EXPECT_EQ(file, "skies/sky.hdr");
  EXPECT_EQ(e.image, "skies/sky.hdr");
  EXPECT_TRUE(contains(env_error("1,2"), "--env '1,2': a colour is one number (a grey) or three")) << env_error("1,2");
  EXPECT_TRUE(contains(env_error("1,-1,1"), "--env: environment colour values must be finite and in [0, 1e6]"));
  EXPECT_TRUE(contains(env_error(""), "--env: expects an image file"));
}

TEST(Lighting, SunFlagTakesDirectionAngleAndIrradiance) {
  SunLight s = parse_sun_flag("0,2,0");
  EXPECT_EQ(s.direction, Vec3(0, 1, 0));
  EXPECT_EQ(s.angle_deg, 0.53f);
  EXPECT_EQ(s.irradiance, Vec3(1.f));
  s = parse_sun_flag("1,1,0,2,5");
  EXPECT_EQ(s.angle_deg, 2.f);
  EXPECT_EQ(s.irradiance, Vec3(5.f));
  s = parse_sun_flag("1,1,0,2,5,4,3");
  EXPECT_EQ(s.irradiance, Vec3(5, 4, 3));
  // The disc's radiance gives back the irradiance: L pi sin^2(h).
  const float h = std::sin(1.f * kPi / 180);
  EXPECT_NEAR(s.radiance().x * kPi * h * h, 5.f, 1e-4f);
  EXPECT_TRUE(contains(sun_error("1,1"), "--sun '1,1': expects DX,DY,DZ[,ANGLE_DEG[,E or ,R,G,B]]"))
      << sun_error("1,1");
  EXPECT_TRUE(contains(sun_error("1,1,0,2,5,4"), "expects DX,DY,DZ"));
  EXPECT_TRUE(contains(sun_error("0,0,0"), "--sun: sun direction must be a finite non-zero vector"));
  EXPECT_TRUE(contains(sun_error("0,1,0,120"), "--sun: sun angle (angular diameter, degrees) must be in [0.001, 90]"));
  EXPECT_TRUE(contains(sun_error("0,1,0,1,-2"), "--sun: sun irradiance must be finite"));
  EXPECT_TRUE(contains(sun_error("0,1,x"), "expects DX,DY,DZ"));
}

TEST(Lighting, SceneJsonEnvironmentAndSun) {
  TempDir dir;
  dir.write("dark.obj", kDarkObj);
  std::filesystem::create_directories(dir.path("skies"));
  write_sky(dir.path("skies/sky.exr"), 8, 4, 0.5f);
  const std::string json = dir.write("s.json", R"({
  "obj": "dark.obj",
  "environment": {"image": "skies/sky.exr", "strength": 2, "rotation_deg": 90},
  "sun": {"direction": [0, 3, 0], "angle_deg": 1, "irradiance": [1, 2, 3]}
})");
  LoadReport report;
  const Scene s = load_scene(json, {}, &report);
  ASSERT_TRUE(s.lighting.environment);
  ASSERT_TRUE(s.lighting.environment->pixels);
  EXPECT_EQ(s.lighting.environment->pixels->width, 8);
  EXPECT_EQ(s.lighting.environment->strength, 2.f);
  EXPECT_EQ(s.lighting.environment->rotation_deg, 90.f);
  EXPECT_NEAR(s.lighting.environment->radiance({1, 0, 0}).y, 1.f, 1e-6f);
  ASSERT_TRUE(s.lighting.sun);
  EXPECT_EQ(s.lighting.sun->direction, Vec3(0, 1, 0));
  EXPECT_EQ(s.lighting.sun->irradiance, Vec3(1, 2, 3));
  // The image is one of the scene's files: it travels in the bundle.
  bool listed = false;
  for (const FileRef& f : report.files) listed |= f.display == "skies/sky.exr" || contains(f.real.string(), "sky.exr");
  EXPECT_TRUE(listed);
  EXPECT_FALSE(unlit_reason(s)) << "a sky lights the scene";

  // "radiance" instead of "irradiance": the disc's radiance.
  const Scene r = load_scene(dir.write("r.json", R"({"obj": "dark.obj", "sun": {"direction": [0, 1, 0],
    "angle_deg": 2, "radiance": 100}})"));
  const float h = std::sin(1.f * kPi / 180);
  EXPECT_NEAR(r.lighting.sun->irradiance.x, 100 * kPi * h * h, 1e-4f);
}

TEST(Lighting, SceneJsonErrorsNameFileAndLine) {
  TempDir dir;
  dir.write("dark.obj", kDarkObj);
  dir.write("outside/sky.exr", "");
  const auto err = [&](const std::string& name, const std::string& body) {
    return load_error(dir.write(name, "{\"obj\": \"dark.obj\",\n" + body + "}"));
  };
  std::string e = err("a.json", R"("environment": {"color": [1, 1, 1], "image": "x.hdr"})");
  EXPECT_TRUE(contains(e, "a.json:2: give exactly one of \"color\" and \"image\" for the environment")) << e;
  e = err("b.json", "\"environment\": {\n\"color\": [1, -1, 1]}");
  EXPECT_TRUE(contains(e, "b.json:3: environment color values must lie in [0, 1000000]")) << e;
  e = err("c.json", R"("environment": {"image": "../sky.hdr"})");
  EXPECT_TRUE(contains(e, "c.json:2: environment image '../sky.hdr' leaves the scene folder")) << e;
  e = err("d.json", R"("environment": {"image": "missing.hdr"})");
  EXPECT_TRUE(contains(e, "d.json:2: environment image 'missing.hdr' does not exist")) << e;
  e = err("e.json", R"("environment": {"image": "outside/sky.exr"})");
  EXPECT_TRUE(contains(e, "e.json:2: cannot read environment image 'outside/sky.exr'")) << e;
  e = err("f.json", "\"sun\": {\"angle_deg\": 1}");
  EXPECT_TRUE(contains(e, "f.json:2: the sun needs a \"direction\"")) << e;
  e = err("g.json", "\"sun\": {\"direction\": [0, 1, 0],\n\"angle_deg\": 100}");
  EXPECT_TRUE(contains(e, "g.json:2: sun angle (angular diameter, degrees) must be in [0.001, 90]")) << e;
  e = err("h.json", "\"sun\": {\"direction\": [0, 1, 0], \"radiance\": 1, \"irradiance\": 1}");
  EXPECT_TRUE(contains(e, "h.json:2: give at most one of \"irradiance\" and \"radiance\"")) << e;
  e = err("i.json", "\"environment\": {\"colour\": [1, 1, 1]}");
  EXPECT_TRUE(contains(e, "i.json:2: unknown key 'colour' (known: color, image, strength, rotation_deg)")) << e;
}

TEST(Lighting, UnlitSceneIsRefusedWithHowToLightIt) {
  TempDir dir;
  const std::string obj = dir.write("dark.obj", kDarkObj);
  std::string msg;
  try {
    load_job_scene(obj);
  } catch (const SceneError& e) {
    msg = e.what();
  }
  EXPECT_TRUE(contains(msg, "has no light")) << msg;
  EXPECT_TRUE(contains(msg, "--env 1,1,1")) << msg;
  EXPECT_TRUE(contains(msg, "--sun")) << msg;
  EXPECT_TRUE(contains(msg, "Ke 10 10 10")) << msg;
  // The job's sky or sun lights it.
  Lighting job;
  job.environment = EnvironmentLight{};
  EXPECT_NO_THROW(load_job_scene(obj, {}, nullptr, job));
  Lighting sun;
  sun.sun = SunLight{};
  EXPECT_NO_THROW(load_job_scene(obj, {}, nullptr, sun));
  // A black sky does not.
  job.environment->color = Vec3(0.f);
  EXPECT_THROW(load_job_scene(obj, {}, nullptr, job), SceneError);
  // A job's image is read inside the scene's folder and recorded with the scene's files.
  write_sky(dir.path("sky.exr"), 4, 2, 1.f);
  Lighting image;
  image.environment = EnvironmentLight{};
  image.environment->image = "sky.exr";
  LoadReport report;
  const Scene s = load_job_scene(obj, {}, &report, image);
  ASSERT_TRUE(s.lighting.environment && s.lighting.environment->pixels);
  EXPECT_EQ(report.files.size(), 2u);
  image.environment->image = "../sky.exr";
  try {
    load_job_scene(obj, {}, nullptr, image);
    ADD_FAILURE() << "an image outside the scene's folder was read";
  } catch (const SceneError& e) {
    EXPECT_TRUE(contains(e.what(), "--env: environment image '../sky.exr' leaves the scene folder")) << e.what();
  }
}

}  // namespace
}  // namespace epr
