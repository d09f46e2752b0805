// Frame sequences (client/batch.h, client/batch_commands.h): frame lists, the per-frame job specs,
// and `epr submit --frames`, `epr watch BATCH`, `epr get BATCH`, `epr list --batch` against the real
// epr-master and epr-worker processes on loopback: a batch of three frames of an animated file
// scene is uploaded once, each frame's job carries the interpolated camera, and each frame's images
// equal those of the same frame submitted alone as an ordinary job with that camera.
#include "client/batch.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <regex>
#include <set>

#include "common/camera_animation.h"
#include "common/image.h"
#include "tests/integration/cluster/image_difference.h"
#include "tests/integration/cluster/process.h"
#include "wire/convert.h"

namespace epr {
namespace {
namespace fs = std::filesystem;
using namespace std::chrono_literals;
using testing::binary;
using testing::Process;
using testing::run_process;
using testing::RunResult;

// ---- frame lists and plans ------------------------------------------------------------------------

TEST(FrameList, RangesStepsAndLists) {
  EXPECT_EQ(parse_frame_list("1-3"), (std::vector<uint32_t>{1, 2, 3}));
  EXPECT_EQ(parse_frame_list("7"), (std::vector<uint32_t>{7}));
  EXPECT_EQ(parse_frame_list("1-9x4"), (std::vector<uint32_t>{1, 5, 9}));
  EXPECT_EQ(parse_frame_list("1-10x4"), (std::vector<uint32_t>{1, 5, 9}));
  EXPECT_EQ(parse_frame_list("9,1,5"), (std::vector<uint32_t>{1, 5, 9}));
  EXPECT_EQ(parse_frame_list("0,2-4,3,20-30x10"), (std::vector<uint32_t>{0, 2, 3, 4, 20, 30}));
  EXPECT_EQ(parse_frame_list("1-240").size(), 240u);
  EXPECT_EQ(parse_frame_list("9999999").back(), kMaxFrame);
  for (const char* bad : {"", "a", "1-", "-3", "3-1", "1-5x0", "1,,2", "1-5x", "10000000", "1.5", "1-3y2", " 1"})
    EXPECT_THROW(parse_frame_list(bad), std::invalid_argument) << bad;
  EXPECT_THROW(parse_frame_list("0-9999999"), std::invalid_argument);  // over kMaxBatchFrames
}

TEST(FrameList, FileNamesHaveFourDigitsOrMore) {
  EXPECT_EQ(frame_file_name("out/name", 1), "out/name.0001");
  EXPECT_EQ(frame_file_name("n", 240), "n.0240");
  EXPECT_EQ(frame_file_name("n", 12345), "n.12345");
  EXPECT_TRUE(valid_batch_id(new_batch_id()));
  EXPECT_NE(new_batch_id(), new_batch_id());
  EXPECT_FALSE(valid_batch_id("a b"));
  EXPECT_FALSE(valid_batch_id(""));
}

// A file scene (scene JSON + the Cornell box OBJ and MTL) whose camera moves from frame 1 to 3.
std::string write_animated_scene(const fs::path& dir) {
  fs::create_directories(dir);
  for (const char* f : {"CornellBox-Original.obj", "CornellBox-Original.mtl"})
    fs::copy_file(fs::path(EPR_SOURCE_DIR) / "scenes/cornell-box" / f, dir / f, fs::copy_options::overwrite_existing);
  std::ofstream(dir / "anim.json") << R"({
  "obj": "CornellBox-Original.obj",
  "camera": {"fov": 40},
  "animation": {"camera": [
    {"frame": 1, "eye": [0, 1, 3.9], "look": [0, 1, 0]},
    {"frame": 3, "eye": [0.4, 1.2, 3.5], "look": [0.2, 1, 0], "fov": 50}
  ]}
})";
  return (dir / "anim.json").string();
}

