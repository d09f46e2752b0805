// The real programs on loopback, no mocks: an epr-master process, epr-worker processes and the `epr`
// client. A job rendered by the cluster must equal `epr render --single-process` of the same job
// (DESIGN.md section 2, "Determinism"): per-pixel counts M and M' and the path-traced estimate
// bit-identical, the combined image equal up to float rounding — whatever the number of workers,
// whether a worker joins mid-job or is killed with SIGKILL (section 4). Also: a job whose pixels are
// all skipped ends, and bad arguments or an unreachable master give a quick, clear failure.
//
// Jobs are small (Cornell box or furnace, 48x48 to 96x96, skip mode so that reprojection and
// skipping both run) and every worker traces with one thread: the file takes about a minute on two
// cores. Each test gets a temp folder with every process's stdout/stderr; it is kept, and the logs'
// tails printed, when the test fails. Workers log at debug level: their lease lines say which
// worker committed which tile, the only per-worker record the system keeps.
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <regex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "binaries.h"
#include "common/image.h"
#include "common/render_options.h"
#include "farm_steps.h"
#include "image_difference.h"
#include "process.h"

namespace epr::testing {
namespace {
namespace fs = std::filesystem;
using namespace std::chrono_literals;

// ---- jobs ----------------------------------------------------------------------------------------

// The default: about a second of tracing for one worker, in 36 tiles per round and 4 rounds, with
// reprojection and pixel skipping (most pixels stop after the first round).
struct Job {
  std::string scene = "builtin:cornell";
  int size = 96;  // width = height, pixels
  int spp = 32;   // P
  int k = 8;      // paths per round
  int tile = 16;
  int min_paths = 8;
  float round_growth = RenderOptions{}.round_growth;
  uint64_t seed = 7;
  bool mis = true;  // false: --no-mis (next event estimation only)
  float reprojected_weight = RenderOptions{}.reprojected_weight;
  std::string rr;       // --rr; empty: the default roulette
  Args camera;          // camera overrides (--eye, --look, ...); empty: the scene's camera
  std::string combine;  // --combine; empty: the default rule
  bool path_budget = false;

  // The flags shared by `epr render` and `epr submit`. The reprojector is the default (the OSMesa
  // deep framebuffer) on both sides: the cluster runs what a user runs.
  Args flags() const {
    Args a{scene,
           "--width",
           std::to_string(size),
           "--height",
           std::to_string(size),
           "--spp",
           std::to_string(spp),
           "--paths-per-round",
           std::to_string(k),
           "--tile",
           std::to_string(tile),
           "--mode",
           "skip",
           "--min-paths",
           std::to_string(min_paths),
           "--round-growth",
           std::to_string(round_growth),
           "--seed",
           std::to_string(seed)};
    if (!mis) a.push_back("--no-mis");
    if (!rr.empty()) {
      a.push_back("--rr");
      a.push_back(rr);
    }
    if (reprojected_weight != RenderOptions{}.reprojected_weight) {
      a.push_back("--reprojected-weight");
      a.push_back(fmt::format("{}", reprojected_weight));
    }
    if (!combine.empty()) {
      a.push_back("--combine");
      a.push_back(combine);
    }
    if (path_budget) a.push_back("--path-budget");
    a.insert(a.end(), camera.begin(), camera.end());
    return a;
  }
};

// A job that keeps one single-threaded worker busy for several seconds: the first `full_rounds`
// rounds trace every pixel (min-paths), then skipping thins the work out until round 16.
Job long_job(int k, int full_rounds) {
  Job job;
  job.size = 96;
  job.spp = 128;
  job.k = k;
  job.min_paths = k * full_rounds;
  job.tile = 32;
  return job;
}

// ---- image comparison ------------------------------------------------------------------------------

struct Images {
  Image counts, pathtrace, combined;
  nlohmann::json stats;
};

Images load_outputs(const std::string& prefix) {
  Images im;
  im.counts = read_image(prefix + ".counts.exr");
  im.pathtrace = read_image(prefix + ".pathtrace.exr");
  im.combined = read_image(prefix + ".exr");
  im.stats = nlohmann::json::parse(read_text(prefix + ".json"));
  return im;
}

// Per-pixel M (channel 0) and M' (channel 1) of a counts image.
struct Counts {
  uint64_t pixels = 0, m_sum = 0, mprime_sum = 0, m_below_target = 0, m_max = 0;
  uint64_t m_min = ~uint64_t(0), effective_min = ~uint64_t(0);
};

Counts summarize(const Image& counts, int target) {
  Counts c;
  for (int y = 0; y < counts.height; ++y)
    for (int x = 0; x < counts.width; ++x) {
      const uint64_t m = uint64_t(counts.at(x, y)[0]), mp = uint64_t(counts.at(x, y)[1]);
      ++c.pixels;
      c.m_sum += m;
      c.mprime_sum += mp;
      c.m_below_target += m < uint64_t(target);
      c.m_min = std::min(c.m_min, m);
      c.m_max = std::max(c.m_max, m);
      c.effective_min = std::min(c.effective_min, m + mp);
    }
  return c;
}

// Pixels whose M is no sum of whole rounds of the job's schedule: they traced a path budget of fewer
// than a round's paths (FrameState::path_budget).
uint64_t budgeted_pixels(const Image& counts, const Job& job) {
  RenderOptions o;
  o.spp = job.spp, o.paths_per_round = job.k, o.round_growth = job.round_growth;
  std::vector<uint64_t> ends{0};
  while (ends.back() < uint64_t(o.spp)) ends.push_back(ends.back() + uint64_t(round_paths(o, int(ends.back()))));
  uint64_t n = 0;
  for (int y = 0; y < counts.height; ++y)
    for (int x = 0; x < counts.width; ++x)
      n += !std::binary_search(ends.begin(), ends.end(), uint64_t(counts.at(x, y)[0]));
  return n;
}

// ---- the fixture -----------------------------------------------------------------------------------

class ClusterTest : public SingleMasterTest {
 protected:
  void SetUp() override { start_story("epr-cluster"); }

