// The programs under careless or hostile use, run as the built epr, epr-master and epr-worker
// processes (tests/integration/cluster/process.h): permanent refusals end a process with the reason
// instead of retrying forever; one master per state directory; a corrupt epoch file is reported;
// a killed `epr render` leaves no state folder behind (the next run clears what SIGKILL left); an
// unwritable HOME, a large scene and a time limit are handled; bad output prefixes are refused.
// Children get a private TMPDIR (through /usr/bin/env, leaving this process's environment alone).
#include <gtest/gtest.h>
#include <signal.h>

#include <filesystem>

#include "tests/client/large_obj.h"
#include "tests/integration/cluster/process.h"

namespace epr {
namespace {
namespace fs = std::filesystem;
using namespace std::chrono_literals;
using testing::binary;
using testing::Process;
using testing::run_process;
using testing::RunResult;

const std::string kCornellObj = EPR_SOURCE_DIR "/scenes/cornell-box/CornellBox-Original.obj";

class ProcessHardening : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("epr-hardening-" + std::to_string(::getpid()) + "-" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_ / "tmp");
    for (const char* b : {"client/epr", "master/epr-master", "worker/epr-worker"}) {
      const fs::path p = binary(fs::path(b).parent_path().c_str(), fs::path(b).filename().c_str());
      ASSERT_TRUE(fs::exists(p)) << p << " not built";
    }
  }
  void TearDown() override { fs::remove_all(dir_); }

  // argv run through env with TMPDIR (and `env`, e.g. "HOME=/dev/null") set for the child, and no
  // cache folder of the caller's.
  std::vector<std::string> with_env(std::vector<std::string> argv, std::vector<std::string> env = {}) const {
    std::vector<std::string> out{
        "/usr/bin/env", "-u", "XDG_CACHE_HOME", "-u", "EPR_CACHE_DIR", "TMPDIR=" + (dir_ / "tmp").string()};
    out.insert(out.end(), env.begin(), env.end());
    out.insert(out.end(), argv.begin(), argv.end());
    return out;
  }
  std::vector<std::string> epr(std::vector<std::string> args) const {
    args.insert(args.begin(), binary("client", "epr"));
    return args;
  }
  RunResult run(const std::vector<std::string>& argv, const std::string& log,
                std::chrono::milliseconds timeout = 120s) {
    return run_process(argv, dir_ / log, timeout);
  }
  // A master on a free port; its port once it listens (0 if it did not come up).
  int start_master(std::unique_ptr<Process>& p, const std::string& log, std::vector<std::string> args = {}) {
    std::vector<std::string> argv{binary("master", "epr-master"), "--listen", "127.0.0.1:0", "--http", ""};
    argv.insert(argv.end(), args.begin(), args.end());
    p = std::make_unique<Process>(with_env(argv), dir_ / log);
    return testing::listening_port(*p, 60s);
  }
  // The private state folders of `epr render` processes in the children's TMPDIR.
  std::vector<fs::path> render_dirs() const {
    std::vector<fs::path> out;
    for (const auto& e : fs::directory_iterator(dir_ / "tmp"))
      if (e.path().filename().string().rfind("epr-render-", 0) == 0) out.push_back(e.path());
    return out;
  }

  fs::path dir_;
};

// ---- permanent errors end the process ---------------------------------------------------------------

TEST_F(ProcessHardening, RenderWithThreadsOverTheMastersLimitExitsWithTheReason) {
  const RunResult r = run(with_env(epr({"render", "builtin:cornell", "--threads", "5000", "--width", "16", "--height",
                                        "16", "--spp", "1", "--http", "", "--out", (dir_ / "x").string()})),
                          "render", 60s);
  EXPECT_FALSE(r.timed_out) << "epr render kept retrying a permanent INVALID_ARGUMENT";
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("threads must be between 1 and 4096"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir_ / "x.exr"));
}

TEST_F(ProcessHardening, WorkerWithANameOverTheLimitExitsWithTheReason) {
  std::unique_ptr<Process> master;
  const int port = start_master(master, "master");
  ASSERT_NE(port, 0) << master->err();
  const RunResult r = run(with_env({binary("worker", "epr-worker"), "--master", "127.0.0.1:" + std::to_string(port),
                                    "--name", std::string(300, 'w'), "--threads", "1"}),
                          "worker", 60s);
  EXPECT_FALSE(r.timed_out) << "epr-worker kept retrying a permanent INVALID_ARGUMENT";
  EXPECT_EQ(r.code, 1) << r.err;
  EXPECT_NE(r.err.find("worker names are limited to 256 bytes"), std::string::npos) << r.err;
  EXPECT_TRUE(master->running()) << "the master is not hurt";
}

