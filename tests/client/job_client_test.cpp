// JobClient and the `epr` cluster commands where no master is needed: building the JobSpec (scene
// bundling, camera, inline vs upload), and the behaviour against an address that refuses
// connections or accepts them and never answers — a clear error naming the master within the
// deadline, never a hang. The CLI is run as the built `epr` binary to check its exit codes.
#include "client/job_client.h"

#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>

#include "client/remote_commands.h"
#include "common/image.h"
#include "common/scene_loader.h"
#include "wire/scene_bundle.h"

namespace epr {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

// A loopback TCP socket. listening=false: bound then closed, so connecting to its port is refused
// (another process could take the port in between; unlikely within a test). listening=true: the
// kernel completes TCP handshakes into the backlog but nothing ever speaks HTTP/2 — a master that
// hangs.
class LoopbackPort {
 public:
  explicit LoopbackPort(bool listening) {
    fd_ = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    a.sin_port = 0;
    EXPECT_EQ(::bind(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a), 0);
    socklen_t len = sizeof a;
    ::getsockname(fd_, reinterpret_cast<sockaddr*>(&a), &len);
    port_ = ntohs(a.sin_port);
    if (listening) {
      EXPECT_EQ(::listen(fd_, 16), 0);
    } else {
      ::close(fd_);
      fd_ = -1;
    }
  }
  ~LoopbackPort() {
    if (fd_ >= 0) ::close(fd_);
  }
  std::string target() const { return "127.0.0.1:" + std::to_string(port_); }

 private:
  int fd_ = -1;
  int port_ = 0;
};

JobClientOptions quick(int timeout_ms) {
  JobClientOptions o;
  o.timeout = std::chrono::milliseconds(timeout_ms);
  o.transfer_timeout = std::chrono::milliseconds(timeout_ms);
  return o;
}

// Runs `call`, expecting an RpcError with `code` whose message names `target`; returns its message.
template <typename F>
std::string expect_rpc_error(F&& call, grpc::StatusCode code, const std::string& target) {
  try {
    call();
  } catch (const RpcError& e) {
    EXPECT_EQ(e.code(), code) << e.what();
    EXPECT_NE(std::string(e.what()).find(target), std::string::npos) << e.what();
    return e.what();
  } catch (const std::exception& e) {
    ADD_FAILURE() << "expected RpcError, got: " << e.what();
    return e.what();
  }
  ADD_FAILURE() << "expected RpcError, the call succeeded";
  return "";
}

// ---- unreachable and silent masters -------------------------------------------------------------

TEST(JobClient, RefusedConnectionFailsAtOnceNamingTheMaster) {
  LoopbackPort closed(false);
  JobClient client(closed.target(), quick(5000));
  const auto t0 = Clock::now();
  const std::string msg =
      expect_rpc_error([&] { client.get("job-1"); }, grpc::StatusCode::UNAVAILABLE, closed.target());
  EXPECT_NE(msg.find("cannot reach master at " + closed.target()), std::string::npos) << msg;
  expect_rpc_error([&] { client.list(); }, grpc::StatusCode::UNAVAILABLE, closed.target());
  expect_rpc_error([&] { client.cancel("job-1"); }, grpc::StatusCode::UNAVAILABLE, closed.target());
  RenderOptions opts;
  opts.scene = "builtin:cornell";
  expect_rpc_error([&] { client.submit(opts); }, grpc::StatusCode::UNAVAILABLE, closed.target());
  expect_rpc_error([&] { client.watch("job-1", [](const v1::JobStatus&) { return true; }); },
                   grpc::StatusCode::UNAVAILABLE, closed.target());
  expect_rpc_error([&] { client.fetch("job-1", v1::RESULT_KIND_EXR, "/tmp/never-written.exr"); },
                   grpc::StatusCode::UNAVAILABLE, closed.target());
  // Refused connections do not wait for the 5 s deadline.
  EXPECT_LT(seconds_since(t0), 4.0);
}

TEST(JobClient, SilentMasterEndsEveryCallAtItsDeadline) {
  LoopbackPort silent(true);
  JobClient client(silent.target(), quick(300));
  auto timed = [&](auto&& call) {
    const auto t0 = Clock::now();
    try {
      call();
      ADD_FAILURE() << "a silent master answered";
    } catch (const RpcError& e) {
      EXPECT_TRUE(e.unreachable()) << e.what();
      EXPECT_NE(std::string(e.what()).find(silent.target()), std::string::npos) << e.what();
    }
    const double s = seconds_since(t0);
    EXPECT_GE(s, 0.25);
    EXPECT_LT(s, 5.0);
  };
  timed([&] { client.get("job-1"); });
  timed([&] { client.list(); });
  // Streaming calls have long deadlines of their own; the reachability check bounds their start.
  timed([&] { client.watch("job-1", [](const v1::JobStatus&) { return true; }); });
  timed([&] { client.fetch("job-1", v1::RESULT_KIND_PNG, "/tmp/never-written.png"); });
  SceneBundleData bundle;
  bundle.entry_path = "a.obj";
  bundle.files = {{"a.obj", "v 0 0 0\n"}};
  timed([&] { client.upload_scene(bundle); });
}

TEST(JobClient, CancellerStopsAWatchBeforeItStarts) {
  LoopbackPort closed(false);
  JobClient client(closed.target(), quick(1000));
  CallCanceller canceller;
  canceller.cancel();
  EXPECT_TRUE(canceller.cancelled());
  // Not reachable either way; what matters is that a cancelled canceller never waits.
  const auto t0 = Clock::now();
  EXPECT_THROW(client.watch(
                   "job-1", [](const v1::JobStatus&) { return true; }, 0, &canceller),
               RpcError);
  EXPECT_LT(seconds_since(t0), 2.0);
}

TEST(JobClient, TokenMustBePrintableAscii) {
  JobClientOptions o;
  o.token = "abc def";
  EXPECT_THROW(JobClient("127.0.0.1:1", o), std::runtime_error);
  o.token = "abc\n";
  EXPECT_THROW(JobClient("127.0.0.1:1", o), std::runtime_error);
  o.token = "abc.DEF-123_~";
  EXPECT_NO_THROW(JobClient("127.0.0.1:1", o));
}

// ---- the JobSpec ----------------------------------------------------------------------------------

class JobSpecTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("epr-job-client-test-" + std::to_string(::getpid()));
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  // A one-quad OBJ with an MTL (a lit floor), so the bundle has two files.
  std::string write_scene() {
    std::ofstream(dir_ / "floor.mtl") << "newmtl white\nKd 0.8 0.8 0.8\nKe 1 1 1\n";
    std::ofstream(dir_ / "floor.obj") << "mtllib floor.mtl\nusemtl white\n"
                                         "v -1 0 -1\nv 1 0 -1\nv 1 0 1\nv -1 0 1\nf 1 2 3\nf 1 3 4\n";
    return (dir_ / "floor.obj").string();
  }

