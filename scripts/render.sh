#!/usr/bin/env bash
# Installs what the project needs, builds in ./build and renders the Cornell box with the embedded
# default; extra arguments go to `epr render` (e.g. --spp 64 --mode skip).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release
cmake --build build -j "$(nproc)"
build/client/epr render builtin:cornell --spp 64 --mode skip --out cornell "$@"
