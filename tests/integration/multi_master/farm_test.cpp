// The client over several masters (client/farm.h) with real processes: two epr-master processes (one
// named with --name, one by its default name, kept in its state directory), epr-worker processes
// given both addresses, and `epr --master A,B`.
//  - A batch of eight frames of a camera animation spreads over both masters; one master is
//    SIGKILLed mid-batch and restarted on its state directory; `epr get BATCH`, started before the
//    kill, gathers every frame from both masters, each equal to `epr render --single-process` of
//    that frame's camera (M, M' and the path-traced estimate bit-identical, the combined image within
//    float rounding, as tests/integration/cluster checks).
//  - Jobs submitted through the list land on both masters; get, watch and cancel find a job on the
//    second master by its id; with one master down, `epr list` lists the other's jobs, names the down
//    one and exits 3, and `epr submit` goes to the master that is up.
#include <fmt/format.h>

#include <fstream>
#include <set>
#include <sstream>

#include "common/camera_animation.h"
#include "multi_master_fixture.h"

namespace epr::testing {
namespace {

// The frames' settings: 64x64 pixels in 4 tiles, `rounds` rounds of 4 paths, every pixel traced in
// each, as job_flags.
Args frame_flags(int seed, int rounds) {
  Args f = job_flags(seed, rounds);
  f.erase(f.begin());  // the scene
  return f;
}

// A camera move through the Cornell box over frames 1 to 8.
const char* kAnimation = R"({
  "builtin": "cornell",
  "animation": {
    "camera": [
      {"frame": 1, "eye": [0, 1, 3.9],      "look": [0, 1, 0]},
      {"frame": 5, "eye": [0.4, 1.15, 3.2], "look": [0.05, 1, 0], "fov": 44},
      {"frame": 8, "eye": [-0.3, 1.2, 2.8], "look": [-0.1, 0.95, 0], "fov": 50}
    ]
  }
}
)";

std::string vec(const Vec3& v) { return fmt::format("{:.9g},{:.9g},{:.9g}", v.x, v.y, v.z); }

class FarmTest : public MultiMasterTest {
 protected:
  // The master name a master's current process printed ("master name: NAME (...)").
  static std::string master_name(const std::string& log) {
    std::smatch m;
    const std::regex name("master name: ([A-Za-z0-9_-]+) ");
    return std::regex_search(log, m, name) ? m[1].str() : "";
  }

  // `epr` with --master naming both masters (a first).
  RunResult farm_epr(Args args, Millis timeout = 60s) {
    args.insert(args.end(), {"--master", all_addresses()});
    return epr(args, timeout);
  }

  static std::string first_line(const std::string& s) { return s.substr(0, s.find('\n')); }
  // Whether a line of `err` says the master at `address` did not answer; the client names a master by its
  // address, or as "NAME (ADDRESS)" once it has learnt the name.
  static bool says_did_not_answer(const std::string& err, const std::string& address) {
    std::istringstream lines(err);
    for (std::string line; std::getline(lines, line);)
      if (line.find("did not answer") != std::string::npos &&
          (line.find("master " + address + " ") != std::string::npos ||
           line.find(" (" + address + ") did not answer") != std::string::npos))
        return true;
    return false;
  }
};

