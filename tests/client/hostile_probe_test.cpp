// The programs under a hostile probe, as the built epr, epr-master and epr-worker processes on
// loopback (tests/integration/cluster/process.h): an output prefix that would replace a file the
// scene reads is refused; ports outside 1-65535 are refused by every program instead of wrapping; a
// full or broken worker cache is the worker's disk, named with the system's reason, and the worker
// fetches into its private folder instead; batches are cancelled as a whole and malformed batch
// flags refused; one master under two addresses is used once, two masters with one name are told
// apart.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>

#include "tests/integration/cluster/process.h"

namespace epr {
namespace {
namespace fs = std::filesystem;
using namespace std::chrono_literals;
using testing::binary;
using testing::count_of;
using testing::Process;
using testing::run_process;
using testing::RunResult;

class HostileProbe : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("epr-probe-" + std::to_string(::getpid()) + "-" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_ / "tmp");
    fs::create_directories(dir_ / "scn");
    for (const char* f : {"sky/courtyard.obj", "sky/courtyard.mtl", "sky/courtyard.json", "sky/sky.exr",
                          "cornell-box.gltf", "cornell-box.bin"})
      fs::copy_file(fs::path(EPR_SOURCE_DIR) / "scenes" / f, dir_ / "scn" / fs::path(f).filename());
    // A scene JSON beside the glTF it names, as scenes/garden ships garden.json beside garden.gltf.
    std::ofstream(dir_ / "scn/cornell-box.json") << R"({"obj": "cornell-box.gltf"})"
                                                 << "\n";
  }
  void TearDown() override {
    if (!HasFailure()) fs::remove_all(dir_);
  }

  std::vector<std::string> with_tmp(std::vector<std::string> argv) const {
    argv.insert(argv.begin(), {"/usr/bin/env", "TMPDIR=" + (dir_ / "tmp").string()});
    return argv;
  }
  RunResult epr(std::vector<std::string> args, std::chrono::milliseconds timeout = 120s) {
    args.insert(args.begin(), binary("client", "epr"));
    return run_process(with_tmp(args), dir_ / ("epr-" + std::to_string(++runs_)), timeout);
  }
  // A master on a free port (no dashboard); its port (0 if it did not come up).
  int start_master(std::unique_ptr<Process>& p, const std::string& log, std::vector<std::string> args = {}) {
    std::vector<std::string> argv{
        binary("master", "epr-master"), "--listen", "127.0.0.1:0", "--http", "", "--reproject", "cpu"};
    argv.insert(argv.end(), args.begin(), args.end());
    p = std::make_unique<Process>(with_tmp(argv), dir_ / log);
    return testing::listening_port(*p, 60s);
  }
  std::unique_ptr<Process> start_worker(const std::string& masters, const std::string& log) {
    return std::make_unique<Process>(with_tmp({binary("worker", "epr-worker"), "--master", masters, "--threads", "1",
                                               "--cache-dir", (dir_ / ("cache-" + log)).string()}),
                                     dir_ / log);
  }
  static std::vector<std::string> tiny(std::vector<std::string> args) {
    for (const char* a : {"--width", "16", "--height", "16", "--spp", "1", "--tile", "16"}) args.push_back(a);
    return args;
  }
  std::string scn(const std::string& f) const { return (dir_ / "scn" / f).string(); }

  fs::path dir_;
  int runs_ = 0;
};

// ---- 1: --out never replaces a file the scene reads ------------------------------------------------

