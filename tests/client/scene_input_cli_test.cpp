// Scene input through the real `epr` binary (issue 16): a scene's warnings are printed once, naming
// the user's file; an unlit scene is refused before anything renders, saying how to light it; FIFOs,
// devices and directories named as scene files fail at once; a texture whose name has blanks renders
// through the embedded cluster (which bundles the scene) as it does in a single process; so does a
// built-in scene under an `--env` image.
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <nlohmann/json.hpp>
#include <string>

#include "common/image.h"
#include "tests/common/scene_test_files.h"

namespace epr {
namespace {

namespace fs = std::filesystem;
using test::TempDir;

// The `epr` executable: $EPR_BIN, else client/epr beside the test binary's tests/ folder.
std::string epr_binary() {
  if (const char* env = std::getenv("EPR_BIN"); env && *env) return env;
  return (fs::read_symlink("/proc/self/exe").parent_path().parent_path() / "client" / "epr").string();
}

struct EprRun {
  int exit_code = -1;
  std::string output;  // stdout and stderr
};

/// Runs `epr ARGS` in `cwd` with its scene cache below `cwd`/cache (shell quoting is the caller's).
EprRun run_epr(const std::string& cwd, const std::string& args) {
  const std::string cmd =
      "cd '" + cwd + "' && EPR_CACHE_DIR='" + cwd + "/cache' '" + epr_binary() + "' " + args + " 2>&1 </dev/null";
  EprRun r;
  FILE* p = ::popen(cmd.c_str(), "r");
  if (!p) return r;
  std::array<char, 4096> buf;
  size_t n;
  while ((n = std::fread(buf.data(), 1, buf.size(), p)) > 0) r.output.append(buf.data(), n);
  const int status = ::pclose(p);
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

size_t count(const std::string& text, const std::string& part) {
  size_t n = 0;
  for (size_t p = text.find(part); p != std::string::npos; p = text.find(part, p + 1)) ++n;
  return n;
}

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

// A wall (material `wall`) under a glowing ceiling (material `glow`), in the default camera's view.
const std::string kRoom =
    "v -1 0 -1\nv 1 0 -1\nv 1 2 -1\nv -1 2 -1\nv -1 2 1\nv 1 2 1\n"
    "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
    "usemtl wall\nf 1/1 2/2 3/3 4/4\nusemtl glow\nf 4 3 6 5\n";
const std::string kFast = " --width 16 --height 16 --spp 2 --mode pt";

class SceneInputCli : public ::testing::Test {
 protected:
  void SetUp() override { ASSERT_TRUE(fs::exists(epr_binary())) << "epr not found at " << epr_binary(); }
  TempDir dir;
};

// The master and the worker load the scene again from their caches: only the client's load shows
// its warnings, once, naming the file as the user named it.
TEST_F(SceneInputCli, RenderPrintsEachWarningOnceNamingTheUsersFile) {
  dir.write("scene/m.mtl", "newmtl wall\nKd 0.5 0.5 0.5\nnewmtl glow\nKd 0 0 0\nKe 5 5 5\n");
  dir.write("scene/w.obj", "mtllib m.mtl\n" + kRoom + "curv 0 1 2\n");
  for (const std::string mode : {"", " --single-process"}) {
    SCOPED_TRACE(mode);
    const EprRun r = run_epr(dir.path(""), "render scene/w.obj" + mode + kFast + " --out out/w");
    ASSERT_EQ(r.exit_code, 0) << r.output;
    EXPECT_EQ(count(r.output, "unsupported statement 'curv' ignored"), 1u) << r.output;
    EXPECT_TRUE(contains(r.output, "scene/w.obj:16: unsupported statement 'curv' ignored")) << r.output;
    EXPECT_FALSE(contains(r.output, "/scenes/")) << "a cache path is named:\n" << r.output;
  }
}

// No emitter: refused by `render` (embedded and single-process) and by `submit` before it connects.
TEST_F(SceneInputCli, UnlitSceneIsRefusedSayingHowToLightIt) {
  dir.write("m.mtl", "newmtl wall\nKd 0.5 0.5 0.5\nnewmtl glow\nKd 0.8 0.8 0.8\nKe 0 0 0\n");
  dir.write("dark.obj", "mtllib m.mtl\n" + kRoom);
  for (const std::string& args :
       {"render dark.obj" + kFast + " --out out/a", "render --single-process dark.obj" + kFast + " --out out/b",
        std::string("submit --master 127.0.0.1:1 dark.obj")}) {
    SCOPED_TRACE(args);
    const EprRun r = run_epr(dir.path(""), args);
    EXPECT_NE(r.exit_code, 0) << r.output;
    EXPECT_TRUE(contains(r.output, "dark.obj has no light: no material has an emission (Ke)")) << r.output;
    EXPECT_TRUE(contains(r.output, "Ke 10 10 10")) << r.output;
    EXPECT_FALSE(contains(r.output, "master on ")) << "refused before a master started: " << r.output;
  }
  EXPECT_FALSE(fs::exists(dir.path("out/a.exr")));
  EXPECT_FALSE(fs::exists(dir.path("out/b.exr")));
}

// Each fails at once naming the file (a FIFO once blocked the bundler, /dev/zero filled memory).
TEST_F(SceneInputCli, FifosDevicesAndDirectoriesFailAtOnce) {
  ASSERT_EQ(::mkfifo(dir.path("pipe.obj").c_str(), 0600), 0);
  ASSERT_EQ(::mkfifo(dir.path("pipe.png").c_str(), 0600), 0);
  fs::create_directories(dir.path("x.obj"));
  dir.write("t.mtl", "newmtl wall\nmap_Kd pipe.png\nnewmtl glow\nKe 5 5 5\n");
  dir.write("t.obj", "mtllib t.mtl\n" + kRoom);
  const struct {
    std::string scene, expect;
  } cases[] = {{"pipe.obj", "pipe.obj: is a FIFO (named pipe), not a regular file"},
               {"t.obj", "t.mtl:2: texture 'pipe.png' is a FIFO"},
               {"x.obj", "x.obj: is a directory"},
               {"/dev/zero", "/dev/zero: is a character device, not a regular file"}};
  for (const auto& c : cases)
    for (const std::string mode : {"", " --single-process"}) {
      SCOPED_TRACE(c.scene + mode);
      const EprRun r = run_epr(dir.path(""), "render " + c.scene + mode + kFast + " --out out/f");
      EXPECT_NE(r.exit_code, 0) << r.output;
      EXPECT_TRUE(contains(r.output, c.expect)) << r.output;
    }
}

// `map_Kd -s 1 1 1 tex/my texture.png`: the single-process render reads the file itself, the embedded
// cluster gets it in the bundle; both images are the same, bit for bit.
TEST_F(SceneInputCli, TextureNameWithBlanksRendersTheSameThroughTheCluster) {
  Image tex(8, 8, 3);
  for (int y = 0; y < 8; ++y)
    for (int x = 0; x < 8; ++x) tex.set_rgb(x, y, (x + y) % 2 ? Vec3(0.9f, 0.2f, 0.1f) : Vec3(0.1f, 0.3f, 0.9f));
  fs::create_directories(dir.path("scene/tex"));
  write_png_srgb(dir.path("scene/tex/my texture.png"), tex);
  dir.write("scene/m.mtl", "newmtl wall\nmap_Kd -s 1 1 1 tex/my texture.png\nnewmtl glow\nKd 0 0 0\nKe 5 5 5\n");
  dir.write("scene/room.obj", "mtllib m.mtl\n" + kRoom);
  const std::string flags = " --width 24 --height 24 --spp 4 --mode pt --seed 3 --threads 2";
  const EprRun local = run_epr(dir.path(""), "render --single-process scene/room.obj" + flags + " --out out/local");
  ASSERT_EQ(local.exit_code, 0) << local.output;
  const EprRun cluster = run_epr(dir.path(""), "render scene/room.obj" + flags + " --out out/cluster");
  ASSERT_EQ(cluster.exit_code, 0) << cluster.output;
  const Image a = read_image(dir.path("out/local.exr")), b = read_image(dir.path("out/cluster.exr"));
  ASSERT_EQ(a.width, b.width);
  ASSERT_EQ(a.height, b.height);
  EXPECT_TRUE(a.data == b.data) << "the cluster's image differs from the single-process one";
  double sum = 0;
  for (float v : a.data) sum += v;
  EXPECT_GT(sum, 0.0) << "the room is lit";
}

double mean(const Image& img) {
  double sum = 0;
  for (float v : img.data) sum += v;
  return sum / double(img.data.size());
}

// A room without a ceiling and without emitters, lit by `--env`: through the embedded cluster the
// environment image travels in the scene's bundle and renders as in a single process, bit for bit;
// skip mode, which reprojects the sky-lit vertices, agrees with path tracing within the noise.
TEST_F(SceneInputCli, SkyLitSceneRendersThroughTheClusterAndInSkipMode) {
  dir.write("scene/m.mtl", "newmtl wall\nKd 0.6 0.6 0.6\nnewmtl glow\nKd 0.8 0.8 0.8\n");
  dir.write("scene/room.obj",
            "mtllib m.mtl\nv -1 0 -1\nv 1 0 -1\nv 1 2 -1\nv -1 2 -1\nv -1 0 1\nv 1 0 1\nv -1 2 1\nv 1 2 1\n"
            "usemtl wall\nf 1 2 3 4\nf 5 1 4 7\nusemtl glow\nf 1 5 6 2\nf 2 6 8 3\n");
  Image sky(16, 8, 3);
  for (int y = 0; y < 8; ++y)
    for (int x = 0; x < 16; ++x) sky.set_rgb(x, y, y < 4 ? Vec3(0.5f + 0.2f * float(x % 4), 0.8f, 1.2f) : Vec3(0.2f));
  fs::create_directories(dir.path("scene/skies"));
  write_exr(dir.path("scene/skies/sky.exr"), sky);
  const std::string flags = " --width 24 --height 24 --spp 4 --mode pt --seed 3 --threads 2";
  const std::string env = " --env scene/skies/sky.exr --sun 1,2,1,2,3";
  const EprRun local =
      run_epr(dir.path(""), "render --single-process scene/room.obj" + env + flags + " --out out/local");
  ASSERT_EQ(local.exit_code, 0) << local.output;
  const EprRun cluster = run_epr(dir.path(""), "render scene/room.obj" + env + flags + " --out out/cluster");
  ASSERT_EQ(cluster.exit_code, 0) << cluster.output;
  const Image a = read_image(dir.path("out/local.exr")), b = read_image(dir.path("out/cluster.exr"));
  ASSERT_EQ(a.data.size(), b.data.size());
  EXPECT_TRUE(a.data == b.data) << "the cluster's image differs from the single-process one";
  EXPECT_GT(mean(a), 0.1) << "the sky lights the room";

  // The mean radiance of the image in pt and in skip mode (most samples reprojected).
  const std::string big = " --width 48 --height 48 --spp 32 --seed 5 --threads 2 --env 1,1,1";
  const EprRun pt = run_epr(dir.path(""), "render scene/room.obj --mode pt" + big + " --out out/pt");
  ASSERT_EQ(pt.exit_code, 0) << pt.output;
  const EprRun skip = run_epr(dir.path(""), "render scene/room.obj --mode skip" + big + " --out out/skip");
  ASSERT_EQ(skip.exit_code, 0) << skip.output;
  const double m_pt = mean(read_image(dir.path("out/pt.exr"))), m_skip = mean(read_image(dir.path("out/skip.exr")));
  EXPECT_NEAR(m_skip, m_pt, 0.02 * m_pt) << "skip " << m_skip << " pt " << m_pt;
  std::ifstream stats(dir.path("out/skip.json"));
  const auto json = nlohmann::json::parse(stats);
  EXPECT_GT(json.at("mean_reprojected_per_pixel").get<double>(), 1.0) << "skip mode reprojected the sky-lit vertices";
  // Without the sky the room is refused as unlit, naming the flags that light it.
  const EprRun dark = run_epr(dir.path(""), "render scene/room.obj" + kFast + " --out out/dark");
  EXPECT_NE(dark.exit_code, 0);
  EXPECT_TRUE(contains(dark.output, "--env 1,1,1")) << dark.output;
}

// `--env FILE` with a built-in scene: the image lies anywhere (a built-in has no folder); the single
// process reads it there, the embedded cluster gets it in the scene's bundle, and the two images are
// the same, bit for bit. Seen from afar, the box's surroundings show the sky. A missing file is
// refused before anything renders, naming it.
TEST_F(SceneInputCli, BuiltInSceneRendersUnderAnEnvImage) {
  const Vec3 blue(0.2f, 0.4f, 0.8f);
  Image sky(16, 8, 3);
  for (int y = 0; y < 8; ++y)
    for (int x = 0; x < 16; ++x) sky.set_rgb(x, y, blue);
  fs::create_directories(dir.path("skies"));
  write_exr(dir.path("skies/blue.exr"), sky);
  const std::string flags =
      " --width 24 --height 24 --spp 4 --mode pt --seed 3 --threads 2 --eye 0,1,9 --sun 1,2,3,2,0.5";
  const EprRun local = run_epr(
      dir.path(""), "render --single-process builtin:cornell --env skies/blue.exr" + flags + " --out out/local");
  ASSERT_EQ(local.exit_code, 0) << local.output;
  const EprRun cluster =
      run_epr(dir.path(""), "render builtin:cornell --env skies/blue.exr" + flags + " --out out/cluster");
  ASSERT_EQ(cluster.exit_code, 0) << cluster.output;
  const Image a = read_image(dir.path("out/local.exr")), b = read_image(dir.path("out/cluster.exr"));
  ASSERT_EQ(a.data.size(), b.data.size());
  EXPECT_TRUE(a.data == b.data) << "the cluster's image differs from the single-process one";
  // The top-left corner looks past the box: the sky's radiance, whatever the samples.
  const Vec3 corner = a.rgb(0, 0);
  EXPECT_NEAR(corner.x, blue.x, 1e-5f);
  EXPECT_NEAR(corner.y, blue.y, 1e-5f);
  EXPECT_NEAR(corner.z, blue.z, 1e-5f);

  for (const std::string cmd : {"render --single-process", "render", "submit --master 127.0.0.1:1"}) {
    const EprRun missing =
        run_epr(dir.path(""), cmd + " builtin:cornell --env skies/none.exr" + kFast + " --out out/m");
    EXPECT_NE(missing.exit_code, 0) << cmd;
    EXPECT_TRUE(contains(missing.output, "--env: 'skies/none.exr' is not a readable file"))
        << cmd << ": " << missing.output;
  }
}

// The shipped glTF Cornell box with its first position at 1e25 (issue "Step 14"): every command
// refuses it naming the file and the element, before anything renders; nothing aborts (rc 134 was
// Embree's assertion on the worker).
TEST_F(SceneInputCli, GltfVertexBeyondTheLimitIsRefusedByEveryCommand) {
  const fs::path src = fs::path(EPR_SOURCE_DIR) / "scenes";
  dir.write("far/cornell-box.gltf", "");
  fs::copy_file(src / "cornell-box.gltf", dir.path("far/cornell-box.gltf"), fs::copy_options::overwrite_existing);
  std::ifstream in(src / "cornell-box.bin", std::ios::binary);
  std::string bin((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  ASSERT_GE(bin.size(), 4u);
  const float far = 1e25f;
  std::memcpy(bin.data(), &far, 4);  // meshes[0].primitives[0]'s POSITION is accessors[0], bytes 0..47
  dir.write("far/cornell-box.bin", bin);
  for (const std::string cmd : {"render --mode skip", "render --mode pt", "render --single-process --mode skip",
                                "submit --master 127.0.0.1:1"}) {
    const EprRun r = run_epr(dir.path(""), cmd + " far/cornell-box.gltf --width 16 --height 16 --spp 2 --out out/far");
    EXPECT_NE(r.exit_code, 0) << cmd << ": " << r.output;
    EXPECT_NE(r.exit_code, 134) << cmd << ": " << r.output;
    if (cmd.rfind("render", 0) == 0) {
      EXPECT_EQ(r.exit_code, 1) << cmd << ": " << r.output;
    }
    EXPECT_TRUE(contains(r.output,
                         "far/cornell-box.gltf: meshes[0].primitives[0]: POSITION accessors[0] element 0 "
                         "(1e+25, 0, 0.99) exceeds the magnitude limit 1e+08 (metres)"))
        << cmd << ": " << r.output;
    EXPECT_FALSE(fs::exists(dir.path("out/far.exr"))) << cmd;
  }
}

}  // namespace
}  // namespace epr
