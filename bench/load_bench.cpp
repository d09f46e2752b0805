// Peak memory of the master against image size and number of jobs: for each size x jobs pair, a fresh
// epr-master process gets that many jobs at once (queued behind one another), in-process WorkerNodes
// render them, and the master's VmHWM (/proc/PID/status) is read once every job is done. Prints one
// row per pair with the wall time and the load average, and what the jobs added to the idle master's
// RSS per pixel and per subpixel of one job (peak minus the RSS before the first submission), and the
// longest frame-state set-up the master logged (its deep framebuffer / plane grid and accumulation).
// Square sides with --sizes, any frames with --frames 1920x1080,3840x2160. See docs/BENCHMARKS.md
// section 7.
#include <grpcpp/grpcpp.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <regex>
#include <sstream>
#include <thread>

#include "bench/bench_worker.h"
#include "common/log.h"
#include "epr/v1/job_service.grpc.pb.h"
#include "tests/integration/cluster/process.h"
#include "wire/convert.h"
#include "wire/scene_bundle.h"
#include "worker/worker_node.h"

namespace {
namespace fs = std::filesystem;
using namespace std::chrono_literals;

std::vector<int> parse_list(const std::string& s) {
  std::vector<int> out;
  std::stringstream ss(s);
  for (std::string item; std::getline(ss, item, ',');) out.push_back(std::stoi(item));
  return out;
}

// "1920x1080,3840x2160" -> {{1920, 1080}, {3840, 2160}}; a plain number is a square side.
std::vector<std::pair<int, int>> parse_frames(const std::string& s) {
  std::vector<std::pair<int, int>> out;
  std::stringstream ss(s);
  for (std::string item; std::getline(ss, item, ',');) {
    const size_t x = item.find('x');
    if (x == std::string::npos)
      out.emplace_back(std::stoi(item), std::stoi(item));
    else
      out.emplace_back(std::stoi(item.substr(0, x)), std::stoi(item.substr(x + 1)));
  }
  return out;
}

// VmHWM and VmRSS of a process, bytes.
std::pair<uint64_t, uint64_t> memory_of(pid_t pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/status");
  uint64_t hwm = 0, rss = 0;
  for (std::string line; std::getline(in, line);) {
    if (line.rfind("VmHWM:", 0) == 0) hwm = std::stoull(line.substr(6)) * 1024;
    if (line.rfind("VmRSS:", 0) == 0) rss = std::stoull(line.substr(6)) * 1024;
  }
  return {hwm, rss};
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"load_bench: epr-master peak RSS against image size and number of jobs"};
  std::string sizes = "256,512,1024", frames, jobs = "1,4,16", mode = "skip", reproject = "cpu";
  int spp = 2, k = 1, threads = 2, max_depth = 4, subpixels = 4;
  app.add_option("--sizes", sizes, "image sides (square images)")->capture_default_str();
  app.add_option("--frames", frames, "image sizes WxH, e.g. 1920x1080,3840x2160 (instead of --sizes)");
  app.add_option("--subpixels", subpixels, "S, subpixels per axis")->capture_default_str();
  std::string master_bin = EPR_MASTER_BIN;
  bool checkpoints = true;
  app.add_flag("--checkpoints,!--no-checkpoints", checkpoints,
               "run the master with a state directory (checkpoints after rounds), as by default");
  app.add_option("--master-bin", master_bin, "the epr-master to measure (e.g. an older build, side by side)")
      ->capture_default_str();
  std::vector<std::string> master_args;
  app.add_option("--master-arg", master_args, "an extra epr-master argument (repeat for several)");
  app.add_option("--jobs", jobs, "numbers of jobs submitted at once")->capture_default_str();
  app.add_option("--spp", spp, "samples per pixel of each job")->capture_default_str();
  app.add_option("--paths-per-round", k, "paths per pixel and round")->capture_default_str();
  app.add_option("--max-depth", max_depth, "path length limit (keeps the tracing short)")->capture_default_str();
  app.add_option("--mode", mode, "pt, rp or skip")->check(CLI::IsMember({"pt", "rp", "skip"}))->capture_default_str();
  app.add_option("--reproject", reproject, "master reprojector: cpu, or gl (OSMesa)")
      ->check(CLI::IsMember({"cpu", "gl"}))
      ->capture_default_str();
  app.add_option("--threads", threads, "tracing threads (one in-process WorkerNode)")->capture_default_str();
  CLI11_PARSE(app, argc, argv);
  epr::set_log_level("warn");