RenderOptions tiny_job(const std::string& scene) {
  RenderOptions o;
  o.scene = scene;
  o.width = o.height = 32;
  o.spp = 4;
  o.paths_per_round = 2;
  o.tile_size = 16;
  o.mode = RenderMode::kSkip;
  o.reproject = ReprojectMethod::kCpu;
  o.seed = 5;
  return o;
}

TEST(FrameBatchPlan, OneSpecPerFrameWithItsCameraAndBatchFields) {
  const fs::path dir = fs::temp_directory_path() / ("epr-batch-plan-" + std::to_string(::getpid()));
  const std::string scene = write_animated_scene(dir);
  RenderOptions o = tiny_job(scene);
  SubmitOptions submit;
  submit.priority = 3;
  const FrameBatch b = plan_batch(o, submit, {3, 1, 2, 2}, "b-test");
  EXPECT_EQ(b.id, "b-test");
  EXPECT_EQ(b.name, "anim");
  EXPECT_EQ(b.frames, (std::vector<uint32_t>{1, 2, 3}));
  ASSERT_EQ(b.specs.size(), 3u);
  EXPECT_EQ(b.bundle.entry_path, "anim.json");
  EXPECT_EQ(b.bundle.files.size(), 3u);
  for (size_t i = 0; i < 3; ++i) {
    const v1::JobSpec& s = b.specs[i];
    EXPECT_FALSE(s.has_scene());
    EXPECT_EQ(s.batch_id(), "b-test");
    EXPECT_EQ(s.batch_name(), "anim");
    EXPECT_EQ(s.frame(), i + 1);
    EXPECT_EQ(s.batch_frames(), 3u);
    EXPECT_EQ(s.name(), "anim.000" + std::to_string(i + 1));
    EXPECT_EQ(s.request_id(), "b-test-" + std::to_string(i + 1));
    EXPECT_EQ(s.priority(), 3);
    EXPECT_EQ(s.width(), 32u);
  }
  const CameraSpec mid = from_proto(b.specs[1].camera());
  EXPECT_NEAR(mid.eye.x, 0.2f, 1e-6f);
  EXPECT_NEAR(mid.eye.y, 1.1f, 1e-6f);
  EXPECT_NEAR(mid.eye.z, 3.7f, 1e-6f);
  EXPECT_NEAR(mid.look.x, 0.1f, 1e-6f);
  EXPECT_NEAR(mid.fov_y_degrees, 45.f, 1e-5f);

  // Camera overrides apply to every frame.
  o.fov = 30.f;
  for (const auto& s : plan_batch(o, submit, {1, 2, 3}).specs) EXPECT_EQ(s.camera().fov_y_degrees(), 30.f);
  // A degenerate frame camera is refused naming the file, the key's line and the frame.
  o.fov.reset();
  o.look = Vec3(0.2f, 1.1f, 3.7f);  // frame 2's eye
  try {
    plan_batch(o, submit, {1, 2, 3});
    ADD_FAILURE() << "a frame whose eye is its look-at point was planned";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("frame 2: the camera with the overrides given"), std::string::npos)
        << e.what();
  }
  EXPECT_THROW(plan_batch(tiny_job(scene), submit, {}), std::invalid_argument);
  EXPECT_THROW(plan_batch(tiny_job(scene), submit, {1}, "bad id"), std::invalid_argument);
  fs::remove_all(dir);
}

