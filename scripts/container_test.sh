#!/usr/bin/env bash
# The farm in real containers: the images of deploy/Dockerfile (scripts/container_images.sh) run with
# podman, driven from the host's `epr` through the published ports.
#
#   scripts/container_test.sh --epr BIN [--keep] [--single | --compose]
#
# Needs root, podman set up by scripts/container_setup.sh and the images eprfarm/epr-master and
# eprfarm/epr-worker (EPR_REGISTRY, EPR_TAG as in the compose file). --keep leaves the containers,
# network and volumes for a look (they are named eprct<PID>-*).
#
# One master and one worker, each a container of its image, on a podman network (netavark, with
# aardvark-dns answering the master's network alias `masters`, as compose's DNS does): the master's
# state on a named volume, the bearer token bind-mounted read-only at /run/secrets/epr_token as
# compose's file secret is, gRPC and HTTP published on 127.0.0.1 at ports podman picks. Checked:
#   - the master's image health check (`podman healthcheck run`: epr-health master --ready) passes, and
#     the worker's (epr-health worker) once it runs;
#   - /healthz answers without the token, /metrics and the dashboard answer 401 without it and 200 with
#     it, and /metrics counts the worker;
#   - a job submitted from the host's epr (--wait) ends DONE, and its PREFIX.counts.exr (M, M' per
#     pixel) and PREFIX.pathtrace.exr equal those of `epr render --single-process` with the same flags,
#     bit for bit (tests/deploy/same_images.py).
# --compose (deploy/docker-compose.yml, run by Debian's docker-compose against podman's Docker API on a
# socket of this run: Debian's podman-compose 1.0.3 cannot read the file's service networks with
# ipv4_address and aliases), with EPR_WORKER_THREADS=1, a 2 s lease timeout and ports podman's host has
# free: two masters, workers scaled to three, the state on the named volumes, the token as the compose
# secret. Checked:
#   - both masters' health checks pass; every worker registers with both through the alias `masters`;
#   - /metrics answers on both masters with the token;
#   - a batch of eight frames of a camera fly-through, submitted from the host's epr to both published
#     gRPC ports, during which one worker container is killed (SIGKILL; it stays down), master2's
#     container is stopped (SIGTERM: it drains; its open rounds are checkpointed) and started again on
#     its volume, and another worker container is stopped (SIGTERM: it returns its leases): `epr watch`
#     rides through, all eight frames end DONE and `epr get` fetches them, `epr list --batch` shows them on both
#     masters, and each frame's counts.exr and pathtrace.exr equal `epr render --single-process` of
#     that frame's camera (tests/deploy/frame_cameras.py);
#   - measured from the frames' statistics (the masters' counters): tiles committed, leased, re-leased,
#     speculative copies and dropped results (a tile traced twice), printed, not asserted.
# Default: --single, then --compose. Exit 0 passed, 1 failed (the reason on stderr). A missing or refusing engine is a failure, not a skip.
set -uo pipefail

here="$(cd "$(dirname "$0")" && pwd)"
src="$(cd "$here/.." && pwd)"
PY=/usr/bin/python3
EPR_BIN="" KEEP="" PHASES="single compose"
while [ $# -gt 0 ]; do
  case "$1" in
    --epr) EPR_BIN="$2"; shift 2 ;;
    --keep) KEEP=1; shift ;;
    --single) PHASES=single; shift ;;
    --compose) PHASES=compose; shift ;;
    *) echo "usage: $0 --epr BIN [--keep] [--single | --compose]" >&2; exit 2 ;;
  esac
done
[ -x "$EPR_BIN" ] || { echo "container_test: --epr: not an executable: '$EPR_BIN'" >&2; exit 2; }

REGISTRY="${EPR_REGISTRY:-eprfarm}"
TAG="${EPR_TAG:-0.1.0}"
MASTER_IMAGE="$REGISTRY/epr-master:$TAG"
WORKER_IMAGE="$REGISTRY/epr-worker:$TAG"
id="eprct$$"
tmp="$(mktemp -d "/tmp/epr-containers.XXXXXX")"

