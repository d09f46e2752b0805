#!/usr/bin/env bash
# Installs what the project needs, builds from scratch in ./build and runs the whole test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release
cmake --build build -j "$(nproc)"
(cd build && ctest --output-on-failure -j 1 "$@")

# Fuzzing (tests/fuzz/): the libFuzzer targets, built with clang and the sanitizers in build/fuzz, each
# run for EPR_FUZZ_SECONDS (default 45) in parallel, then every saved crash input replayed.
cmake -S tests/fuzz -B build/fuzz -G Ninja -DCMAKE_C_COMPILER=clang -DCMAKE_CXX_COMPILER=clang++ \
      -DEPR_FUZZ_SECONDS="${EPR_FUZZ_SECONDS:-45}"
cmake --build build/fuzz -j "$(nproc)"
(cd build/fuzz && ctest --output-on-failure -j 2)