TEST(FrameBatchPlan, AFrameWindowSplitsTheFramesIntoRunsOfConsecutiveFrames) {
  RenderOptions o;
  o.scene = "builtin:cornell";
  o.width = o.height = 16;
  o.mode = RenderMode::kSkip;
  o.seed = 5;
  WindowOptions w;
  w.frame_window = 1;
  w.run = 3;
  const FrameBatch b = plan_batch(o, SubmitOptions{}, {1, 2, 3, 4, 5, 7, 8, 10}, "b-win", w);
  // Runs: at most 3 frames, a gap ends one.
  const std::vector<std::pair<uint32_t, uint32_t>> runs{{1, 3}, {1, 3}, {1, 3}, {4, 5},
                                                        {4, 5}, {7, 8}, {7, 8}, {10, 10}};
  ASSERT_EQ(b.specs.size(), runs.size());
  for (size_t i = 0; i < runs.size(); ++i) {
    const v1::JobSpec& s = b.specs[i];
    SCOPED_TRACE("frame " + std::to_string(s.frame()));
    EXPECT_EQ(s.frame_window(), 1u);
    EXPECT_EQ(s.window_first(), runs[i].first);
    EXPECT_EQ(s.window_last(), runs[i].second);
    EXPECT_EQ(s.seed(), 5u + s.frame()) << "each frame traces paths of its own";
  }
  // Without a window: no window fields, the one seed.
  for (const auto& s : plan_batch(o, SubmitOptions{}, {1, 2}, "b-plain").specs) {
    EXPECT_EQ(s.frame_window(), 0u);
    EXPECT_EQ(s.window_last(), 0u);
    EXPECT_EQ(s.seed(), 5u);
  }
  auto refused = [&](RenderOptions opts, WindowOptions window, const std::string& words) {
    try {
      plan_batch(opts, SubmitOptions{}, {1, 2, 3}, "b-bad", window);
      ADD_FAILURE() << "planned: " << words;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(words), std::string::npos) << e.what();
    }
  };
  refused(o, {17, 3}, "--frame-window 17 must be between 0 and 16");
  refused(o, {1, 0}, "--window-run 0 must be between 1 and 64");
  RenderOptions pt = o;
  pt.mode = RenderMode::kPathTrace;
  refused(pt, w, "--frame-window needs reprojection");
  RenderOptions exact = o;
  exact.reproject = ReprojectMethod::kExact;
  refused(exact, w, "--reproject gl or cpu");
  // --window-halving: carried by every frame of a window, refused without one or out of range.
  WindowOptions halved = w;
  halved.halving = 2.5f;
  for (const auto& s : plan_batch(o, SubmitOptions{}, {1, 2}, "b-halved", halved).specs)
    EXPECT_EQ(s.window_halving(), 2.5f);
  refused(o, {0, 16, 2.f}, "--window-halving needs --frame-window");
  refused(o, {1, 3, 17.f}, "--window-halving 17 must be between 0 and 16 frames");
  refused(o, {1, 3, -1.f}, "--window-halving -1 must be between 0 and 16 frames");
}

TEST(FrameBatchPlan, SummaryCountsFramesByState) {
  std::vector<v1::JobStatus> jobs(4);
  const v1::JobState states[] = {v1::JOB_STATE_DONE, v1::JOB_STATE_RUNNING, v1::JOB_STATE_QUEUED, v1::JOB_STATE_FAILED};
  for (size_t i = 0; i < jobs.size(); ++i) {
    jobs[i].set_batch_id("b-1");
    jobs[i].set_batch_name("n");
    jobs[i].set_batch_frames(5);  // one frame not listed (on another master, or not submitted yet)
    jobs[i].set_state(states[i]);
  }
  jobs[1].set_round(1);
  jobs[1].set_rounds_planned(2);
  const BatchSummary b = summarize_batch(jobs);
  EXPECT_EQ(b.frames, 5u);
  EXPECT_EQ(b.done, 1u);
  EXPECT_EQ(b.running, 1u);
  EXPECT_EQ(b.queued, 1u);
  EXPECT_EQ(b.failed, 1u);
  EXPECT_NEAR(b.progress, 1.5 / 5, 1e-12);
  EXPECT_FALSE(b.finished());
}

// ---- against a real master ------------------------------------------------------------------------