  LoopbackPort closed_{false};
  JobClient client_{closed_.target(), quick(2000)};
  fs::path dir_;
};

TEST_F(JobSpecTest, BuiltinWithoutOverridesSendsTheScenesOwnCamera) {
  RenderOptions o;
  o.scene = "builtin:hall?tess=2";
  o.width = 320;
  o.height = 200;
  o.spp = 64;
  o.paths_per_round = 4;
  o.mode = RenderMode::kSkip;
  o.seed = 77;
  SubmitOptions s;
  s.priority = 5;
  s.time_budget_seconds = 30;
  const v1::JobSpec spec = client_.make_job_spec(o, s);
  EXPECT_EQ(spec.scene().builtin(), "builtin:hall?tess=2");
  const CameraSpec own = load_scene("builtin:hall?tess=2").camera;
  ASSERT_TRUE(spec.has_camera());
  EXPECT_FLOAT_EQ(spec.camera().eye().x(), own.eye.x);
  EXPECT_FLOAT_EQ(spec.camera().eye().z(), own.eye.z);
  EXPECT_FLOAT_EQ(spec.camera().look().z(), own.look.z);
  EXPECT_FLOAT_EQ(spec.camera().fov_y_degrees(), own.fov_y_degrees);
  EXPECT_EQ(spec.name(), "hall?tess=2");
  EXPECT_EQ(spec.width(), 320u);
  EXPECT_EQ(spec.height(), 200u);
  EXPECT_EQ(spec.target_spp(), 64u);
  EXPECT_EQ(spec.paths_per_round(), 4u);
  EXPECT_EQ(spec.mode(), v1::RENDER_MODE_SKIP);
  EXPECT_EQ(spec.seed(), 77u);
  EXPECT_EQ(spec.priority(), 5);
  EXPECT_DOUBLE_EQ(spec.time_budget_seconds(), 30.0);
  // A fresh idempotency key per spec, unless the caller gives one.
  EXPECT_EQ(spec.request_id().size(), 32u);
  EXPECT_NE(client_.make_job_spec(o, s).request_id(), spec.request_id());
  s.request_id = "retry-me";
  EXPECT_EQ(client_.make_job_spec(o, s).request_id(), "retry-me");
}

