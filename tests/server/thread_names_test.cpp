// The master's and a worker node's long-lived threads carry names (`top -H`, `ps -L`, perf), so that
// an operator sees which part of the pipeline uses the CPU: tracing, the reprojection thread, the
// tile submissions.
#include <fstream>
#include <map>
#include <string>

#include "tests/server/farm_fixture.h"

namespace epr::test {
namespace {

std::map<std::string, int> thread_names() {
  std::map<std::string, int> names;
  for (const auto& task : fs::directory_iterator("/proc/self/task")) {
    std::ifstream in(task.path() / "comm");
    std::string name;
    if (std::getline(in, name)) ++names[name];
  }
  return names;
}

TEST_F(FarmFixture, ThreadsAreNamedAfterTheirWork) {
  // A thread inherits its creator's name: library pool threads that an earlier test's tracing
  // thread happened to start are named "epr-trace" too, and live on. The node's own count on top.
  const int others = thread_names()["epr-trace"];
  start();
  EXPECT_EQ(thread_names()["epr-trace"], others) << "the master traces nothing";
  // The master's threads name themselves once they run, which may be after start() returns.
  EXPECT_TRUE(eventually([] {
    auto n = thread_names();
    return n["epr-reproject"] >= 1 && n["epr-reaper"] >= 1;
  })) << "the master's reprojection and reaper threads carry their names";
  RunningNode node(node_options("named", 2));
  // Each tracing thread names itself when its session starts; its two couriers start with it.
  EXPECT_TRUE(eventually([&] {
    auto n = thread_names();
    return n["epr-trace"] == others + 2 && n["epr-submit"] == 2 && n["epr-lease"] == 2 && n["epr-heartbeat"] == 1;
  }));
  node.stop();
  EXPECT_EQ(thread_names()["epr-trace"], others) << "the tracing threads end with the node";
}

}  // namespace
}  // namespace epr::test