log() { echo "[containers $(date +%T)] $*" >&2; }
fail() {
  echo "FAILED: container test: $*" >&2
  for c in $(podman ps -a --filter "name=^$id" --format '{{.Names}}' 2>/dev/null); do
    podman logs "$c" > "$tmp/$c.log" 2>&1
    echo "---- podman logs $c (last 30 lines; all in $tmp/$c.log)" >&2
    tail -n 30 "$tmp/$c.log" >&2
  done
  echo "(files in $tmp)" >&2
  exit 1
}
service_pid=""
cleanup() {
  if [ -n "$KEEP" ]; then
    log "kept: containers, networks and volumes $id*; files in $tmp"
  else
    podman rm -f -v -t 0 $(podman ps -a --filter "name=^$id" --format '{{.Names}}') >/dev/null 2>&1
    podman volume rm -f $(podman volume ls --filter "name=^$id" --format '{{.Name}}') >/dev/null 2>&1
    podman network rm -f "$id-net" "${id}_farm" >/dev/null 2>&1
  fi
  [ -z "$service_pid" ] || kill "$service_pid" 2>/dev/null
}
trap cleanup EXIT

# ---- the engine and the images ------------------------------------------------------------------------
command -v podman >/dev/null || fail "podman is not installed (scripts/container_setup.sh installs it)"
[ "$(id -u)" -eq 0 ] || fail "needs root (rootful podman: published ports, named volumes and networks as compose makes them)"
"$PY" -c 'import OpenImageIO' 2>/dev/null || fail "python3-openimageio is not installed (scripts/setup.sh)"
command -v curl >/dev/null || fail "curl is not installed (scripts/setup.sh)"
out="$(podman info --format '{{.Host.OCIRuntime.Name}}' 2>&1)" || fail "podman does not start: $out"
for image in "$MASTER_IMAGE" "$WORKER_IMAGE"; do
  podman image exists "$image" || fail "no image $image (scripts/container_images.sh builds it)"
done

# wait_for SECONDS WHAT COMMAND...: polls COMMAND every half second until it succeeds.
wait_for() {
  local limit="$1" what="$2" deadline=$((SECONDS + $1))
  shift 2
  until "$@" >/dev/null 2>&1; do
    [ "$SECONDS" -lt "$deadline" ] || fail "$what: not within $limit s"
    sleep 0.5
  done
}

token="$tmp/epr_token"
head -c 32 /dev/urandom | base64 > "$token"
chmod 0644 "$token"  # read by uid 10001 in the containers: the bind mount keeps the host's mode
code() { curl -s -o /dev/null -w '%{http_code}' "$@"; }
auth=(-H "Authorization: Bearer $(cat "$token")")

podman network create "$id-net" >/dev/null || fail "podman network create failed"
# The compose services' settings (deploy/docker-compose.yml), with a short lease timeout and debug logs.
common=(--network "$id-net" -v "$token:/run/secrets/epr_token:ro" -e EPR_TOKEN_FILE=/run/secrets/epr_token
        -e EPR_LOG_LEVEL=debug)
start_master() { # NAME
  podman run -d --name "$id-$1" "${common[@]}" --network-alias masters \
    -p 127.0.0.1::50051 -p 127.0.0.1::8080 -v "$id-$1-state:/var/lib/eprfarm" \
    -e EPR_MASTER_NAME="$1" -e EPR_LEASE_TIMEOUT_MS=2000 -e EPR_HEARTBEAT_MS=500 \
    "$MASTER_IMAGE" >/dev/null
}
start_worker() { # NAME
  podman run -d --name "$id-$1" "${common[@]}" -e EPR_MASTER=masters:50051 -e EPR_THREADS=2 \
    -e EPR_NAME="$1" "$WORKER_IMAGE" >/dev/null
}
# host_port NAME CONTAINER_PORT: the host port podman published it on.
host_port() { podman port "$id-$1" "$2/tcp" | head -n 1 | sed 's/.*://'; }

