// A frame that cannot fit the master's memory budget is refused at submission, over real gRPC on
// loopback, with the memory it would need (master/memory_estimate.h); a fitting one is accepted and
// renders. `epr render` refuses it before it starts anything.
#include <chrono>
#include <cstdio>
#include <string>

#include "master/memory_estimate.h"
#include "tests/server/farm_fixture.h"

namespace epr::test {
namespace {

class MemoryBudgetTest : public FarmFixture {
 protected:
  void SetUp() override {
    FarmFixture::SetUp();
    MasterOptions mo;
    mo.memory_budget_bytes = 256ull << 20;  // 0.25 GiB
    start(mo);
  }
};

TEST_F(MemoryBudgetTest, AnOversizeFrameIsRefusedWithWhatItNeeds) {
  RenderOptions big = cornell(RenderMode::kSkip, 64, 4, 2);
  big.width = 512;
  big.height = 512;
  const auto t0 = std::chrono::steady_clock::now();
  const grpc::Status st = submit(to_job_spec(big, bundle_scene(big.scene), CameraSpec{}));
  EXPECT_LT(std::chrono::steady_clock::now() - t0, std::chrono::seconds(5));  // no setup
  EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  // The fixture's master has a state folder: its checkpoints count.
  const std::string need = format_gib(estimate_job_memory(big, /*checkpoints=*/true).total());
  EXPECT_NE(
      st.error_message().find("a 512x512 frame at S=4 needs " + need + " of master memory; the budget is 0.25 GiB"),
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
  RenderOptions o;
  o.width = 1920;
  o.height = 1080;
  o.subpixels = 4;
  o.mode = RenderMode::kSkip;
  const MemoryEstimate e = estimate_job_memory(o, false);
  EXPECT_EQ(e.subpixel_bytes, 1920ull * 1080 * 16 * 20);
  EXPECT_EQ(e.checkpoint_bytes, 0u);
  EXPECT_GT(estimate_job_memory(o, true).total(), e.total());
  o.mode = RenderMode::kPathTrace;
  EXPECT_EQ(estimate_job_memory(o, false).subpixel_bytes, 0u);
  EXPECT_GT(physical_memory_bytes(), 0u);
}

}  // namespace
}  // namespace epr::test
