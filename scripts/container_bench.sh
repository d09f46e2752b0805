#!/usr/bin/env bash
# Container figures for docs/BENCHMARKS.md: cold start of a master and of a worker container to the
# first leased tile, and the compose farm's render time against the same farm as plain processes.
#
#   scripts/container_bench.sh --build BUILD_DIR [--runs N]
#
# Needs what scripts/container_test.sh needs (root, podman, the images). Cold start, N times: `podman
# run` of the master image until its health check passes; a job is queued; `podman run` of the worker
# image until the worker's log shows its first lease. The farm: two masters and three one-thread
# workers render the container test's batch of eight 96x96 frames (no faults), once from
# deploy/docker-compose.yml on podman and once as processes on loopback with the same flags; the time
# is from `epr submit --frames` to the end of `epr watch`, and the farm's CPU seconds over that time
# (the masters' and workers' own: their containers' cgroups, cpuacct or cpu.stat; the processes'
# utime + stime from /proc), which a busy machine does not inflate as it does the wall time. Prints one
# line per measurement.
set -uo pipefail

here="$(cd "$(dirname "$0")" && pwd)"
src="$(cd "$here/.." && pwd)"
BUILD="" RUNS=3
while [ $# -gt 0 ]; do
  case "$1" in
    --build) BUILD="$(cd "$2" && pwd)"; shift 2 ;;
    --runs) RUNS="$2"; shift 2 ;;
    *) echo "usage: $0 --build BUILD_DIR [--runs N]" >&2; exit 2 ;;
  esac
