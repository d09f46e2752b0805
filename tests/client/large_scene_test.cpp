// Large file scenes through JobClient against a real in-process master over loopback: the upload and
// SubmitJob deadlines grow with the scene (the master parses it before SubmitJob answers), and the
// upload reports its progress. The per-call base deadline is scaled down to 10 ms so that a
// multi-megabyte scene stands in for a 200 MB one against the default 10 s.
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <filesystem>

#include "client/job_client.h"
#include "master/server/master_server.h"
#include "tests/client/large_obj.h"
#include "wire/scene_bundle.h"

namespace epr {
namespace {
namespace fs = std::filesystem;
using namespace std::chrono_literals;

TEST(LargeScene, UploadAndSubmitDeadlinesFollowTheScenesSize) {
  const fs::path dir = fs::temp_directory_path() / ("epr-large-scene-" + std::to_string(::getpid()));
  const std::string obj = test::write_large_obj(dir, 16u << 20);
  const uint64_t bytes = bundle_scene(obj).total_bytes();
  ASSERT_GT(bytes, 16u << 20);

  MasterServerOptions mo;
  mo.listen = "127.0.0.1:0";
  mo.http_listen = "";
  MasterServer master(mo);
  // Connected first, so that only the calls themselves run against the 10 ms base deadline.
  auto channel = grpc::CreateChannel(master.local_target(), grpc::InsecureChannelCredentials());
  ASSERT_TRUE(channel->WaitForConnected(std::chrono::system_clock::now() + 30s));

  JobClientOptions o;
  o.timeout = 10ms;  // a master parses 16 MB of OBJ in far more than that
  std::vector<UploadProgress> reports;
  o.upload_progress = [&](const UploadProgress& p) { reports.push_back(p); };
  JobClient client(channel, master.local_target(), o);
  RenderOptions ro;
  ro.scene = obj;
  ro.width = ro.height = 16;
  ro.spp = 1;
  std::string id;
  ASSERT_NO_THROW(id = client.submit(ro)) << "a fixed 10 ms deadline cannot carry a 16 MB scene";
  EXPECT_FALSE(id.empty());

  // The last two reports: the master loading the scene, then done with it.
  using Stage = UploadProgress::Stage;
  ASSERT_GE(reports.size(), 3u);
  EXPECT_EQ(reports.back().stage, Stage::kLoaded);
  EXPECT_GT(reports.back().seconds, 0.0);
  reports.pop_back();
  EXPECT_EQ(reports.back().stage, Stage::kLoading);
  EXPECT_EQ(reports.back().total, bytes);
  reports.pop_back();
  // Then the upload's: the last says the whole scene went; none says more, and they only go up.
  EXPECT_EQ(reports.back().stage, Stage::kUploaded);
  EXPECT_TRUE(reports.back().done);
  EXPECT_EQ(reports.back().sent, bytes);
  EXPECT_EQ(reports.back().total, bytes);
  for (size_t i = 1; i < reports.size(); ++i) EXPECT_GE(reports[i].sent, reports[i - 1].sent);
  // At most one report a second besides the last one.
  for (size_t i = 1; i + 1 < reports.size(); ++i) EXPECT_GE(reports[i].seconds - reports[i - 1].seconds, 0.99);

  master.shutdown();
  fs::remove_all(dir);
}

}  // namespace
}  // namespace epr
