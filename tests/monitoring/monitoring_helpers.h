// Shared pieces of the monitoring tests: an in-process master with its HTTP endpoint, a hand-driven
// worker (rounds advance only when the test says), the Prometheus text parser of
// python3-prometheus-client, PNG header checks, and a child process with its output in a file.
#pragma once

#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>
#include <httplib.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <optional>
#include <regex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "client/job_client.h"
#include "epr/v1/worker_service.grpc.pb.h"
#include "master/server/master_server.h"
#include "tests/wait_until.h"
#include "wire/convert.h"
#include "wire/scene_bundle.h"
#include "wire/tile_result_stream.h"
#include "worker/tile_renderer.h"

extern char** environ;

namespace epr::monitoring_test {

using json = nlohmann::json;
using Clock = std::chrono::steady_clock;
namespace fs = std::filesystem;

inline double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

/// Polls `done` every 20 ms for up to `seconds`.
template <typename F>
bool wait_for(F done, double seconds) {
  return test::wait_until(done, std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(seconds)),
                          std::chrono::milliseconds(20));
}

/// An in-process master (gRPC and HTTP on free loopback ports); `token`: the bearer token it requires.
inline std::unique_ptr<MasterServer> start_master(const std::string& reproject_override = "cpu",
                                                  const std::string& token = "") {
  MasterServerOptions o;
  o.listen = "127.0.0.1:0";
  o.http_listen = "127.0.0.1:0";
  o.jobs.reproject_backend_override = reproject_override;
  o.token = token;
  return std::make_unique<MasterServer>(o);
}

inline httplib::Client http_client(const MasterServer& m) {
  httplib::Client c("127.0.0.1", m.http_port());
  c.set_connection_timeout(5, 0);
  c.set_read_timeout(10, 0);
  return c;
}

/// GET that must answer; returns status and body.
inline std::pair<int, std::string> get(httplib::Client& c, const std::string& path) {
  auto r = c.Get(path.c_str());
  if (!r) {
    ADD_FAILURE() << "GET " << path << " failed: " << httplib::to_string(r.error());
    return {0, ""};
  }
  return {r->status, r->body};
}

inline json get_json(httplib::Client& c, const std::string& path, int want_status = 200) {
  auto r = c.Get(path.c_str());
  if (!r) {
    ADD_FAILURE() << "GET " << path << " failed: " << httplib::to_string(r.error());
    return {};
  }
  EXPECT_EQ(r->status, want_status) << path << ": " << r->body;
  EXPECT_EQ(r->get_header_value("Content-Type"), "application/json") << path;
  return json::parse(r->body, nullptr, false);
}

/// A small skip-mode job (4 x 3 tiles of 16 pixels).
inline RenderOptions small_job(int spp = 8) {
  RenderOptions o;
  o.scene = "builtin:cornell";
  o.width = 64;
  o.height = 48;
  o.spp = spp;
  o.paths_per_round = 1;
  o.mode = RenderMode::kSkip;
  o.tile_size = 16;
  return o;
}

/// Width and height from a PNG's IHDR chunk; {0, 0} if the bytes are not a PNG.
inline std::pair<uint32_t, uint32_t> png_size(const std::string& bytes) {
  static const std::string sig("\x89PNG\r\n\x1a\n", 8);
  if (bytes.size() < 33 || bytes.compare(0, 8, sig) != 0 || bytes.compare(12, 4, "IHDR") != 0) return {0, 0};
  auto be32 = [&](size_t at) {
    return uint32_t(uint8_t(bytes[at])) << 24 | uint32_t(uint8_t(bytes[at + 1])) << 16 |
           uint32_t(uint8_t(bytes[at + 2])) << 8 | uint32_t(uint8_t(bytes[at + 3]));
  };
  return {be32(16), be32(20)};
}