done
EPR="$BUILD/client/epr"
[ -x "$EPR" ] || { echo "container_bench: no $EPR" >&2; exit 2; }
MASTER_IMAGE="${EPR_REGISTRY:-eprfarm}/epr-master:${EPR_TAG:-0.1.0}"
WORKER_IMAGE="${EPR_REGISTRY:-eprfarm}/epr-worker:${EPR_TAG:-0.1.0}"
id="eprcb$$"
tmp="$(mktemp -d /tmp/epr-container-bench.XXXXXX)"
pids=()
cleanup() {
  [ ${#pids[@]} -eq 0 ] || kill "${pids[@]}" 2>/dev/null
  podman rm -f -v -t 0 $(podman ps -a --filter "name=^$id" --format '{{.Names}}') >/dev/null 2>&1
  podman volume rm -f $(podman volume ls --filter "name=^$id" --format '{{.Name}}') >/dev/null 2>&1
  podman network rm -f "$id-net" "${id}_farm" >/dev/null 2>&1
  rm -rf "$tmp"
}
trap cleanup EXIT
die() { echo "container_bench: $*" >&2; exit 1; }
now() { date +%s.%N; }
elapsed() { awk -v a="$1" -v b="$2" 'BEGIN { printf "%.2f", b - a }'; }
token="$tmp/epr_token"
head -c 32 /dev/urandom | base64 > "$token"
chmod 0644 "$token"
free_ports() {
  /usr/bin/python3 -c '
import socket, sys
socks = [socket.socket() for _ in range(int(sys.argv[1]))]
for s in socks: s.bind(("127.0.0.1", 0))
print(" ".join(str(s.getsockname()[1]) for s in socks))' "$1"
}
echo "load average at the start: $(cut -d' ' -f1-3 /proc/loadavg)"

# ---- cold start --------------------------------------------------------------------------------------
podman network create "$id-net" >/dev/null || die "podman network create"
common=(--network "$id-net" -v "$token:/run/secrets/epr_token:ro" -e EPR_TOKEN_FILE=/run/secrets/epr_token)
for run in $(seq "$RUNS"); do
  t0="$(now)"
  podman run -d --name "$id-m$run" "${common[@]}" --network-alias "m$run" -p 127.0.0.1::50051 \
    -e EPR_LOG_LEVEL=debug "$MASTER_IMAGE" >/dev/null || die "podman run $MASTER_IMAGE"
  until podman healthcheck run "$id-m$run" >/dev/null 2>&1; do sleep 0.1; done
  t1="$(now)"
  port="$(podman port "$id-m$run" 50051/tcp | head -n 1 | sed 's/.*://')"
  "$EPR" --log-level warn submit builtin:cornell --width 64 --height 64 --spp 4 --master "127.0.0.1:$port" \
    --token-file "$token" >/dev/null 2>&1 || die "epr submit to the master container"
  t2="$(now)"
  podman run -d --name "$id-w$run" "${common[@]}" -e EPR_MASTER="m$run:50051" -e EPR_THREADS=1 \
    -e EPR_LOG_LEVEL=debug "$WORKER_IMAGE" >/dev/null || die "podman run $WORKER_IMAGE"
  until podman logs "$id-w$run" 2>&1 | grep -q "lease [0-9]*: job"; do sleep 0.05; done
  t3="$(now)"
  echo "cold start $run: master container to healthy $(elapsed "$t0" "$t1") s; worker container to its first leased tile $(elapsed "$t2" "$t3") s"
  podman rm -f -v -t 0 "$id-m$run" "$id-w$run" >/dev/null 2>&1
done

# ---- the farm: compose on podman against plain processes ---------------------------------------------
cat > "$tmp/flythrough.json" <<'EOF'
{"builtin": "cornell", "animation": {"camera": [
  {"frame": 1, "eye": [0, 1, 3.9], "look": [0, 1, 0], "up": [0, 1, 0], "fov": 39.3},
  {"frame": 5, "eye": [0.4, 1.15, 3.2], "look": [0.05, 1, 0], "up": [0, 1, 0], "fov": 44},
  {"frame": 8, "eye": [-0.3, 1.2, 2.8], "look": [-0.1, 0.95, 0], "up": [0.05, 1, 0], "fov": 50}]}}
EOF
flags=(--width 96 --height 96 --spp 128 --paths-per-round 8 --tile 32 --mode skip --min-paths 128 --round-growth 0 --seed 31)
# farm_cpu: the CPU seconds the farm has used so far (farm_cpu_containers or farm_cpu_processes).
farm_cpu_containers() {
  local total=0 c cid dir v
  for c in $(podman ps --filter "name=^${id}_" --format '{{.ID}}'); do
    cid="$(podman inspect --format '{{.Id}}' "$c")"
    dir="$(find /sys/fs/cgroup -maxdepth 4 -type d -name "*libpod-$cid*" 2>/dev/null | head -n 1)"
    [ -n "$dir" ] || die "no cgroup of container $c"
    if [ -r "$dir/cpuacct.usage" ]; then
      v="$(awk '{ printf "%.6f", $1 / 1e9 }' "$dir/cpuacct.usage")"
    else
      v="$(awk '$1 == "usage_usec" { printf "%.6f", $2 / 1e6 }' "$dir/cpu.stat")"
    fi
    total="$(awk -v a="$total" -v b="$v" 'BEGIN { printf "%.6f", a + b }')"
  done
  echo "$total"
}
farm_cpu_processes() {
  local tck
  tck="$(getconf CLK_TCK)"
  cat "${farm_pids[@]/#//proc/}" 2>/dev/null | sed 's/.*) //' |
    awk -v t="$tck" '{ s += $12 + $13 } END { printf "%.6f", s / t }'
}
farm_pids=()
# batch MASTERS LABEL: submit the frames and watch them to the end; prints the wall and CPU time.
batch() {
  local t0 t1 b c0 c1
  c0="$($farm_cpu)"
  t0="$(now)"
  b="$("$EPR" --log-level warn submit "$tmp/flythrough.json" --frames 1-8 "${flags[@]}" --master "$1" --token-file "$token" 2>"$tmp/submit.log")" ||
    die "$2: epr submit"
  "$EPR" --log-level warn watch "$b" --master "$1" --token-file "$token" >/dev/null 2>&1 || die "$2: epr watch $b"
  t1="$(now)"
  c1="$($farm_cpu)"
  echo "$2: 8 frames in $(elapsed "$t0" "$t1") s, the farm's CPU $(elapsed "$c0" "$c1") s" \
    "(load average $(cut -d' ' -f1-3 /proc/loadavg))"
}
wait_ports() { # PORT...: until each answers an unauthenticated health probe (epr list with the token)
  local p
  for p in "$@"; do
    until "$EPR" --log-level off list --master "127.0.0.1:$p" --token-file "$token" >/dev/null 2>&1; do sleep 0.2; done
  done
}

sock="$tmp/podman.sock"
podman system service --time=0 "unix://$sock" >/dev/null 2>&1 &
pids+=($!)
until [ -S "$sock" ]; do sleep 0.1; done
read -r p1 p2 h1 h2 <<< "$(free_ports 4)"
export DOCKER_HOST="unix://$sock" EPR_TOKEN_PATH="$token" EPR_GRPC_PORT="$p1" EPR_GRPC_PORT2="$p2"
export EPR_HTTP_PORT="$h1" EPR_HTTP_PORT2="$h2" EPR_WORKER_THREADS=1
dc() { docker-compose -p "$id" -f "$src/deploy/docker-compose.yml" -f "$src/deploy/docker-compose.podman.yml" "$@"; }
dc up -d --no-build --scale worker=3 >/dev/null 2>&1 || die "docker-compose up"
wait_ports "$p1" "$p2"
until [ "$(podman logs "${id}_worker_3" 2>&1 | grep -c 'registered with')" -ge 2 ]; do sleep 0.2; done
farm_cpu=farm_cpu_containers
for run in $(seq "$RUNS"); do batch "127.0.0.1:$p1,127.0.0.1:$p2" "compose farm run $run"; done
dc down -v -t 120 >/dev/null 2>&1

read -r p1 p2 <<< "$(free_ports 2)"
for m in 1 2; do
  port="$([ $m -eq 1 ] && echo "$p1" || echo "$p2")"
  "$BUILD/master/epr-master" --listen "127.0.0.1:$port" --http "" --state-dir "$tmp/state$m" --name "master$m" \
    --token-file "$token" --log-level warn >"$tmp/master$m.log" 2>&1 &
  pids+=($!)
  farm_pids+=("$!/stat")
done
wait_ports "$p1" "$p2"
for w in 1 2 3; do
  "$BUILD/worker/epr-worker" --master "127.0.0.1:$p1,127.0.0.1:$p2" --threads 1 --name "w$w" \
    --cache-dir "$tmp/cache$w" --token-file "$token" --log-level warn >"$tmp/worker$w.log" 2>&1 &
  pids+=($!)
  farm_pids+=("$!/stat")
done
sleep 2
farm_cpu=farm_cpu_processes
for run in $(seq "$RUNS"); do batch "127.0.0.1:$p1,127.0.0.1:$p2" "processes run $run"; done