  // Starts epr-master on a free loopback port and waits until it says which.
  void start_master(Args extra = {}) {
    Args argv{kMaster, "--listen", "127.0.0.1:0", "--state-dir", path("master-state")};
    // Monitoring on a free port as well: the default 0.0.0.0:8080 collides between tests run in parallel.
    argv.insert(argv.end(), {"--http", "127.0.0.1:0", "--log-level", "info"});
    argv.insert(argv.end(), extra.begin(), extra.end());
    master_ = std::make_unique<Process>(argv, dir_ / "master");
    const std::regex listening("epr-master listening on port ([0-9]+)");
    std::smatch m;
    std::string err;
    const bool up = wait_until(
        [&] {
          err = master_->err();
          return std::regex_search(err, m, listening) || !master_->running();
        },
        10s);
    ASSERT_TRUE(up && master_->running() && m.size() == 2) << "epr-master did not start:\n" << err;
    port_ = std::stoi(m[1].str());
    // The default reprojector: the OSMesa context holds the deep framebuffer, no CPU fallback.
    const bool gl_known = wait_until(
        [&] {
          err = master_->err();
          return err.find("reprojection context: ") != std::string::npos ||
                 err.find("will use the CPU reprojector") != std::string::npos;
        },
        30s);
    ASSERT_TRUE(gl_known && err.find("will use the CPU reprojector") == std::string::npos)
        << "epr-master has no OSMesa reprojector:\n"
        << err;
  }

  // Starts an epr-worker with one tracing thread. Debug logs name every lease and its outcome.
  Process& start_worker(const std::string& name) {
    workers_.push_back(std::make_unique<Process>(Args{kWorker, "--master", address(), "--threads", "1", "--name", name,
                                                      "--cache-dir", path("cache-" + name), "--log-level", "debug"},
                                                 dir_ / name));
    return *workers_.back();
  }

  // `epr render --single-process` of the job into PREFIX.*: the reference.
  void render_single_process(const Job& job, const std::string& prefix) {
    Args args{"render"};
    const Args f = job.flags();
    args.insert(args.end(), f.begin(), f.end());
    args.insert(args.end(), {"--single-process", "--threads", "2", "--out", prefix});
    const RunResult r = run_epr(args, 120s);
    ASSERT_EQ(r.code, 0) << "epr render --single-process failed:\n" << r.err;
  }

  // `epr submit --wait --out PREFIX`: queues the job, follows it and fetches its results.
  void submit_and_wait(const Job& job, const std::string& prefix, std::string* id = nullptr) {
    Args args{"submit"};
    const Args f = job.flags();
    args.insert(args.end(), f.begin(), f.end());
    args.insert(args.end(), {"--wait", "--out", prefix});
    const RunResult r = epr(args, 120s);
    ASSERT_FALSE(r.timed_out) << "epr submit --wait did not return within 120 s:\n" << r.err;
    ASSERT_EQ(r.code, 0) << r.err;
    EXPECT_NE(r.err.find("DONE"), std::string::npos) << r.err;
    if (id) *id = r.out.substr(0, r.out.find('\n'));
  }