class BatchCluster : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("epr-batch-" + std::to_string(::getpid()) + "-" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    ASSERT_NO_FATAL_FAILURE(start_master());
  }
  // epr-master on a free loopback port with the state folder dir_/state (kept across restarts).
  void start_master() {
    master_ =
        std::make_unique<Process>(std::vector<std::string>{binary("master", "epr-master"), "--listen", "127.0.0.1:0",
                                                           "--http", "", "--state-dir", (dir_ / "state").string()},
                                  dir_ / ("master-" + std::to_string(++masters_)));
    const int port = testing::listening_port(*master_, 60s);
    ASSERT_NE(port, 0) << "epr-master did not start:\n" << master_->err();
    target_ = "127.0.0.1:" + std::to_string(port);
  }
  void TearDown() override {
    worker_.reset();
    master_.reset();
    if (!HasFailure()) fs::remove_all(dir_);
  }
  void start_worker() {
    worker_ =
        std::make_unique<Process>(std::vector<std::string>{binary("worker", "epr-worker"), "--master", target_,
                                                           "--threads", "2", "--cache-dir", (dir_ / "cache").string()},
                                  dir_ / "worker");
  }
  RunResult epr(std::vector<std::string> args, std::chrono::milliseconds timeout = 120s) {
    args.insert(args.begin(), binary("client", "epr"));
    args.insert(args.end(), {"--master", target_});
    return run_process(args, dir_ / ("epr-" + std::to_string(++runs_)), timeout);
  }
  static std::vector<std::string> job_flags(const std::string& scene) {
    return {scene, "--width", "32",   "--height",    "32",  "--spp",  "4", "--paths-per-round", "2", "--tile",
            "16",  "--mode",  "skip", "--reproject", "cpu", "--seed", "5"};
  }

  fs::path dir_;
  std::string target_;
  std::unique_ptr<Process> master_, worker_;
  int runs_ = 0, masters_ = 0;
};

