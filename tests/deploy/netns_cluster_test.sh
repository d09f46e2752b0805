#!/usr/bin/env bash
# The docker-compose cluster without Docker: the real epr-master, epr-worker and epr programs on six
# "hosts" -- Linux network namespaces on a private bridge -- started with the environment, commands,
# secrets and health checks that `docker-compose config` prints for deploy/docker-compose.yml, through
# the images' own entrypoint (deploy/docker-entrypoint.sh) and health check (deploy/epr-health).
#
#   netns_cluster_test.sh --epr BIN --master BIN --worker BIN
#
# Topology (nothing outside it is touched: no interface, address or route in the caller's namespace):
#   <id>-sw      a bridge br0, one veth port per host
#   <id>-master1, <id>-master2  the compose file's masters at their addresses (10.231.0.11, .12); a
#                small DNS server on the bridge answers their service names, and their shared network
#                alias ("masters") with both addresses, as compose's DNS does
#   <id>-w1..w3  workers, 10.231.0.21-23 (compose gives scaled workers dynamic addresses)
#   <id>-client  the client, 10.231.0.100
# The compose variables the test sets, as a user would: EPR_LEASE_TIMEOUT_MS=2000 (a killed worker's
# tile is re-queued quickly), EPR_HEARTBEAT_MS=500, EPR_LOG_LEVEL=debug (the workers log their
# leases), EPR_TOKEN_PATH (a token made for the run). Processes run as nobody, as the images run as
# uid 10001; a container's paths (/var/lib/eprfarm, /run/secrets/...) live under a per-host folder.
#
# The test: the masters' and the client's health checks pass; every worker registers with both
# masters through the alias; the client submits a job (to the masters' alias: it lands on one); one
# worker host's processes are killed while that worker holds a lease; the job still ends DONE, its
# master re-queued the dead worker's tile, and PREFIX.counts.exr (M, M' per pixel) and
# PREFIX.pathtrace.exr equal those of `epr render --single-process` with the same flags
# (bit-identical by design). Then a batch (issue #18): w2's host is restarted, the client submits
# frames 1-8 of a camera fly-through with --master master1:50051,master2:50051 (four frames land on
# each), runs `epr watch BATCH` and `epr get BATCH --out DIR/fly`, and master1's epr-master is
# SIGKILLed while its frames are mid-way (each past a round checkpoint, none done), then restarted
# in its namespace on the same state directory; it resumes its frames from their checkpoints, watch
# and get ride through, all 8 frames end DONE, and each frame's counts.exr and pathtrace.exr equal
# `epr render --single-process` of that frame's camera. Last, both masters get SIGTERM and must
# drain and exit 0.
#
# Exit 0 passed, 1 failed, 77 skipped (not root, no `ip netns`, or docker-compose / python3-yaml
# missing outside CI) -- a skip always says why. Cleans up namespaces and processes on any exit.
set -uo pipefail

SKIP=77
here="$(cd "$(dirname "$0")" && pwd)"
src="$(cd "$here/../.." && pwd)"
EPR_BIN="" MASTER_BIN="" WORKER_BIN=""
while [ $# -gt 0 ]; do
  case "$1" in
    --epr) EPR_BIN="$2"; shift 2 ;;
    --master) MASTER_BIN="$2"; shift 2 ;;
    --worker) WORKER_BIN="$2"; shift 2 ;;
    *) echo "usage: $0 --epr BIN --master BIN --worker BIN" >&2; exit 2 ;;
  esac
done
for b in "$EPR_BIN" "$MASTER_BIN" "$WORKER_BIN"; do
  [ -x "$b" ] || { echo "netns_cluster_test: not an executable: '$b'" >&2; exit 2; }
done

log() { echo "[netns $(date +%T)] $*" >&2; }
skip() { echo "SKIPPED: netns cluster test: $*" >&2; exit "$SKIP"; }
# A missing tool that scripts/setup.sh installs is a failure in CI, a skip elsewhere.
need_tool() {
  if [ -n "${CI:-}" ]; then echo "FAILED: netns cluster test: $1 (scripts/setup.sh installs it)" >&2; exit 1; fi
  skip "$1 (scripts/setup.sh installs it)"
}

