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
  std::string efbig() const { return std::strerror(EFBIG); }
};

TEST_F(FullStateDirTest, AJobWhoseSpecCannotBeStoredIsRefused) {
  start();
  // The scene is stored by an earlier submission, so that only the spec is written below.
  std::string first;
  ASSERT_TRUE(submit(spec(), &first).ok());
  // Started (its frame built), it waits for workers, of which there are none: it writes nothing more.
  ASSERT_TRUE(wait_until([&] { return status(first).state() == v1::JOB_STATE_RUNNING; }, 30s));
  std::string id;
  grpc::Status st;
  {
    FileSizeLimit limit(256);
    st = submit(spec(), &id);
  }
  EXPECT_EQ(st.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << st.error_message();
  EXPECT_NE(st.error_message().find("cannot store the job's spec"), std::string::npos) << st.error_message();
  EXPECT_NE(st.error_message().find(efbig()), std::string::npos) << st.error_message();
  EXPECT_TRUE(id.empty()) << id;
  EXPECT_EQ(server_->jobs().list().size(), 1u);
  EXPECT_EQ(job_folders(), 1u) << "the refused job's folder is removed";
  // A restart brings back the first job only.
  server_->shutdown();
  start();
  const auto jobs = server_->jobs().list();
  ASSERT_EQ(jobs.size(), 1u);
  EXPECT_EQ(jobs[0].id, first);
  // With room again, the same submission is taken.
  EXPECT_TRUE(submit(spec(), &id).ok());
}

TEST_F(FullStateDirTest, AJobWhoseSceneCannotBeStoredIsRefused) {
  start();
  std::string id;
  grpc::Status st;
  {
    FileSizeLimit limit(8);
    st = submit(spec(), &id);
  }
  EXPECT_EQ(st.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << st.error_message();
  EXPECT_NE(st.error_message().find("cannot store the job's scene"), std::string::npos) << st.error_message();
  EXPECT_NE(st.error_message().find(efbig()), std::string::npos) << st.error_message();
  EXPECT_TRUE(id.empty()) << id;
  EXPECT_TRUE(server_->jobs().list().empty());
  EXPECT_EQ(job_folders(), 0u);
}

}  // namespace
}  // namespace epr::test