  // `epr submit` without --wait: the job id.
  std::string submit(const Job& job) { return SingleMasterTest::submit(job.flags()); }

  // `epr get JOB --json`: the job's status as the master reports it.
  nlohmann::json status(const std::string& id) {
    const RunResult r = epr({"get", id, "--json"}, 20s);
    EXPECT_EQ(r.code, 0) << r.err;
    try {
      return nlohmann::json::parse(r.out);
    } catch (const std::exception& e) {
      ADD_FAILURE() << "epr get --json printed no JSON (" << e.what() << "):\n" << r.out << r.err;
      return {};
    }
  }

  // `epr watch JOB` until the job ends, then `epr get JOB --out PREFIX`.
  void watch_and_get(const std::string& id, const std::string& prefix) {
    const RunResult w = epr({"watch", id}, 120s);
    ASSERT_FALSE(w.timed_out) << "the job did not end within 120 s:\n" << w.err;
    ASSERT_EQ(w.code, 0) << w.err;
    const RunResult g = epr({"get", id, "--out", prefix}, 30s);
    ASSERT_EQ(g.code, 0) << g.err;
  }

  // Cluster result PREFIX.* against the single-process reference REF.*: M, M' and the path-traced
  // estimate bit-identical, the combined image within float rounding.
  void expect_equal_to_reference(const std::string& prefix, const std::string& ref) {
    const Images a = load_outputs(prefix), b = load_outputs(ref);
    ASSERT_EQ(a.counts.channels, 2) << "counts.exr holds M and M'";
    EXPECT_EQ(exact_difference(a.counts, b.counts), "") << "M and M' per pixel";
    EXPECT_EQ(exact_difference(a.pathtrace, b.pathtrace), "") << "path-traced estimate (sum / M)";
    EXPECT_EQ(close_difference(a.combined, b.combined, 1e-4f, 1e-5f), "") << "combined image";
  }

  // A master and two workers render `job` to `prefix`; the single-process render to `prefix`_ref must
  // equal it bit for bit (expect_equal_to_reference).
  void expect_two_workers_equal_single_process(const Job& job, const std::string& prefix) {
    ASSERT_NO_FATAL_FAILURE(start_master());
    for (const char* name : {"w1", "w2"}) start_worker(name);
    ASSERT_NO_FATAL_FAILURE(wait_for_workers(2));
    ASSERT_NO_FATAL_FAILURE(submit_and_wait(job, path(prefix)));
    ASSERT_NO_FATAL_FAILURE(render_single_process(job, path(prefix + "_ref")));
    expect_equal_to_reference(path(prefix), path(prefix + "_ref"));
  }

  // Tiles the worker's log says the master committed for `job_id` (needs --log-level debug):
  // "lease N: job J round R tile T" when leased, "lease N: submitted, accepted=true" when committed.
  static size_t tiles_committed(const Process& worker, const std::string& job_id) {
    const std::string log = worker.err();
    const std::regex leased("lease ([0-9]+): job (\\S+) round"), committed("lease ([0-9]+): submitted, accepted=true");
    std::map<std::string, std::string> job_of;
    for (auto it = std::sregex_iterator(log.begin(), log.end(), leased); it != std::sregex_iterator(); ++it)
      job_of[(*it)[1]] = (*it)[2];
    size_t n = 0;
    for (auto it = std::sregex_iterator(log.begin(), log.end(), committed); it != std::sregex_iterator(); ++it)
      n += job_of[(*it)[1]] == job_id;
    return n;
  }

  // Waits until the master has registered `n` workers (its log says so for each).
  void wait_for_workers(size_t n) {
    ASSERT_TRUE(wait_until([&] { return count_of(master_->err(), ") registered") >= n; }, 30s))
        << n << " workers did not register within 30 s";
  }