PY=/usr/bin/python3
[ "$(id -u)" -eq 0 ] || skip "needs root to create network namespaces (run as root, or in CI)"
command -v ip >/dev/null || skip "no ip command (iproute2)"
command -v docker-compose >/dev/null || need_tool "docker-compose is not installed"
"$PY" -c 'import yaml' 2>/dev/null || need_tool "python3-yaml is not installed"
"$PY" -c 'import grpc' 2>/dev/null || need_tool "python3-grpcio (for epr-health) is not installed"

# Namespaces left by an earlier run that was killed before its clean-up (e.g. a ctest timeout):
# eprt<PID>-* whose PID is gone. Their processes are ended first.
for ns in $(ip netns list 2>/dev/null | awk '{print $1}' | grep -E '^eprt[0-9]+-' || true); do
  owner="${ns#eprt}"
  owner="${owner%%-*}"
  [ -d "/proc/$owner" ] && continue
  pids="$(ip netns pids "$ns" 2>/dev/null)"
  [ -z "$pids" ] || kill -KILL $pids 2>/dev/null
  ip netns del "$ns" 2>/dev/null && echo "removed the stale namespace $ns" >&2
  rm -rf "/etc/netns/$ns" /tmp/epr-netns."$owner".*
done

id="eprt$$"
probe="$id-probe"
ip netns add "$probe" 2>/dev/null || skip "cannot create a network namespace (ip netns add failed: no CAP_SYS_ADMIN?)"
ip -n "$probe" link add br0 type bridge 2>/dev/null || { ip netns del "$probe"; skip "cannot create a bridge in a namespace"; }
ip netns del "$probe"

tmp="$(mktemp -d "/tmp/epr-netns.$$.XXXXXX")"
chmod 0755 "$tmp"
hosts=(sw master1 master2 w1 w2 w3 client)
failed=0

