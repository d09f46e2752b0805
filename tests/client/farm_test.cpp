// The masters of `epr --master` (client/farm.h) without processes: the list and its resolution, the
// master part of job ids, and what a farm of masters that are all down answers.
#include "client/farm.h"

#include <gtest/gtest.h>

namespace epr {
namespace {

TEST(Farm, JobIdsNameTheirMaster) {
  EXPECT_EQ(job_id_master("alpha.j000001-beef"), "alpha");
  EXPECT_EQ(job_id_master("j000001-beef"), "");
  EXPECT_EQ(job_id_master("epr-master-0.j000123-abcd"), "epr-master-0");
}

TEST(Farm, ANameWithSeveralAddressesIsOneMasterEach) {
  const MasterResolver resolver = [](const std::string& host) -> std::optional<std::vector<std::string>> {
    if (host == "masters") return std::vector<std::string>{"10.0.0.2", "10.0.0.1"};
    return std::vector<std::string>{"10.0.0.9"};
  };
  JobClientOptions o;
  o.tls = true;
  Farm farm("masters:50051,single:7000", o, resolver);
  ASSERT_EQ(farm.masters().size(), 3u);
  EXPECT_TRUE(farm.several());
  EXPECT_EQ(farm.masters()[0].endpoint.target, "ipv4:10.0.0.1:50051");
  EXPECT_EQ(farm.masters()[0].endpoint.tls_server_name, "masters");
  EXPECT_EQ(farm.masters()[1].endpoint.target, "ipv4:10.0.0.2:50051");
  EXPECT_EQ(farm.masters()[2].endpoint.target, "single:7000");
  EXPECT_EQ(farm.masters()[0].client->options().tls_server_name, "masters");
  EXPECT_FALSE(Farm("one:1", {}, resolver).several());
  EXPECT_THROW(Farm("a:1,,b:2", {}, resolver), std::invalid_argument);
  EXPECT_THROW(Farm("nocolon", {}, resolver), std::invalid_argument);
}

TEST(Farm, MastersThatAreAllDownAreReported) {
  JobClientOptions o;
  o.timeout = std::chrono::milliseconds(2000);
  Farm farm("127.0.0.1:1,127.0.0.1:2", o);
  try {
    farm.least_loaded();
    FAIL() << "no master answered, yet one was picked";
  } catch (const RpcError& e) {
    EXPECT_TRUE(e.unreachable()) << e.what();
  }
  EXPECT_EQ(farm.failed().size(), 2u);
  EXPECT_TRUE(farm.list({}, 0).empty());
  EXPECT_EQ(farm.failed().size(), 2u);
  try {
    farm.locate("alpha.j000001-beef");
    FAIL() << "a job was located on masters that are down";
  } catch (const RpcError& e) {
    EXPECT_TRUE(e.unreachable()) << e.what();
    EXPECT_NE(std::string(e.what()).find("did not answer"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace epr
