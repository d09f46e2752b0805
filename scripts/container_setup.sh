#!/usr/bin/env bash
# Makes this machine able to build and run eprfarm's containers with Debian's podman, without any image
# registry. Idempotent: what is already there is left alone. Needs root (or sudo).
#
#   scripts/container_setup.sh
#
# 1. Debian packages: podman with the runc runtime (crun refuses this kind of machine's cgroups),
#    netavark + aardvark-dns (networks with DNS, so compose's service names and aliases resolve),
#    catatonit (podman's --init), mmdebstrap (the base image), podman-compose (deploy/docker-compose.yml).
# 2. /etc/containers/containers.conf: runtime runc, netavark, and explicit ulimits (with podman's
#    default limits runc fails: "error setting rlimits for ready process: error setting rlimit type 7:
#    operation not permitted"; type 7 is RLIMIT_NOFILE).
# 3. The base image localhost/debian:bookworm-slim, made by mmdebstrap (variant minbase) from Debian's
#    archive and imported with `podman import`; deploy/Dockerfile takes it as
#    --build-arg DEBIAN_IMAGE=localhost/debian:bookworm-slim.
# Environment: EPR_BASE_IMAGE (default localhost/debian:bookworm-slim), EPR_DEBIAN_MIRROR (default
# http://deb.debian.org/debian), EPR_CONTAINERS_CONF (default /etc/containers/containers.conf).
set -euo pipefail

BASE_IMAGE="${EPR_BASE_IMAGE:-localhost/debian:bookworm-slim}"
MIRROR="${EPR_DEBIAN_MIRROR:-http://deb.debian.org/debian}"
CONF="${EPR_CONTAINERS_CONF:-/etc/containers/containers.conf}"

SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi

PACKAGES=(podman runc conmon netavark aardvark-dns catatonit mmdebstrap podman-compose iptables)
missing=()
for p in "${PACKAGES[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "container_setup: installing ${missing[*]}"
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi

# The marker line tells this script's file from one written by hand, which it leaves alone.
marker="# written by eprfarm scripts/container_setup.sh"
if [ -e "$CONF" ] && ! grep -qF "$marker" "$CONF"; then
  echo "container_setup: $CONF exists and was not written by this script; leaving it (it needs" \
    "runtime = \"runc\", network_backend = \"netavark\" and default_ulimits set)" >&2
else
  tmp="$(mktemp)"
  cat >"$tmp" <<EOF
$marker
[containers]
# podman's own defaults ask for limits above what this machine allows a container
default_ulimits = ["nofile=20000:20000", "nproc=4096:4096"]
pids_limit = 4096

[network]
network_backend = "netavark"

[engine]
runtime = "runc"
EOF
  $SUDO install -D -m 0644 "$tmp" "$CONF"
  rm -f "$tmp"
fi

if podman image exists "$BASE_IMAGE"; then
  echo "container_setup: $BASE_IMAGE present"
else
  work="$(mktemp -d)"
  trap 'rm -rf "$work"' EXIT
  echo "container_setup: building $BASE_IMAGE with mmdebstrap from $MIRROR"
  # minbase: essential packages + apt. The dpkg options stay in the image
  # (/etc/dpkg/dpkg.cfg.d/99mmdebstrap), so, as in debian:bookworm-slim, no package installed later
  # in it brings manuals, documentation or translations either.
  slim=()
  for p in /usr/share/man/ /usr/share/doc/ /usr/share/info/ /usr/share/locale/ /usr/share/groff/ /usr/share/lintian/; do
    slim+=("--dpkgopt=path-exclude=$p*")
  done
  slim+=("--dpkgopt=path-include=/usr/share/doc/*/copyright" "--dpkgopt=path-include=/usr/share/locale/locale.alias")
  $SUDO mmdebstrap --variant=minbase --quiet "${slim[@]}" bookworm "$work/base.tar" "$MIRROR"
  $SUDO podman import --change 'CMD ["bash"]' "$work/base.tar" "$BASE_IMAGE" >/dev/null
  echo "container_setup: imported $BASE_IMAGE ($(podman image inspect --format '{{.Size}}' "$BASE_IMAGE") bytes)"
fi

# The engine must start a container: a missing or refused runtime fails here with its reason.
if ! out="$(podman run --rm --network none "$BASE_IMAGE" true 2>&1)"; then
  echo "container_setup: podman cannot start a container from $BASE_IMAGE: $out" >&2
  exit 1
fi
echo "container_setup: podman $(podman version --format '{{.Client.Version}}') runs containers" \
  "(runtime $(podman info --format '{{.Host.OCIRuntime.Name}}'), network $(podman info --format '{{.Host.NetworkBackend}}'))"
