// common/address.h: the one HOST:PORT parser of every program.
#include "common/address.h"

#include <gtest/gtest.h>

#include <stdexcept>

namespace epr {
namespace {

TEST(Address, HostsAddressesAndBracketedV6) {
  auto a = parse_address("127.0.0.1:50051");
  ASSERT_TRUE(a);
  EXPECT_EQ(a->host, "127.0.0.1");
  EXPECT_EQ(a->port, 50051);
  a = parse_address("[::1]:9");
  ASSERT_TRUE(a);
  EXPECT_EQ(a->host, "::1");
  EXPECT_EQ(a->port, 9);
  EXPECT_EQ(format_host_port(*a), "[::1]:9");
  a = parse_address("master-1.farm.example:65535");
  ASSERT_TRUE(a);
  EXPECT_EQ(a->host, "master-1.farm.example");
  EXPECT_EQ(a->port, 65535);
  EXPECT_EQ(parse_address("h:0080")->port, 80);
}

TEST(Address, PortsOutsideTheRangeAreRefusedNotWrapped) {
  std::string why;
  EXPECT_FALSE(parse_address("127.0.0.1:112837", {}, &why));
  EXPECT_EQ(why, "port 112837 is outside 1-65535");
  for (const char* bad : {"h:65536", "h:0", "h:99999999999999999999", "[::1]:70000", "h:-1", "h:+80", "h: 80"})
    EXPECT_FALSE(parse_address(bad)) << bad;
  EXPECT_TRUE(parse_address("h:0", {.port_zero = true}));
  EXPECT_FALSE(parse_address("h:65536", {.port_zero = true}));
}

TEST(Address, MalformedAddressesSayWhy) {
  for (const char* bad :
       {"", "host", "host:", ":80", "::1:80", "[::1]", "[::1]80", "[host]:80", "[::1:80", "a b:1", "h:http"}) {
    std::string why;
    EXPECT_FALSE(parse_address(bad, {}, &why)) << bad;
    EXPECT_FALSE(why.empty()) << bad;
  }
  auto a = parse_address(":8080", {.empty_host = true});
  ASSERT_TRUE(a);
  EXPECT_EQ(a->host, "");
  EXPECT_EQ(a->port, 8080);
}

TEST(Address, RequireNamesTheFlagAndTheValue) {
  try {
    require_address("--listen", "0.0.0.0:112837");
    ADD_FAILURE() << "accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_STREQ(e.what(), "--listen '0.0.0.0:112837': port 112837 is outside 1-65535");
  }
}

}  // namespace
}  // namespace epr