cleanup() {
  local ns pids
  for h in "${hosts[@]}"; do
    ns="$id-$h"
    pids="$(ip netns pids "$ns" 2>/dev/null)"
    [ -z "$pids" ] || kill -CONT $pids 2>/dev/null
    [ -z "$pids" ] || kill -KILL $pids 2>/dev/null
  done
  for _ in $(seq 50); do  # until the killed processes are gone (at most 5 s)
    pids=""
    for h in "${hosts[@]}"; do pids+="$(ip netns pids "$id-$h" 2>/dev/null)"; done
    [ -n "$pids" ] || break
    sleep 0.1
  done
  for h in "${hosts[@]}"; do
    ip netns del "$id-$h" 2>/dev/null
    rm -rf "/etc/netns/$id-$h"
  done
  rmdir /etc/netns 2>/dev/null
  if [ "$failed" -ne 0 ] || [ -n "${EPR_KEEP_NETNS_TMP:-}" ]; then
    for f in "$tmp"/*.log; do
      [ -f "$f" ] || continue
      echo "---- $(basename "$f") (last 40 lines)" >&2
      tail -n 40 "$f" >&2
    done
  fi
  if [ -n "${EPR_KEEP_NETNS_TMP:-}" ]; then echo "kept $tmp" >&2; else rm -rf "$tmp"; fi
}
trap cleanup EXIT
trap 'failed=1; exit 1' INT TERM

fail() {
  failed=1
  echo "FAILED: netns cluster test: $*" >&2
  exit 1
}

# wait_for SECONDS CMD...: retries CMD every 0.5 s until it succeeds.
wait_for() {
  local deadline=$((SECONDS + $1))
  shift
  until "$@"; do
    [ "$SECONDS" -lt "$deadline" ] || return 1
    sleep 0.5
  done
}

# ---- the compose file, resolved ------------------------------------------------------------------
mkdir -p "$tmp/secrets"
head -c 24 /dev/urandom | od -An -tx1 | tr -d ' \n' > "$tmp/secrets/epr_token"
compose_vars=(EPR_LEASE_TIMEOUT_MS=2000 EPR_HEARTBEAT_MS=500 EPR_LOG_LEVEL=debug
              EPR_TOKEN_PATH="$tmp/secrets/epr_token" EPR_OUT_DIR="$tmp/out")
env -i PATH="/usr/bin:/bin" HOME="$tmp" "${compose_vars[@]}" \
  docker-compose -f "$src/deploy/docker-compose.yml" config > "$tmp/compose.yml" 2> "$tmp/compose-config.log" ||
  fail "docker-compose config rejected deploy/docker-compose.yml: $(cat "$tmp/compose-config.log")"

# bin/: the names the images have on PATH, pointing at the built programs and the deploy scripts.
mkdir -p "$tmp/bin"
ln -s "$(readlink -f "$MASTER_BIN")" "$tmp/bin/epr-master"
ln -s "$(readlink -f "$WORKER_BIN")" "$tmp/bin/epr-worker"
ln -s "$(readlink -f "$EPR_BIN")" "$tmp/bin/epr"
ln -s "$src/deploy/docker-entrypoint.sh" "$tmp/bin/epr-entrypoint"
ln -s "$src/deploy/epr-health" "$tmp/bin/epr-health"

# Run as nobody (the images run as uid 10001) when nobody can reach the programs; else as root.
as_user=(setpriv --reuid=65534 --regid=65534 --clear-groups --)
if ! "${as_user[@]}" test -x "$tmp/bin/epr-master" -a -r "$src/deploy/docker-entrypoint.sh" 2>/dev/null; then
  log "nobody cannot run the programs here; running them as root"
  as_user=()
fi

# service_config SERVICE HOST: loads SVC_* for the service into this shell, with HOST's root folder.
service_config() {
  local root="$tmp/hosts/$2"
  local out
  out="$("$PY" "$here/compose_hosts.py" "$tmp/compose.yml" "$src/deploy/Dockerfile" "$1" "$root")" ||
    fail "cannot read service $1 from the compose file"
  eval "$out"
  mkdir -p "$root/home"
  local s
  for s in "${SVC_SECRETS[@]}"; do
    install -D -m 0400 "${s%%=*}" "${s#*=}"
  done
  [ ${#as_user[@]} -eq 0 ] || chown -R 65534:65534 "$root"
}

"$PY" "$here/compose_hosts.py" "$tmp/compose.yml" "$src/deploy/Dockerfile" --check-scalable worker ||
  fail "the compose file's worker service cannot be scaled with --scale worker=N"

declare -A addr
masters=(master1 master2)
alias_name=""
for m in "${masters[@]}"; do
  service_config "$m" "$m"
  [ -n "$SVC_ADDR" ] && [ -n "$SVC_SUBNET" ] || fail "the compose file gives $m no fixed address on a subnet"
  addr[$m]="$SVC_ADDR"
  subnet="$SVC_SUBNET"
  [ ${#SVC_ALIASES[@]} -eq 1 ] || fail "$m has network aliases (${SVC_ALIASES[*]}), expected one shared by the masters"
  [ -z "$alias_name" ] || [ "$alias_name" = "${SVC_ALIASES[0]}" ] || fail "the masters' aliases differ"
  alias_name="${SVC_ALIASES[0]}"
done
prefix_len="${subnet#*/}"
net_base="${subnet%/*}"
net_base="${net_base%.*}"
addr+=([w1]="$net_base.21" [w2]="$net_base.22" [w3]="$net_base.23" [client]="$net_base.100")
log "subnet $subnet, masters ${addr[master1]} ${addr[master2]} (alias $alias_name), workers ${addr[w1]}-${addr[w3]}, client ${addr[client]}"

# ---- the hosts -------------------------------------------------------------------------------------
sw="$id-sw"
ip netns add "$sw" || fail "ip netns add $sw"
ip -n "$sw" link add br0 type bridge
ip -n "$sw" link set br0 up
# The bridge's own address (.1, Docker's gateway address) serves DNS for the service names, as
# Docker's embedded DNS does in a compose network.
dns_addr="$net_base.1"
ip -n "$sw" addr add "$dns_addr/$prefix_len" dev br0
ip -n "$sw" link set lo up
ip netns exec "$sw" "$PY" "$here/tiny_dns.py" "$dns_addr" "master1=${addr[master1]}" "master2=${addr[master2]}" \
  "$alias_name=${addr[master1]},${addr[master2]}" > "$tmp/dns.log" 2>&1 &
disown $!  # servers are ended by the clean-up, without job-control noise
for h in master1 master2 w1 w2 w3 client; do
  ns="$id-$h"
  ip netns add "$ns" || fail "ip netns add $ns"
  ip -n "$sw" link add "p-$h" type veth peer name eth0 netns "$ns" || fail "veth for $h"
  ip -n "$sw" link set "p-$h" master br0
  ip -n "$sw" link set "p-$h" up
  ip -n "$ns" link set lo up
  ip -n "$ns" addr add "${addr[$h]}/$prefix_len" dev eth0
  ip -n "$ns" link set eth0 up
  # A container's /etc/hosts and /etc/resolv.conf: other services are found through DNS only; no
  # resolver outside the namespaces is asked.
  mkdir -p "/etc/netns/$ns"
  printf '127.0.0.1 localhost\n::1 localhost\n%s %s\n' "${addr[$h]}" "$h" > "/etc/netns/$ns/hosts"
  printf 'nameserver %s\noptions timeout:1 attempts:2\n' "$dns_addr" > "/etc/netns/$ns/resolv.conf"