// ---- the state directory ------------------------------------------------------------------------------

TEST_F(ProcessHardening, SecondMasterOnTheSameStateDirExitsNamingItAndTheHolder) {
  const std::string state = (dir_ / "state").string();
  std::unique_ptr<Process> first, second, third;
  ASSERT_NE(start_master(first, "first", {"--state-dir", state}), 0) << first->err();
  EXPECT_EQ(start_master(second, "second", {"--state-dir", state}), 0) << "a second master came up on " << state;
  const auto code = second->wait_for(30s);
  ASSERT_TRUE(code.has_value());
  EXPECT_NE(*code, 0);
  EXPECT_NE(second->err().find(state), std::string::npos) << second->err();
  EXPECT_NE(second->err().find("pid " + std::to_string(first->pid())), std::string::npos) << second->err();
  // The lock goes with its master, however it ends.
  first->signal(SIGKILL);
  first->wait_for(30s);
  EXPECT_NE(start_master(third, "third", {"--state-dir", state}), 0) << third->err();
}

TEST_F(ProcessHardening, CorruptEpochFileIsReplacedWithAWarningNamingIt) {
  const fs::path state = dir_ / "state";
  fs::create_directories(state);
  std::ofstream(state / "epoch") << "not a sealed state file";
  std::unique_ptr<Process> master;
  ASSERT_NE(start_master(master, "master", {"--state-dir", state.string()}), 0) << master->err();
  const std::string err = master->err();
  EXPECT_NE(err.find("warn"), std::string::npos) << err;
  EXPECT_NE(err.find((state / "epoch").string()), std::string::npos) << err;
  EXPECT_NE(err.find("starts again at 1"), std::string::npos) << err;
  // A master started on its own folder says nothing about a missing epoch file.
  std::unique_ptr<Process> fresh;
  ASSERT_NE(start_master(fresh, "fresh", {"--state-dir", (dir_ / "fresh").string()}), 0) << fresh->err();
  EXPECT_EQ(fresh->err().find("epoch"), std::string::npos) << fresh->err();
}

// ---- epr render's temporary folders ---------------------------------------------------------------------

TEST_F(ProcessHardening, KilledRenderLeavesNoStateFolderBehind) {
  // Long enough to be killed in the middle.
  const auto long_render =
      with_env(epr({"render", "builtin:cornell", "--width", "128", "--height", "128", "--spp", "1000000", "--threads",
                    "1", "--http", "", "--out", (dir_ / "long").string()}));
  for (const int sig : {SIGTERM, SIGINT}) {
    Process p(long_render, dir_ / ("render-" + std::to_string(sig)));
    ASSERT_TRUE(testing::wait_until([&] { return p.err().find("round") != std::string::npos; }, 60s)) << p.err();
    EXPECT_EQ(render_dirs().size(), 1u);
    p.signal(sig);
    const auto code = p.wait_for(60s);
    ASSERT_TRUE(code.has_value()) << "epr render did not stop on signal " << sig;
    EXPECT_EQ(*code, 128 + sig) << p.err();
    EXPECT_TRUE(render_dirs().empty()) << "signal " << sig << " left " << render_dirs()[0];
  }

  // SIGKILL leaves the folder; the next run removes it.
  {
    Process p(long_render, dir_ / "render-kill");
    ASSERT_TRUE(testing::wait_until([&] { return p.err().find("round") != std::string::npos; }, 60s)) << p.err();
    p.signal(SIGKILL);
    p.wait_for(60s);
  }
  ASSERT_EQ(render_dirs().size(), 1u);
  const RunResult r = run(with_env(epr({"render", "builtin:cornell", "--width", "16", "--height", "16", "--spp", "1",
                                        "--http", "", "--out", (dir_ / "short").string()})),
                          "render-after");
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_TRUE(render_dirs().empty()) << "the folder of the killed render is still there";
}

// ---- HOME, large scenes, time limits, output prefixes ------------------------------------------------------

