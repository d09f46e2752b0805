// JobManager::admit, the checks of a job request before submit(), without gRPC: the name, the batch
// fields, the limits, the memory budget and the scene, each refused with its reason; a refused scene
// leaves nothing in the master's scene cache; a request without a camera takes the scene's own.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <string>

#include "master/server/job_manager.h"

namespace epr::test {
namespace {

namespace fs = std::filesystem;

class JobAdmissionTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::path(::testing::TempDir()) / ("epr-admission-" + std::to_string(::getpid()) + "-" +
                                             ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    options_.state_dir = dir_.string();
  }
  void TearDown() override { fs::remove_all(dir_); }

  static JobRequest admission_request() {
    JobRequest r;
    r.options.width = r.options.height = 32;
    r.options.spp = 4;
    r.options.paths_per_round = 2;
    r.options.reproject = ReprojectMethod::kCpu;
    r.options.tile_size = 16;
    r.bundle.builtin = "builtin:cornell";
    return r;
  }
  // The reason admit() gives, or "" if it admits the request.
  std::string refusal(JobRequest r, bool has_camera = true) {
    JobManager jobs(options_);
    const auto err = jobs.admit(&r, has_camera);
    return err ? *err : std::string();
  }

  fs::path dir_;
  MasterOptions options_;
};

TEST_F(JobAdmissionTest, RefusesEachBadFieldWithItsReason) {
  EXPECT_EQ(refusal(admission_request()), "");
  {
    JobRequest r = admission_request();
    r.name = std::string(257, 'n');
    EXPECT_EQ(refusal(r), "job names are limited to 256 bytes");
    r.name.resize(256);
    EXPECT_EQ(refusal(r), "");
  }
  {
    JobRequest r = admission_request();
    r.batch.frame = 3;
    EXPECT_EQ(refusal(r), "frame, batch_frames and batch_name need a batch_id");
    r.batch.id = "shot 1";
    EXPECT_EQ(refusal(r), "batch_id 'shot 1' is not 1 to 64 of [A-Za-z0-9_-]");
    r.batch.id = "shot-1";
    r.batch.name = std::string(257, 'b');
    EXPECT_EQ(refusal(r), "batch names are limited to 256 bytes");
    r.batch.name = "shot";
    EXPECT_EQ(refusal(r), "");
  }
  {
    JobRequest r = admission_request();
    r.options.width = 0;
    EXPECT_NE(refusal(r), "");
  }
  {
    options_.memory_budget_bytes = 1 << 20;
    const std::string why = refusal(admission_request());
    EXPECT_NE(why.find("a 32x32 frame at S="), std::string::npos) << why;
    EXPECT_NE(why.find("the budget is"), std::string::npos) << why;
  }
}

TEST_F(JobAdmissionTest, ABadSceneIsRefusedNamingFileAndLineAndLeavesNoCachedCopy) {
  JobRequest r = admission_request();
  r.bundle = {};
  r.bundle.entry_path = "box.obj";
  r.bundle.files.emplace_back("box.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n");
  const std::string hash = content_hash(r.bundle);
  const std::string why = refusal(r);
  EXPECT_NE(why.find("box.obj:4"), std::string::npos) << why;
  EXPECT_EQ(why.find(dir_.string()), std::string::npos) << "names the file as the client knows it: " << why;
  EXPECT_FALSE(fs::exists(dir_ / "cache" / "scenes" / hash)) << "the refused scene is removed from the cache";
}

TEST_F(JobAdmissionTest, WithoutACameraTheRequestTakesTheScenesOwn) {
  JobManager jobs(options_);
  CameraSpec own;
  ASSERT_FALSE(jobs.check_scene(admission_request().bundle, &own));
  JobRequest r = admission_request();
  r.camera.eye = {5, 5, 5};
  ASSERT_FALSE(jobs.admit(&r, /*has_camera=*/true));
  EXPECT_EQ(r.camera.eye, (Vec3{5, 5, 5})) << "a request's own camera is kept";
  ASSERT_FALSE(jobs.admit(&r, /*has_camera=*/false));
  EXPECT_EQ(r.camera.eye, own.eye);
  EXPECT_EQ(r.camera.look, own.look);
  EXPECT_EQ(r.camera.fov_y_degrees, own.fov_y_degrees);
}

}  // namespace
}  // namespace epr::test
