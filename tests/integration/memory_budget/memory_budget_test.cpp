// A frame that cannot fit the master's memory budget is refused at submission, over real gRPC on
// loopback, with the memory it would need (master/memory_estimate.h); a fitting one is accepted and
// renders. `epr render` refuses it before it starts anything.
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

#include "master/memory_estimate.h"
#include "tests/server/farm_fixture.h"

namespace epr::test {
namespace {

class MemoryBudgetTest : public FarmFixture {
 protected:
  void SetUp() override {
    FarmFixture::SetUp();
    MasterOptions mo;
    mo.memory_budget_bytes = 256ull << 20;  // 256 MiB
    start(mo);
  }
};

TEST_F(MemoryBudgetTest, AnOversizeFrameIsRefusedWithWhatItNeeds) {
  RenderOptions big = cornell(RenderMode::kSkip, 64, 4, 2);
  big.width = 1024;
  big.height = 1024;
  const auto t0 = std::chrono::steady_clock::now();
  const grpc::Status st = submit(to_job_spec(big, bundle_scene(big.scene), CameraSpec{}));
  EXPECT_LT(std::chrono::steady_clock::now() - t0, std::chrono::seconds(5));  // no setup
  EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  // The fixture's master has a state folder: its checkpoints count.
  const std::string need = format_byte_size(estimate_job_memory(big, /*checkpoints=*/true).total());
  EXPECT_NE(
      st.error_message().find("a 1024x1024 frame at S=4 needs " + need + " of master memory; the budget is 256.00 MiB"),
      std::string::npos)
      << st.error_message();
  // Path tracing needs no subpixel arrays: the same frame fits.
  RenderOptions pt = big;
  pt.mode = RenderMode::kPathTrace;
  std::string pt_id;
  EXPECT_TRUE(submit(to_job_spec(pt, bundle_scene(pt.scene), CameraSpec{}), &pt_id).ok());
}

TEST_F(MemoryBudgetTest, AFittingFrameIsAcceptedAndRenders) {
  const RenderOptions small = cornell(RenderMode::kSkip, 64, 4, 2);
  ASSERT_LT(estimate_job_memory(small, true).total(), 256ull << 20);
  std::string id;
  const grpc::Status st = submit(to_job_spec(small, bundle_scene(small.scene), CameraSpec{}), &id);
  ASSERT_TRUE(st.ok()) << st.error_message();
  RunningNode node(node_options("w", 1));
  EXPECT_EQ(wait_done(id).state(), v1::JOB_STATE_DONE);
  expect_same_as_local(id, small);  // and the batched reprojection gives the single-process image
}

#ifdef EPR_CLIENT_BIN
// Peak RSS (bytes) of `epr render` with these arguments, run to completion (wait4's rusage).
uint64_t render_peak_rss(const std::vector<std::string>& args) {
  std::vector<char*> argv;
  std::string bin = EPR_CLIENT_BIN;
  argv.push_back(bin.data());
  std::vector<std::string> copy = args;
  for (std::string& a : copy) argv.push_back(a.data());
  argv.push_back(nullptr);
  const pid_t pid = fork();
  if (pid == 0) {
    if (std::freopen("/dev/null", "w", stdout) == nullptr || std::freopen("/dev/null", "w", stderr) == nullptr)
      _exit(126);
    execv(argv[0], argv.data());
    _exit(127);
  }
  int status = 0;
  struct rusage ru {};
  if (pid < 0 || wait4(pid, &status, 0, &ru) != pid || !WIFEXITED(status) || WEXITSTATUS(status) != 0) return 0;
  return uint64_t(ru.ru_maxrss) * 1024;
}

// The estimate follows what a job really costs: two renders of different frame sizes in the embedded
// master (and worker), the estimate's difference within 0.8x..1.5x of the measured peaks' difference
// (what both share -- the process, the scene, the worker -- cancels).
TEST(MemoryBudgetRender, TheEstimateIsNearAMeasuredPeak) {
  const std::string out = (std::filesystem::temp_directory_path() / "epr-memory-estimate-test").string();
  auto peak = [&](int w, int h) {
    return render_peak_rss({"render",
                            "builtin:cornell",
                            "--width",
                            std::to_string(w),
                            "--height",
                            std::to_string(h),
                            "--spp",
                            "2",
                            "--paths-per-round",
                            "1",
                            "--max-depth",
                            "4",
                            "--mode",
                            "skip",
                            "--reproject",
                            "cpu",
                            "--threads",
                            "2",
                            "--http",
                            "",
                            "--out",
                            out});
  };
  auto estimate = [](int w, int h) {
    RenderOptions o;
    o.width = w;
    o.height = h;
    o.subpixels = 4;
    o.mode = RenderMode::kSkip;
    return estimate_job_memory(o, /*checkpoints=*/true).total();
  };
  const uint64_t small = peak(128, 72), big = peak(1280, 720);
  ASSERT_GT(small, 0u) << "epr render failed";
  ASSERT_GT(big, small);
  const double measured = double(big - small), estimated = double(estimate(1280, 720) - estimate(128, 72));
  std::printf("1280x720 against 128x72: measured %.1f MiB, estimated %.1f MiB\n", measured / (1 << 20),
              estimated / (1 << 20));
  RecordProperty("measured_mib", int(measured / (1 << 20)));
  RecordProperty("estimated_mib", int(estimated / (1 << 20)));
  EXPECT_GE(estimated, 0.8 * measured) << "measured " << measured / (1 << 20) << " MiB";
  EXPECT_LE(estimated, 1.5 * measured) << "measured " << measured / (1 << 20) << " MiB";
  for (const char* suffix :
       {".exr", ".png", ".json", ".pathtrace.exr", ".counts.exr", ".reprojection.exr", ".samples.exr", ".samples.png"})
    std::filesystem::remove(out + suffix);
}

TEST(MemoryBudgetRender, EprRenderRefusesBeforeItStarts) {
  const std::string cmd = std::string(EPR_CLIENT_BIN) +
                          " render builtin:cornell --width 4096 --height 4096 --spp 4 --mode skip --reproject cpu "
                          "--memory-budget 1G --out /tmp/epr-memory-budget-test 2>&1";
  const auto t0 = std::chrono::steady_clock::now();
  FILE* p = popen(cmd.c_str(), "r");
  ASSERT_NE(p, nullptr);
  std::string out;
  char buf[512];
  while (size_t n = fread(buf, 1, sizeof buf, p)) out.append(buf, n);
  const int status = pclose(p);
  EXPECT_LT(std::chrono::steady_clock::now() - t0, std::chrono::seconds(10));
  EXPECT_EQ(WEXITSTATUS(status), 2) << out;
  EXPECT_NE(out.find("a 4096x4096 frame at S=4 needs"), std::string::npos) << out;
  EXPECT_NE(out.find("the budget is 1.00 GiB"), std::string::npos) << out;
  EXPECT_EQ(out.find("master on"), std::string::npos) << out;  // nothing started
}
#endif

TEST(MemoryEstimate, ParsesSizesAndCountsTheSubpixels) {
  EXPECT_EQ(parse_byte_size("8G"), 8ull << 30);
  EXPECT_EQ(parse_byte_size("512MiB"), 512ull << 20);
  EXPECT_EQ(parse_byte_size("1.5g"), 3ull << 29);
  EXPECT_EQ(parse_byte_size("100000"), 100000u);
  EXPECT_FALSE(parse_byte_size("8X"));
  EXPECT_FALSE(parse_byte_size("G"));
  EXPECT_FALSE(parse_byte_size("0"));
  EXPECT_EQ(format_byte_size(3ull << 29), "1.50 GiB");
  EXPECT_EQ(format_byte_size(256ull << 20), "256.00 MiB");
  EXPECT_EQ(format_byte_size(1536), "1.50 KiB");
  EXPECT_EQ(format_byte_size(100), "100 bytes");
  // A small budget shows its figure, not "0.00 GiB".
  RenderOptions small;
  small.width = 64;
  small.height = 64;
  small.subpixels = 4;
  small.mode = RenderMode::kSkip;
  const std::optional<std::string> refusal = memory_budget_error(small, false, 64 << 10);
  ASSERT_TRUE(refusal);
  EXPECT_NE(refusal->find("needs " + format_byte_size(estimate_job_memory(small, false).total())), std::string::npos)
      << *refusal;
  EXPECT_NE(refusal->find("the budget is 64.00 KiB"), std::string::npos) << *refusal;
  EXPECT_EQ(refusal->find("0.00 GiB"), std::string::npos) << *refusal;
  RenderOptions o;
  o.width = 1920;
  o.height = 1080;
  o.subpixels = 4;
  o.mode = RenderMode::kSkip;
  const MemoryEstimate e = estimate_job_memory(o, false);
  EXPECT_EQ(e.subpixel_bytes, 1920ull * 1080 * 16 * 18);
  EXPECT_EQ(e.build_bytes, 1920ull * 1080 * 16 * kBuildIndexBytesPerTexel + kBuildBandBytes);
  EXPECT_EQ(e.queue_bytes, kCommitQueueBytes);  // a 1080p round fills the commit queue
  // The rounds, not the build, set the peak.
  EXPECT_EQ(e.total(), e.subpixel_bytes + e.pixel_bytes + e.queue_bytes);
  EXPECT_EQ(e.checkpoint_bytes, 0u);
  EXPECT_GT(estimate_job_memory(o, true).total(), e.total());
  o.mode = RenderMode::kPathTrace;
  EXPECT_EQ(estimate_job_memory(o, false).subpixel_bytes, 0u);
  EXPECT_GT(physical_memory_bytes(), 0u);
}

}  // namespace
}  // namespace epr::test