TEST_F(ProcessHardening, FileSceneRendersWithAnUnwritableHome) {
  // HOME below a regular file: ~/.cache cannot be created, not even by root.
  const RunResult r = run(with_env(epr({"render", kCornellObj, "--width", "16", "--height", "16", "--spp", "1",
                                        "--http", "", "--out", (dir_ / "x").string()}),
                                   {"HOME=/dev/null"}),
                          "render");
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_TRUE(fs::exists(dir_ / "x.exr"));
  for (const auto& e : fs::directory_iterator(dir_ / "tmp")) ADD_FAILURE() << e.path() << " left behind";

  // $XDG_CACHE_HOME names the cache when it is set.
  const fs::path xdg = dir_ / "xdg";
  const RunResult x = run(with_env(epr({"render", kCornellObj, "--width", "16", "--height", "16", "--spp", "1",
                                        "--http", "", "--out", (dir_ / "y").string()}),
                                   {"HOME=/dev/null", "XDG_CACHE_HOME=" + xdg.string()}),
                          "render-xdg");
  EXPECT_EQ(x.code, 0) << x.err;
  // The local workers share the scene the render loaded (they fetch none), but their cache is there.
  EXPECT_TRUE(fs::is_directory(xdg / "eprfarm" / "scenes")) << "the workers' scene cache is not under $XDG_CACHE_HOME";
}

TEST_F(ProcessHardening, LargeSceneIsUploadedWithProgressShown) {
  const std::string obj = test::write_large_obj(dir_ / "scene", 6u << 20);
  // `epr submit` to a master (no worker: the job stays queued) uploads it with its progress.
  std::unique_ptr<Process> master;
  const int port = start_master(master, "master");
  ASSERT_NE(port, 0) << master->err();
  const RunResult s = run(with_env(epr({"submit", obj, "--width", "16", "--height", "16", "--spp", "1", "--master",
                                        "127.0.0.1:" + std::to_string(port)})),
                          "submit");
  EXPECT_EQ(s.code, 0) << s.err;
  EXPECT_NE(s.err.find("uploaded the scene ("), std::string::npos) << s.err;
  EXPECT_NE(s.err.find("the master is loading the scene ("), std::string::npos) << s.err;
  EXPECT_NE(s.err.find("the master loaded the scene in "), std::string::npos) << s.err;
  // `epr render` hands it to its in-process master as loaded: nothing is uploaded.
  const RunResult r = run(with_env(epr({"render", obj, "--width", "16", "--height", "16", "--spp", "1", "--mode", "pt",
                                        "--http", "", "--out", (dir_ / "x").string()})),
                          "render");
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.err.find("uploaded the scene"), std::string::npos) << r.err;
  EXPECT_TRUE(fs::exists(dir_ / "x.exr"));
}

TEST_F(ProcessHardening, TimeoutEndsTheWholeRender) {
  const RunResult r =
      run(with_env(epr({"render", "builtin:cornell", "--width", "128", "--height", "128", "--spp", "1000000",
                        "--threads", "1", "--timeout", "2", "--http", "", "--out", (dir_ / "x").string()})),
          "render", 120s);
  EXPECT_FALSE(r.timed_out);
  EXPECT_EQ(r.code, 1) << r.err;
  EXPECT_NE(r.err.find("did not finish within its time limit of 2 s"), std::string::npos) << r.err;
  EXPECT_TRUE(render_dirs().empty());
}

TEST_F(ProcessHardening, SubmitTimeoutEndsTheWholeSubmission) {
  // No worker: the job stays queued, and `submit --wait` would wait for ever.
  std::unique_ptr<Process> master;
  const int port = start_master(master, "master");
  ASSERT_NE(port, 0) << master->err();
  const RunResult r =
      run(with_env(epr({"submit", "builtin:cornell", "--spp", "1", "--wait", "--timeout", "2", "--master",
                        "127.0.0.1:" + std::to_string(port), "--out", (dir_ / "x").string()})),
          "submit", 120s);
  EXPECT_FALSE(r.timed_out);
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("the time limit ran out during WatchJob"), std::string::npos) << r.err;
}

TEST_F(ProcessHardening, OutputPrefixThatIsEmptyOrAFolderIsRefused) {
  fs::create_directories(dir_ / "out");
  const std::string folder = (dir_ / "out").string();
  const std::pair<std::string, std::string> cases[] = {
      {"", "the output prefix is empty"},
      {folder, "is a folder"},
      {folder + "/", "names a folder"},
      {folder + "/..", "names a folder"},
  };
  for (const auto& [out, message] : cases)
    for (const char* cmd : {"render", "submit"}) {
      const RunResult r = run(with_env(epr({cmd, "builtin:cornell", "--spp", "1", "--out", out})), "cli", 60s);
      EXPECT_NE(r.code, 0) << cmd << " --out '" << out << "'";
      EXPECT_NE(r.err.find(message), std::string::npos) << cmd << " --out '" << out << "': " << r.err;
    }
  EXPECT_TRUE(fs::is_empty(dir_ / "out")) << "nothing was written";
}

}  // namespace
}  // namespace epr