TEST_F(HostileProbe, RenderRefusesAnOutputPrefixThatReplacesTheScenesFiles) {
  const std::string json = testing::read_text(scn("courtyard.json"));
  const std::string sky = testing::read_text(scn("sky.exr"));
  const std::string gltf_json = testing::read_text(scn("cornell-box.json"));
  struct Case {
    std::vector<std::string> args;
    std::string replaced;
  };
  // The prefix written another way (./scn/../scn) is the same folder: compared by identity.
  const std::string twisted = (dir_ / "scn" / ".." / "scn").string();
  const std::vector<Case> cases{
      {{"render", scn("courtyard.json"), "--out", scn("courtyard"), "--single-process"}, "courtyard.json"},
      {{"render", scn("courtyard.json"), "--out", twisted + "/courtyard", "--http", ""}, "courtyard.json"},
      {{"render", scn("courtyard.obj"), "--env", scn("sky.exr"), "--out", scn("sky.exr"), "--http", ""}, "sky.exr"},
      {{"render", scn("courtyard.obj"), "--env", scn("sky.exr"), "--out", scn("courtyard.v2"), "--single-process"},
       ""},  // control: courtyard.v2.exr, ... replace nothing the scene reads
      {{"render", scn("cornell-box.gltf"), "--out", scn("cornell-box"), "--single-process"}, "cornell-box.json"},
  };
  for (const Case& c : cases) {
    const RunResult r = epr(tiny(c.args));
    if (c.replaced.empty()) {
      EXPECT_EQ(r.code, 0) << r.err;
      EXPECT_TRUE(fs::exists(scn("courtyard.v2.exr")));
      continue;
    }
    EXPECT_EQ(r.code, 2) << c.args[3] << ": " << r.err;
    EXPECT_NE(r.err.find("would replace"), std::string::npos) << r.err;
    EXPECT_NE(r.err.find(c.replaced), std::string::npos) << r.err;
  }
  EXPECT_EQ(testing::read_text(scn("courtyard.json")), json);
  EXPECT_EQ(testing::read_text(scn("sky.exr")), sky);
  EXPECT_EQ(testing::read_text(scn("cornell-box.json")), gltf_json);
  EXPECT_FALSE(fs::exists(scn("courtyard.png")));
  EXPECT_FALSE(fs::exists(scn("cornell-box.png")));
}

TEST_F(HostileProbe, SubmitWaitRefusesAnOutputPrefixThatReplacesTheScenesFilesBeforeSubmitting) {
  std::unique_ptr<Process> master;
  const int port = start_master(master, "master");
  ASSERT_NE(port, 0) << master->err();
  const std::string target = "127.0.0.1:" + std::to_string(port);
  const std::string json = testing::read_text(scn("courtyard.json"));
  RunResult r = epr(tiny({"submit", scn("courtyard.json"), "--wait", "--out", scn("courtyard"), "--master", target}));
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("would replace"), std::string::npos) << r.err;
  r = epr(tiny(
      {"submit", scn("courtyard.json"), "--frames", "1-2", "--wait", "--out", scn("courtyard"), "--master", target}));
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("would replace"), std::string::npos) << r.err;
  r = epr({"list", "--master", target});
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(count_of(r.out, "\n"), 1u) << "a job was submitted:\n" << r.out;  // the header alone
  EXPECT_EQ(testing::read_text(scn("courtyard.json")), json);
}

// ---- 2: write errors name the reason; a broken worker cache falls back ---------------------------------

TEST_F(HostileProbe, WorkerCacheThatCannotTakeASceneIsTheWorkersDiskAndFallsBack) {
  std::unique_ptr<Process> master;
  const int port = start_master(master, "master");
  ASSERT_NE(port, 0) << master->err();
  const std::string target = "127.0.0.1:" + std::to_string(port);
  auto worker = start_worker(target, "worker");
  ASSERT_TRUE(testing::wait_until([&] { return worker->err().find("registered with") != std::string::npos; }, 60s))
      << worker->err();
  // The cache could be written when the worker started; now its scenes folder is a regular file, so
  // no scene can be written there (as root, permission bits would not stop a write).
  const fs::path scenes = dir_ / "cache-worker" / "scenes";
  fs::remove_all(scenes);
  std::ofstream(scenes) << "not a folder\n";
  RunResult r = epr(tiny({"submit", scn("courtyard.json"), "--wait", "--out", (dir_ / "img").string(), "--timeout",
                          "300", "--master", target}),
                    320s);
  EXPECT_EQ(r.code, 0) << r.err << "\n---- worker\n" << worker->err();
  EXPECT_TRUE(fs::exists(dir_ / "img.exr"));
  const std::string log = worker->err();
  EXPECT_NE(log.find("the worker's scene cache " + (dir_ / "cache-worker").string()), std::string::npos) << log;
  EXPECT_NE(log.find("Not a directory"), std::string::npos) << log;
  EXPECT_NE(log.find("fetching the scene into"), std::string::npos) << log;

  // `epr get` into a path under a regular file says why it cannot write.
  const std::string id = r.out.substr(0, r.out.find('\n'));
  std::ofstream(dir_ / "afile") << "x\n";
  r = epr({"get", id, "--out", (dir_ / "afile" / "x").string(), "--master", target});
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("cannot write"), std::string::npos) << r.err;
  EXPECT_TRUE(r.err.find("Not a directory") != std::string::npos || r.err.find("File exists") != std::string::npos)
      << r.err;
}

