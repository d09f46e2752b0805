// The reprojected-sample weight W (--reprojected-weight, DESIGN.md "The subpixel deep framebuffer,
// L_rp and M'"): a skip render with W < 1 traces more of its own paths than with W = 1, every pixel
// stops only once M + W M' >= P, and W outside (0, 1] is refused by `epr render` with the reason.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cstdio>
#include <filesystem>
#include <string>

#include "client/local_render.h"
#include "client/render_flags.h"
#include "wire/convert.h"

namespace epr {
namespace {

namespace fs = std::filesystem;

RenderOptions skip_job(float weight) {
  RenderOptions o;
  o.scene = "builtin:cornell";
  o.width = o.height = 32;
  o.spp = 16;
  o.mode = RenderMode::kSkip;
  o.reprojected_weight = weight;
  return o;
}

uint64_t paths_traced(const RenderOutputs& out) { return out.stats.at("paths_traced").get<uint64_t>(); }

TEST(ReprojectedWeight, ALowerWeightTracesMorePathsAndEveryPixelReachesTheWeightedTarget) {
  const RenderOutputs one = render_local(skip_job(1.f));
  const RenderOptions o = skip_job(0.25f);
  const RenderOutputs quarter = render_local(o);
  EXPECT_GT(paths_traced(quarter), paths_traced(one) * 5 / 4) << "W = 0.25 must trace clearly more of its own paths";
  EXPECT_LT(paths_traced(quarter), uint64_t(o.spp) * o.width * o.height) << "W = 0.25 must still skip";
  EXPECT_EQ(quarter.stats.at("reprojected_weight").get<float>(), 0.25f);
  double sum_weighted = 0;
  for (int y = 0; y < o.height; ++y)
    for (int x = 0; x < o.width; ++x) {
      const double m = quarter.path_count.at(x, y)[0], mp = quarter.mprime.at(x, y)[0];
      ASSERT_TRUE(m + 0.25 * mp >= o.spp || m == o.spp) << x << "," << y << ": M " << m << ", M' " << mp;
      sum_weighted += m + 0.25 * mp;
    }
  // mean_spp counts samples as the skip rule does.
  EXPECT_NEAR(quarter.stats.at("mean_spp").get<double>(), sum_weighted / (o.width * o.height), 1e-6 * sum_weighted);
  // The combined image is (sum + W M' L_rp) / (M + W M'), pixel by pixel.
  int checked = 0;
  for (int y = 0; y < o.height; y += 5)
    for (int x = 0; x < o.width; x += 5) {
      const double m = quarter.path_count.at(x, y)[0], mp = quarter.mprime.at(x, y)[0];
      const double pt = quarter.pathtrace.at(x, y)[0], rp = quarter.reprojection.at(x, y)[0];
      const double want = (m * pt + 0.25 * mp * rp) / (m + 0.25 * mp);
      EXPECT_NEAR(quarter.combined.at(x, y)[0], want, 1e-4 * std::max(1.0, want)) << x << "," << y;
      checked += mp > 0;
    }
  EXPECT_GT(checked, 10);
}

TEST(ReprojectedWeight, TheFlagSetsTheOption) {
  CLI::App app;
  RenderOptions o;
  std::map<std::string, std::string> extra;
  add_render_flags(&app, o, extra, RenderFlagSet::kRemote);
  app.parse(std::vector<std::string>{"0.75", "--reprojected-weight", "builtin:cornell"});  // reversed
  finish_options(o, extra);
  EXPECT_EQ(o.reprojected_weight, 0.75f);
  EXPECT_EQ(RenderOptions{}.reprojected_weight, 0.5f);
}

// A job spec carries W; one without the field (written before it existed) means W = 1, whatever the
// default of new jobs.
TEST(ReprojectedWeight, TheJobSpecCarriesItAndUnsetMeansOne) {
  RenderOptions o = skip_job(0.75f);
  v1::JobSpec spec = to_job_spec(o, SceneBundleData{}, CameraSpec{});
  RenderOptions back;
  CameraSpec camera;
  ASSERT_EQ(from_job_spec(spec, &back, &camera), std::nullopt);
  EXPECT_EQ(back.reprojected_weight, 0.75f);
  spec.mutable_reprojection()->clear_reprojected_weight();
  ASSERT_EQ(from_job_spec(spec, &back, &camera), std::nullopt);
  EXPECT_EQ(back.reprojected_weight, 1.f);
}

// `epr render` beside this test binary's tests/ folder, with its output and exit code.
std::pair<int, std::string> run_epr(const std::string& args) {
  const fs::path epr = fs::read_symlink("/proc/self/exe").parent_path().parent_path() / "client" / "epr";
  const fs::path dir = fs::temp_directory_path() / ("epr_rw_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  const std::string cmd = "cd '" + dir.string() + "' && '" + epr.string() + "' " + args + " 2>&1 </dev/null";
  std::string out;
  FILE* p = ::popen(cmd.c_str(), "r");
  if (!p) return {-1, ""};
  std::array<char, 4096> buf;
  size_t n;
  while ((n = std::fread(buf.data(), 1, buf.size(), p)) > 0) out.append(buf.data(), n);
  const int status = ::pclose(p);
  fs::remove_all(dir);
  return {WIFEXITED(status) ? WEXITSTATUS(status) : -1, out};
}

TEST(ReprojectedWeight, EprRenderRefusesAWeightOutsideZeroToOne) {
  for (const std::string w : {"0", "1.5"}) {
    const auto [code, out] = run_epr("render builtin:cornell --width 16 --height 16 --spp 4 --reprojected-weight " + w);
    EXPECT_EQ(code, 2) << w << ": " << out;
    EXPECT_NE(out.find("--reprojected-weight " + w + " must be in (0, 1]"), std::string::npos) << out;
  }
}

}  // namespace
}  // namespace epr
