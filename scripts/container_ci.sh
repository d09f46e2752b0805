#!/usr/bin/env bash
# The container stage in one command, for CI: set-up, runtime-only images from a host build, the farm
# in containers, and what podman kube play runs of deploy/k8s. A step that cannot run fails the stage
# with its reason; nothing is skipped.
#
#   scripts/container_ci.sh BUILD_DIR      (root; BUILD_DIR holds a Release build of epr, epr-master, epr-worker)
set -euo pipefail

here="$(cd "$(dirname "$0")" && pwd)"
[ $# -eq 1 ] && [ -d "$1" ] || { echo "usage: $0 BUILD_DIR" >&2; exit 2; }
build="$(cd "$1" && pwd)"

step() {
  local name="$1" start=$SECONDS
  shift
  echo "container_ci: $name"
  "$@" || { echo "FAILED: container stage: $name (exit $?)" >&2; exit 1; }
  echo "container_ci: $name: $((SECONDS - start)) s"
}
step "set-up (scripts/container_setup.sh)" bash "$here/container_setup.sh"
step "images (scripts/container_images.sh --prebuilt)" bash "$here/container_images.sh" --prebuilt "$build"
step "farm (scripts/container_test.sh)" bash "$here/container_test.sh" --epr "$build/client/epr"
step "kube play (scripts/container_k8s_test.sh)" bash "$here/container_k8s_test.sh" --epr "$build/client/epr"
echo "container_ci: passed in $SECONDS s"
