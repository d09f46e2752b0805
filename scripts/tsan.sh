#!/usr/bin/env bash
# ThreadSanitizer (a stage of scripts/test.sh): the tests of the master (tests/server) and of the
# worker node (tests/worker_node), whose threads (gRPC handlers, the reprojection thread, the reaper,
# tracing threads, couriers) share data, then a cluster test, whose epr-master, epr-worker
# and epr processes are TSan builds too; built with clang and -fsanitize=thread in build/tsan -- only
# what those binaries need, a unity build (CMakeLists.txt) -- at -O1 without NDEBUG, so EPR_DCHECK
# and assert() run too, with TBB's loops on the calling thread (tests/tsan_serial_tbb.cpp). The two
# unit-test binaries run side by side, then the cluster test; TSan writes its reports
# (the child processes' too: they inherit TSAN_OPTIONS) to build/tsan/reports/, and any report, or any
# failed test, fails the run. scripts/tsan.supp names what is suppressed and why (Debian's gRPC, TBB,
# Embree and Mesa are not instrumented).
# Arguments go to every test binary after the stage's own filter (e.g. --gtest_filter=LeaseTable*
# replaces it); EPR_TSAN_BUILD names another build folder.
set -euo pipefail
cd "$(dirname "$0")/.."
build=${EPR_TSAN_BUILD:-build/tsan}
cmake -S . -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=Release -DCMAKE_C_COMPILER=clang -DCMAKE_CXX_COMPILER=clang++ \
      -DCMAKE_C_FLAGS_RELEASE=-O1 -DCMAKE_CXX_FLAGS_RELEASE=-O1 -DEPR_SANITIZE=thread -DEPR_BUILD_BENCH=OFF \
      -DCMAKE_UNITY_BUILD=ON -DCMAKE_UNITY_BUILD_BATCH_SIZE=16
cmake --build "$build" -j "$(nproc)" --target server_test worker_node_test epr epr-master epr-worker \
      cluster_integration_test

# The cluster test that runs here: three workers' render equal to the single-process one -- the
# master's threads with real workers over gRPC. The others run in the main ctest only: under TSan on
# two loaded cores the master restart's job outlasted its 120 s watch, drains of slow jobs, several
# masters and timed kills took minutes or raced the clock.
cluster_filter='ClusterTest.ThreeWorkersEqualSingleProcessRender'

reports=$PWD/$build/reports
rm -rf "$reports" && mkdir -p "$reports"
export TSAN_OPTIONS="suppressions=$PWD/scripts/tsan.supp second_deadlock_stack=1 log_path=$reports/tsan ${TSAN_OPTIONS:-}"
failed=0
pids=()
for t in server_test worker_node_test; do
  "$build/tests/$t" "$@" > "$reports/$t.out" 2>&1 &
  pids+=($!)
done
for pid in "${pids[@]}"; do
  wait "$pid" || failed=1
done
"$build/tests/cluster_integration_test" --gtest_filter="$cluster_filter" "$@" \
  > "$reports/cluster_integration_test.out" 2>&1 || failed=1

tests=(server_test worker_node_test cluster_integration_test)
for t in "${tests[@]}"; do
  grep "^\[  FAILED  \]\|^\[  PASSED  \]" "$reports/$t.out" | sed "s/^/$t: /" || true
done
if compgen -G "$reports/tsan.*" > /dev/null; then
  cat "$reports"/tsan.*
  echo "tsan: ThreadSanitizer reported the above ($reports)" >&2
  exit 1
fi
if [ "$failed" != 0 ]; then
  for t in "${tests[@]}"; do tail -n 50 "$reports/$t.out"; done
  echo "tsan: a test failed ($reports/*.out)" >&2
  exit 1
fi
echo "tsan: no report"
