// Which failed calls are retried (wire/rpc/status.h is_transient) and how deadlines grow with the
// work a call carries (wire/rpc/channel.h scaled_deadline).
#include <gtest/gtest.h>

#include "wire/rpc/channel.h"
#include "wire/rpc/status.h"

namespace epr::rpc {
namespace {

using grpc::StatusCode;
using std::chrono::milliseconds;

TEST(RetryPolicy, OnlyAnAbsentOrBusyMasterIsRetried) {
  for (StatusCode c : {StatusCode::UNAVAILABLE, StatusCode::DEADLINE_EXCEEDED, StatusCode::RESOURCE_EXHAUSTED,
                       StatusCode::ABORTED, StatusCode::CANCELLED, StatusCode::UNKNOWN, StatusCode::INTERNAL})
    EXPECT_TRUE(is_transient(c)) << status_code_name(c);
  // The same request would be refused again: the caller ends with the reason.
  for (StatusCode c : {StatusCode::INVALID_ARGUMENT, StatusCode::UNAUTHENTICATED, StatusCode::PERMISSION_DENIED,
                       StatusCode::FAILED_PRECONDITION, StatusCode::UNIMPLEMENTED, StatusCode::NOT_FOUND,
                       StatusCode::ALREADY_EXISTS, StatusCode::OUT_OF_RANGE, StatusCode::DATA_LOSS})
    EXPECT_FALSE(is_transient(c)) << status_code_name(c);
  EXPECT_FALSE(is_transient(StatusCode::OK));
}

TEST(RetryPolicy, DeadlinesGrowWithTheBytesACallCarries) {
  EXPECT_EQ(scaled_deadline(milliseconds(10'000), 0, 1e6), milliseconds(10'000));
  // 200 MB at the slowest accepted 1 MB/s: 200 s on top of the base.
  EXPECT_EQ(scaled_deadline(milliseconds(10'000), 200'000'000, 1e6), milliseconds(210'000));
  EXPECT_EQ(scaled_deadline(milliseconds(20), 4'000'000, 256e3), milliseconds(20 + 15'625));
  // No overflow for absurd sizes or rates.
  EXPECT_GT(scaled_deadline(milliseconds(1), UINT64_MAX, 0), milliseconds(1'000'000'000));
}

}  // namespace
}  // namespace epr::rpc