// ---- 3: one address parser, ports 1-65535 ---------------------------------------------------------------

TEST_F(HostileProbe, PortsOutsideTheRangeAreRefusedByEveryProgramNamingTheFlag) {
  RunResult r = epr({"list", "--master", "127.0.0.1:112837"}, 60s);
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("--master '127.0.0.1:112837': port 112837 is outside 1-65535"), std::string::npos) << r.err;
  r = epr({"list", "--master", "localhost:1,[::1]:65536"}, 60s);
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("port 65536 is outside 1-65535"), std::string::npos) << r.err;
  r = epr(tiny({"render", "builtin:cornell", "--http", "127.0.0.1:99999", "--out", (dir_ / "x").string()}), 60s);
  EXPECT_NE(r.code, 0) << r.err;  // CLI11's code for a flag's failed check
  EXPECT_NE(r.err.find("--http: '127.0.0.1:99999': port 99999 is outside 0-65535"), std::string::npos) << r.err;

  r = run_process(with_tmp({binary("worker", "epr-worker"), "--master", "127.0.0.1:112837"}), dir_ / "worker", 60s);
  EXPECT_FALSE(r.timed_out) << "epr-worker kept trying port 112837 (wrapped to 47301)";
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("--master '127.0.0.1:112837': port 112837 is outside 1-65535"), std::string::npos) << r.err;

  for (const auto& [flag, value] : std::vector<std::pair<std::string, std::string>>{
           {"--listen", "127.0.0.1:112837"}, {"--listen", "[::1]:65536"}, {"--http", "127.0.0.1:70000"}}) {
    std::vector<std::string> argv{binary("master", "epr-master"), flag, value};
    for (const char* f : {"--listen", "--http"})
      if (flag != f) argv.insert(argv.end(), {f, f == std::string("--http") ? "" : "127.0.0.1:0"});
    r = run_process(with_tmp(argv), dir_ / "master", 60s);
    EXPECT_FALSE(r.timed_out) << "epr-master came up with " << flag << " " << value;
    EXPECT_EQ(r.code, 2) << r.err;
    EXPECT_NE(r.err.find(flag + " '" + value + "': port"), std::string::npos) << r.err;
  }
}

// ---- 4: batches ---------------------------------------------------------------------------------------------

