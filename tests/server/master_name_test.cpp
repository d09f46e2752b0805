// Master names (master/server/master_name.h): chosen, saved in the state directory and kept across
// starts; the job ids of a named master and its GetMasterInfo answer.
#include "master/server/master_name.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <regex>

#include "client/job_client.h"
#include "master/server/master_server.h"

namespace epr {
namespace {
namespace fs = std::filesystem;

class MasterNameTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("epr-master-name-" + std::to_string(::getpid()) + "-" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
};

TEST_F(MasterNameTest, NamesAreCheckedAndTheListenPortIsRead) {
  EXPECT_TRUE(is_valid_master_name("alpha"));
  EXPECT_TRUE(is_valid_master_name("epr-master-0_x"));
  EXPECT_FALSE(is_valid_master_name(""));
  EXPECT_FALSE(is_valid_master_name("a.b"));
  EXPECT_FALSE(is_valid_master_name(std::string(41, 'a')));
  EXPECT_THROW(choose_master_name("no.dots", "", 1), std::invalid_argument);
  EXPECT_EQ(listen_port("0.0.0.0:50051"), 50051);
  EXPECT_EQ(listen_port("[::]:7000"), 7000);
  EXPECT_EQ(listen_port("127.0.0.1:0"), 0);
  EXPECT_EQ(listen_port("unix:/tmp/s"), 0);
}

TEST_F(MasterNameTest, TheDefaultIsSavedInTheStateDirectoryAndKept) {
  fs::create_directories(dir_);
  const std::string first = choose_master_name("", dir_.string(), 50051);
  EXPECT_TRUE(std::regex_match(first, std::regex("[A-Za-z0-9_-]+-50051"))) << first;
  EXPECT_EQ(choose_master_name("", dir_.string(), 6000), first) << "a restart keeps the saved name";
  // A random suffix when the port is chosen by the system, kept as well.
  const fs::path other = dir_ / "other";
  fs::create_directories(other);
  const std::string random = choose_master_name("", other.string(), 0);
  EXPECT_TRUE(std::regex_match(random, std::regex("[A-Za-z0-9_-]+-[0-9a-f]{6}"))) << random;
  EXPECT_EQ(choose_master_name("", other.string(), 0), random);
  // A given name replaces the saved one.
  EXPECT_EQ(choose_master_name("alpha", dir_.string(), 50051), "alpha");
  EXPECT_EQ(choose_master_name("", dir_.string(), 50051), "alpha");
  std::ofstream(dir_ / "master-name") << "bad.name\n";
  EXPECT_THROW(choose_master_name("", dir_.string(), 50051), std::invalid_argument);
}

TEST_F(MasterNameTest, JobIdsCarryTheNameAndGetMasterInfoTellsItAndTheLoad) {
  MasterServerOptions o;
  o.listen = "127.0.0.1:0";
  o.jobs.name = "alpha";
  o.jobs.reproject_backend_override = "cpu";
  MasterServer server(o);
  JobClient client(server.local_target());
  EXPECT_EQ(client.master_info().name(), "alpha");
  EXPECT_EQ(client.master_info().samples_left(), 0u);
  RenderOptions job;
  job.scene = "builtin:cornell";
  job.width = 32;
  job.height = 16;
  job.spp = 4;
  const std::string id = client.submit(job);
  EXPECT_TRUE(std::regex_match(id, std::regex("alpha\\.j[0-9]{6}-[0-9a-f]{4}"))) << id;
  const v1::MasterInfo info = client.master_info();
  EXPECT_EQ(info.jobs_queued() + info.jobs_running(), 1u);
  EXPECT_EQ(info.samples_left(), 32u * 16 * 4) << "no worker: nothing traced yet";
  server.shutdown();
}

}  // namespace
}  // namespace epr