  const fs::path dir = fs::temp_directory_path() / ("epr-load-bench-" + std::to_string(::getpid()));
  std::printf(
      "# epr-master peak RSS (VmHWM); %s, spp %d, k %d, max depth %d, S %d, %s reprojector, %d tracing threads\n"
      "# B/pixel, B/subpixel: (peak - idle RSS) over the pixels (subpixels) of one job\n",
      mode.c_str(), spp, k, max_depth, subpixels, reproject.c_str(), threads);
  std::printf("%10s %5s %10s %14s %12s %9s %8s %8s %8s %9s %7s\n", "frame", "jobs", "pixels", "peak RSS MiB",
              "end RSS MiB", "idle MiB", "B/pixel", "B/subpx", "setup s", "seconds", "load");
  const auto frame_list = frames.empty() ? parse_frames(sizes) : parse_frames(frames);
  for (const auto& [fw, fh] : frame_list) {
    for (int n : parse_list(jobs)) {
      fs::remove_all(dir);
      fs::create_directories(dir);
      std::vector<std::string> args = {
          master_bin,    "--listen", "127.0.0.1:0", "--http", "", "--state-dir", (dir / "state").string(),
          "--log-level", "info"};
      if (reproject == "cpu") args.insert(args.end(), {"--reproject", "cpu"});
      if (!checkpoints) args.erase(args.begin() + 5, args.begin() + 7);  // no --state-dir: no checkpoints
      args.insert(args.end(), master_args.begin(), master_args.end());
      epr::testing::Process master(args, dir / "master");
      const std::regex listening("epr-master listening on port ([0-9]+)");
      std::smatch m;
      std::string err;
      if (!epr::testing::wait_until(
              [&] { return std::regex_search(err = master.err(), m, listening) || !master.running(); }, 120s) ||
          !master.running()) {
        std::fprintf(stderr, "epr-master did not start (%s):\n%s\n",
                     master.running() ? "no port within 120 s"
                                      : ("exit code " + std::to_string(master.exit_code().value_or(-1))).c_str(),
                     err.c_str());
        return 1;
      }
      const std::string target = "127.0.0.1:" + m[1].str();
      const uint64_t idle = memory_of(master.pid()).second;
      auto stub = epr::v1::JobService::NewStub(grpc::CreateChannel(target, grpc::InsecureChannelCredentials()));
      const auto start = std::chrono::steady_clock::now();
      std::vector<std::string> ids;
      for (int j = 0; j < n; ++j) {
        epr::RenderOptions o;
        o.width = fw;
        o.height = fh;
        o.subpixels = subpixels;
        o.spp = spp;
        o.paths_per_round = k;
        o.mode = mode == "pt"   ? epr::RenderMode::kPathTrace
                 : mode == "rp" ? epr::RenderMode::kReproject
                                : epr::RenderMode::kSkip;
        o.reproject = reproject == "cpu" ? epr::ReprojectMethod::kCpu : epr::ReprojectMethod::kGl;
        o.rr.max_depth = max_depth;
        o.seed = uint64_t(j + 1);
        grpc::ClientContext ctx;
        ctx.set_deadline(std::chrono::system_clock::now() + 30s);
        epr::v1::JobId id;
        const grpc::Status st =
            stub->SubmitJob(&ctx, epr::to_job_spec(o, epr::bundle_scene("builtin:cornell"), epr::CameraSpec{}), &id);
        if (!st.ok()) {
          std::fprintf(stderr, "SubmitJob: %s\n", st.error_message().c_str());
          return 1;
        }
        ids.push_back(id.id());
      }
      epr::WorkerNodeOptions wo;
      wo.master = target;
      wo.threads = threads;
      wo.name = "bench";
      wo.cache_dir = (dir / "cache").string();
      epr::WorkerNode node(wo);
      std::thread node_thread([&] { node.run(); });
      bool ok = true;
      for (const std::string& id : ids) {
        while (ok) {
          grpc::ClientContext ctx;
          ctx.set_deadline(std::chrono::system_clock::now() + 30s);
          epr::v1::JobId req;
          req.set_id(id);
          epr::v1::JobStatus s;
          if (const grpc::Status st = stub->GetJob(&ctx, req, &s); !st.ok()) {
            std::fprintf(stderr, "GetJob %s: %s\n", id.c_str(), st.error_message().c_str());
            ok = false;
            break;
          }
          if (s.state() == epr::v1::JOB_STATE_DONE) break;
          if (s.state() == epr::v1::JOB_STATE_FAILED || s.state() == epr::v1::JOB_STATE_CANCELLED) {
            std::fprintf(stderr, "job %s ended: %s\n", id.c_str(), s.error_message().c_str());
            ok = false;
            break;
          }
          std::this_thread::sleep_for(50ms);
        }
      }
      const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      const auto [hwm, rss] = memory_of(master.pid());
      node.stop();
      node_thread.join();
      master.stop();
      if (!ok) {
        fs::remove_all(dir);
        return 1;
      }
      const double pixels = double(fw) * fh, added = double(hwm) - double(idle);
      // The longest set-up of a job's frame state (deep framebuffer or plane grid, accumulation), from
      // the master's log.
      double setup = -1;
      const std::string log = master.err();
      const std::regex setup_line(R"(frame state \(deep framebuffer, accumulation\) ([0-9.]+) s)");
      for (auto it = std::sregex_iterator(log.begin(), log.end(), setup_line); it != std::sregex_iterator(); ++it)
        setup = std::max(setup, std::stod((*it)[1].str()));
      const std::string frame = std::to_string(fw) + "x" + std::to_string(fh);
      std::printf("%10s %5d %10llu %14.1f %12.1f %9.1f %8.1f %8.2f %8.2f %9.1f %7.2f\n", frame.c_str(), n,
                  (unsigned long long)fw * fh * n, double(hwm) / (1 << 20), double(rss) / (1 << 20),
                  double(idle) / (1 << 20), added / pixels, added / (pixels * subpixels * subpixels), setup, seconds,
                  epr::bench::load_average());
      std::fflush(stdout);
    }
  }
  fs::remove_all(dir);
  return 0;
}
