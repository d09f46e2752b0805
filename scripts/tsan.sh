#!/usr/bin/env bash
# ThreadSanitizer: the tests of the master (tests/server) and of the worker node (tests/worker_node),
# whose threads (gRPC handlers, the reprojection thread, the reaper, tracing threads, couriers) share
# data, built with clang and -fsanitize=thread in build/tsan -- only what those two binaries need -- at
# -O1 without NDEBUG, so EPR_DCHECK and assert() run too. Any report fails the run (TSan's exit code
# 66). scripts/tsan.supp names what is suppressed and why. Not yet part of scripts/test.sh: Debian's
# gRPC, TBB and Embree are not instrumented, and the build does not fit CI's time (README.md).
# Arguments go to both test binaries (e.g. --gtest_filter=LeaseTable*).
set -euo pipefail
cd "$(dirname "$0")/.."
cmake -S . -B build/tsan -G Ninja -DCMAKE_BUILD_TYPE=Release -DCMAKE_C_COMPILER=clang -DCMAKE_CXX_COMPILER=clang++ \
      -DCMAKE_C_FLAGS_RELEASE=-O1 -DCMAKE_CXX_FLAGS_RELEASE=-O1 -DEPR_SANITIZE=thread -DEPR_BUILD_BENCH=OFF
cmake --build build/tsan -j "$(nproc)" --target server_test worker_node_test
for t in server_test worker_node_test; do
  TSAN_OPTIONS="suppressions=$PWD/scripts/tsan.supp second_deadlock_stack=1 ${TSAN_OPTIONS:-}" build/tsan/tests/$t "$@"
done