TEST_F(JobSpecTest, FullCameraOverrideIsSentAsGiven) {
  RenderOptions o;
  o.scene = "builtin:cornell";
  o.eye = Vec3{1, 2, 3};
  o.look = Vec3{0, 1, 0};
  o.up = Vec3{0, 1, 0};
  o.fov = 50.f;
  const v1::JobSpec spec = client_.make_job_spec(o);
  ASSERT_TRUE(spec.has_camera());
  EXPECT_FLOAT_EQ(spec.camera().eye().x(), 1.f);
  EXPECT_FLOAT_EQ(spec.camera().eye().y(), 2.f);
  EXPECT_FLOAT_EQ(spec.camera().eye().z(), 3.f);
  EXPECT_FLOAT_EQ(spec.camera().fov_y_degrees(), 50.f);
}

TEST_F(JobSpecTest, PartialCameraOverrideIsCompletedFromTheScene) {
  RenderOptions o;
  o.scene = "builtin:hall";
  o.fov = 20.f;
  const CameraSpec own = load_scene("builtin:hall").camera;
  const v1::JobSpec spec = client_.make_job_spec(o);
  ASSERT_TRUE(spec.has_camera());
  EXPECT_FLOAT_EQ(spec.camera().eye().x(), own.eye.x);
  EXPECT_FLOAT_EQ(spec.camera().eye().y(), own.eye.y);
  EXPECT_FLOAT_EQ(spec.camera().eye().z(), own.eye.z);
  EXPECT_FLOAT_EQ(spec.camera().look().z(), own.look.z);
  EXPECT_FLOAT_EQ(spec.camera().fov_y_degrees(), 20.f);
}

TEST_F(JobSpecTest, SmallFileSceneTravelsInlineWithItsHash) {
  RenderOptions o;
  o.scene = write_scene();
  const v1::JobSpec spec = client_.make_job_spec(o);
  ASSERT_TRUE(spec.scene().has_files());
  EXPECT_EQ(spec.scene().files().entry_path(), "floor.obj");
  ASSERT_EQ(spec.scene().files().files_size(), 2);
  EXPECT_EQ(spec.scene().content_hash(), content_hash(bundle_scene(o.scene)));
  EXPECT_EQ(spec.name(), "floor.obj");
  ASSERT_TRUE(spec.has_camera());  // an OBJ's camera is CameraSpec's default
  EXPECT_FLOAT_EQ(spec.camera().eye().z(), CameraSpec{}.eye.z);
}

// `epr submit builtin:cornell --env FILE`: the image travels in the job's bundle beside a scene JSON
// naming the built-in, and the job names it by its file name inside that bundle.
TEST_F(JobSpecTest, BuiltinWithAnEnvironmentImageSendsTheImageInItsBundle) {
  Image sky(4, 2, 3);
  for (float& v : sky.data) v = 0.5f;
  write_exr((dir_ / "sky.exr").string(), sky);
  RenderOptions o;
  o.scene = "builtin:cornell";
  o.lighting.environment = EnvironmentLight{};
  o.lighting.environment->image = "sky.exr";
  o.env_folder = dir_.string();
  const v1::JobSpec spec = client_.make_job_spec(o);
  ASSERT_TRUE(spec.scene().has_files());
  EXPECT_EQ(spec.scene().files().entry_path(), "builtin.json");
  ASSERT_EQ(spec.scene().files().files_size(), 2);
  EXPECT_EQ(spec.scene().files().files(1).path(), "sky.exr");
  EXPECT_EQ(spec.environment().image(), "sky.exr");
  EXPECT_EQ(spec.scene().content_hash(), content_hash(bundle_scene(o.scene, o.lighting, o.env_folder)));
  EXPECT_EQ(spec.name(), "cornell");
  EXPECT_FLOAT_EQ(spec.camera().eye().z(), load_scene("builtin:cornell").camera.eye.z);  // the built-in's camera
}