TEST_F(HostileProbe, BatchesAreCancelledWholeOnEveryMasterAndMalformedBatchFlagsRefused) {
  std::unique_ptr<Process> m1, m2;
  const int p1 = start_master(m1, "m1", {"--name", "one"});
  const int p2 = start_master(m2, "m2", {"--name", "two"});
  ASSERT_NE(p1 * p2, 0) << m1->err() << m2->err();
  const std::string masters = "127.0.0.1:" + std::to_string(p1) + ",127.0.0.1:" + std::to_string(p2);
  // No worker: the frames do not finish; spread over both masters.
  RunResult r = epr(tiny({"submit", scn("courtyard.json"), "--frames", "1-4", "--master", masters}));
  ASSERT_EQ(r.code, 0) << r.err;
  const std::string batch = r.out.substr(0, r.out.find('\n'));
  r = epr({"list", "--batch", batch, "--master", masters});
  ASSERT_EQ(count_of(r.out, batch), 4u) << r.out;
  EXPECT_EQ(count_of(r.out, "one.j"), 2u) << r.out;  // spread: the cancel has to reach both masters

  r = epr({"cancel", batch, "--master", masters});
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.out, batch + " CANCELLED\n");
  EXPECT_NE(r.err.find("4 job(s) cancelled"), std::string::npos) << r.err;
  r = epr({"list", "--batch", batch, "--master", masters});
  EXPECT_EQ(count_of(r.out, "CANCELLED"), 4u) << r.out;
  r = epr({"cancel", batch, "--master", masters});  // again: nothing left to cancel
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("0 job(s) cancelled, 4 had already ended"), std::string::npos) << r.err;

  const std::string one = "127.0.0.1:" + std::to_string(p1);
  r = epr(tiny({"submit", scn("courtyard.json"), "--frames", "", "--master", one}));
  EXPECT_EQ(r.code, 2) << r.out << r.err;
  EXPECT_NE(r.err.find("--frames: empty"), std::string::npos) << r.err;
  r = epr(tiny({"submit", scn("courtyard.json"), "--frames", "1-2x99999999999999999", "--master", one}));
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("too large"), std::string::npos) << r.err;
  r = epr({"list", "--batch", "", "--master", one});
  EXPECT_EQ(r.code, 2) << r.out << r.err;
  EXPECT_NE(r.err.find("--batch ''"), std::string::npos) << r.err;
  r = epr({"list", "--master", masters});
  EXPECT_EQ(count_of(r.out, "\n"), 5u) << "a refused submission queued a job:\n" << r.out;  // header, 4 frames
}

// ---- 5: several masters -------------------------------------------------------------------------------------

TEST_F(HostileProbe, OneMasterUnderTwoAddressesIsUsedOnce) {
  std::unique_ptr<Process> master;
  const int port = start_master(master, "master", {"--name", "solo"});
  ASSERT_NE(port, 0) << master->err();
  const std::string twice = "127.0.0.1:" + std::to_string(port) + ",localhost:" + std::to_string(port);
  RunResult r = epr(tiny({"submit", "builtin:cornell", "--master", twice}));
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("are the same master (solo); using it once"), std::string::npos) << r.err;
  r = epr({"list", "--master", twice});
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(count_of(r.out, "solo.j"), 1u) << r.out;

  auto worker = start_worker(twice, "worker");
  ASSERT_TRUE(testing::wait_until([&] { return worker->err().find("served once") != std::string::npos; }, 60s))
      << worker->err();
  EXPECT_EQ(count_of(worker->err(), "registered with"), 1u) << worker->err();
  EXPECT_TRUE(worker->running()) << worker->err();
}

TEST_F(HostileProbe, TwoMastersWithOneNameAreToldApart) {
  std::unique_ptr<Process> m1, m2;
  const int p1 = start_master(m1, "m1", {"--name", "twin"});
  const int p2 = start_master(m2, "m2", {"--name", "twin"});
  ASSERT_NE(p1 * p2, 0) << m1->err() << m2->err();
  const std::string second = "127.0.0.1:" + std::to_string(p2);
  const std::string both = "127.0.0.1:" + std::to_string(p1) + "," + second;
  RunResult r = epr(tiny({"submit", "builtin:cornell", "--master", second}));
  ASSERT_EQ(r.code, 0) << r.err;
  const std::string id = r.out.substr(0, r.out.find('\n'));
  r = epr({"get", id, "--json", "--master", both});
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("\"id\": \"" + id + "\""), std::string::npos) << r.out;
  EXPECT_NE(r.err.find("two masters with the same name 'twin'"), std::string::npos) << r.err;
  r = epr({"list", "--master", both});  // both are listed: they are not one master
  EXPECT_EQ(count_of(r.out, "twin.j"), 1u) << r.out;
  EXPECT_EQ(r.err.find("same master"), std::string::npos) << r.err;
}

}  // namespace
}  // namespace epr