  // Waits until the worker has leased a tile of round `round` or later of some job; reading the
  // worker's log is far cheaper than asking the master through another `epr` process.
  static bool wait_for_round(const Process& worker, int round, Millis timeout) {
    const std::regex leased("lease [0-9]+: job \\S+ round ([0-9]+) tile");
    return wait_until(
        [&] {
          const std::string log = worker.err();
          for (auto it = std::sregex_iterator(log.begin(), log.end(), leased); it != std::sregex_iterator(); ++it)
            if (std::stoi((*it)[1]) >= round) return true;
          return false;
        },
        timeout);
  }
};

// ---- 1. a cluster equals the single-process render ---------------------------------------------------

// `epr render --out` into a folder that does not exist yet makes it; one that cannot exist fails
// before rendering, naming it, instead of losing the render at its end.
TEST(EprRender, MakesTheOutputFolderOrRefusesBeforeRendering) {
  const fs::path dir = fs::temp_directory_path() / ("epr_out_test_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  const std::vector<std::string> render = {kEpr,    "render", "builtin:cornell", "--width", "32", "--height", "32",
                                           "--spp", "2",      "--http",          ""};
  for (const bool single : {false, true}) {
    const fs::path prefix = dir / (single ? "single" : "embedded") / "nested" / "cornell";
    std::vector<std::string> args = render;
    args.insert(args.end(), {"--out", prefix.string()});
    if (single) args.push_back("--single-process");
    const RunResult r = run_process(args, dir / (single ? "log-single" : "log-embedded"), Millis(120000));
    ASSERT_EQ(r.code, 0) << r.err;
    EXPECT_TRUE(fs::is_regular_file(prefix.string() + ".exr"));
    EXPECT_TRUE(fs::is_regular_file(prefix.string() + ".png"));
  }
  {
    std::ofstream(dir / "a-file") << "not a folder";
    std::vector<std::string> args = render;
    args.insert(args.end(), {"--out", (dir / "a-file" / "sub" / "cornell").string()});
    const RunResult r = run_process(args, dir / "log-refused", Millis(60000));
    EXPECT_EQ(r.code, 2) << r.err;
    EXPECT_NE(r.err.find("cannot create the output folder"), std::string::npos) << r.err;
    EXPECT_NE(r.err.find((dir / "a-file" / "sub").string()), std::string::npos) << r.err;
    EXPECT_EQ(r.err.find("round"), std::string::npos) << "refused before rendering: " << r.err;
  }
  fs::remove_all(dir);
}

TEST_F(ClusterTest, ThreeWorkersEqualSingleProcessRender) {
  const Job job;
  ASSERT_NO_FATAL_FAILURE(start_master());
  for (const char* name : {"w1", "w2", "w3"}) start_worker(name);
  ASSERT_NO_FATAL_FAILURE(wait_for_workers(3));
  std::string id;
  ASSERT_NO_FATAL_FAILURE(submit_and_wait(job, path("cluster"), &id));
  ASSERT_NO_FATAL_FAILURE(render_single_process(job, path("ref")));
  expect_equal_to_reference(path("cluster"), path("ref"));

  // The comparison means something: paths were traced, reprojection added samples, pixels were
  // skipped before P, and more than one worker took part.
  const Counts c = summarize(read_image(path("cluster.counts.exr")), job.spp);
  EXPECT_EQ(c.pixels, uint64_t(job.size * job.size));
  EXPECT_GT(c.m_sum, 0u);
  EXPECT_GT(c.mprime_sum, 0u);
  EXPECT_GT(c.m_below_target, 0u) << "no pixel was skipped: skip mode not exercised";
  size_t workers_with_tiles = 0, tiles = 0;
  for (auto& w : workers_) {
    const size_t n = tiles_committed(*w, id);
    workers_with_tiles += n > 0;
    tiles += n;
  }
  EXPECT_GE(workers_with_tiles, 2u) << "the work was not shared";
  const auto stats = load_outputs(path("cluster")).stats;
  EXPECT_EQ(tiles, stats.value("tiles_committed", uint64_t(0))) << "workers' commits against the master's count";
}

TEST_F(ClusterTest, NextEventEstimationOnlyTravelsToTheWorkers) {
  // --no-mis must reach the workers (JobSpec.mis -> RenderSettings.mis): the cluster's image equals
  // the single-process --no-mis render bit for bit, and differs from the MIS one.
  Job job;
  job.size = 48;
  job.spp = 8;
  job.k = 4;
  job.min_paths = 4;
  job.mis = false;
  ASSERT_NO_FATAL_FAILURE(expect_two_workers_equal_single_process(job, "nee"));
  job.mis = true;
  ASSERT_NO_FATAL_FAILURE(render_single_process(job, path("mis_ref")));
  EXPECT_NE(exact_difference(load_outputs(path("nee")).pathtrace, load_outputs(path("mis_ref")).pathtrace), "")
      << "the MIS and NEE-only renders are identical: the estimator option did nothing";
}

TEST_F(ClusterTest, TheReprojectedWeightTravelsToTheMaster) {
  // --reprojected-weight reaches the master's frame (JobSpec.reprojection.reprojected_weight): the
  // cluster's images and counts equal the single-process render's bit for bit, which traced more
  // paths than at W = 1.
  Job job;
  job.size = 48;
  job.spp = 16;
  job.k = 2;
  job.min_paths = 2;
  job.reprojected_weight = 0.25f;
  ASSERT_NO_FATAL_FAILURE(expect_two_workers_equal_single_process(job, "w"));
  EXPECT_EQ(load_outputs(path("w")).stats.value("reprojected_weight", 0.f), 0.25f);
  job.reprojected_weight = 1.f;
  ASSERT_NO_FATAL_FAILURE(render_single_process(job, path("one_ref")));
  EXPECT_GT(summarize(read_image(path("w.counts.exr")), job.spp).m_sum,
            summarize(read_image(path("one_ref.counts.exr")), job.spp).m_sum)
      << "W = 0.25 traced no more paths than W = 1: the weight did nothing";
}

TEST_F(ClusterTest, TheVarianceCombinationEqualsTheSingleProcessRender) {
  // --combine variance: the halves of each pixel's samples (by round and by subpixel) are the same
  // in the master as in one process, so the counts and path sums are bit-identical and the combined
  // image equal within float rounding; and it differs from the fixed rule's.
  Job job;
  job.size = 48;
  job.spp = 32;
  job.k = 2;
  job.min_paths = 2;
  job.combine = "variance";
  ASSERT_NO_FATAL_FAILURE(expect_two_workers_equal_single_process(job, "v"));
  EXPECT_EQ(load_outputs(path("v")).stats.value("combine", std::string()), "variance");
  job.combine = "fixed";
  ASSERT_NO_FATAL_FAILURE(render_single_process(job, path("fixed_ref")));
  EXPECT_NE(close_difference(load_outputs(path("v")).combined, load_outputs(path("fixed_ref")).combined, 1e-4f, 1e-5f),
            "")
      << "the variance and fixed combinations gave the same image: the option did nothing";
}

TEST_F(ClusterTest, ThePathBudgetEqualsTheSingleProcessRender) {
  // --path-budget: the per-pixel path counts travel in the leases; counts and path sums are the same
  // as in one process, and pixels traced budgets of fewer than a round's paths (none without it).
  Job job;
  job.path_budget = true;
  ASSERT_NO_FATAL_FAILURE(expect_two_workers_equal_single_process(job, "b"));
  EXPECT_GT(budgeted_pixels(read_image(path("b.counts.exr")), job), 0u) << "no pixel traced a path budget";
  job.path_budget = false;
  ASSERT_NO_FATAL_FAILURE(render_single_process(job, path("whole_rounds")));
  EXPECT_EQ(budgeted_pixels(read_image(path("whole_rounds.counts.exr")), job), 0u);
  // The same image within noise: the mean of the per-pixel differences within 4 of its standard errors.
  const Image a = load_outputs(path("b")).combined, w = load_outputs(path("whole_rounds")).combined;
  double sum = 0, sum2 = 0;
  const size_t n = a.data.size();
  for (size_t i = 0; i < n; ++i)
    sum += double(a.data[i]) - w.data[i], sum2 += std::pow(double(a.data[i]) - w.data[i], 2);
  const double mean = sum / double(n), sigma = std::sqrt((sum2 / double(n) - mean * mean) / double(n));
  EXPECT_GT(sigma, 0) << "the budget changed no pixel";
  EXPECT_LE(std::abs(mean), 4 * sigma) << "mean difference " << mean;
}

// ---- 2. the number of workers does not change the result ----------------------------------------------

TEST_F(ClusterTest, OneTwoAndFourWorkersGiveIdenticalCountsAndPathSums) {
  // One master, jobs one after the other; workers are added between them.
  const Job job;
  ASSERT_NO_FATAL_FAILURE(start_master());
  std::map<int, std::string> ids;
  for (int n : {1, 2, 4}) {
    while (int(workers_.size()) < n) start_worker(fmt::format("w{}", workers_.size() + 1));
    ASSERT_NO_FATAL_FAILURE(wait_for_workers(size_t(n)));
    ASSERT_NO_FATAL_FAILURE(submit_and_wait(job, path("n" + std::to_string(n)), &ids[n]));
  }
  for (int n : {2, 4}) {
    const Images a = load_outputs(path("n1")), b = load_outputs(path("n" + std::to_string(n)));
    EXPECT_EQ(exact_difference(a.counts, b.counts), "") << "M and M', 1 vs " << n << " workers";
    EXPECT_EQ(exact_difference(a.pathtrace, b.pathtrace), "") << "path sums, 1 vs " << n << " workers";
    EXPECT_EQ(close_difference(a.combined, b.combined, 1e-4f, 1e-5f), "") << "combined, 1 vs " << n << " workers";
  }
  // The runs differ in who traced what: with four workers the tiles were spread over several.
  size_t workers_with_tiles = 0;
  for (auto& w : workers_) workers_with_tiles += tiles_committed(*w, ids[4]) > 0;
  EXPECT_GE(workers_with_tiles, 2u);
  EXPECT_EQ(tiles_committed(*workers_[0], ids[1]), load_outputs(path("n1")).stats.value("tiles_committed", 0u));
  const Counts c = summarize(read_image(path("n1.counts.exr")), job.spp);
  EXPECT_GT(c.mprime_sum, 0u);
  EXPECT_GT(c.m_below_target, 0u);
}

// ---- 3. a worker that joins mid-job gets work ------------------------------------------------------------

TEST_F(ClusterTest, WorkerJoiningMidJobGetsWork) {
  const Job job = long_job(8, 12);  // several seconds for one worker
  ASSERT_NO_FATAL_FAILURE(start_master());
  Process& early = start_worker("early");
  ASSERT_NO_FATAL_FAILURE(wait_for_workers(1));
  const std::string id = submit(job);
  ASSERT_FALSE(id.empty());
  ASSERT_TRUE(wait_for_round(early, 1, 60s)) << "the job did not reach its second round";
  Process& late = start_worker("late");
  ASSERT_NO_FATAL_FAILURE(wait_for_workers(2));
  ASSERT_NO_FATAL_FAILURE(watch_and_get(id, path("cluster")));

  // It registered after round 1 had begun, so every tile it committed was taken mid-job.
  EXPECT_GT(tiles_committed(late, id), 0u) << "the worker that joined mid-job committed no tile";
  EXPECT_GT(tiles_committed(early, id), 0u);
  const auto stats = load_outputs(path("cluster")).stats;
  EXPECT_EQ(tiles_committed(early, id) + tiles_committed(late, id), stats.value("tiles_committed", 0u));

  ASSERT_NO_FATAL_FAILURE(render_single_process(job, path("ref")));
  expect_equal_to_reference(path("cluster"), path("ref"));
}

// ---- 4. a job whose pixels are all skipped ends ------------------------------------------------------------

TEST_F(ClusterTest, JobEndsWhenReprojectionSkipsEveryPixel) {
  // The furnace (a closed box seen from inside, no background, every surface diffuse) gives every
  // pixel reprojected samples. With P = 32, k = 4, min-paths 12 and reprojected samples counted in
  // full (W = 1), reprojection brings most pixels to P by the time they have traced min-paths; the
  // rest follow within a few rounds. The job must end as soon as no pixel is left (no empty rounds,
  // no hang), before P / k rounds. The camera sees one wall and none of the box's edges: a pixel
  // over an edge takes no reprojected samples (DESIGN.md "Edge pixels") and traces all P paths.
  Job job;
  job.camera = {"--eye", "0,0,0.95", "--look", "0,0,-1", "--up", "0,1,0", "--fov", "52"};
  job.reprojected_weight = 1.f;
  job.scene = "builtin:furnace";
  job.size = 48;
  job.spp = 32;
  job.k = 4;
  job.min_paths = 12;
  // k paths in every round: with growing rounds (the default), a straggler still active when the
  // last, larger round opens traces it whole and may end at P paths.
  job.round_growth = 0;
  // Long paths (the paper's roulette: none before 8 bounces) give each pixel enough reprojected
  // samples to reach P at min-paths; the default roulette ends paths in this box after about two
  // vertices, and most pixels then trace on towards P.
  job.rr = "paper";
  ASSERT_NO_FATAL_FAILURE(start_master());
  start_worker("w1");
  start_worker("w2");
  std::string id;
  ASSERT_NO_FATAL_FAILURE(submit_and_wait(job, path("cluster"), &id));
  const auto st = status(id);
  EXPECT_EQ(st.value("state", ""), "JOB_STATE_DONE");

  const Images out = load_outputs(path("cluster"));
  const Counts c = summarize(out.counts, job.spp);
  EXPECT_GE(c.effective_min, uint64_t(job.spp)) << "a pixel ended below P samples (M + M')";
  EXPECT_GE(c.m_min, uint64_t(job.min_paths)) << "a pixel was skipped before min-paths";
  EXPECT_LT(c.m_max, uint64_t(job.spp)) << "a pixel traced P paths: not every pixel was skipped";
  uint64_t at_min_paths = 0;
  for (int y = 0; y < out.counts.height; ++y)
    for (int x = 0; x < out.counts.width; ++x) at_min_paths += out.counts.at(x, y)[0] == float(job.min_paths);
  EXPECT_GT(at_min_paths, c.pixels / 2) << "most pixels should stop tracing at min-paths";
  EXPECT_LT(out.stats.value("rounds", 99), job.spp / job.k) << "the job ran as many rounds as without skipping";
  EXPECT_EQ(st.value("round", 0), out.stats.value("rounds", -1));

  ASSERT_NO_FATAL_FAILURE(render_single_process(job, path("ref")));
  expect_equal_to_reference(path("cluster"), path("ref"));
}

TEST_F(ClusterTest, OneSamplePerPixelIsOneRound) {
  Job job;
  job.size = 48;
  job.spp = 1;
  job.k = 1;
  job.min_paths = 1;
  ASSERT_NO_FATAL_FAILURE(start_master());
  start_worker("w1");
  std::string id;
  ASSERT_NO_FATAL_FAILURE(submit_and_wait(job, path("cluster"), &id));
  EXPECT_EQ(status(id).value("state", ""), "JOB_STATE_DONE");
  const Images out = load_outputs(path("cluster"));
  EXPECT_EQ(out.stats.value("rounds", 0), 1);
  const Counts c = summarize(out.counts, job.spp);
  EXPECT_EQ(c.m_min, 1u);
  EXPECT_EQ(c.m_max, 1u) << "every pixel traces exactly one path";
  ASSERT_NO_FATAL_FAILURE(render_single_process(job, path("ref")));
  expect_equal_to_reference(path("cluster"), path("ref"));
}

// ---- 5. a worker killed with SIGKILL loses nothing ---------------------------------------------------------

// Milliseconds since local midnight: what spdlog's "[YYYY-mm-dd HH:MM:SS.mmm]" stamps count.
int64_t local_ms_of_day() {
  const auto now = std::chrono::system_clock::now();
  const time_t t = std::chrono::system_clock::to_time_t(now);
  tm local{};
  localtime_r(&t, &local);
  const int64_t ms = std::chrono::duration_cast<std::chrono::milliseconds>(now.time_since_epoch()).count() % 1000;
  return ((local.tm_hour * 60 + local.tm_min) * 60 + local.tm_sec) * 1000 + ms;
}

TEST_F(ClusterTest, WorkerKilledMidJobLosesNothing) {
  // Tiles of 32x32 pixels x 16 paths take a single thread 50 ms or more in the first rounds.
  const Job job = long_job(16, 4);
  // No speculative copies: the victim's tile must come back through its lease's expiry.
  ASSERT_NO_FATAL_FAILURE(
      start_master({"--lease-timeout-ms", "1500", "--heartbeat-ms", "300", "--speculative-factor", "0"}));
  Process& victim = start_worker("victim");
  Process& survivor = start_worker("survivor");
  ASSERT_NO_FATAL_FAILURE(wait_for_workers(2));
  const std::string id = submit(job);
  ASSERT_FALSE(id.empty());
  ASSERT_TRUE(wait_for_round(victim, 1, 60s)) << "the victim never reached round 1";

  // Kill the victim in the middle of tracing a tile: watch its log closely and kill it as soon as
  // its newest line is a lease taken less than 15 ms ago. No tile of the first rounds is traced that
  // fast, so the tile's result cannot have reached the master.
  const std::regex lease_line(
      "\\[\\d{4}-\\d\\d-\\d\\d (\\d\\d):(\\d\\d):(\\d\\d)\\.(\\d{3})\\] \\[worker\\] \\[debug\\] "
      "lease [0-9]+: job \\S+ round ([0-9]+) tile ([0-9]+)\\s*$");
  std::string held_tile, held_round;
  bool killed = false;
  uintmax_t seen_bytes = 0;
  for (const auto end = std::chrono::steady_clock::now() + 30s; !killed && std::chrono::steady_clock::now() < end;
       std::this_thread::sleep_for(1ms)) {
    std::error_code ec;
    const uintmax_t bytes = fs::file_size(victim.err_path(), ec);
    if (ec || bytes == seen_bytes) continue;
    seen_bytes = bytes;
    std::string log = victim.err();
    log.resize(log.rfind('\n') == std::string::npos ? 0 : log.rfind('\n'));  // whole lines only
    const std::string last = log.substr(log.rfind('\n') == std::string::npos ? 0 : log.rfind('\n') + 1);
    std::smatch m;
    if (!std::regex_search(last, m, lease_line) || std::stoi(m[5]) >= 4) continue;
    const int64_t stamp =
        ((std::stoll(m[1]) * 60 + std::stoll(m[2])) * 60 + std::stoll(m[3])) * 1000 + std::stoll(m[4]);
    if ((local_ms_of_day() - stamp + 86'400'000) % 86'400'000 >= 15) continue;
    victim.signal(SIGKILL);
    killed = true;
    held_round = m[5];
    held_tile = m[6];
  }
  ASSERT_TRUE(killed) << "never caught the victim at the start of a tile";
  ASSERT_EQ(victim.wait_for(5s), 128 + SIGKILL);

  ASSERT_NO_FATAL_FAILURE(watch_and_get(id, path("cluster")));
  // The master's side: the dead worker's lease ran out, the tile was traced again by the survivor.
  EXPECT_NE(master_->err().find("job " + id + " tile " + held_tile + ": lease expired, re-queued"), std::string::npos)
      << "the victim was killed holding round " << held_round << " tile " << held_tile;
  const auto stats = load_outputs(path("cluster")).stats;
  EXPECT_GE(stats.value("tiles_re_leased", 0u), 1u);
  EXPECT_NE(survivor.err().find("round " + held_round + " tile " + held_tile + "\n"), std::string::npos)
      << "the survivor did not trace the victim's tile";
  // The victim (one thread) submits in the background while it traces its next tile: killed then,
  // its last submission may be committed by the master without the victim living to log it.
  const uint64_t logged = tiles_committed(victim, id) + tiles_committed(survivor, id);
  EXPECT_GE(stats.value("tiles_committed", 0u), logged) << "tiles committed by the workers against the master's count";
  EXPECT_LE(stats.value("tiles_committed", 0u), logged + 1) << "at most the victim's one submission in flight unlogged";

  ASSERT_NO_FATAL_FAILURE(render_single_process(job, path("ref")));
  expect_equal_to_reference(path("cluster"), path("ref"));
}

// ---- 6. bad arguments and an unreachable master ------------------------------------------------------------

TEST_F(ClusterTest, UnreachableMasterFailsQuicklyNamingTheAddress) {
  const RunResult r =
      run_epr({"submit", "builtin:cornell", "--width", "16", "--height", "16", "--master", "127.0.0.1:1"}, 30s);
  EXPECT_FALSE(r.timed_out);
  EXPECT_NE(r.code, 0);
  EXPECT_LT(r.seconds, 12.0) << "epr submit took " << r.seconds << " s to give up";
  EXPECT_NE(r.err.find("127.0.0.1:1"), std::string::npos) << r.err;
  EXPECT_TRUE(r.out.empty()) << "no job id may be printed: " << r.out;
}

TEST_F(ClusterTest, UnknownSceneIsRefusedWithAClearMessage) {
  const RunResult local =
      run_epr({"render", "builtin:nope", "--width", "16", "--height", "16", "--out", path("x")}, 30s);
  EXPECT_FALSE(local.timed_out);
  EXPECT_NE(local.code, 0);
  EXPECT_NE(local.err.find("nope"), std::string::npos) << local.err;
  EXPECT_FALSE(fs::exists(path("x.exr")));

  const RunResult single = run_epr(
      {"render", "builtin:nope", "--single-process", "--width", "16", "--height", "16", "--out", path("y")}, 30s);
  EXPECT_NE(single.code, 0);
  EXPECT_NE(single.err.find("nope"), std::string::npos) << single.err;
}

TEST_F(ClusterTest, BadRequestsToARunningMasterFailWithReasons) {
  ASSERT_NO_FATAL_FAILURE(start_master());
  const RunResult spp = epr({"submit", "builtin:cornell", "--spp", "0"}, 30s);
  EXPECT_NE(spp.code, 0);
  EXPECT_NE(spp.err.find("spp"), std::string::npos) << spp.err;

  const RunResult scene = epr({"submit", "builtin:nope"}, 30s);
  EXPECT_NE(scene.code, 0);
  EXPECT_NE(scene.err.find("nope"), std::string::npos) << scene.err;

  const RunResult get = epr({"get", "no-such-job", "--out", path("z")}, 30s);
  EXPECT_NE(get.code, 0);
  EXPECT_NE(get.err.find("no-such-job"), std::string::npos) << get.err;

  const RunResult list = epr({"list"}, 30s);
  EXPECT_EQ(list.code, 0) << list.err;
  EXPECT_EQ(count_of(list.out, "\n"), 1u) << "nothing was queued: " << list.out;
  EXPECT_TRUE(master_->running()) << "the master survived the bad requests";
}

}  // namespace
}  // namespace epr::testing
