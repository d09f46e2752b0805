// A state folder that cannot take a job: SubmitJob is refused with RESOURCE_EXHAUSTED, naming what
// could not be stored and the errno, and nothing of the job remains (not listed, no folder, not back
// after a restart). The full disk is this process's RLIMIT_FSIZE around the one call
// (tests/file_size_limit.h). Nothing else of this process writes
// to a file meanwhile (the master's one running job has no worker).
#include <cerrno>
#include <cstring>

#include "tests/file_size_limit.h"
#include "tests/server/farm_fixture.h"

namespace epr::test {
namespace {

class FullStateDirTest : public FarmFixture {
 protected:
  // A job whose spec is larger than its (built-in) scene's stored file: a name of 256 bytes.
  v1::JobSpec spec() const {
    v1::JobSpec s = to_job_spec(cornell(RenderMode::kPathTrace, 32, 2, 2), bundle_scene("builtin:cornell"), {});
    s.set_name(std::string(256, 'n'));
    return s;
  }
  size_t job_folders() const {
    size_t n = 0;
    if (fs::exists(dir_ / "master" / "jobs"))
      for ([[maybe_unused]] const auto& e : fs::directory_iterator(dir_ / "master" / "jobs")) ++n;
    return n;
  }
  // Submits spec() with room for `room` bytes a file: refused with RESOURCE_EXHAUSTED, naming
  // "cannot store the job's WHAT" and EFBIG, with no job id.
  void expect_submit_refused(rlim_t room, const std::string& what) {
    std::string id;
    grpc::Status st;
    {
      FileSizeLimit limit(room);
      st = submit(spec(), &id);
    }
    const std::string efbig = std::strerror(EFBIG);
    EXPECT_EQ(st.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << st.error_message();
    EXPECT_NE(st.error_message().find("cannot store the job's " + what), std::string::npos) << st.error_message();
    EXPECT_NE(st.error_message().find(efbig), std::string::npos) << st.error_message();
    EXPECT_TRUE(id.empty()) << id;
  }
};

TEST_F(FullStateDirTest, AJobWhoseSpecCannotBeStoredIsRefused) {
  start();
  // The scene is stored by an earlier submission, so that only the spec is written below.
  std::string first;
  ASSERT_TRUE(submit(spec(), &first).ok());
  // Started (its frame built), it waits for workers, of which there are none: it writes nothing more.
  ASSERT_TRUE(wait_until([&] { return status(first).state() == v1::JOB_STATE_RUNNING; }, 30s));
  expect_submit_refused(256, "spec");
  EXPECT_EQ(server_->jobs().list().size(), 1u);
  EXPECT_EQ(job_folders(), 1u) << "the refused job's folder is removed";
  // A restart brings back the first job only.
  server_->shutdown();
  start();
  const auto jobs = server_->jobs().list();
  ASSERT_EQ(jobs.size(), 1u);
  EXPECT_EQ(jobs[0].id, first);
  // With room again, the same submission is taken.
  std::string id;
  EXPECT_TRUE(submit(spec(), &id).ok());
}

TEST_F(FullStateDirTest, AJobWhoseSceneCannotBeStoredIsRefused) {
  start();
  expect_submit_refused(8, "scene");
  EXPECT_TRUE(server_->jobs().list().empty());
  EXPECT_EQ(job_folders(), 0u);
}

}  // namespace
}  // namespace epr::test
