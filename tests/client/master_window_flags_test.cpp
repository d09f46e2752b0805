// epr-master's frame-window flags (--window-run-wait, --window-cut-share; ranges in common/limits.h)
// on the built executable: listed by --help, a value out of range refused naming the range, and a
// short --window-run-wait starting an incomplete run (two of its three frames, sent over gRPC by
// JobClient) after that wait, which the master's log names.
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <string>

#include "client/job_client.h"
#include "epr/v1/job_service.pb.h"
#include "tests/integration/cluster/process.h"

namespace epr {
namespace master_window_flags_test {
namespace {
namespace fs = std::filesystem;
using namespace std::chrono_literals;

class MasterWindowFlags : public ::testing::Test {
 protected:
  void SetUp() override {
    bin_ = testing::binary("master", "epr-master");
    ASSERT_TRUE(fs::exists(bin_)) << bin_ << " not built";
    dir_ = fs::temp_directory_path() / ("epr-window-flags-" + std::to_string(::getpid()) + "-" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  testing::RunResult run(std::vector<std::string> args) {
    args.insert(args.begin(), bin_);
    return testing::run_process(args, dir_ / "run", 60s);
  }
  std::string bin_;
  fs::path dir_;
};

TEST_F(MasterWindowFlags, HelpListsThemAndOutOfRangeValuesAreRefusedWithTheRange) {
  const testing::RunResult help = run({"--help"});
  EXPECT_EQ(help.code, 0);
  EXPECT_NE(help.out.find("--window-run-wait"), std::string::npos) << help.out;
  EXPECT_NE(help.out.find("--window-cut-share"), std::string::npos) << help.out;
  const testing::RunResult wait = run({"--window-run-wait", "100000"});
  EXPECT_NE(wait.code, 0);
  EXPECT_NE((wait.out + wait.err).find("--window-run-wait 100000 must be between 0 and 86400"), std::string::npos)
      << wait.out << wait.err;
  const testing::RunResult share = run({"--window-cut-share", "1.5"});
  EXPECT_NE(share.code, 0);
  EXPECT_NE((share.out + share.err).find("--window-cut-share 1.5 must be between 0 and 1"), std::string::npos)
      << share.out << share.err;
  const testing::RunResult word = run({"--window-run-wait", "soon"});
  EXPECT_NE(word.code, 0);
  EXPECT_NE((word.out + word.err).find("expected a number, got 'soon'"), std::string::npos) << word.out << word.err;
}

TEST_F(MasterWindowFlags, AShortRunWaitStartsAnIncompleteRunAfterIt) {
  testing::Process master({bin_, "--listen", "127.0.0.1:0", "--http", "", "--reproject", "cpu", "--state-dir",
                           (dir_ / "state").string(), "--window-run-wait", "1.5"},
                          dir_ / "master");
  const int port = testing::listening_port(master, 60s);
  ASSERT_GT(port, 0) << master.err();
  auto log = [&] { return master.out() + master.err(); };
  EXPECT_NE(log().find("window runs: wait 1.5 s for their frames"), std::string::npos) << log();
  JobClient client("127.0.0.1:" + std::to_string(port));
  RenderOptions o;
  o.scene = "builtin:cornell";
  o.width = o.height = 32;
  o.spp = 4;
  o.tile_size = 16;
  o.mode = RenderMode::kSkip;
  o.reproject = ReprojectMethod::kCpu;
  std::vector<std::string> ids;
  for (uint32_t frame : {1u, 2u}) {  // frame 3 of the run never comes
    v1::JobSpec spec = client.make_job_spec(o);
    spec.set_batch_id("flags");
    spec.set_frame(frame);
    spec.set_batch_frames(3);
    spec.set_frame_window(1);
    spec.set_window_first(1);
    spec.set_window_last(3);
    spec.set_seed(frame);
    ids.push_back(client.submit(spec));
  }
  // No worker: the frames start (RUNNING) and stay so. The log names the wait it gave them.
  EXPECT_TRUE(testing::wait_until(
      [&] {
        for (const auto& id : ids)
          if (client.get(id).state() != v1::JOB_STATE_RUNNING) return false;
        return true;
      },
      120s));
  EXPECT_TRUE(testing::wait_until([&] { return log().find("did not come within 1.5 s") != std::string::npos; }, 60s))
      << log();
  master.stop();
}

}  // namespace
}  // namespace master_window_flags_test
}  // namespace epr
