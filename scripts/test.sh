#!/usr/bin/env bash
# Installs what the project needs, builds from scratch in ./build and runs the whole test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# -Werror for the project's own code (CMakeLists.txt: EPR_WERROR; generated code and system headers excluded).
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release -DEPR_WERROR=ON
cmake --build build -j "$(nproc)"

# The tree's shape: every C++ file formatted by .clang-format, layers that point one way without
# include cycles or overlong files, and clang's thread-safety analysis of the lock annotations.
git ls-files -- '*.cpp' '*.h' | xargs clang-format --dry-run --Werror
/usr/bin/python3 scripts/check_layers.py
/usr/bin/python3 scripts/check_thread_safety.py build

# Two tests at a time: the tests wait by polling with generous guards, never on the wall clock, so
# they pass with both cores busy (tests with RUN_SERIAL still run alone).
(cd build && ctest --output-on-failure -j 2 "$@")

# ThreadSanitizer (scripts/tsan.sh): the master's and the worker node's tests and a cluster test
# (its programs TSan builds too) built with clang and -fsanitize=thread in build/tsan; any report
# fails the run.
bash scripts/tsan.sh

# Fuzzing (tests/fuzz/): the libFuzzer targets, built with clang and the sanitizers in build/fuzz, each
# run for EPR_FUZZ_SECONDS (default 45) in parallel, then every saved crash input replayed.
cmake -S tests/fuzz -B build/fuzz -G Ninja -DCMAKE_C_COMPILER=clang -DCMAKE_CXX_COMPILER=clang++ \
      -DEPR_FUZZ_SECONDS="${EPR_FUZZ_SECONDS:-45}"
cmake --build build/fuzz -j "$(nproc)"
(cd build/fuzz && ctest --output-on-failure -j 2)

# Containers (docs/DEPLOY.md): runtime-only images of this build, the farm from deploy/docker-compose.yml
# and deploy/k8s (podman kube play) in real containers. A container engine that is missing or refuses
# to start fails this stage with its reason.
bash scripts/container_ci.sh build