TEST_F(JobSpecTest, LargeFileSceneIsUploadedFirst) {
  // With an inline limit below the scene's size the client must stream it with UploadScene, which
  // fails here (nothing listens) — and nothing else may be tried instead.
  JobClientOptions opts = quick(2000);
  opts.inline_scene_limit = 16;
  JobClient client(closed_.target(), opts);
  RenderOptions o;
  o.scene = write_scene();
  expect_rpc_error([&] { client.make_job_spec(o); }, grpc::StatusCode::UNAVAILABLE, closed_.target());
}

TEST_F(JobSpecTest, BadInputIsRejectedBeforeAnyCall) {
  RenderOptions o;
  o.scene = (dir_ / "missing.obj").string();
  EXPECT_THROW(client_.make_job_spec(o), SceneError);
  o.scene = "builtin:cornell";
  SubmitOptions s;
  s.name = std::string(300, 'n');
  EXPECT_THROW(client_.make_job_spec(o, s), std::invalid_argument);
  o.fov = 190.f;  // completed from the scene's camera, then rejected
  EXPECT_THROW(client_.make_job_spec(o), std::invalid_argument);
}

// ---- progress line ------------------------------------------------------------------------------

TEST(ProgressLine, ShowsRoundSamplesSkippedAndTimes) {
  v1::JobStatus s;
  s.set_id("j1");
  s.set_state(v1::JOB_STATE_RUNNING);
  s.mutable_effective()->set_mode(v1::RENDER_MODE_RP);
  s.mutable_effective()->set_width(100);
  s.mutable_effective()->set_height(50);
  s.set_target_spp(64);
  s.set_round(8);
  s.set_rounds_planned(16);
  s.set_spp_mean(32.0);
  s.set_spp_min(8);
  s.set_reprojected_per_pixel_mean(4.5);
  s.set_pixels_skipped(1250);  // a quarter of 5000
  s.set_seconds_elapsed(75);
  s.set_eta_seconds(12);
  const std::string line = progress_line(s, 10);
  EXPECT_NE(line.find("[#####.....]"), std::string::npos) << line;
  EXPECT_NE(line.find("round    8/16"), std::string::npos) << line;  // the bar: 8 of 16 rounds
  EXPECT_NE(line.find("spp   32.0/64 (min 8)"), std::string::npos) << line;
  EXPECT_NE(line.find("M'   4.5"), std::string::npos) << line;
  EXPECT_NE(line.find("skipped  25%"), std::string::npos) << line;
  EXPECT_NE(line.find("1m15s"), std::string::npos) << line;
  EXPECT_NE(line.find("ETA 12.0s"), std::string::npos) << line;
  // SKIP: the slowest pixel, 8 of 64 samples, is what is left to do.
  s.mutable_effective()->set_mode(v1::RENDER_MODE_SKIP);
  EXPECT_NE(progress_line(s, 8).find("[#.......]"), std::string::npos) << progress_line(s, 8);
  s.set_state(v1::JOB_STATE_DONE);
  EXPECT_NE(progress_line(s, 8).find("[########]"), std::string::npos) << progress_line(s, 8);
  s.set_state(v1::JOB_STATE_RUNNING);
  s.set_eta_seconds(-1);
  EXPECT_NE(progress_line(s).find("ETA ?"), std::string::npos);
  s.set_state(v1::JOB_STATE_QUEUED);
  EXPECT_NE(progress_line(s).find("queued"), std::string::npos);
}

// ---- the epr binary -----------------------------------------------------------------------------

// The `epr` executable: $EPR_BIN, the EPR_CLI_PATH compile definition, or client/epr beside the
// test binary's tests/ folder in the build tree.
std::string epr_binary() {
  if (const char* env = std::getenv("EPR_BIN"); env && *env) return env;
#ifdef EPR_CLI_PATH
  return EPR_CLI_PATH;
#else
  const fs::path self = fs::read_symlink("/proc/self/exe");
  return (self.parent_path().parent_path() / "client" / "epr").string();
#endif
}

struct CliRun {
  int exit_code = -1;
  std::string err;  // stderr
  std::string out;  // stdout
  double seconds = 0;
};

CliRun run_epr(const std::string& args, const std::string& env = "") {
  const fs::path err_file = fs::temp_directory_path() / ("epr-cli-test-" + std::to_string(::getpid()) + ".err");
  const std::string cmd = env + " '" + epr_binary() + "' " + args + " 2>'" + err_file.string() + "'";
  CliRun r;
  const auto t0 = Clock::now();
  FILE* p = ::popen(cmd.c_str(), "r");
  if (!p) return r;
  std::array<char, 4096> buf;
  size_t n;
  while ((n = std::fread(buf.data(), 1, buf.size(), p)) > 0) r.out.append(buf.data(), n);
  const int status = ::pclose(p);
  r.seconds = seconds_since(t0);
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  std::ifstream in(err_file);
  r.err.assign(std::istreambuf_iterator<char>(in), {});
  fs::remove(err_file);
  return r;
}