inline std::string read_file(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

/// Parses Prometheus text with python3-prometheus-client (Debian's /usr/bin/python3):
/// {family: {"type", "help", "samples": [[name, {labels}, value], ...]}}. Fails the test if the parser
/// rejects the text.
inline json parse_prometheus(const std::string& text, const fs::path& scratch) {
  fs::create_directories(scratch);
  const fs::path in = scratch / "metrics.txt", script = scratch / "parse_metrics.py", out = scratch / "metrics.json";
  std::ofstream(in, std::ios::binary) << text;
  std::ofstream(script) << R"PY(import json, math, sys
from prometheus_client.parser import text_string_to_metric_families
families = {}
for f in text_string_to_metric_families(open(sys.argv[1]).read()):
    families[f.name] = {"type": f.type, "help": f.documentation,
                        "samples": [[s.name, s.labels, s.value if math.isfinite(s.value) else str(s.value)] for s in f.samples]}
json.dump(families, open(sys.argv[2], "w"))
)PY";
  const std::string cmd = "/usr/bin/python3 " + script.string() + " " + in.string() + " " + out.string() + " 2>&1";
  std::string output;
  FILE* p = popen(cmd.c_str(), "r");
  if (!p) {
    ADD_FAILURE() << "cannot run " << cmd;
    return {};
  }
  char buf[512];
  while (size_t n = fread(buf, 1, sizeof buf, p)) output.append(buf, n);
  const int status = pclose(p);
  if (status != 0) {
    ADD_FAILURE() << "the Prometheus parser rejected /metrics: " << output;
    return {};
  }
  return json::parse(read_file(out));
}

/// The value of one sample (family sample `name` with exactly `labels`); NaN if absent.
inline double sample(const json& families, const std::string& name, const json& labels = json::object()) {
  for (const auto& [fname, f] : families.items())
    for (const auto& s : f["samples"])
      if (s[0] == name && s[1] == labels) return s[2].is_number() ? s[2].get<double>() : NAN;
  return NAN;
}

/// A worker driven by the test over the real WorkerService: it leases, traces and submits tiles only
/// when asked, so rounds close exactly when the test wants.
class ManualWorker {
 public:
  /// `token`: the master's bearer token, if it requires one.
  explicit ManualWorker(const std::string& target, std::string token = "")
      : stub_(v1::WorkerService::NewStub(grpc::CreateChannel(target, grpc::InsecureChannelCredentials()))),
        token_(std::move(token)) {
    register_worker();
  }

  /// Leases, traces and submits the tiles of one round until the master has none to give; returns how
  /// many were committed. A tile of a later round (the round closed between two leases) is kept for
  /// the next call, so that each call closes at most one round.
  int work_available() {
    int committed = 0;
    std::optional<uint32_t> round;
    for (;;) {
      v1::Lease lease;
      if (next_) {
        lease = std::move(*next_);
        next_.reset();
      } else {
        grpc::ClientContext ctx;
        deadline(&ctx);
        v1::LeaseRequest req;
        req.mutable_worker_id()->set_id(id_);
        const grpc::Status st = stub_->LeaseTile(&ctx, req, &lease);
        if (st.error_code() == grpc::StatusCode::NOT_FOUND) {  // forgotten after a long pause
          register_worker();
          continue;
        }
        if (!st.ok()) {
          ADD_FAILURE() << "LeaseTile: " << st.error_message();
          return committed;
        }
      }
      if (!lease.has_tile()) return committed;
      if (round && lease.tile().round() != *round) {
        next_ = std::move(lease);
        return committed;
      }
      round = lease.tile().round();
      committed += submit(lease.tile()) ? 1 : 0;
    }
  }

  /// Keeps the worker registered during long pauses of the test.
  void heartbeat() {
    grpc::ClientContext ctx;
    deadline(&ctx);
    v1::HeartbeatRequest req;
    req.mutable_worker_id()->set_id(id_);
    v1::HeartbeatResponse resp;
    if (stub_->Heartbeat(&ctx, req, &resp).error_code() == grpc::StatusCode::NOT_FOUND) register_worker();
  }

