// A frame window never spans a cut (window_run.h, master/view_overlap.h): in a run of four Cornell-box
// frames, frames 3 and 4 turn to a close view of the left wall (little of frames 1 and 2's view), so
// the master measures a cut between frames 2 and 3 and each side renders as it would alone. Driven
// through a JobManager in the test process with real tracing (JobsWorker), as window_run_test.cpp.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>

#include "common/embree_bvh.h"
#include "master/server/job_manager.h"
#include "tests/server/in_process_worker.h"
#include "tests/server/job_images.h"
#include "tests/server/render_jobs.h"
#include "wire/scene_bundle.h"

namespace epr {
namespace window_cut_test {
namespace {
namespace fs = std::filesystem;
using test::JobImages;
using test::JobsWorker;
using test::results_of;
using test::trace_until;

// Frame `frame` of batch "cut" (frames 1..4) with window K in the run first..last (K = 0: no window).
// Frames 1 and 2 see the whole box, a little apart; frames 3 and 4 have turned to the left wall,
// close up.
JobRequest cut_frame(uint32_t frame, uint32_t window, uint32_t first = 1, uint32_t last = 4) {
  JobRequest req;
  req.options.width = req.options.height = 32;
  req.options.spp = 16;
  req.options.paths_per_round = 4;
  req.options.min_paths = 4;
  req.options.mode = RenderMode::kSkip;
  req.options.reproject = ReprojectMethod::kCpu;
  req.options.tile_size = 16;
  req.options.seed = 200 + frame;
  if (frame <= 2) {
    req.camera.eye.x += 0.1f * float(frame);
  } else {
    req.camera.eye = {0.3f + 0.05f * float(frame), 1.f, 0.4f};
    req.camera.look = {-1.f, 1.1f, 0.2f};
    req.camera.fov_y_degrees = 30;
  }
  req.bundle.builtin = "builtin:cornell";
  req.name = "frame-" + std::to_string(frame);
  req.request_id = req.name + "-" + std::to_string(first) + "-" + std::to_string(last) + "-w" + std::to_string(window);
  req.batch.id = "cut";
  req.batch.frame = frame;
  req.batch.frames = 4;
  if (window) {
    req.batch.window = window;
    req.batch.window_first = first;
    req.batch.window_last = last;
  }
  return req;
}

// A master without checkpoints whose budget holds every frame at once (the default cut share).
MasterOptions options(const fs::path& dir) { return test::all_frames_at_once(dir); }

using Rendered = test::RenderedJob;

/// Renders the requests on one master (budget for all at once, MasterOptions' default cut share).
std::vector<Rendered> render(const std::vector<JobRequest>& reqs, int workers = 1) {
  const fs::path dir = test::fresh_dir("epr-window-cut-test", "render");
  std::vector<Rendered> out = test::render_jobs(options(dir), reqs, workers);
  fs::remove_all(dir);
  return out;
}

uint64_t total_mprime(const Image& counts) {
  uint64_t s = 0;
  for (size_t p = 0; p < size_t(counts.width) * size_t(counts.height); ++p)
    s += uint64_t(counts.data[p * size_t(counts.channels) + 1]);
  return s;
}

std::vector<JobRequest> frames(uint32_t from, uint32_t to, uint32_t window, uint32_t first, uint32_t last) {
  std::vector<JobRequest> out;
  for (uint32_t f = from; f <= to; ++f) out.push_back(cut_frame(f, window, first, last));
  return out;
}

TEST(WindowCut, FramesOnEachSideOfACutGetNothingFromTheOtherSide) {
  // K = 3 reaches across the whole run; the cut between 2 and 3 stops it.
  const std::vector<Rendered> run = render(frames(1, 4, 3, 1, 4));
  const std::vector<Rendered> before = render(frames(1, 2, 3, 1, 2)), after = render(frames(3, 4, 3, 3, 4));
  const std::vector<Rendered> alone = render(frames(1, 1, 0, 0, 0));
  ASSERT_EQ(run.size(), 4u);
  for (int f = 0; f < 4; ++f) {
    SCOPED_TRACE("frame " + std::to_string(f + 1));
    const Rendered& side = f < 2 ? before[f] : after[f - 2];
    EXPECT_EQ(run[f].images.counts.data, side.images.counts.data) << "M and M' as its side of the cut alone gives";
    EXPECT_EQ(run[f].images.pathtrace.data, side.images.pathtrace.data) << "path sums";
    const nlohmann::json& w = run[f].stats.at("frame_window");
    EXPECT_EQ(w.at("fed_by_first").get<uint32_t>(), f < 2 ? 1u : 3u) << w;
    EXPECT_EQ(w.at("fed_by_last").get<uint32_t>(), f < 2 ? 2u : 4u) << w;
  }
  // The measurement behind it: frames 1-2 and 3-4 share their views, 2-3 do not.
  const double cut_share = MasterOptions{}.window_cut_share;
  const nlohmann::json& w2 = run[1].stats.at("frame_window");
  EXPECT_TRUE(run[0].stats.at("frame_window").at("view_share_previous").is_null()) << "frame 1 has none before it";
  EXPECT_GE(w2.at("view_share_previous").get<double>(), cut_share) << w2;
  EXPECT_LT(w2.at("view_share_next").get<double>(), cut_share) << w2;
  EXPECT_GE(run[3].stats.at("frame_window").at("view_share_previous").get<double>(), cut_share);
  // Frames on one side still exchange: frame 1 takes frame 2's vertices.
  EXPECT_GT(double(total_mprime(run[0].images.counts)), 1.3 * double(total_mprime(alone[0].images.counts)));
}

TEST(WindowCut, TheMasterBuildsOneBvhForTheCutsAndEveryFrame) {
  // The cut measurement's rays and each frame's edge pixels use the scene's BVH on the shelf; the
  // test's worker (in_process_worker.h) builds one of its own per frame.
  const uint64_t before = embree_bvh_builds();
  const std::vector<Rendered> run = render(frames(1, 4, 3, 1, 4));
  ASSERT_EQ(run.size(), 4u);
  for (const Rendered& r : run) ASSERT_GT(r.stats.at("edge_pixels").get<uint64_t>(), 0u) << "no rays to trace";
  EXPECT_EQ(embree_bvh_builds() - before, 1u + 4u) << "the master built more than one BVH of the scene";
}

TEST(WindowCut, CountsWithACutAreTheSameForOneAndThreeWorkers) {
  const std::vector<Rendered> one = render(frames(1, 4, 2, 1, 4), 1), three = render(frames(1, 4, 2, 1, 4), 3);
  for (int f = 0; f < 4; ++f) {
    SCOPED_TRACE("frame " + std::to_string(f + 1));
    EXPECT_EQ(one[f].images.counts.data, three[f].images.counts.data) << "M and M'";
    EXPECT_EQ(one[f].images.pathtrace.data, three[f].images.pathtrace.data) << "path sums";
    EXPECT_EQ(one[f].stats.at("frame_window").at("fed_by_last"), f < 2 ? 2 : 4) << "the cut after frame 2";
    EXPECT_EQ(three[f].stats.at("frame_window").at("fed_by_last"), f < 2 ? 2 : 4) << "the cut after frame 2";
  }
}

TEST(WindowCut, ALeaseCarriesTheCamerasOfItsSideOfTheCutOnly) {
  // TileLease.window_cameras: the worker keeps a vertex one of them shows; across the cut none.
  const fs::path dir = test::fresh_dir("epr-window-cut-test", "lease");
  const MasterOptions o = options(dir);
  {
    JobManager jobs(o);
    const std::vector<JobRequest> reqs = frames(1, 4, 3, 1, 4);
    std::vector<std::string> ids;
    for (const auto& r : reqs) ids.push_back(jobs.submit(r).id);
    // A lease names the neighbours that are running: once all four are.
    ASSERT_TRUE(test::poll_until([&] {
      for (const auto& id : ids)
        if (jobs.get(id)->state != JobState::kRunning) return false;
      return true;
    }));
    JobsWorker w(jobs);
    std::map<std::string, std::vector<CameraSpec>> seen;
    EXPECT_TRUE(test::poll_until([&] {
      if (auto l = w.lease()) {
        seen[l->job_id] = l->window_cameras;
        w.submit(*l);
      }
      return seen.size() == 4;
    }));
    for (size_t f = 0; f < 4 && seen.size() == 4; ++f) {
      SCOPED_TRACE("frame " + std::to_string(f + 1));
      const std::vector<CameraSpec>& cams = seen[ids[f]];
      ASSERT_EQ(cams.size(), 1u) << "K = 3 reaches all three others; the cut leaves one";
      EXPECT_EQ(cams[0].eye, reqs[f ^ 1].camera.eye) << "the other frame of its side";
    }
    jobs.shutdown();
  }
  fs::remove_all(dir);
}

TEST(WindowStillScene, AFrameWithAnotherSceneOrLightIsRefusedNamingIt) {
  // A window run renders one still scene: a frame whose scene file differs (an object moved: the
  // exporter wrote another file) or whose job lighting differs is refused, naming what differs.
  const fs::path dir = test::fresh_dir("epr-window-cut-test", "still");
  const MasterOptions o = options(dir);
  JobManager jobs(o);
  const SceneBundleData box = bundle_scene(std::string(EPR_SOURCE_DIR) + "/scenes/cornell-box/CornellBox-Original.obj",
                                           {}, "", BundleLoad::kUpload);
  auto frame = [&](uint32_t f) {
    JobRequest r = cut_frame(f, 1, 1, 3);
    r.bundle = box;
    return r;
  };
  auto refused = [&](const JobRequest& r, const std::string& words) {
    const auto s = jobs.submit(r);
    EXPECT_EQ(s.id, "") << words;
    EXPECT_NE(s.error.find(words), std::string::npos) << "'" << s.error << "' should say '" << words << "'";
  };
  ASSERT_EQ(jobs.submit(frame(1)).error, "");
  JobRequest sunlit = frame(2);
  sunlit.options.lighting.sun = SunLight{};
  refused(sunlit, "sun");
  JobRequest sky = frame(2);
  sky.options.lighting.environment = EnvironmentLight{};
  refused(sky, "environment");
  JobRequest moved = frame(2);
  bool edited = false;
  for (auto& [path, bytes] : moved.bundle.files)
    if (path.ends_with(".obj")) {
      const size_t v = bytes.find("v  -1.01  0.00   0.99");
      ASSERT_NE(v, std::string::npos);
      bytes.replace(v, 21, "v  -1.21  0.00   0.99");  // the floor's corner moved
      edited = true;
    }
  ASSERT_TRUE(edited);
  refused(moved, "its scene (content hash");
  refused(moved, "a window run renders one still scene");
  EXPECT_EQ(jobs.submit(frame(3)).error, "") << "the same scene and lighting, another camera: admitted";
  jobs.shutdown();
  fs::remove_all(dir);
}

}  // namespace
}  // namespace window_cut_test
}  // namespace epr
