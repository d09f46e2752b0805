// Frame windows (master/server/window_run.h): a run's frames start together, their rounds go in step,
// and each frame's vertices are reprojected into its neighbours within K frames. Driven through a
// JobManager in the test process with real tracing (JobsWorker).
#include "master/server/window_run.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <nlohmann/json.hpp>
#include <thread>

#include "common/image.h"
#include "master/memory_estimate.h"
#include "master/server/job_manager.h"
#include "tests/server/in_process_worker.h"
#include "tests/server/job_images.h"
#include "tests/server/render_jobs.h"

namespace epr {
namespace window_test {
namespace {
namespace fs = std::filesystem;
using namespace std::chrono_literals;
using test::JobImages;
using test::JobsWorker;
using test::poll_until;
using test::results_of;
using test::trace_until;

fs::path fresh_dir(const std::string& name) { return test::fresh_dir("epr-window-test", name); }

// Frame `frame` of batch "win" (frames 1..3), its camera's eye `dx` to the side of the Cornell view.
JobRequest frame_request(uint32_t frame, RenderMode mode, int spp, uint32_t window, float dx = 0, float halving = 0) {
  JobRequest req;
  req.options.width = req.options.height = 32;
  req.options.spp = spp;
  req.options.paths_per_round = 4;
  req.options.min_paths = 4;
  req.options.mode = mode;
  req.options.reproject = ReprojectMethod::kCpu;
  req.options.tile_size = 16;
  req.options.seed = 100 + frame;  // every frame its own paths
  req.camera.eye.x += dx;
  req.bundle.builtin = "builtin:cornell";
  req.name = "frame-" + std::to_string(frame);
  req.request_id = req.name + "-w" + std::to_string(window) + "-h" + std::to_string(halving);
  req.batch.id = "win";
  req.batch.frame = frame;
  req.batch.frames = 3;
  if (window) {
    req.batch.window = window;
    req.batch.window_first = 1;
    req.batch.window_last = 3;
    req.batch.window_halving = halving;
  }
  return req;
}

/// Renders the requests on one master (budget for all of them at once) and returns their images;
/// `area_weighted` gets each frame's count of area-weighted edge pixels (its statistics file).
std::vector<JobImages> render(const std::vector<JobRequest>& reqs, int workers = 1,
                              std::vector<size_t>* area_weighted = nullptr) {
  const fs::path dir = fresh_dir("render");
  MasterOptions o;
  o.state_dir = dir.string();
  o.checkpoints = false;
  o.memory_budget_bytes = uint64_t(1) << 40;
  std::vector<JobImages> out;
  std::vector<test::RenderedJob> rendered = test::render_jobs(o, reqs, workers);
  for (size_t i = 0; i < rendered.size(); ++i) {
    const nlohmann::json& stats = rendered[i].stats;
    out.push_back(std::move(rendered[i].images));
    if (stats.is_null()) continue;
    if (area_weighted) area_weighted->push_back(stats.at("area_weighted_pixels").get<size_t>());
    // The statistics file names the frame's window and run (absent without one).
    const BatchMembership& b = reqs[i].batch;
    EXPECT_EQ(stats.contains("frame_window"), b.window > 0) << reqs[i].name;
    if (b.window > 0 && stats.contains("frame_window")) {
      EXPECT_EQ(stats["frame_window"].at("k").get<uint32_t>(), b.window);
      EXPECT_EQ(stats["frame_window"].at("window_first").get<uint32_t>(), b.window_first);
      EXPECT_EQ(stats["frame_window"].at("window_last").get<uint32_t>(), b.window_last);
      EXPECT_EQ(stats["frame_window"].at("halving").get<float>(), b.window_halving);
    }
  }
  fs::remove_all(dir);
  return out;
}

// Channel c of pixel p of a multi-channel image.
float at(const Image& im, size_t p, int c) { return im.data[p * size_t(im.channels) + size_t(c)]; }

// Checks frame f's windowed M' against `expected` (the weighted sum of its window's frames' M' alone)
// pixel by pixel. A plain pixel's M' counts samples, so it is that sum exactly. An area-weighted edge
// pixel's M' = 1 / sum_k a_k^2 / C_k (DESIGN.md "Edge pixels") is concave and of degree one in the
// surfaces' counts C_k, so it is superadditive: at least the sum, at most `area_weighted` such pixels.
void expect_window_sum(const Image& windowed, const std::vector<float>& expected, size_t area_weighted) {
  size_t wrong = 0, above = 0;
  for (size_t p = 0; p < expected.size(); ++p) {
    const float got = at(windowed, p, 1);
    if (got == expected[p]) continue;
    if (got > expected[p] * (1 - 1e-5f))
      ++above;
    else
      ++wrong;
  }
  EXPECT_EQ(wrong, 0u) << "pixels whose M' is below the sum of its window's";
  EXPECT_LE(above, area_weighted) << "pixels whose M' is above the sum of its window's";
  EXPECT_LT(above, expected.size() / 4) << "most pixels' M' is the plain sum";
}

// Frames 1-3 of one static camera in rp at 16 spp, alone (*alone) and with a window (*windowed,
// with each frame's area-weighted pixels).
void render_static_frames(uint32_t window, float halving, std::vector<JobImages>* alone,
                          std::vector<JobImages>* windowed, std::vector<size_t>* area_weighted) {
  std::vector<JobRequest> a, w;
  for (uint32_t f = 1; f <= 3; ++f) {
    a.push_back(frame_request(f, RenderMode::kReproject, 16, 0));
    w.push_back(frame_request(f, RenderMode::kReproject, 16, window, 0, halving));
  }
  *alone = render(a);
  *windowed = render(w, 1, area_weighted);
  ASSERT_EQ(alone->size(), 3u);
  ASSERT_EQ(windowed->size(), 3u);
  ASSERT_EQ(area_weighted->size(), 3u);
}

TEST(WindowRun, AStaticCameraGivesEachFrameTheSamplesOfItsWindow) {
  // rp traces every path whatever M' says, so a frame's paths do not depend on its window: with one
  // camera for all three frames, frame f's M' is the sum of the M' its window's frames get alone.
  std::vector<JobImages> a, w;
  std::vector<size_t> area_weighted;
  ASSERT_NO_FATAL_FAILURE(render_static_frames(/*window=*/1, /*halving=*/0, &a, &w, &area_weighted));
  const size_t pixels = size_t(a[0].counts.width) * size_t(a[0].counts.height);
  uint64_t total_alone = 0;
  for (int f = 0; f < 3; ++f) {
    SCOPED_TRACE("frame " + std::to_string(f + 1));
    EXPECT_EQ(w[f].pathtrace.data, a[f].pathtrace.data) << "its own paths";
    std::vector<float> expected(pixels, 0.f);
    for (size_t p = 0; p < pixels; ++p) {
      EXPECT_EQ(at(w[f].counts, p, 0), at(a[f].counts, p, 0)) << "M, pixel " << p;
      for (int g = std::max(0, f - 1); g <= std::min(2, f + 1); ++g) expected[p] += at(a[g].counts, p, 1);
      total_alone += uint64_t(at(a[f].counts, p, 1));
    }
    expect_window_sum(w[f].counts, expected, area_weighted[size_t(f)]);
  }
  EXPECT_GT(total_alone, 10 * pixels) << "the frames reproject samples at all";
}

TEST(WindowRun, AStaticCameraWeighsItsNeighboursSamplesByTheirDistance) {
  // As above with K = 2 and a halving distance of 1 frame: a sample traced for the next frame counts
  // 8 / 16 of one of the frame's own, one from two frames away 4 / 16 (window_sample_weight), in M'.
  EXPECT_EQ(window_sample_weight(0, 1.f), 16u);
  EXPECT_EQ(window_sample_weight(1, 1.f), 8u);
  EXPECT_EQ(window_sample_weight(2, 1.f), 4u);
  EXPECT_EQ(window_sample_weight(9, 1.f), 1u);
  EXPECT_EQ(window_sample_weight(3, 0.f), 16u);
  std::vector<JobImages> a, w;
  std::vector<size_t> area_weighted;
  ASSERT_NO_FATAL_FAILURE(render_static_frames(/*window=*/2, /*halving=*/1, &a, &w, &area_weighted));
  const size_t pixels = size_t(a[0].counts.width) * size_t(a[0].counts.height);
  const float weight[] = {1.f, 0.5f, 0.25f};
  for (int f = 0; f < 3; ++f) {
    SCOPED_TRACE("frame " + std::to_string(f + 1));
    EXPECT_EQ(w[f].pathtrace.data, a[f].pathtrace.data) << "its own paths";
    std::vector<float> expected(pixels, 0.f);
    size_t fractional = 0;
    for (size_t p = 0; p < pixels; ++p) {
      for (int g = 0; g < 3; ++g) expected[p] += weight[std::abs(g - f)] * at(a[g].counts, p, 1);
      fractional += expected[p] != std::floor(expected[p]);
    }
    expect_window_sum(w[f].counts, expected, area_weighted[size_t(f)]);
    EXPECT_GT(fractional, pixels / 8) << "M' counts in sixteenths";
  }
}

// Mean of channel-averaged values over the block [x0, x0 + n) x [y0, y0 + n).
double block_mean(const Image& im, int x0, int y0, int n) {
  double s = 0;
  for (int y = y0; y < y0 + n; ++y)
    for (int x = x0; x < x0 + n; ++x)
      for (int c = 0; c < 3; ++c) s += at(im, size_t(y) * size_t(im.width) + size_t(x), c);
  return s / (3.0 * n * n);
}

TEST(WindowRun, AMovingCameraFrameConvergesToTheSameImageAsWithoutAWindow) {
  // Frames 1..3 with the eye moving sideways; frame 2 with a window of 1 (it takes frames 1 and 3's
  // vertices) against frame 2 path traced at many samples: the image mean and 8 x 8 blocks agree
  // within what frame 2 rendered without a window also reaches.
  // The same with the neighbours' samples weighed by their distance (a halving distance of 1 frame).
  JobRequest alone = frame_request(2, RenderMode::kSkip, 32, 0);
  JobRequest reference = frame_request(2, RenderMode::kPathTrace, 1024, 0);
  reference.request_id = "reference";
  const JobImages a = render({alone})[0], ref = render({reference})[0];
  for (const float halving : {0.f, 1.f}) {
    SCOPED_TRACE("halving " + std::to_string(halving));
    std::vector<JobRequest> run;
    for (uint32_t f = 1; f <= 3; ++f)
      run.push_back(frame_request(f, RenderMode::kSkip, 32, 1, 0.15f * (float(f) - 2), halving));
    const std::vector<JobImages> w = render(run);
    const Image& r = ref.combined;
    ASSERT_EQ(w[1].combined.width, r.width);
    double worst_window = 0, worst_alone = 0;
    for (int y = 0; y < r.height; y += 8)
      for (int x = 0; x < r.width; x += 8) {
        const double m = block_mean(r, x, y, 8);
        worst_window = std::max(worst_window, std::fabs(block_mean(w[1].combined, x, y, 8) - m) / (m + 0.02));
        worst_alone = std::max(worst_alone, std::fabs(block_mean(a.combined, x, y, 8) - m) / (m + 0.02));
      }
    const double mr = block_mean(r, 0, 0, r.width);
    EXPECT_NEAR(block_mean(w[1].combined, 0, 0, r.width), mr, 0.03 * mr) << "the image mean";
    EXPECT_LT(worst_window, std::max(0.15, 1.5 * worst_alone))
        << "the worst 8 x 8 block, relative (alone: " << worst_alone << ")";
    // The window fed frame 2 more reprojected samples than it got alone.
    double mp_window = 0, mp_alone = 0;
    for (size_t p = 0; p < size_t(r.width) * size_t(r.height); ++p) {
      mp_window += at(w[1].counts, p, 1);
      mp_alone += at(a.counts, p, 1);
    }
    EXPECT_GT(mp_window, halving > 0 ? 1.2 * mp_alone : 1.5 * mp_alone);
  }
}

TEST(WindowRun, CountsAreTheSameForOneAndThreeWorkers) {
  std::vector<JobRequest> run;
  for (uint32_t f = 1; f <= 3; ++f) run.push_back(frame_request(f, RenderMode::kSkip, 16, 2, 0.1f * float(f)));
  const std::vector<JobImages> one = render(run, 1), three = render(run, 3);
  for (int f = 0; f < 3; ++f) {
    SCOPED_TRACE("frame " + std::to_string(f + 1));
    EXPECT_EQ(one[f].counts.data, three[f].counts.data) << "M and M'";
    EXPECT_EQ(one[f].pathtrace.data, three[f].pathtrace.data) << "path sums";
  }
}

TEST(WindowRun, ARunResumesAsARunAfterARestartWithTheSameCounts) {
  std::vector<JobRequest> run;
  for (uint32_t f = 1; f <= 3; ++f) {
    run.push_back(frame_request(f, RenderMode::kSkip, 24, 1, 0.1f * float(f)));
    run.back().options.paths_per_round = 2;  // rounds of 2 paths: mid-way at round 2
    run.back().options.round_growth = 0;
  }
  const std::vector<JobImages> whole = render(run);
  const fs::path dir = fresh_dir("restart");
  MasterOptions o;
  o.state_dir = dir.string();
  o.checkpoint_interval_s = 0;  // after every round
  o.memory_budget_bytes = uint64_t(1) << 40;
  std::vector<std::string> ids;
  {
    JobManager jobs(o);
    for (const auto& r : run) ids.push_back(jobs.submit(r).id);
    JobsWorker w(jobs);
    for (auto end = std::chrono::steady_clock::now() + 120s; std::chrono::steady_clock::now() < end;) {
      if (jobs.get(ids[0])->progress.round >= 2) break;
      if (auto l = w.lease())
        w.submit(*l);
      else
        std::this_thread::sleep_for(1ms);
    }
    for (const auto& id : ids) ASSERT_EQ(jobs.get(id)->state, JobState::kRunning);
  }  // destroyed mid-run
  {
    JobManager jobs(o);
    ASSERT_TRUE(poll_until([&] {
      return std::all_of(ids.begin(), ids.end(),
                         [&](const std::string& id) { return jobs.get(id)->state == JobState::kRunning; });
    }));
    const int round = jobs.get(ids[0])->progress.round;
    EXPECT_GE(round, 1) << "from the checkpoints, not round 0";
    for (const auto& id : ids) EXPECT_EQ(jobs.get(id)->progress.round, round) << "every frame at one round";
    JobsWorker w(jobs);
    trace_until(jobs, {&w}, ids);
    for (size_t f = 0; f < ids.size(); ++f) {
      SCOPED_TRACE("frame " + std::to_string(f + 1));
      const JobImages r = results_of(jobs, ids[f]);
      EXPECT_EQ(r.counts.data, whole[f].counts.data) << "M and M'";
      EXPECT_EQ(r.pathtrace.data, whole[f].pathtrace.data) << "path sums";
    }
  }
  fs::remove_all(dir);
}

TEST(WindowRun, ARunStartsOnceAllItsFramesAreQueued) {
  const fs::path dir = fresh_dir("complete");
  MasterOptions o;
  o.state_dir = dir.string();
  o.checkpoints = false;
  o.memory_budget_bytes = uint64_t(1) << 40;
  {
    JobManager jobs(o);
    const std::string f1 = jobs.submit(frame_request(1, RenderMode::kSkip, 8, 1)).id;
    const std::string f2 = jobs.submit(frame_request(2, RenderMode::kSkip, 8, 1)).id;
    // A job outside the run passes it while it waits.
    JobRequest other = frame_request(1, RenderMode::kSkip, 8, 0);
    other.batch = {};
    other.request_id = "other";
    const std::string io = jobs.submit(other).id;
    EXPECT_TRUE(poll_until([&] { return jobs.get(io)->state == JobState::kRunning; })) << "a job behind the run starts";
    EXPECT_EQ(jobs.get(f1)->state, JobState::kQueued) << "frame 3 is missing";
    EXPECT_EQ(jobs.get(f2)->state, JobState::kQueued);
    const std::string f3 = jobs.submit(frame_request(3, RenderMode::kSkip, 8, 1)).id;
    EXPECT_TRUE(poll_until([&] {
      return jobs.get(f1)->state == JobState::kRunning && jobs.get(f2)->state == JobState::kRunning &&
             jobs.get(f3)->state == JobState::kRunning;
    })) << "the whole run starts";
    jobs.shutdown();
  }
  fs::remove_all(dir);
}

TEST(WindowRun, AnIncompleteRunStartsAfterTheWaitAndACancelledFrameLeavesIt) {
  const fs::path dir = fresh_dir("incomplete");
  MasterOptions o;
  o.state_dir = dir.string();
  o.checkpoints = false;
  o.memory_budget_bytes = uint64_t(1) << 40;
  o.window_run_wait_ms = 1500;
  {
    JobManager jobs(o);
    const std::string f1 = jobs.submit(frame_request(1, RenderMode::kSkip, 8, 1)).id;
    const std::string f2 = jobs.submit(frame_request(2, RenderMode::kSkip, 8, 1)).id;
    // Frame 3 never comes: the run starts after the wait, with frames 1 and 2.
    EXPECT_TRUE(poll_until(
        [&] { return jobs.get(f1)->state == JobState::kRunning && jobs.get(f2)->state == JobState::kRunning; }));
    // Frame 1's tiles of rounds 0 and 1 are applied while frame 2's are out (leased, never sent):
    // frame 1 closes round 0 (its neighbours' round -1 is nothing), but its round 1 cannot close
    // without frame 2's round 0, until frame 2 leaves the run by its cancellation; then frame 1 goes
    // on alone.
    JobsWorker w(jobs);
    for (auto end = std::chrono::steady_clock::now() + 60s;
         jobs.get(f1)->counters.tiles_committed < 8 && std::chrono::steady_clock::now() < end;) {
      auto l = w.lease();
      if (l && l->job_id == f1) w.submit(*l);
      if (!l) std::this_thread::sleep_for(1ms);
    }
    ASSERT_EQ(jobs.get(f1)->counters.tiles_committed, 8u);
    EXPECT_EQ(jobs.get(f1)->progress.round, 1) << "round 0 closed without frame 2";
    EXPECT_FALSE(poll_until([&] { return jobs.get(f1)->progress.round > 1; }, 500ms)) << "round 1 waits for frame 2";
    ASSERT_TRUE(jobs.cancel(f2));
    trace_until(jobs, {&w}, {f1});
  }
  fs::remove_all(dir);
}

TEST(WindowRun, BadWindowRequestsAreRefusedWithTheReason) {
  const fs::path dir = fresh_dir("bad");
  MasterOptions o;
  o.state_dir = dir.string();
  o.checkpoints = false;
  JobManager jobs(o);
  auto refused = [&](JobRequest r, const std::string& words) {
    const auto s = jobs.submit(r);
    EXPECT_EQ(s.id, "") << words;
    EXPECT_NE(s.error.find(words), std::string::npos) << "'" << s.error << "' should say '" << words << "'";
  };
  JobRequest no_batch = frame_request(1, RenderMode::kSkip, 8, 1);
  no_batch.batch.id.clear();
  refused(no_batch, "needs a batch_id and a frame");
  refused(frame_request(1, RenderMode::kPathTrace, 8, 1), "needs reprojection");
  JobRequest exact = frame_request(1, RenderMode::kSkip, 8, 1);
  exact.options.reproject = ReprojectMethod::kExact;
  refused(exact, "exact");
  JobRequest outside = frame_request(1, RenderMode::kSkip, 8, 1);
  outside.batch.frame = 7;
  refused(outside, "frame 7 is not inside its window run, frames 1 to 3");
  refused(frame_request(1, RenderMode::kSkip, 8, 17), "--frame-window 17 must be between 0 and 16");
  JobRequest stray = frame_request(1, RenderMode::kSkip, 8, 0);
  stray.batch.window_last = 3;
  refused(stray, "need a frame_window");
  // A frame whose settings differ from its run's: named with the field.
  ASSERT_EQ(jobs.submit(frame_request(1, RenderMode::kSkip, 8, 1)).error, "");
  refused(frame_request(2, RenderMode::kSkip, 16, 1), "target_spp");
  JobRequest twice = frame_request(1, RenderMode::kSkip, 8, 1);
  twice.request_id = "again";
  refused(twice, "frame 1 of window run 1..3 of batch win is already on this master");
  jobs.shutdown();
  fs::remove_all(dir);
}

TEST(WindowRun, ARunOverTheMemoryBudgetIsRefusedAtSubmission) {
  const fs::path dir = fresh_dir("budget");
  MasterOptions o;
  o.state_dir = dir.string();
  o.checkpoints = false;
  const JobRequest f1 = frame_request(1, RenderMode::kSkip, 8, 1);
  o.memory_budget_bytes = frames_memory(f1.options, false, 2);  // two frames fit, the run of three not
  JobManager jobs(o);
  JobRequest r = f1;
  const auto err = jobs.admit(&r, /*has_camera=*/true);
  ASSERT_TRUE(err);
  EXPECT_NE(err->find("frame 1: a window run of 3 32x32 frames"), std::string::npos) << *err;
  EXPECT_NE(err->find("the budget is"), std::string::npos) << *err;
  JobRequest alone = frame_request(1, RenderMode::kSkip, 8, 0);
  EXPECT_FALSE(jobs.admit(&alone, true)) << "one frame alone fits";
  jobs.shutdown();
  fs::remove_all(dir);
}

}  // namespace
}  // namespace window_test
}  // namespace epr