class EprCli : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_TRUE(fs::exists(epr_binary())) << "epr binary not found at " << epr_binary() << " (set EPR_BIN)";
  }
};

TEST_F(EprCli, UnreachableMasterExitsWithCode3AndNamesIt) {
  LoopbackPort closed(false);
  for (const std::string cmd : {"list", "get job-1", "cancel job-1", "watch job-1", "submit builtin:cornell --spp 4"}) {
    const CliRun r = run_epr(cmd + " --master " + closed.target());
    EXPECT_EQ(r.exit_code, kExitUnreachable) << cmd << ": " << r.err;
    EXPECT_NE(r.err.find("cannot reach master at " + closed.target()), std::string::npos) << cmd << ": " << r.err;
    EXPECT_TRUE(r.out.empty()) << cmd << ": " << r.out;
    EXPECT_LT(r.seconds, 8.0) << cmd;
  }
}

TEST_F(EprCli, MasterDefaultsToTheEnvironment) {
  LoopbackPort closed(false);
  const CliRun r = run_epr("list", "EPR_MASTER=" + closed.target());
  EXPECT_EQ(r.exit_code, kExitUnreachable) << r.err;
  EXPECT_NE(r.err.find(closed.target()), std::string::npos) << r.err;
}

TEST_F(EprCli, SilentMasterEndsAtTheTimeout) {
  LoopbackPort silent(true);
  for (const std::string cmd : {"list", "watch job-1", "get job-1"}) {
    const CliRun r = run_epr(cmd + " --timeout 0.5 --master " + silent.target());
    EXPECT_EQ(r.exit_code, kExitUnreachable) << cmd << ": " << r.err;
    EXPECT_NE(r.err.find(silent.target()), std::string::npos) << cmd << ": " << r.err;
    EXPECT_LT(r.seconds, 6.0) << cmd;
  }
}

TEST_F(EprCli, BadArgumentsExitNonZeroWithAMessage) {
  LoopbackPort closed(false);
  const std::string master = " --master " + closed.target();
  struct Case {
    std::string args;
    std::string message;
    int code;  // 0: any non-zero code (CLI11's parse errors have their own)
  };
  const Case cases[] = {
      {"submit builtin:cornell --spp 0" + master, "--spp", kExitUsage},
      {"submit builtin:cornell --eye 1,2" + master, "--eye", kExitUsage},
      {"submit /nonexistent/scene.obj" + master, "/nonexistent/scene.obj", kExitUsage},
      {"submit builtin:nosuchscene" + master, "nosuchscene", kExitUsage},
      {"submit builtin:nosuchscene --eye 0,1,3 --look 0,1,0" + master, "nosuchscene", kExitUsage},
      {"get job-1 --token-file /nonexistent/token" + master, "/nonexistent/token", kExitUsage},
      {"list --master nocolon", "HOST:PORT", kExitUsage},
      {"watch" + master, "job", 0},
      {"list --timeout 0" + master, "--timeout", 0},
      {"list --state sleeping" + master, "--state", 0},
      {"submit builtin:cornell --threads 2" + master, "--threads", 0},
  };
  for (const Case& c : cases) {
    const CliRun r = run_epr(c.args);
    if (c.code)
      EXPECT_EQ(r.exit_code, c.code) << c.args << ": " << r.err;
    else
      EXPECT_NE(r.exit_code, 0) << c.args << ": " << r.err;
    EXPECT_NE(r.err.find(c.message), std::string::npos) << c.args << ": " << r.err;
  }
}

TEST_F(EprCli, EmptyTokenFileIsAUsageError) {
  const fs::path token = fs::temp_directory_path() / ("epr-cli-token-" + std::to_string(::getpid()));
  std::ofstream(token) << "  \n";
  const CliRun r = run_epr("list --master 127.0.0.1:1 --token-file " + token.string());
  fs::remove(token);
  EXPECT_EQ(r.exit_code, kExitUsage) << r.err;
  EXPECT_NE(r.err.find("empty"), std::string::npos) << r.err;
}

}  // namespace
}  // namespace epr
