// JobClient and the `epr` cluster commands against the real thing: the built epr-master and
// epr-worker executables, started as processes on loopback (no fakes). Jobs are tiny (32 x 32
// pixels, a few samples), so each test takes about a second. Skipped when the executables are not
// in the build tree (set EPR_MASTER_BIN / EPR_WORKER_BIN / EPR_BIN to point elsewhere).
#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <regex>
#include <set>
#include <sstream>
#include <thread>

#include "client/job_client.h"
#include "client/remote_commands.h"
#include "common/result_kinds.h"
#include "tests/wait_until.h"
#include "wire/scene_bundle.h"

namespace epr {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
using namespace std::chrono_literals;
using test::wait_until;

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

// An executable of the build tree: $ENV, else BUILD/<subdir>/<name> where BUILD holds this test.
std::string build_binary(const char* env, const char* subdir, const char* name) {
  if (const char* e = std::getenv(env); e && *e) return e;
  return (fs::read_symlink("/proc/self/exe").parent_path().parent_path() / subdir / name).string();
}

std::string read_file(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// A child process with stdout and stderr in a log file. Stopped with SIGTERM (then SIGKILL) when
// destroyed.
class Process {
 public:
  Process(const std::vector<std::string>& args, const fs::path& log) {
    std::vector<char*> argv;
    for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    const std::string log_path = log.string();
    pid_ = ::fork();
    if (pid_ == 0) {  // only async-signal-safe calls until exec
      const int fd = ::open(log_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
      ::dup2(fd, 1);
      ::dup2(fd, 2);
      ::execv(argv[0], argv.data());
      ::_exit(127);
    }
  }
  ~Process() { stop(SIGTERM); }
  Process(const Process&) = delete;
  Process& operator=(const Process&) = delete;

  void stop(int sig) {
    if (pid_ <= 0) return;
    ::kill(pid_, sig);
    // 10 s to wind down, then SIGKILL.
    if (!wait_until([&] { return ::waitpid(pid_, nullptr, WNOHANG) == pid_; }, 10s, 10ms)) {
      ::kill(pid_, SIGKILL);
      ::waitpid(pid_, nullptr, 0);
    }
    pid_ = -1;
  }

 private:
  pid_t pid_ = -1;
};

struct CliRun {
  int exit_code = -1;
  std::string out, err;
};

class ClusterTest : public ::testing::Test {
 protected:
  void SetUp() override {
    master_bin_ = build_binary("EPR_MASTER_BIN", "master", "epr-master");
    worker_bin_ = build_binary("EPR_WORKER_BIN", "worker", "epr-worker");
    epr_bin_ = build_binary("EPR_BIN", "client", "epr");
    for (const auto& b : {master_bin_, worker_bin_, epr_bin_}) ASSERT_TRUE(fs::exists(b)) << b << " not built";
    dir_ = fs::temp_directory_path() / ("epr-cluster-test-" + std::to_string(::getpid()) + "-" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    master_ = std::make_unique<Process>(
        std::vector<std::string>{master_bin_, "--listen", "127.0.0.1:0", "--http", "127.0.0.1:0", "--reproject", "cpu",
                                 "--state-dir", (dir_ / "state").string()},
        dir_ / "master.log");
    // The master prints its port once it listens.
    const std::regex listening("listening on port ([0-9]+)");
    wait_until(
        [&] {
          std::smatch m;
          const std::string log = read_file(dir_ / "master.log");
          if (std::regex_search(log, m, listening)) target_ = "127.0.0.1:" + m[1].str();
          return !target_.empty();
        },
        60s, 20ms);
    ASSERT_FALSE(target_.empty()) << "epr-master did not start:\n" << read_file(dir_ / "master.log");
  }

  void TearDown() override {
    worker_.reset();
    master_.reset();
    if (!HasFailure()) fs::remove_all(dir_);
  }

  void start_worker() {
    worker_ = std::make_unique<Process>(std::vector<std::string>{worker_bin_, "--master", target_, "--threads", "2",
                                                                 "--cache-dir", (dir_ / "cache").string()},
                                        dir_ / "worker.log");
  }

  JobClientOptions client_options() const {
    JobClientOptions o;
    o.timeout = std::chrono::seconds(10);
    return o;
  }

  static RenderOptions tiny_job(RenderMode mode) {
    RenderOptions o;
    o.scene = "builtin:cornell";
    o.width = o.height = 32;
    o.spp = 4;
    o.paths_per_round = 2;
    o.tile_size = 16;
    o.mode = mode;
    o.reproject = ReprojectMethod::kCpu;
    return o;
  }

  CliRun epr(const std::string& args) {
    const fs::path err = dir_ / "cli.err";
    const std::string cmd = "'" + epr_bin_ + "' " + args + " --master " + target_ + " 2>'" + err.string() + "'";
    CliRun r;
    FILE* p = ::popen(cmd.c_str(), "r");
    if (!p) return r;
    std::array<char, 4096> buf;
    size_t n;
    while ((n = std::fread(buf.data(), 1, buf.size(), p)) > 0) r.out.append(buf.data(), n);
    const int status = ::pclose(p);
    r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    r.err = read_file(err);
    return r;
  }

  std::string master_bin_, worker_bin_, epr_bin_;
  fs::path dir_;
  std::string target_;
  std::unique_ptr<Process> master_, worker_;
};

// Every file written by fetch_all, by suffix after the prefix.
std::set<std::string> suffixes(const std::vector<FetchedFile>& files, const std::string& prefix) {
  std::set<std::string> s;
  for (const auto& f : files) s.insert(f.path.substr(prefix.size()));
  return s;
}

bool starts_with(const std::string& s, const std::string& magic) { return s.compare(0, magic.size(), magic) == 0; }

TEST_F(ClusterTest, JobRunsToDoneAndEveryResultIsFetchedAndVerified) {
  start_worker();
  JobClient client(target_, client_options());
  const std::string id = client.submit(tiny_job(RenderMode::kReproject));
  EXPECT_TRUE(std::regex_match(id, std::regex("[A-Za-z0-9_.-]{1,64}"))) << id;

  std::vector<v1::JobStatus> seen;
  const v1::JobStatus last = client.watch(id, [&](const v1::JobStatus& s) {
    seen.push_back(s);
    return true;
  });
  ASSERT_EQ(last.state(), v1::JOB_STATE_DONE) << last.error_message();
  EXPECT_EQ(last.round(), 2u);  // ceil(P / k) = ceil(4 / 2)
  EXPECT_GE(last.spp_mean(), 4.0);
  for (size_t i = 1; i < seen.size(); ++i) EXPECT_LE(seen[i - 1].round(), seen[i].round());  // never reordered

  const std::string prefix = (dir_ / "rp").string();
  const auto files = client.fetch_all(id, prefix);
  EXPECT_EQ(suffixes(files, prefix),
            (std::set<std::string>{".exr", ".png", ".json", ".pathtrace.exr", ".reprojection.exr", ".counts.exr",
                                   ".samples.exr", ".samples.png"}));
  for (const auto& f : files) {
    EXPECT_EQ(fs::file_size(f.path), f.bytes) << f.path;
    EXPECT_EQ(f.round, 2u) << f.path;
    EXPECT_FALSE(f.partial) << f.path;
  }
  EXPECT_TRUE(starts_with(read_file(prefix + ".exr"), "\x76\x2f\x31\x01")) << "not OpenEXR";
  EXPECT_TRUE(starts_with(read_file(prefix + ".png"), "\x89PNG")) << "not PNG";
  EXPECT_TRUE(starts_with(read_file(prefix + ".samples.png"), "\x89PNG")) << "not PNG";
  EXPECT_TRUE(nlohmann::json::parse(read_file(prefix + ".json"), nullptr, false).is_object());
  for (const auto& e : fs::directory_iterator(dir_))
    EXPECT_EQ(e.path().string().find(".part-"), std::string::npos) << "temporary file left: " << e.path();

  // fetch replaces an existing file as a whole.
  const fs::path png = dir_ / "again.png";
  std::ofstream(png) << "stale bytes that are longer than nothing at all";
  client.fetch(id, v1::RESULT_KIND_PNG, png.string());
  EXPECT_EQ(read_file(png), read_file(prefix + ".png"));
}

TEST_F(ClusterTest, PathTracedJobSkipsTheResultsItDoesNotProduce) {
  start_worker();
  JobClient client(target_, client_options());
  const std::string id = client.submit(tiny_job(RenderMode::kPathTrace));
  ASSERT_EQ(client.watch(id, [](const v1::JobStatus&) { return true; }).state(), v1::JOB_STATE_DONE);
  const std::string prefix = (dir_ / "pt").string();
  const auto files = client.fetch_all(id, prefix);
  EXPECT_EQ(suffixes(files, prefix), (std::set<std::string>{".exr", ".png", ".json", ".pathtrace.exr", ".counts.exr"}));
  EXPECT_FALSE(fs::exists(prefix + ".reprojection.exr"));
}

TEST_F(ClusterTest, ResultsOfAnUnfinishedJobAreRefusedAndNothingIsWritten) {
  JobClient client(target_, client_options());  // no worker: the job never ends
  const std::string id = client.submit(tiny_job(RenderMode::kPathTrace));
  const fs::path path = dir_ / "early.exr";
  try {
    client.fetch(id, v1::RESULT_KIND_EXR, path.string());
    ADD_FAILURE() << "an unfinished job served its result";
  } catch (const RpcError& e) {
    EXPECT_EQ(e.code(), grpc::StatusCode::FAILED_PRECONDITION) << e.what();
    EXPECT_NE(std::string(e.what()).find(target_), std::string::npos) << e.what();
  }
  EXPECT_FALSE(fs::exists(path));
  EXPECT_THROW(client.fetch_all(id, (dir_ / "early").string()), RpcError);  // the EXR is required
}

TEST_F(ClusterTest, LargeFileSceneIsUploadedOnceAndRenderedByHash) {
  start_worker();
  // An emitting wall in front of the default (OBJ) camera.
  std::ofstream(dir_ / "wall.mtl") << "newmtl glow\nKd 0.5 0.5 0.5\nKe 2 2 2\n";
  std::ofstream(dir_ / "wall.obj") << "mtllib wall.mtl\nusemtl glow\n"
                                      "v -1 0 0\nv 1 0 0\nv 1 2 0\nv -1 2 0\nf 1 2 3\nf 1 3 4\n";
  JobClientOptions opts = client_options();
  opts.inline_scene_limit = 16;  // below the scene's size: it must go through UploadScene
  JobClient client(target_, opts);
  RenderOptions job = tiny_job(RenderMode::kPathTrace);
  job.scene = (dir_ / "wall.obj").string();
  const std::string hash = content_hash(bundle_scene(job.scene));

  const v1::JobSpec spec = client.make_job_spec(job);
  EXPECT_EQ(spec.scene().uploaded_hash(), hash);
  EXPECT_FALSE(spec.scene().has_files());
  EXPECT_EQ(client.upload_scene(bundle_scene(job.scene)), hash);  // again: same hash

  const std::string id = client.submit(spec);
  const v1::JobStatus last = client.watch(id, [](const v1::JobStatus&) { return true; });
  ASSERT_EQ(last.state(), v1::JOB_STATE_DONE) << last.error_message();
  EXPECT_EQ(last.scene().content_hash(), hash);
}

TEST_F(ClusterTest, RetriedSubmitWithTheSameRequestIdQueuesOneJob) {
  JobClient client(target_, client_options());
  const v1::JobSpec spec = client.make_job_spec(tiny_job(RenderMode::kPathTrace));
  ASSERT_FALSE(spec.request_id().empty());
  const std::string first = client.submit(spec);
  EXPECT_EQ(client.submit(spec), first);
  EXPECT_EQ(client.list().size(), 1u);
  EXPECT_NE(client.submit(client.make_job_spec(tiny_job(RenderMode::kPathTrace))), first);  // a fresh key
  EXPECT_EQ(client.list().size(), 2u);
}

TEST_F(ClusterTest, CancelEndsAWatchWithTheCancelledState) {
  JobClient client(target_, client_options());  // no worker: the job waits until cancelled
  const std::string id = client.submit(tiny_job(RenderMode::kPathTrace));
  v1::JobStatus last;
  std::atomic<int> updates{0};
  std::thread watcher([&] {
    last = client.watch(id, [&](const v1::JobStatus&) {
      ++updates;
      return true;
    });
  });
  // The watch is established once its first status (the job as it is) has arrived.
  EXPECT_TRUE(wait_until([&] { return updates > 0; })) << "no status from WatchJob";
  const auto t0 = Clock::now();
  EXPECT_EQ(client.cancel(id).state(), v1::JOB_STATE_CANCELLED);
  watcher.join();
  EXPECT_LT(seconds_since(t0), 5.0);
  EXPECT_EQ(last.state(), v1::JOB_STATE_CANCELLED);
  EXPECT_EQ(client.cancel(id).state(), v1::JOB_STATE_CANCELLED);  // again: nothing changes
  EXPECT_EQ(client.list({v1::JOB_STATE_CANCELLED}).size(), 1u);
  EXPECT_TRUE(client.list({v1::JOB_STATE_RUNNING, v1::JOB_STATE_QUEUED}).empty());
}

TEST_F(ClusterTest, CallCancellerStopsAWatchFromAnotherThread) {
  JobClient client(target_, client_options());
  const std::string id = client.submit(tiny_job(RenderMode::kPathTrace));
  CallCanceller canceller;
  std::atomic<int> updates{0};
  std::optional<grpc::StatusCode> code;
  std::thread watcher([&] {
    try {
      client.watch(
          id,
          [&](const v1::JobStatus&) {
            ++updates;
            return true;
          },
          0, &canceller);
    } catch (const RpcError& e) {
      code = e.code();
    }
  });
  wait_until([&] { return updates > 0; });  // the watch is established (checked below)
  const auto t0 = Clock::now();
  canceller.cancel();
  watcher.join();
  EXPECT_LT(seconds_since(t0), 2.0);
  EXPECT_GE(updates.load(), 1);
  EXPECT_EQ(code, grpc::StatusCode::CANCELLED);
  EXPECT_NE(client.get(id).state(), v1::JOB_STATE_CANCELLED);  // only the watch stopped, not the job
}

TEST_F(ClusterTest, WatchGivesUpWithinTheReconnectWindowWhenTheMasterDies) {
  JobClientOptions opts = client_options();
  opts.watch_reconnect_timeout = std::chrono::milliseconds(1500);
  JobClient client(target_, opts);
  const std::string id = client.submit(tiny_job(RenderMode::kPathTrace));
  std::atomic<int> updates{0};
  std::string error;
  bool unreachable = false;
  Clock::time_point failed_at;
  std::thread watcher([&] {
    try {
      client.watch(id, [&](const v1::JobStatus&) {
        ++updates;
        return true;
      });
    } catch (const RpcError& e) {
      error = e.what();
      unreachable = e.unreachable();
    }
    failed_at = Clock::now();
  });
  // The watch is established before the master dies, so what follows is a lost master, not a refused call.
  EXPECT_TRUE(wait_until([&] { return updates > 0; })) << "no status from WatchJob";
  const auto killed_at = Clock::now();
  master_->stop(SIGKILL);
  watcher.join();
  const double s = std::chrono::duration<double>(failed_at - killed_at).count();
  EXPECT_GE(s, 1.0);
  EXPECT_LT(s, 10.0);
  EXPECT_TRUE(unreachable) << error;
  EXPECT_NE(error.find("lost master at " + target_), std::string::npos) << error;
}

// ---- the epr commands ---------------------------------------------------------------------------

TEST_F(ClusterTest, CliSubmitWaitThenListGetAndWatch) {
  start_worker();
  const std::string prefix = (dir_ / "cli").string();
  const CliRun submit =
      epr("submit builtin:cornell --width 32 --height 32 --spp 4 --paths-per-round 2 --tile 16 --mode rp "
          "--reproject cpu --name cli-job --wait --out " +
          prefix);
  ASSERT_EQ(submit.exit_code, kExitOk) << submit.err;
  std::smatch m;
  ASSERT_TRUE(std::regex_match(submit.out, m, std::regex("([A-Za-z0-9_.-]{1,64})\n"))) << "stdout: " << submit.out;
  const std::string id = m[1];
  EXPECT_NE(submit.err.find("DONE"), std::string::npos) << submit.err;
  // The files `epr render` writes (common/result_kinds.h).
  for (const ResultKindInfo& k : result_kinds()) EXPECT_TRUE(fs::exists(prefix + std::string(k.suffix))) << k.suffix;

  const CliRun list = epr("list");
  EXPECT_EQ(list.exit_code, kExitOk) << list.err;
  EXPECT_TRUE(std::regex_search(list.out, std::regex(id + " +cli-job +DONE +2/2 "))) << list.out;

  const CliRun get = epr("get " + id + " --out " + (dir_ / "got").string());
  EXPECT_EQ(get.exit_code, kExitOk) << get.err;
  EXPECT_EQ(read_file(dir_ / "got.exr"), read_file(prefix + ".exr"));

  const CliRun json = epr("get " + id + " --json");
  EXPECT_EQ(json.exit_code, kExitOk) << json.err;
  EXPECT_EQ(nlohmann::json::parse(json.out).value("state", ""), "JOB_STATE_DONE") << json.out;

  EXPECT_EQ(epr("watch " + id).exit_code, kExitOk);
}

TEST_F(ClusterTest, CliExitCodesForUnknownAndCancelledJobs) {
  const CliRun unknown = epr("get no-such-job");
  EXPECT_EQ(unknown.exit_code, kExitRefused) << unknown.err;
  EXPECT_NE(unknown.err.find("NOT_FOUND"), std::string::npos) << unknown.err;
  EXPECT_EQ(epr("watch no-such-job").exit_code, kExitRefused);
  EXPECT_EQ(epr("cancel no-such-job").exit_code, kExitRefused);

  const CliRun submit = epr("submit builtin:cornell --width 32 --height 32 --spp 4");  // no worker
  ASSERT_EQ(submit.exit_code, kExitOk) << submit.err;
  const std::string id = submit.out.substr(0, submit.out.find('\n'));
  const CliRun running = epr("get " + id);
  EXPECT_EQ(running.exit_code, kExitJobFailed) << running.err;  // no results before the end
  const CliRun cancel = epr("cancel " + id);
  EXPECT_EQ(cancel.exit_code, kExitOk) << cancel.err;
  EXPECT_EQ(cancel.out, id + " CANCELLED\n");
  EXPECT_EQ(epr("watch " + id).exit_code, kExitJobFailed);
}

TEST_F(ClusterTest, CliListLimitShowsTheNewestJobs) {
  std::vector<std::string> ids;
  for (int i = 0; i < 3; ++i) {  // no worker: they wait
    const CliRun submit = epr("submit builtin:cornell --width 32 --height 32 --spp 4 --name job-" + std::to_string(i));
    ASSERT_EQ(submit.exit_code, kExitOk) << submit.err;
    ids.push_back(submit.out.substr(0, submit.out.find('\n')));
  }
  const CliRun one = epr("list --limit 1");
  ASSERT_EQ(one.exit_code, kExitOk) << one.err;
  EXPECT_NE(one.out.find(ids[2]), std::string::npos) << one.out;
  EXPECT_EQ(one.out.find(ids[0]), std::string::npos) << one.out;
  EXPECT_EQ(one.out.find(ids[1]), std::string::npos) << one.out;
  const CliRun all = epr("list");
  ASSERT_EQ(all.exit_code, kExitOk) << all.err;
  EXPECT_LT(all.out.find(ids[2]), all.out.find(ids[1])) << all.out;
  EXPECT_LT(all.out.find(ids[1]), all.out.find(ids[0])) << all.out;
}

TEST_F(ClusterTest, CliGetPartialOfARunningJobAndGetOfACancelledOne) {
  start_worker();
  // Far more rounds than the test lasts: the job is still running when it is cancelled.
  const CliRun submit =
      epr("submit builtin:cornell --width 32 --height 32 --spp 20000 --paths-per-round 1 --tile 16 --mode rp "
          "--reproject cpu");
  ASSERT_EQ(submit.exit_code, kExitOk) << submit.err;
  const std::string id = submit.out.substr(0, submit.out.find('\n'));
  JobClient client(target_, client_options());
  ASSERT_TRUE(wait_until([&] { return client.get(id).round() >= 1; }, 60s, 20ms));

  const CliRun refused = epr("get " + id + " --out " + (dir_ / "no").string());
  EXPECT_EQ(refused.exit_code, kExitJobFailed) << refused.err;
  EXPECT_FALSE(fs::exists(dir_ / "no.exr"));
  // The round's copy follows the round's close: fetched once it is there.
  const std::string running = (dir_ / "running").string();
  CliRun partial;
  EXPECT_TRUE(wait_until(
      [&] {
        partial = epr("get " + id + " --partial --out " + running);
        return partial.exit_code == kExitOk;
      },
      30s, 50ms))
      << partial.err;
  EXPECT_NE(partial.err.find("partial"), std::string::npos) << partial.err;
  EXPECT_TRUE(starts_with(read_file(running + ".exr"), "\x76\x2f\x31\x01")) << "not OpenEXR";
  const auto stats = nlohmann::json::parse(read_file(running + ".json"), nullptr, false);
  EXPECT_EQ(stats.value("partial", false), true) << read_file(running + ".json");

  const CliRun cancel = epr("cancel " + id);
  ASSERT_EQ(cancel.exit_code, kExitOk) << cancel.err;
  const std::string cancelled = (dir_ / "cancelled").string();
  const CliRun get = epr("get " + id + " --out " + cancelled);
  EXPECT_EQ(get.exit_code, kExitOk) << get.err;
  EXPECT_NE(get.err.find("partial"), std::string::npos) << get.err;
  EXPECT_TRUE(starts_with(read_file(cancelled + ".exr"), "\x76\x2f\x31\x01")) << "not OpenEXR";
  EXPECT_TRUE(fs::exists(cancelled + ".samples.png"));
  EXPECT_EQ(nlohmann::json::parse(read_file(cancelled + ".json")).value("state", ""), "cancelled");
}

}  // namespace
}  // namespace epr
