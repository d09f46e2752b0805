// The --master list (worker/master_targets.h): entries, names and addresses, resolution through a
// given resolver and through getaddrinfo itself.
#include "worker/master_targets.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <stdexcept>

namespace epr {
namespace {

TEST(WorkerMasterTargets, ListEntriesAreNamesOrTakenAsIs) {
  const auto t =
      parse_master_list(" m1:50051,10.0.0.2:50052 , dns:///svc.ns:7000,[::1]:9,unix:/tmp/s,dns://1.1.1.1/x:5");
  ASSERT_EQ(t.size(), 6u);
  EXPECT_EQ(t[0].spec, "m1:50051");
  EXPECT_EQ(t[0].host, "m1");
  EXPECT_EQ(t[0].port, "50051");
  EXPECT_EQ(t[1].spec, "10.0.0.2:50052");
  EXPECT_EQ(t[1].host, "");  // an address: gRPC's
  EXPECT_EQ(t[2].host, "svc.ns");
  EXPECT_EQ(t[2].port, "7000");
  EXPECT_EQ(t[3].host, "");
  EXPECT_EQ(t[4].host, "");
  EXPECT_EQ(t[5].host, "x");
  EXPECT_EQ(t[5].port, "5");
}

TEST(WorkerMasterTargets, MalformedEntriesAreRefusedByName) {
  for (const std::string bad : {"", "a:1,,b:2", "nohost", "host:", ":5", "host:http"}) {
    try {
      parse_master_list(bad);
      ADD_FAILURE() << "accepted '" << bad << "'";
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find("--master"), std::string::npos) << e.what();
    }
  }
}

TEST(WorkerMasterTargets, PortsOutsideTheRangeAreRefusedNotWrapped) {
  for (const std::string bad : {"127.0.0.1:112837", "localhost:65536", "dns:///m:70000", "ipv4:127.0.0.1:112837",
                                "ipv6:[::1]:0", "[::1]:99999", "m:1,m:0"}) {
    try {
      parse_master_list(bad);
      ADD_FAILURE() << "accepted '" << bad << "'";
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find("is outside 1-65535"), std::string::npos) << e.what();
    }
  }
}

TEST(WorkerMasterTargets, ANameWithSeveralAddressesIsOneMasterPerAddress) {
  int calls = 0;
  const MasterResolver resolver = [&](const std::string& host) -> std::optional<std::vector<std::string>> {
    ++calls;
    if (host == "many") return std::vector<std::string>{"10.0.0.3", "10.0.0.1", "fd00::7"};
    if (host == "one") return std::vector<std::string>{"10.0.0.5"};
    if (host == "none") return std::vector<std::string>{};
    return std::nullopt;
  };
  bool complete = false;
  const auto e = resolve_masters(parse_master_list("many:50051,one:7,10.0.0.1:50051,none:1"), resolver, &complete);
  EXPECT_EQ(calls, 3);
  EXPECT_TRUE(complete);
  ASSERT_EQ(e.size(), 6u);
  EXPECT_EQ(e[0].target, "ipv4:10.0.0.1:50051");
  EXPECT_EQ(e[0].name, "many:50051 (10.0.0.1)");
  EXPECT_EQ(e[0].tls_server_name, "many");
  EXPECT_EQ(e[1].target, "ipv4:10.0.0.3:50051");
  EXPECT_EQ(e[2].target, "ipv6:[fd00::7]:50051");
  // One address: the name itself, as with a single master before.
  EXPECT_EQ(e[3].target, "one:7");
  EXPECT_EQ(e[3].tls_server_name, "");
  EXPECT_EQ(e[4].target, "10.0.0.1:50051");  // given as an address: not the same target as e[0]
  EXPECT_EQ(e[5].target, "none:1");

  // Duplicates go; a name that does not resolve stays on its name and the resolution is incomplete.
  const auto d = resolve_masters(parse_master_list("many:1,many:1,broken:2"), resolver, &complete);
  EXPECT_FALSE(complete);
  ASSERT_EQ(d.size(), 4u);
  EXPECT_EQ(d[3].target, "broken:2");
}

// getaddrinfo itself: an address is itself; localhost is one master even where it also has ::1.
TEST(WorkerMasterTargets, GetaddrinfoPrefersIpv4AndKeepsOneAddressPerHost) {
  const auto a = resolve_host("127.0.0.1");
  ASSERT_TRUE(a.has_value());
  EXPECT_EQ(*a, std::vector<std::string>{"127.0.0.1"});
  const auto l = resolve_host("localhost");
  ASSERT_TRUE(l.has_value());
  ASSERT_FALSE(l->empty());
  EXPECT_TRUE(std::find(l->begin(), l->end(), "127.0.0.1") != l->end());
  EXPECT_TRUE(std::find(l->begin(), l->end(), "::1") == l->end());
  EXPECT_FALSE(resolve_host("no-such-host.invalid").has_value());
  const auto e = resolve_masters(parse_master_list("localhost:50051"), nullptr);
  ASSERT_EQ(e.size(), 1u);
  EXPECT_EQ(e[0].target, "localhost:50051");
}

}  // namespace
}  // namespace epr
