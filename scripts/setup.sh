#!/usr/bin/env bash
# Installs every Debian package eprfarm needs to build, test, benchmark and deploy.
# Idempotent: packages already present are left alone. Needs root (or sudo).
set -euo pipefail

PACKAGES=(
  # toolchain
  build-essential cmake ninja-build pkg-config git clang libclang-rt-14-dev clang-format
  # rendering
  libembree-dev libtbb-dev libosmesa6-dev libopenimageio-dev openimageio-tools
  libtinyobjloader-dev libtinygltf-dev
  # services
  libgrpc++-dev libprotobuf-dev protobuf-compiler protobuf-compiler-grpc libssl-dev
  libcpp-httplib-dev
  # utilities
  libspdlog-dev libfmt-dev libcli11-dev nlohmann-json3-dev
  # tests and benchmarks
  libgtest-dev libgmock-dev libbenchmark-dev
)
# the Python packages are for scripts run with Debian's /usr/bin/python3
PACKAGES+=(python3 python3-numpy python3-openimageio python3-prometheus-client python3-yaml python3-grpcio)
# the Python client (client/python): its runtime, pip installing it (into a venv or the system), and
# openssl for the TLS tests' certificates
PACKAGES+=(python3-protobuf python3-pip python3-setuptools python3-wheel python3-venv openssl)
# reference renderer and the Blender add-on (client/blender; xvfb runs Blender's UI in its test), charts,
# browser tests, deployment checks, network namespaces
PACKAGES+=(blender xvfb xauth gnuplot-nox chromium chromium-driver docker-compose iproute2 procps curl)

missing=()
for p in "${PACKAGES[@]}"; do
  [ -n "$p" ] || continue
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi

if [ ${#missing[@]} -gt 0 ]; then
  echo "setup: installing ${#missing[@]} packages: ${missing[*]}"
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
else
  echo "setup: all packages present"
fi

# The container engine (podman with runc, the base image made from Debian's archive): the test command's
# container stage (scripts/container_ci.sh) and DEPLOY.md's container commands need it.
bash "$(dirname "$0")/container_setup.sh"
