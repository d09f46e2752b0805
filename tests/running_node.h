// A WorkerNode running on its own thread, for the tests that put real worker nodes on a master.
#pragma once

#include <chrono>
#include <thread>

#include "worker/worker_node.h"

namespace epr::test {

class RunningNode {
 public:
  explicit RunningNode(WorkerNodeOptions o) : node_(std::move(o)), thread_([this] { node_.run(); }) {}
  ~RunningNode() { stop(); }
  /// Stops the node and waits for run() to return; the time it took.
  std::chrono::duration<double> stop() {
    const auto start = std::chrono::steady_clock::now();
    node_.stop();
    if (thread_.joinable()) thread_.join();
    return std::chrono::steady_clock::now() - start;
  }
  WorkerNodeStats stats() const { return node_.stats(); }

 private:
  WorkerNode node_;
  std::thread thread_;
};

}  // namespace epr::test