TEST_F(FarmTest, ABatchOverTwoMastersEqualsItsSingleProcessFramesThroughAMasterKill) {
  masters_.reserve(2);
  const std::string scene = path("flythrough.json");
  std::ofstream(scene) << kAnimation;
  const Args flags = frame_flags(31, 8);
  // The references: each frame's camera as the client computes it for the batch (client/batch.h),
  // given to `epr render --single-process` as overrides.
  CameraSpec still;
  const CameraAnimation animation = load_camera_animation(scene, {}, &still);
  ASSERT_TRUE(animation.animated());
  for (uint32_t f = 1; f <= 8; ++f) {
    const CameraSpec c = animation.at(f, still);
    Args args{scene,     "--eye",     vec(c.eye),
              "--look",  vec(c.look), "--up",
              vec(c.up), "--fov",     fmt::format("{:.9g}", c.fov_y_degrees)};
    args.insert(args.end(), flags.begin(), flags.end());
    start_reference(args, fmt::format("ref-{}", f));
  }
  MasterProc& a = add_master("master-a", true, {"--name", "alpha"});
  MasterProc& b = add_master("master-b");
  const std::string b_name = master_name(b.proc->err());
  ASSERT_FALSE(b_name.empty()) << b.proc->err();
  for (const char* n : {"w1", "w2", "w3"}) start_worker(n);
  ASSERT_TRUE(wait_until([&] { return registered(a) >= 3 && registered(b) >= 3; }, 30s));

  Args submit{"submit", scene, "--frames", "1-8"};
  submit.insert(submit.end(), flags.begin(), flags.end());
  const RunResult s = farm_epr(submit, 30s);
  ASSERT_EQ(s.code, 0) << s.err;
  const std::string batch = first_line(s.out);
  note("batch %s: %s", batch.c_str(), first_line(s.err.substr(s.err.find("batch "))).c_str());
  EXPECT_NE(s.err.find("4 at alpha"), std::string::npos) << s.err;
  EXPECT_NE(s.err.find("4 at " + b_name), std::string::npos) << s.err;

  // The client that gathers the frames runs through the kill.
  Process get({kEpr, "get", batch, "--out", path("out/fly"), "--master", all_addresses()}, dir_ / "epr-get-batch");
  ASSERT_TRUE(wait_until([&] { return leased_from(b, 2) > 0; }, 60s)) << "master-b's frames never reached round 2";
  const std::regex done("job \\S+ done:");
  const std::string b_log = b.proc->err();
  const auto b_done = std::distance(std::sregex_iterator(b_log.begin(), b_log.end(), done), std::sregex_iterator());
  ASSERT_LT(b_done, 4) << "master-b finished its frames before the kill: make them longer";
  b.proc->signal(SIGKILL);
  ASSERT_EQ(b.proc->wait_for(5s), 128 + SIGKILL);
  b.old_logs.push_back(b.proc->err());
  note("master-b SIGKILLed with %d of its frames done", int(b_done));
  std::this_thread::sleep_for(2s);  // the client and the workers see it down
  ASSERT_NO_FATAL_FAILURE(start_master(b));
  EXPECT_EQ(master_name(b.proc->err()), b_name) << "the default name did not survive the restart";
  EXPECT_NE(b.proc->err().find("run 2, 4 jobs loaded"), std::string::npos) << b.proc->err();
  note("master-b restarted as %s", b_name.c_str());

  ASSERT_TRUE(get.wait_for(180s).has_value()) << "epr get of the batch did not end:\n" << get.err();
  ASSERT_EQ(get.exit_code(), 0) << get.err();
  EXPECT_TRUE(says_did_not_answer(get.err(), b.address())) << get.err();
  note("epr get wrote all 8 frames");
  for (auto& r : references_) {
    ASSERT_TRUE(r->wait_for(120s).has_value()) << "the reference render did not end";
    ASSERT_EQ(r->exit_code(), 0) << r->err();
  }
  for (int f = 1; f <= 8; ++f) {
    const std::string out = path(fmt::format("out/fly.{:04d}", f)), ref = path(fmt::format("ref-{}", f));
    EXPECT_EQ(exact_difference(read_image(out + ".counts.exr"), read_image(ref + ".counts.exr")), "")
        << "frame " << f << ": M and M' per pixel";
    EXPECT_EQ(exact_difference(read_image(out + ".pathtrace.exr"), read_image(ref + ".pathtrace.exr")), "")
        << "frame " << f << ": path-traced estimate";
    EXPECT_EQ(close_difference(read_image(out + ".exr"), read_image(ref + ".exr")), "")
        << "frame " << f << ": combined image";
  }
  // The frames differ from each other: the camera moved.
  EXPECT_NE(
      exact_difference(read_image(path("out/fly.0001.pathtrace.exr")), read_image(path("out/fly.0008.pathtrace.exr"))),
      "");
  const RunResult list = farm_epr({"list", "--batch", batch});
  ASSERT_EQ(list.code, 0) << list.err;
  EXPECT_EQ(count_of(list.out, " DONE "), 8u) << list.out;
  EXPECT_EQ(count_of(list.out, "alpha.j"), 4u) << list.out;
  EXPECT_EQ(count_of(list.out, b_name + ".j"), 4u) << list.out;
}