done
wait_for 20 grep -q ready "$tmp/dns.log" || fail "the DNS stand-in did not start: $(cat "$tmp/dns.log")"

# on HOST CMD...: runs CMD in HOST's namespace with the service environment loaded by service_config
# (and nothing else from this shell's environment), as the images' user.
on() {
  local h="$1"
  shift
  ip netns exec "$id-$h" env -i PATH="$tmp/bin:/usr/bin:/bin" HOME="$tmp/hosts/$h/home" \
    "${SVC_ENV[@]}" "${as_user[@]}" "$@"
}

start=$SECONDS
# ---- masters ---------------------------------------------------------------------------------------
for m in "${masters[@]}"; do
  service_config "$m" "$m"
  on "$m" "${SVC_CMD[@]}" > "$tmp/$m.log" 2>&1 &
  disown $!
done
for m in "${masters[@]}"; do
  service_config "$m" "$m"
  master_health=("${SVC_HEALTH[@]}")
  master_env=("${SVC_ENV[@]}")
  [ ${#master_health[@]} -gt 0 ] || fail "the compose file's $m has no health check"
  wait_for 60 on "$m" "${master_health[@]}" 2>> "$tmp/health.log" ||
    fail "$m's compose health check (${master_health[*]}) never passed"
done
log "masters healthy: ${master_health[*]}"

# ---- client host: the master by name, across the bridge ---------------------------------------------
service_config client client
client_env=("${SVC_ENV[@]}")
client_cmd=("${SVC_CMD[@]}")
master_target="$(printf '%s\n' "${client_env[@]}" | sed -n 's/^EPR_MASTER=//p')"
[ -n "$master_target" ] || fail "the compose file's client has no EPR_MASTER"
on client epr-health grpc "$master_target" 2>> "$tmp/health.log" ||
  fail "gRPC health of $master_target from the client host"
http_port="$(printf '%s\n' "${master_env[@]}" | sed -n 's/^EPR_HTTP=.*://p')"
[ -n "$http_port" ] || fail "the compose file's master has no EPR_HTTP port"
for m in "${masters[@]}"; do
  on client epr-health http "http://$m:$http_port/healthz" 2>> "$tmp/health.log" ||
    fail "HTTP /healthz of $m from the client host"
done
# The compose secret is the master's token too: a call without it is refused.
if on client env -u EPR_TOKEN_FILE epr list --master "$master_target" > /dev/null 2> "$tmp/no-token.log"; then
  fail "the master accepted a client without the token"
fi
grep -qi "UNAUTHENTICATED\|token" "$tmp/no-token.log" || fail "no-token call failed otherwise: $(cat "$tmp/no-token.log")"
log "client host: gRPC health of $master_target and http://master{1,2}:$http_port/healthz pass; no token, no service"

# ---- workers -----------------------------------------------------------------------------------------
for w in w1 w2 w3; do
  service_config worker "$w"
  worker_health=("${SVC_HEALTH[@]}")
  on "$w" "${SVC_CMD[@]}" > "$tmp/$w.log" 2>&1 &
  disown $!
done
# Every worker with both masters: the alias resolves to both.
registered() { [ "$(grep -c "registered with" "$tmp"/w[123].log 2>/dev/null | awk -F: '{s += $2} END {print s}')" -ge 6 ]; }
wait_for 60 registered || fail "the three workers did not register with both masters through $alias_name"
# The compose check (the process is alive) and the Kubernetes readiness check (the master answers,
# by name, from this host) on every worker host.
for w in w1 w2 w3; do
  on "$w" "${worker_health[@]}" 2>> "$tmp/health.log" || fail "worker health check (${worker_health[*]}) on $w"
  on "$w" epr-health worker --ready 2>> "$tmp/health.log" || fail "worker readiness check on $w"
done
log "3 workers registered with both masters; on each: ${worker_health[*]}, epr-health worker --ready"

# ---- the job ---------------------------------------------------------------------------------------
job=(builtin:cornell --width 64 --height 64 --spp 16 --paths-per-round 4 --tile 32 --mode skip
     --min-paths 1 --seed 11)
SVC_ENV=("${client_env[@]}")
out_dir="$tmp/hosts/client/out"
mkdir -p "$out_dir"
[ ${#as_user[@]} -eq 0 ] || chown 65534:65534 "$out_dir"
# client_cmd is the compose client's entrypoint + command (epr-entrypoint client list); keep the
# entrypoint, give our own command, as `docker-compose run client submit ...` does.
entry=("${client_cmd[@]:0:2}")

# Kill w2's host while it holds a lease of a tile it cannot have finished. Before the submission,
# w1 and w3 are frozen (SIGSTOP) and w2 is throttled: it runs in slices of half a millisecond
# (SIGCONT, a timed wait, SIGSTOP), and after each slice its log is read. The slices are timed by
# this shell at real-time priority where the kernel allows it, so no other task can stretch one. A
# round-0 tile is 4096 paths, several milliseconds of tracing, so the first lease w2 logs cannot
# have been traced and submitted within the slice that logged it. Then w2's processes are killed and
# w1, w3 go on: round 0 cannot end before the dead lease expires (EPR_LEASE_TIMEOUT_MS), so the job
# is mid-way, and the tile must be traced again. w2 may hold several leases (two threads, a lease
# asked ahead): the master must re-queue one of the leases w2 logged as open, not a particular one.
victim="$id-w2"
victim_pids="$(ip netns pids "$victim")"
others="$(ip netns pids "$id-w1") $(ip netns pids "$id-w3")"
[ -n "$victim_pids" ] || fail "the victim worker host has no processes"
kill -STOP $others $victim_pids
on client "${entry[@]}" submit "${job[@]}" --wait --out "$out_dir/cluster" \
  > "$tmp/client.out" 2> "$tmp/client.log" &
client_pid=$!
open_lease() {
  awk '/lease [0-9]+: job [^ ]+ round [0-9]+ tile [0-9]+/ { for (i = 1; i <= NF; i++) { if ($i == "lease") { id = $(i + 1); sub(":", "", id) } if ($i == "tile") t = $(i + 1) } open[id] = t }
       /lease [0-9]+: submitted/ { for (i = 1; i <= NF; i++) if ($i == "lease") { id = $(i + 1); sub(":", "", id); delete open[id] } }
       END { for (id in open) print open[id] }' "$tmp/w2.log" | sort -n | tr '\n' ' ' | sed 's/ $//'
}
held_tiles=""
mkfifo "$tmp/never"
exec {never}<> "$tmp/never"  # nothing is written to it: a read on it waits out its timeout
realtime=0
chrt -f -p 1 $$ 2> /dev/null && realtime=1
deadline=$((SECONDS + 120))
while [ "$SECONDS" -lt "$deadline" ] && kill -0 "$client_pid" 2>/dev/null; do
  kill -CONT $victim_pids
  read -r -t 0.0005 -u "$never" _ || true
  kill -STOP $victim_pids
  held_tiles="$(open_lease)"
  [ -z "$held_tiles" ] || break
done
[ "$realtime" -eq 0 ] || chrt -o -p 0 $$
exec {never}<&-
if [ -z "$held_tiles" ]; then
  kill -CONT $others $victim_pids
  fail "worker w2 never held a lease while the job ran"
fi
kill -KILL $victim_pids
kill -CONT $others
# The master can lease the job's tiles before the client has printed the id the master returned.
wait_for 10 test -s "$tmp/client.out"
job_id="$(head -n 1 "$tmp/client.out")"
[ -n "$job_id" ] || fail "the client printed no job id"
job_master=""
for m in "${masters[@]}"; do grep -qF "job $job_id submitted" "$tmp/$m.log" && job_master="$m"; done
[ -n "$job_master" ] || fail "no master logged the submission of job $job_id"
log "killed worker host w2 (pids $victim_pids) holding tile(s) $held_tiles of job $job_id (on $job_master)"
sleep 0.2
[ -z "$(ip netns pids "$victim")" ] || fail "w2's processes survived SIGKILL"

deadline=$((SECONDS + 300))
while kill -0 "$client_pid" 2>/dev/null; do
  [ "$SECONDS" -lt "$deadline" ] || fail "the job did not end within 300 s of the kill"
  sleep 0.5
done
wait "$client_pid"
rc=$?
[ "$rc" -eq 0 ] || fail "epr submit --wait exited $rc"
log "job done after $((SECONDS - start)) s in all: $(tail -n 2 "$tmp/client.log" | tr '\n' ' ')"

# ---- what the master saw -------------------------------------------------------------------------------
# The default reprojector: the master's OSMesa context held the deep framebuffer (no CPU fallback).
master_log="$tmp/$job_master.log"
grep -q "reprojection context: " "$master_log" || fail "the master did not bring up its OSMesa context"
! grep -q "will use the CPU reprojector" "$master_log" || fail "the master fell back to the CPU reprojector"
# Mid-job: the master re-queued the dead worker's tile while the job ran, i.e. before "job ... done".
requeued_line=""
for t in $held_tiles; do
  line="$(grep -nF "job $job_id tile $t: lease expired, re-queued" "$master_log" | head -n 1 | cut -d: -f1)"
  [ -z "$line" ] || { [ -n "$requeued_line" ] && [ "$requeued_line" -lt "$line" ]; } || requeued_line="$line"
done
done_line="$(grep -nF "job $job_id done" "$master_log" | head -n 1 | cut -d: -f1)"
[ -n "$requeued_line" ] || fail "the master never re-queued any of tiles $held_tiles of the killed worker"
[ -n "$done_line" ] && [ "$requeued_line" -lt "$done_line" ] ||
  fail "the master did not re-queue any of tiles $held_tiles before the job ended"
re_leased="$("$PY" -c 'import json,sys; print(json.load(open(sys.argv[1])).get("tiles_re_leased", 0))' "$out_dir/cluster.json")"
[ "$re_leased" -ge 1 ] || fail "cluster.json says tiles_re_leased=$re_leased"

# ---- against the undisturbed reference -------------------------------------------------------------------
# same_images A1 B1 [A2 B2 ...]: each Ai holds the same bytes as Bi, else (e.g. other metadata)
# exactly the same pixels; names the first pair that differs. One Python for all the pairs.
same_images() { "$PY" "$here/same_images.py" "$@"; }
"$EPR_BIN" render "${job[@]}" --single-process --out "$tmp/ref" > "$tmp/reference.log" 2>&1 ||
  fail "epr render --single-process failed"
same_images "$out_dir/cluster.counts.exr" "$tmp/ref.counts.exr" "$out_dir/cluster.pathtrace.exr" "$tmp/ref.pathtrace.exr" ||
  fail "the job's counts.exr or pathtrace.exr differs from the single-process reference"
log "counts.exr and pathtrace.exr: identical to the single-process reference"

# ---- a batch of eight frames over both masters, one master killed mid-batch and restarted ------------
# w2's host comes back first, as compose restarts a killed container (restart: unless-stopped).
service_config worker w2
on w2 "${SVC_CMD[@]}" > "$tmp/w2.restarted.log" 2>&1 &
disown $!
w2_registered() { [ "$(grep -c "registered with" "$tmp/w2.restarted.log")" -ge 2 ]; }
wait_for 60 w2_registered || fail "the restarted worker w2 did not register with both masters"
# The camera flies through the Cornell box over frames 1-8. Every key is a whole camera, so the
# frames' cameras need nothing from the built-in's own camera (see the references below).
scene="$tmp/hosts/client/scenes/flythrough.json"
mkdir -p "$(dirname "$scene")"
cp "$here/flythrough8.json" "$scene"  # every key a whole camera: 8 frames through the Cornell box
[ ${#as_user[@]} -eq 0 ] || chown -R 65534:65534 "$tmp/hosts/client/scenes"
# 64x64 pixels in 4 tiles, 8 rounds of 4 paths, every pixel traced in each round.
frame_flags=(--width 64 --height 64 --spp 32 --paths-per-round 4 --tile 32 --mode skip --min-paths 32
             --round-growth 0 --seed 31)
both="master1:50051,master2:50051"  # the masters by their service names, as a compose user names them
declare -A mark
for m in "${masters[@]}"; do mark[$m]="$(wc -l < "$tmp/$m.log")"; done
# Every worker frozen from the submission on: they run in slices of 50 ms below, so that the kill
# comes while the victim's frames are mid-way however fast the frames are.
worker_pids="$(ip netns pids "$id-w1") $(ip netns pids "$id-w2") $(ip netns pids "$id-w3")"
kill -STOP $worker_pids
on client "${entry[@]}" submit "$scene" --frames 1-8 "${frame_flags[@]}" --master "$both" \
  > "$tmp/batch.out" 2> "$tmp/batch-submit.log" || { kill -CONT $worker_pids; fail "epr submit --frames 1-8 failed: $(cat "$tmp/batch-submit.log")"; }
batch="$(head -n 1 "$tmp/batch.out")"
[[ "$batch" =~ ^b-[0-9a-f]{12}$ ]] || { kill -CONT $worker_pids; fail "epr submit --frames printed no batch id: '$batch'"; }
# The frames each master took: the jobs its log shows submitted since the mark.
declare -A frames_on
for m in "${masters[@]}"; do
  frames_on[$m]="$(tail -n +"$((mark[$m] + 1))" "$tmp/$m.log" | sed -n 's/.*job \([^ ]*\) submitted:.*/\1/p' | tr '\n' ' ')"
done
n1="$(wc -w <<< "${frames_on[master1]}")" n2="$(wc -w <<< "${frames_on[master2]}")"
[ "$((n1 + n2))" -eq 8 ] && [ "$n1" -ge 1 ] && [ "$n2" -ge 1 ] ||
  { kill -CONT $worker_pids; fail "the 8 frames were not spread over both masters: $n1 on master1, $n2 on master2"; }
log "batch $batch: $(grep -o 'queued: .*' "$tmp/batch-submit.log")"
# watch and get run through the kill, as a user's would.
on client "${entry[@]}" watch "$batch" --master "$both" > "$tmp/watch.out" 2> "$tmp/watch.log" &
watch_pid=$!
frames_dir="$tmp/hosts/client/out/frames"
mkdir -p "$frames_dir"
[ ${#as_user[@]} -eq 0 ] || chown 65534:65534 "$frames_dir"
on client "${entry[@]}" get "$batch" --out "$frames_dir/fly" --master "$both" > "$tmp/get.out" 2> "$tmp/get.log" &
get_pid=$!

# master1 is the victim: it holds the first job (done) and its frames. Slices until one of its
# frames has a round checkpoint; then, workers frozen, it still holds running frames.
victim_log="$tmp/master1.log"
checkpointed() {
  local j
  for j in ${frames_on[master1]}; do grep -qF "job $j: round checkpoint synced" "$victim_log" && return 0; done
  return 1
}
frames_done() { # MASTER: how many of its batch frames its log shows done
  local j n=0
  for j in ${frames_on[$1]}; do grep -qF "job $j done:" "$tmp/$1.log" && n=$((n + 1)); done
  echo "$n"
}
deadline=$((SECONDS + 120))
until checkpointed; do
  [ "$SECONDS" -lt "$deadline" ] || { kill -CONT $worker_pids; fail "no frame of master1 reached a round checkpoint"; }
  kill -CONT $worker_pids
  sleep 0.05
  kill -STOP $worker_pids
done
sleep 0.3  # the master ends what it has in hand (tile results already received)
done1="$(frames_done master1)"
[ "$done1" -lt "$n1" ] || { kill -CONT $worker_pids; fail "master1 finished its $n1 frames before the kill"; }
master1_pids="$(ip netns pids "$id-master1")"
kill -KILL $master1_pids
gone() { [ -z "$(ip netns pids "$id-master1")" ]; }
wait_for 5 gone || { kill -CONT $worker_pids; fail "master1 survived SIGKILL"; }
kill -CONT $worker_pids
log "killed master1 (SIGKILL, pids $master1_pids) with $done1 of its $n1 frames done, $(frames_done master2) of master2's $n2"
sleep 2  # the workers and the clients find it down
# Restarted in its namespace on the same state directory, as compose restarts the container.
service_config master1 master1
echo "---- restarted" >> "$victim_log"
on master1 "${SVC_CMD[@]}" >> "$victim_log" 2>&1 &
disown $!
wait_for 60 on master1 "${master_health[@]}" 2>> "$tmp/health.log" || fail "the restarted master1 never became healthy"
run2="$(grep -o "run 2, [0-9]* jobs loaded, [0-9]* resume from their checkpoint" "$victim_log")"
[ -n "$run2" ] || fail "the restarted master1 did not load its state directory (no 'run 2' line)"
loaded="$(awk '{print $3}' <<< "$run2")" resumed="$(awk '{print $6}' <<< "$run2")"
expected=$((n1 + 0))
[ "$job_master" != master1 ] || expected=$((n1 + 1))
[ "$loaded" -eq "$expected" ] || fail "the restarted master1 loaded $loaded jobs, expected $expected: $run2"
[ "$resumed" -ge 1 ] || fail "the restarted master1 resumed no frame from its round checkpoint: $run2"
log "master1 restarted: $run2"

deadline=$((SECONDS + 180))
while kill -0 "$watch_pid" 2>/dev/null || kill -0 "$get_pid" 2>/dev/null; do
  [ "$SECONDS" -lt "$deadline" ] || fail "epr watch / epr get of the batch did not end within 180 s of the restart"
  sleep 0.5
done
wait "$watch_pid" || fail "epr watch $batch exited $?: $(tail -n 5 "$tmp/watch.log")"
wait "$get_pid" || fail "epr get $batch exited $?: $(tail -n 5 "$tmp/get.log")"
grep -q "master master1.* did not answer" "$tmp/watch.log" || fail "epr watch never saw master1 down"
grep -q "master master1.* answers again" "$tmp/watch.log" || fail "epr watch never saw master1 back"
list="$(on client "${entry[@]}" list --batch "$batch" --master "$both" 2>&1)" || fail "epr list --batch: $list"
[ "$(grep -c " DONE " <<< "$list")" -eq 8 ] || fail "epr list --batch does not show 8 DONE frames: $list"
log "batch done after $((SECONDS - start)) s in all; epr watch and epr get rode through the restart"

# The references: each frame's camera as CameraAnimation::at computes it (common/camera_animation.cpp:
# float keys, doubles in between, float results), given to `epr render --single-process` as overrides
# (9 significant digits give a float back exactly).
"$PY" "$here/frame_cameras.py" "$scene" 1 8 > "$tmp/cameras.txt" || fail "cannot compute the frames' cameras"
[ "$(wc -l < "$tmp/cameras.txt")" -eq 8 ] || fail "not 8 cameras: $(cat "$tmp/cameras.txt")"
# All eight at once: a render this small mostly waits (about 1.6 s wall for 0.5 s of CPU).
declare -A ref_pid
while read -r f eye look up fov; do
  "$EPR_BIN" render "$scene" --eye "$eye" --look "$look" --up "$up" --fov "$fov" "${frame_flags[@]}" \
    --single-process --out "$tmp/ref-frame$f" > "$tmp/ref-frame$f.log" 2>&1 &
  ref_pid[$f]=$!
done < "$tmp/cameras.txt"
pairs=()
for f in $(seq 8); do
  ref="$tmp/ref-frame$f"
  wait "${ref_pid[$f]}" || fail "epr render --single-process of frame $f failed: $(tail -n 3 "$ref.log")"
  got="$(printf '%s/fly.%04d' "$frames_dir" "$f")"
  for ext in exr png json; do [ -s "$got.$ext" ] || fail "epr get wrote no $(basename "$got.$ext")"; done
  pairs+=("$got.counts.exr" "$ref.counts.exr" "$got.pathtrace.exr" "$ref.pathtrace.exr")
done
same_images "${pairs[@]}" || fail "a frame differs from its single-process render (above)"
# The frames differ from each other: the camera moved.
! same_images "$frames_dir/fly.0001.pathtrace.exr" "$frames_dir/fly.0008.pathtrace.exr" 2>/dev/null ||
  fail "frames 1 and 8 are the same image: the camera did not move"
log "frames 1-8: counts.exr and pathtrace.exr identical to each frame's single-process render"

# ---- SIGTERM drains the masters (compose's `docker-compose stop`): exit 0 within the grace period ------
for m in "${masters[@]}"; do
  pids="$(ip netns pids "$id-$m")"
  [ -n "$pids" ] || fail "$m is not running any more"
  kill -TERM $pids
done
stopped() { [ -z "$(ip netns pids "$id-master1")$(ip netns pids "$id-master2")" ]; }
wait_for 30 stopped || fail "the masters did not exit within 30 s of SIGTERM"
for m in "${masters[@]}"; do
  grep -q "drained in\|nothing to keep" "$tmp/$m.log" || fail "$m did not drain on SIGTERM"
done
log "SIGTERM: both masters drained and exited"

log "passed in $((SECONDS - start)) s"
echo "netns cluster: 1 passed, 0 failed"