# ---- one master, one worker ---------------------------------------------------------------------------
single_phase() {
start=$SECONDS
start_master master1 || fail "podman run of $MASTER_IMAGE failed"
grpc="127.0.0.1:$(host_port master1 50051)"
http="http://127.0.0.1:$(host_port master1 8080)"
wait_for 120 "master1's health check (epr-health master --ready)" podman healthcheck run "$id-master1"
log "master1 healthy after $((SECONDS - start)) s; gRPC $grpc, HTTP $http"

start_worker worker1 || fail "podman run of $WORKER_IMAGE failed"
wait_for 60 "worker1 registering with master1" sh -c "podman logs $id-master1 2>&1 | grep -q 'worker1'"
podman healthcheck run "$id-worker1" >/dev/null || fail "worker1's health check (epr-health worker) fails"
log "worker1 registered with master1 through the alias 'masters'"

# ---- HTTP: open probes, the token for the rest --------------------------------------------------------
[ "$(code "$http/healthz")" = 200 ] || fail "/healthz without a token: $(code "$http/healthz")"
[ "$(code "$http/readyz")" = 200 ] || fail "/readyz without a token: $(code "$http/readyz")"
for path in /metrics /; do
  [ "$(code "$http$path")" = 401 ] || fail "$path without the token: HTTP $(code "$http$path"), not 401"
  [ "$(code "${auth[@]}" "$http$path")" = 200 ] || fail "$path with the token: HTTP $(code "${auth[@]}" "$http$path")"
done
curl -s "${auth[@]}" "$http/metrics" > "$tmp/metrics.txt"
grep -Eq '^epr_workers(\{[^}]*\})? 1(\.0)?$' "$tmp/metrics.txt" ||
  fail "/metrics does not count one worker: $(grep '^epr_workers' "$tmp/metrics.txt")"
log "/healthz, /readyz open; /metrics and the dashboard 401 without the token, 200 with it"

# ---- a job from the host's epr, against the single-process reference ----------------------------------
job=(builtin:cornell --width 64 --height 64 --spp 16 --paths-per-round 4 --tile 32 --mode skip --min-paths 1 --seed 11)
mkdir -p "$tmp/out"
start=$SECONDS
"$EPR_BIN" submit "${job[@]}" --master "$grpc" --token-file "$token" --wait --out "$tmp/out/job" \
  > "$tmp/submit.log" 2>&1 || fail "epr submit --wait through $grpc failed: $(tail -n 5 "$tmp/submit.log")"
log "the job ended DONE in $((SECONDS - start)) s"
"$EPR_BIN" render "${job[@]}" --single-process --out "$tmp/ref" > "$tmp/reference.log" 2>&1 ||
  fail "epr render --single-process failed: $(tail -n 5 "$tmp/reference.log")"
"$PY" "$src/tests/deploy/same_images.py" "$tmp/out/job.counts.exr" "$tmp/ref.counts.exr" \
  "$tmp/out/job.pathtrace.exr" "$tmp/ref.pathtrace.exr" ||
  fail "the containers' counts.exr or pathtrace.exr differs from epr render --single-process"
log "counts.exr and pathtrace.exr: identical to the single-process reference"
# (through a file: grep -q ending the pipe early would fail it under pipefail)
podman logs "$id-master1" > "$tmp/master1.log" 2>&1
grep -q "reprojection context: " "$tmp/master1.log" ||
  fail "the master container did not bring up its OSMesa context"
podman rm -f -v -t 0 "$id-master1" "$id-worker1" >/dev/null 2>&1
log "single: passed"
}

. "$here/container_test_compose.sh"

for phase in $PHASES; do "${phase}_phase"; done
log "PASSED: $PHASES"
[ -n "$KEEP" ] || rm -rf "$tmp"