TEST_F(BatchCluster, FramesRenderAsOneBatchWithOneUploadAndEqualTheFramesRenderedAlone) {
  start_worker();
  const std::string scene = write_animated_scene(dir_ / "scene");
  std::vector<std::string> submit{"submit"};
  for (const auto& f : job_flags(scene)) submit.push_back(f);
  submit.insert(submit.end(), {"--frames", "1-3"});
  const RunResult sub = epr(submit);
  ASSERT_EQ(sub.code, 0) << sub.err;
  const std::string batch = sub.out.substr(0, sub.out.find('\n'));
  ASSERT_TRUE(valid_batch_id(batch)) << sub.out;
  // The scene went up once, for the three jobs.
  EXPECT_EQ(testing::count_of(sub.err, "uploaded the scene"), 1u) << sub.err;

  JobClientOptions copts;
  copts.timeout = 10s;
  JobClient client(target_, copts);
  std::vector<v1::JobStatus> jobs = list_batch(client, batch);
  ASSERT_EQ(jobs.size(), 3u);
  const std::string hash = content_hash(bundle_scene(scene));
  CameraSpec still;
  const CameraAnimation animation = load_camera_animation(scene, {}, &still);
  std::set<std::string> ids;
  for (uint32_t i = 0; i < 3; ++i) {
    const v1::JobStatus& s = jobs[i];
    ids.insert(s.id());
    EXPECT_EQ(s.batch_id(), batch);
    EXPECT_EQ(s.batch_name(), "anim");
    EXPECT_TRUE(s.has_frame());
    EXPECT_EQ(s.frame(), i + 1);
    EXPECT_EQ(s.batch_frames(), 3u);
    EXPECT_EQ(s.scene().content_hash(), hash);  // one scene for the batch
    const CameraSpec want = animation.at(i + 1, still), got = from_proto(s.effective().camera());
    EXPECT_EQ(got.eye, want.eye) << "frame " << i + 1;
    EXPECT_EQ(got.look, want.look) << "frame " << i + 1;
    EXPECT_EQ(got.up, want.up) << "frame " << i + 1;
    EXPECT_EQ(got.fov_y_degrees, want.fov_y_degrees) << "frame " << i + 1;
  }
  EXPECT_EQ(ids.size(), 3u);
  EXPECT_NEAR(from_proto(jobs[1].effective().camera()).eye.x, 0.2f, 1e-6f);  // half-way

  // `epr get BATCH --out DIR/name` waits for the frames and writes name.0001.* ...
  const RunResult get = epr({"get", batch, "--out", (dir_ / "out" / "name").string()});
  ASSERT_EQ(get.code, 0) << get.err;
  for (const char* f : {"name.0001.exr", "name.0001.png", "name.0001.json", "name.0002.exr", "name.0003.exr",
                        "name.0003.png", "name.0003.counts.exr"})
    EXPECT_TRUE(fs::exists(dir_ / "out" / f)) << f << "\n" << get.err;

  // `epr watch BATCH` ends at once on the finished batch; `epr list` shows the batch and frames.
  const RunResult watch = epr({"watch", batch});
  EXPECT_EQ(watch.code, 0) << watch.err;
  EXPECT_NE(watch.err.find("frames 3/3 done"), std::string::npos) << watch.err;
  const RunResult list = epr({"list", "--batch", batch});
  ASSERT_EQ(list.code, 0) << list.err;
  EXPECT_NE(list.out.find("BATCH"), std::string::npos) << list.out;
  EXPECT_EQ(testing::count_of(list.out, batch), 3u) << list.out;
  EXPECT_TRUE(std::regex_search(list.out, std::regex("anim\\.0002 +DONE .* " + batch + " +2\n"))) << list.out;

  // Each frame equals that frame submitted alone, as an ordinary job with the frame's camera.
  for (uint32_t frame = 1; frame <= 3; ++frame) {
    const CameraSpec c = animation.at(frame, still);
    RenderOptions alone = tiny_job(scene);
    alone.eye = c.eye;
    alone.look = c.look;
    alone.up = c.up;
    alone.fov = c.fov_y_degrees;
    const std::string id = client.submit(alone);
    ASSERT_EQ(client.watch(id, [](const v1::JobStatus&) { return true; }).state(), v1::JOB_STATE_DONE);
    const std::string prefix = (dir_ / ("alone" + std::to_string(frame))).string();
    client.fetch_all(id, prefix);
    const std::string batch_prefix = frame_file_name((dir_ / "out" / "name").string(), frame);
    EXPECT_EQ(testing::exact_difference(read_image(batch_prefix + ".counts.exr"), read_image(prefix + ".counts.exr")),
              "")
        << "frame " << frame;
    EXPECT_EQ(
        testing::exact_difference(read_image(batch_prefix + ".pathtrace.exr"), read_image(prefix + ".pathtrace.exr")),
        "")
        << "frame " << frame;
    EXPECT_EQ(testing::close_difference(read_image(batch_prefix + ".exr"), read_image(prefix + ".exr")), "")
        << "frame " << frame;
  }
  // The frames differ from each other: the camera moved.
  EXPECT_NE(testing::exact_difference(read_image((dir_ / "out" / "name.0001.exr").string()),
                                      read_image((dir_ / "out" / "name.0003.exr").string())),
            "");
}

TEST_F(BatchCluster, ARestartedMasterKeepsItsJobsBatchAndFrame) {
  const std::string scene = write_animated_scene(dir_ / "scene");
  std::vector<std::string> submit{"submit"};
  for (const auto& f : job_flags(scene)) submit.push_back(f);
  submit.insert(submit.end(), {"--frames", "2,3", "--name", "walk"});
  const RunResult sub = epr(submit);  // no worker: the frames stay queued
  ASSERT_EQ(sub.code, 0) << sub.err;
  const std::string batch = sub.out.substr(0, sub.out.find('\n'));
  master_->stop();
  ASSERT_NO_FATAL_FAILURE(start_master());
  JobClient client(target_);
  const std::vector<v1::JobStatus> jobs = list_batch(client, batch);
  ASSERT_EQ(jobs.size(), 2u) << master_->err();
  for (uint32_t i = 0; i < 2; ++i) {
    EXPECT_EQ(jobs[i].batch_name(), "walk");
    EXPECT_EQ(jobs[i].frame(), i + 2);
    EXPECT_EQ(jobs[i].batch_frames(), 2u);
    EXPECT_EQ(jobs[i].name(), "walk.000" + std::to_string(i + 2));
  }
  EXPECT_EQ(client.list().size(), 2u);
}