TEST_F(FarmTest, JobsAreFoundOnEitherMasterAndListedAroundADownOne) {
  masters_.reserve(2);
  MasterProc& a = add_master("master-a", true, {"--name", "alpha"});
  MasterProc& b = add_master("master-b");
  const std::string b_name = master_name(b.proc->err());

  // Four jobs through the list, queued before any worker comes: each goes to the master with the
  // fewest samples left (then the fewest jobs, then the first), so two to each.
  std::vector<std::string> ids;
  for (int seed = 41; seed < 45; ++seed) {
    Args submit{"submit"};
    const Args flags = job_flags(seed, 2);
    submit.insert(submit.end(), flags.begin(), flags.end());
    const RunResult r = farm_epr(submit, 30s);
    ASSERT_EQ(r.code, 0) << r.err;
    ids.push_back(first_line(r.out));
  }
  std::vector<std::string> on_a, on_b;
  for (const auto& id : ids) (id.rfind("alpha.", 0) == 0 ? on_a : on_b).push_back(id);
  ASSERT_EQ(on_a.size(), 2u) << ::testing::PrintToString(ids);
  ASSERT_EQ(on_b.size(), 2u) << ::testing::PrintToString(ids);
  EXPECT_EQ(on_b[0].rfind(b_name + ".", 0), 0u) << on_b[0];
  start_worker("w1");
  ASSERT_TRUE(wait_until([&] { return registered(a) >= 1 && registered(b) >= 1; }, 30s));

  // The second master's job by its id: watch, get, and the cancel of one.
  const RunResult w = farm_epr({"watch", on_b[0]}, 120s);
  ASSERT_EQ(w.code, 0) << w.err;
  const RunResult g = farm_epr({"get", on_b[0], "--out", path("got")});
  ASSERT_EQ(g.code, 0) << g.err;
  EXPECT_TRUE(fs::exists(path("got.exr")));
  const RunResult c = farm_epr({"cancel", on_b[1]});
  EXPECT_EQ(c.code, 0) << c.err;
  const RunResult unknown = farm_epr({"get", "alpha.j999999-0000", "--json"});
  EXPECT_EQ(unknown.code, 4) << unknown.err;
  note("jobs %s and %s on %s found by their ids", on_b[0].c_str(), on_b[1].c_str(), b_name.c_str());

  // Master b down: the list holds a's jobs and says b did not answer (exit 3).
  b.proc->signal(SIGKILL);
  ASSERT_EQ(b.proc->wait_for(5s), 128 + SIGKILL);
  b.old_logs.push_back(b.proc->err());
  const RunResult list = farm_epr({"list"});
  EXPECT_EQ(list.code, 3) << list.err;
  for (const auto& id : on_a) EXPECT_NE(list.out.find(id), std::string::npos) << list.out;
  for (const auto& id : on_b) EXPECT_EQ(list.out.find(id), std::string::npos) << list.out;
  EXPECT_TRUE(says_did_not_answer(list.err, b.address())) << list.err;
  const RunResult lost = farm_epr({"get", on_b[0], "--json"});
  EXPECT_EQ(lost.code, 3) << lost.err;
  EXPECT_NE(lost.err.find(b.address()), std::string::npos) << lost.err;
  const Args flags = job_flags(45, 2);
  Args submit{"submit"};
  submit.insert(submit.end(), flags.begin(), flags.end());
  const RunResult s = farm_epr(submit, 30s);
  ASSERT_EQ(s.code, 0) << s.err;
  EXPECT_EQ(s.out.rfind("alpha.", 0), 0u) << s.out;
  EXPECT_NE(s.err.find(b.address()), std::string::npos) << s.err;
  note("with %s down: list partial, submit to alpha", b_name.c_str());

  // Back on its state directory, b holds its jobs under the same ids.
  ASSERT_NO_FATAL_FAILURE(start_master(b));
  const RunResult back = farm_epr({"get", on_b[0], "--json"});
  ASSERT_EQ(back.code, 0) << back.err;
  EXPECT_NE(back.out.find("\"JOB_STATE_DONE\""), std::string::npos) << back.out;
}

}  // namespace
}  // namespace epr::testing
