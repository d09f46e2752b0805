#!/usr/bin/env bash
# Builds the images eprfarm/epr-master and eprfarm/epr-worker from deploy/Dockerfile with podman, on
# the base image scripts/container_setup.sh makes (no registry needed).
#
#   scripts/container_images.sh --prebuilt BUILD_DIR   runtime-only images holding BUILD_DIR's epr,
#                                                      epr-master and epr-worker (a Release build on this
#                                                      Debian 12 machine): no compilation, ~1 minute
#   scripts/container_images.sh --from-source          the full multi-stage build: the build stage
#                                                      compiles the project inside the image
#
# Environment: EPR_REGISTRY (default eprfarm), EPR_TAG (default 0.1.0), EPR_BASE_IMAGE (default
# localhost/debian:bookworm-slim). Prints each image's size at the end.
set -euo pipefail

here="$(cd "$(dirname "$0")" && pwd)"
src="$(cd "$here/.." && pwd)"
REGISTRY="${EPR_REGISTRY:-eprfarm}"
TAG="${EPR_TAG:-0.1.0}"
BASE_IMAGE="${EPR_BASE_IMAGE:-localhost/debian:bookworm-slim}"

usage() {
  echo "usage: $0 --prebuilt BUILD_DIR | --from-source" >&2
  exit 2
}
mode="" build_dir=""
case "${1:-}" in
  --prebuilt) [ $# -eq 2 ] || usage; mode=prebuilt; build_dir="$(cd "$2" && pwd)" ;;
  --from-source) [ $# -eq 1 ] || usage; mode=source ;;
  *) usage ;;
esac

command -v podman >/dev/null || { echo "container_images: podman is not installed (scripts/container_setup.sh)" >&2; exit 1; }
podman image exists "$BASE_IMAGE" ||
  { echo "container_images: no base image $BASE_IMAGE (scripts/container_setup.sh makes it)" >&2; exit 1; }

# --format docker: the OCI image format has no HEALTHCHECK (podman would drop the images' checks).
args=(--format docker --build-arg "DEBIAN_IMAGE=$BASE_IMAGE" -f "$src/deploy/Dockerfile")
if [ "$mode" = prebuilt ]; then
  # The context holds only what the runtime stage copies: deploy/prebuilt/ (the stripped binaries and
  # the packages owning their libraries), the entrypoint and the health check.
  ctx="$(mktemp -d)"
  trap 'rm -rf "$ctx"' EXIT
  bins=("$build_dir/client/epr" "$build_dir/master/epr-master" "$build_dir/worker/epr-worker")
  for b in "${bins[@]}"; do
    [ -x "$b" ] || { echo "container_images: $b is not an executable (build epr epr-master epr-worker)" >&2; exit 1; }
  done
  install -D -m 0755 -t "$ctx/deploy/prebuilt/bin" "${bins[@]}"
  strip "$ctx"/deploy/prebuilt/bin/*
  bash "$src/deploy/image-packages.sh" runtime "$ctx"/deploy/prebuilt/bin/* > "$ctx/deploy/prebuilt/runtime-packages.txt"
  install -m 0755 -t "$ctx/deploy" "$src/deploy/docker-entrypoint.sh" "$src/deploy/epr-health"
  args+=(--build-arg BINARIES=prebuilt)
  context="$ctx"
else
  # podman reads .dockerignore (or .containerignore) at the context's root, not BuildKit's
  # <Dockerfile>.dockerignore: pass it explicitly.
  args+=(--ignorefile "$src/deploy/Dockerfile.dockerignore")
  # Named although it is the default: podman 4.3's stage skipping resolves `FROM ${BINARIES}` against
  # the stages only for a value given here, and with the default it looks for an image called "build".
  args+=(--build-arg BINARIES=build)
  context="$src"
fi

for target in master worker; do
  image="$REGISTRY/epr-$target:$TAG"
  start=$SECONDS
  podman build --target "$target" "${args[@]}" -t "$image" "$context"
  echo "container_images: built $image in $((SECONDS - start)) s"
done
for target in master worker; do
  image="$REGISTRY/epr-$target:$TAG"
  echo "container_images: $image $(podman image inspect --format '{{.Size}}' "$image") bytes"
done