TEST_F(BatchCluster, BadFramesAndBrokenKeysAreRefusedBeforeAnythingIsSubmitted) {
  const std::string scene = write_animated_scene(dir_ / "scene");
  std::vector<std::string> args{"submit"};
  for (const auto& f : job_flags(scene)) args.push_back(f);
  args.insert(args.end(), {"--frames", "3-1"});
  RunResult r = epr(args);
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("--frames: range '3-1' ends before it starts"), std::string::npos) << r.err;

  std::ofstream(dir_ / "scene" / "broken.json") << "{\"obj\": \"CornellBox-Original.obj\",\n"
                                                   " \"animation\": {\"camera\": [\n"
                                                   "  {\"frame\": 4},\n"
                                                   "  {\"frame\": 2}\n"
                                                   "]}}\n";
  args[1] = (dir_ / "scene" / "broken.json").string();
  args.back() = "1-3";
  r = epr(args);
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("broken.json:4: camera key frame 2 does not come after frame 4"), std::string::npos) << r.err;

  JobClient client(target_);
  EXPECT_TRUE(client.list().empty());
  // An id that is neither a job nor a batch.
  r = epr({"watch", "b-000000000000"});
  EXPECT_EQ(r.code, 4) << r.err;
}

// A frame window through the real programs: the batch's frames' counts and path sums are the same bit
// for bit whether one worker process traced them or three.
TEST_F(BatchCluster, AFrameWindowBatchHasTheSameCountsForOneAndThreeWorkers) {
  const std::string scene = write_animated_scene(dir_ / "scene");
  std::vector<std::unique_ptr<Process>> workers;
  auto start_workers = [&](int n) {
    workers.clear();
    for (int i = 0; i < n; ++i)
      workers.push_back(std::make_unique<Process>(
          std::vector<std::string>{binary("worker", "epr-worker"), "--master", target_, "--threads", "1", "--cache-dir",
                                   (dir_ / ("cache" + std::to_string(i))).string()},
          dir_ / ("worker-" + std::to_string(n) + "-" + std::to_string(i))));
  };
  auto render_batch = [&](const std::string& out) {
    std::vector<std::string> submit{"submit"};
    for (const auto& f : job_flags(scene)) submit.push_back(f);
    *(std::find(submit.begin(), submit.end(), "--spp") + 1) = "16";  // rounds enough for the window to act
    submit.insert(submit.end(), {"--frames", "1-3", "--frame-window", "1", "--window-run", "3"});
    const RunResult sub = epr(submit);
    ASSERT_EQ(sub.code, 0) << sub.err;
    const std::string batch = sub.out.substr(0, sub.out.find('\n'));
    const RunResult get = epr({"get", batch, "--out", (dir_ / out / "f").string()}, 300s);
    ASSERT_EQ(get.code, 0) << get.err;
  };
  start_workers(1);
  ASSERT_NO_FATAL_FAILURE(render_batch("one"));
  start_workers(3);
  ASSERT_NO_FATAL_FAILURE(render_batch("three"));
  for (uint32_t frame = 1; frame <= 3; ++frame) {
    const std::string a = frame_file_name((dir_ / "one" / "f").string(), frame),
                      b = frame_file_name((dir_ / "three" / "f").string(), frame);
    EXPECT_EQ(testing::exact_difference(read_image(a + ".counts.exr"), read_image(b + ".counts.exr")), "")
        << "frame " << frame;
    EXPECT_EQ(testing::exact_difference(read_image(a + ".pathtrace.exr"), read_image(b + ".pathtrace.exr")), "")
        << "frame " << frame;
    EXPECT_EQ(testing::close_difference(read_image(a + ".exr"), read_image(b + ".exr")), "") << "frame " << frame;
  }
  // The window ran: the master logged the run.
  EXPECT_NE(master_->err().find("window run 1..3 of batch"), std::string::npos);
}

}  // namespace
}  // namespace epr