 private:
  void deadline(grpc::ClientContext* ctx) const {
    ctx->set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(30));
    if (!token_.empty()) ctx->AddMetadata("authorization", "Bearer " + token_);
  }

  void register_worker() {
    grpc::ClientContext ctx;
    deadline(&ctx);
    v1::WorkerInfo info;
    info.set_protocol_version(v1::PROTOCOL_VERSION_V1);
    info.set_name("manual-test-worker");
    info.set_threads(1);
    v1::RegisterResponse r;
    const grpc::Status st = stub_->Register(&ctx, info, &r);
    ASSERT_TRUE(st.ok()) << st.error_message();
    id_ = r.worker_id().id();
  }

  bool submit(const v1::TileLease& t) {
    const auto& s = t.settings();
    if (!tracer_ || traced_job_ != t.job_id()) {
      scene_ = std::make_unique<Scene>(load_bundle(bundle_scene(t.scene().builtin()), default_cache_root()));
      embree_ = std::make_unique<EmbreeScene>(*scene_);
      camera_ = std::make_unique<Camera>(from_proto(s.camera()), int(s.width()), int(s.height()));
      tracer_ = std::make_unique<PathTracer>(*embree_, *camera_, t.seed(), from_proto(s.russian_roulette()));
      traced_job_ = t.job_id();
    }
    VertexFilter f;
    f.mode = s.mode() == v1::RENDER_MODE_PT ? VertexFilter::Mode::kNone : VertexFilter::Mode::kCull;
    f.subpixels = int(s.reprojection().subpixels());
    TileRenderer tr(*tracer_, f);
    const TileRect rect{int(t.rect().x0()), int(t.rect().y0()), int(t.rect().x1()), int(t.rect().y1())};
    const size_t n = size_t(rect.pixel_count());
    std::vector<uint8_t> skip(n, 0);
    for (size_t i = 0; i < n && i / 8 < t.skip_bits().size(); ++i)
      skip[i] = (uint8_t(t.skip_bits()[i / 8]) >> (i % 8)) & 1;
    std::vector<uint32_t> first(n, t.uniform_first_sample_index());
    for (int i = 0; i < t.first_sample_index_size(); ++i) first[size_t(i)] = t.first_sample_index(i);
    const std::vector<uint32_t> paths(t.pixel_paths().begin(), t.pixel_paths().end());
    const TileResult result = tr.render({rect, skip, first, int(t.paths_per_pixel()), paths});
    TileResultIdentity identity{t.lease_id(), t.job_id(), t.round(), t.tile_index(), id_};
    const auto chunks = split_tile_result(result, identity, from_proto(s.codec_bounds()), TileResultLimits{});
    grpc::ClientContext ctx;
    deadline(&ctx);
    v1::SubmitAck ack;
    auto writer = stub_->SubmitTile(&ctx, &ack);
    for (const auto& c : chunks)
      if (!writer->Write(c)) break;
    writer->WritesDone();
    const grpc::Status st = writer->Finish();
    EXPECT_TRUE(st.ok()) << "SubmitTile: " << st.error_message();
    return st.ok() && ack.outcome() == v1::SUBMIT_OUTCOME_COMMITTED;
  }

  std::unique_ptr<v1::WorkerService::Stub> stub_;
  std::string token_;
  std::string id_;
  std::optional<v1::Lease> next_;  // a tile of the next round, leased before this round was done
  std::string traced_job_;
  std::unique_ptr<Scene> scene_;
  std::unique_ptr<EmbreeScene> embree_;
  std::unique_ptr<Camera> camera_;
  std::unique_ptr<PathTracer> tracer_;
};

/// A child process whose stdout and stderr go to `log`; killed (SIGTERM, then SIGKILL) on destruction.
class ChildProcess {
 public:
  ChildProcess(const std::vector<std::string>& argv, const fs::path& log) : log_(log) {
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_addopen(&fa, 1, log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    posix_spawn_file_actions_adddup2(&fa, 1, 2);
    std::vector<char*> args;
    for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
    args.push_back(nullptr);
    if (posix_spawn(&pid_, args[0], &fa, nullptr, args.data(), environ) != 0) pid_ = -1;
    posix_spawn_file_actions_destroy(&fa);
  }
  ~ChildProcess() { stop(); }
  ChildProcess(const ChildProcess&) = delete;
  ChildProcess& operator=(const ChildProcess&) = delete;

  bool started() const { return pid_ > 0; }
  std::string output() const { return read_file(log_); }
  /// Waits up to `seconds` for `pattern` in the output; returns its first group (or the whole match).
  std::string wait_for_output(const std::regex& pattern, double seconds) const {
    std::smatch m;
    std::string out;
    wait_for(
        [&] {
          out = output();
          return std::regex_search(out, m, pattern);
        },
        seconds);
    if (m.empty()) return "";
    return m.size() > 1 ? m[1].str() : m[0].str();
  }
  void stop() {
    if (pid_ <= 0) return;
    ::kill(pid_, SIGTERM);
    for (int i = 0; i < 100; ++i) {
      if (::waitpid(pid_, nullptr, WNOHANG) == pid_) {
        pid_ = -1;
        return;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    ::kill(pid_, SIGKILL);
    ::waitpid(pid_, nullptr, 0);
    pid_ = -1;
  }

 private:
  fs::path log_;
  pid_t pid_ = -1;
};

/// A fresh scratch folder for one test.
inline fs::path scratch_dir(const std::string& name) {
  const fs::path d = fs::temp_directory_path() / ("epr-monitoring-" + std::to_string(::getpid()) + "-" + name);
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

}  // namespace epr::monitoring_test
