# The --compose phase of scripts/container_test.sh (sourced by it: uses its log, fail, wait_for, code,
# auth, token, tmp, id, src, PY, EPR_BIN): deploy/docker-compose.yml with two masters and three workers,
# a batch of eight frames through the published ports with faults on the way (see container_test.sh).

compose_phase() {
  command -v docker-compose >/dev/null || fail "docker-compose is not installed (scripts/setup.sh installs it)"
  # podman's Docker-compatible API on a socket of this run, for Debian's docker-compose.
  local sock="$tmp/podman.sock"
  podman system service --time=0 "unix://$sock" > "$tmp/podman-service.log" 2>&1 &
  service_pid=$!
  wait_for 30 "podman's API socket $sock" test -S "$sock"
  export DOCKER_HOST="unix://$sock"

  # Free host ports for the masters' published gRPC and HTTP ports.
  local ports
  ports=($("$PY" -c '
import socket
socks = [socket.socket() for _ in range(4)]
for s in socks: s.bind(("127.0.0.1", 0))
print(" ".join(str(s.getsockname()[1]) for s in socks))'))
  export EPR_TOKEN_PATH="$token" EPR_GRPC_PORT="${ports[0]}" EPR_GRPC_PORT2="${ports[1]}"
  export EPR_HTTP_PORT="${ports[2]}" EPR_HTTP_PORT2="${ports[3]}" EPR_HTTP_HOST_IP=127.0.0.1
  export EPR_LEASE_TIMEOUT_MS=2000 EPR_HEARTBEAT_MS=500 EPR_LOG_LEVEL=debug EPR_WORKER_THREADS=1
  dc() { docker-compose -p "$id" -f "$src/deploy/docker-compose.yml" -f "$src/deploy/docker-compose.podman.yml" "$@"; }
  local m1="${id}_master1_1" m2="${id}_master2_1" w1="${id}_worker_1" w2="${id}_worker_2" w3="${id}_worker_3"
  local both="127.0.0.1:${ports[0]},127.0.0.1:${ports[1]}"

  local start=$SECONDS
  dc up -d --no-build --scale worker=3 > "$tmp/compose-up.log" 2>&1 ||
    fail "docker-compose up failed: $(tail -n 5 "$tmp/compose-up.log")"
  for c in "$m1" "$m2"; do
    wait_for 120 "$c's health check (epr-health master --ready)" podman healthcheck run "$c"
  done
  log "compose: both masters healthy $((SECONDS - start)) s after docker-compose up"
  # Every worker registers with both masters through the alias.
  registered() { [ "$(podman logs "$1" 2>&1 | grep -c 'registered with masters:50051')" -ge 2 ]; }
  for c in "$w1" "$w2" "$w3"; do
    wait_for 60 "$c registering with both masters" registered "$c"
    podman healthcheck run "$c" >/dev/null || fail "$c's health check (epr-health worker) fails"
  done
  log "compose: three workers registered with both masters"
  for port in "${ports[2]}" "${ports[3]}"; do
    [ "$(code "${auth[@]}" "http://127.0.0.1:$port/metrics")" = 200 ] || fail "/metrics on port $port with the token"
    [ "$(code "http://127.0.0.1:$port/metrics")" = 401 ] || fail "/metrics on port $port without the token"
  done

  # ---- the batch ----
  local scene="$tmp/flythrough.json"
  cp "$src/tests/deploy/flythrough8.json" "$scene"  # every key a whole camera: 8 frames through the Cornell box
  # 96x96 pixels in 9 tiles, 16 rounds of 8 paths: about 3 s of one core per frame.
  local flags=(--width 96 --height 96 --spp 128 --paths-per-round 8 --tile 32 --mode skip --min-paths 128
               --round-growth 0 --seed 31)
  local epr=("$EPR_BIN" --log-level warn)
  start=$SECONDS
  "${epr[@]}" submit "$scene" --frames 1-8 "${flags[@]}" --master "$both" --token-file "$token" \
    > "$tmp/batch.out" 2> "$tmp/batch-submit.log" || fail "epr submit --frames 1-8: $(cat "$tmp/batch-submit.log")"
  local batch
  batch="$(head -n 1 "$tmp/batch.out")"
  [[ "$batch" =~ ^b-[0-9a-f]{12}$ ]] || fail "epr submit --frames printed no batch id: '$batch'"
  log "compose: batch $batch submitted to $both"
  "${epr[@]}" watch "$batch" --master "$both" --token-file "$token" > "$tmp/watch.out" 2> "$tmp/watch.log" &
  local watch_pid=$!

  # 1. A worker container killed while it holds a lease of the batch.
  leased() { podman logs "$1" 2>&1 | grep -q "lease [0-9]*: job master"; }
  wait_for 60 "$w1 leasing a tile of the batch" leased "$w1"
  podman kill "$w1" > /dev/null || fail "podman kill $w1"
  log "compose: $w1 killed (SIGKILL) holding a lease"
  # 2. master2 stopped (SIGTERM: drain) once one of its frames has checkpointed a round, then started.
  checkpointed() { podman logs "$m2" 2>&1 | grep -q "round checkpoint synced"; }
  wait_for 120 "master2 checkpointing a round" checkpointed
  local t0=$SECONDS
  dc stop -t 120 master2 > "$tmp/compose-stop.log" 2>&1 || fail "docker-compose stop master2: $(tail -n 3 "$tmp/compose-stop.log")"
  podman logs "$m2" > "$tmp/master2.stopped.log" 2>&1
  grep -E "drained in|drain ended|nothing to keep" "$tmp/master2.stopped.log" >&2 ||
    fail "master2 did not drain on SIGTERM"
  log "compose: master2 stopped in $((SECONDS - t0)) s (docker-compose stop: SIGTERM)"
  dc start master2 > "$tmp/compose-start.log" 2>&1 || fail "docker-compose start master2: $(tail -n 3 "$tmp/compose-start.log")"
  wait_for 120 "master2's health check after its restart" podman healthcheck run "$m2"
  local loaded
  loaded="$(podman logs "$m2" 2>&1 | grep 'state directory' | tail -n 1)"
  log "compose: master2 back: ${loaded#*] }"
  # 3. A worker container stopped (SIGTERM: it returns its leases and leaves).
  podman stop -t 30 "$w3" > /dev/null || fail "podman stop $w3"
  podman logs "$w3" > "$tmp/w3.log" 2>&1
  grep -E "left .* leases returned" "$tmp/w3.log" >&2 || fail "$w3 did not return its leases on SIGTERM"

  wait "$watch_pid" || fail "epr watch $batch exited $?: $(tail -n 5 "$tmp/watch.log")"
  log "compose: batch done $((SECONDS - start)) s after its submission; epr watch rode through"
  # After the batch: `epr get` running through master2's restart can give up while the host cannot
  # reach the restarted container yet (podman gives it a new MAC; see DEPLOY.md).
  mkdir -p "$tmp/frames"
  "${epr[@]}" get "$batch" --out "$tmp/frames/fly" --master "$both" --token-file "$token" \
    > "$tmp/get.out" 2> "$tmp/get.log" || fail "epr get $batch: $(grep -v '^wrote' "$tmp/get.log" | tail -n 5)"
  local list
  list="$("${epr[@]}" list --batch "$batch" --master "$both" --token-file "$token" 2>&1)" || fail "epr list: $list"
  echo "$list" >&2
  [ "$(grep -c " DONE " <<< "$list")" -eq 8 ] || fail "epr list --batch does not show 8 DONE frames"
  # The jobs of both masters (named by their ids' prefix), each under the address it was reached at.
  grep -q "^master1\.j.* 127.0.0.1:${ports[0]}\$" <<< "$list" && grep -q "^master2\.j.* 127.0.0.1:${ports[1]}\$" <<< "$list" ||
    fail "epr list does not show both masters' frames"
  # The compose file's client service, as DEPLOY.md runs it: both masters through the alias.
  mkdir -p "$tmp/out" && chmod 0777 "$tmp/out"
  list="$(EPR_OUT_DIR="$tmp/out" dc run --rm client list 2>&1)" || fail "docker-compose run --rm client list: $list"
  grep -q "^master1\.j" <<< "$list" && grep -q "^master2\.j" <<< "$list" ||
    fail "docker-compose run --rm client list does not show both masters' jobs: $list"
  log "compose: docker-compose run --rm client list shows both masters' jobs"

  # ---- against the single-process references ----
  "$PY" "$src/tests/deploy/frame_cameras.py" "$scene" 1 8 > "$tmp/cameras.txt" || fail "cannot compute the cameras"
  local f eye look up fov pairs=() pids=()
  while read -r f eye look up fov; do
    "$EPR_BIN" render "$scene" --eye "$eye" --look "$look" --up "$up" --fov "$fov" "${flags[@]}" \
      --single-process --threads 1 --out "$tmp/ref$f" > "$tmp/ref$f.log" 2>&1 &
    pids+=($!)
    local got
    got="$(printf '%s/fly.%04d' "$tmp/frames" "$f")"
    pairs+=("$got.counts.exr" "$tmp/ref$f.counts.exr" "$got.pathtrace.exr" "$tmp/ref$f.pathtrace.exr")
  done < "$tmp/cameras.txt"
  for p in "${pids[@]}"; do wait "$p" || fail "an epr render --single-process failed"; done
  "$PY" "$src/tests/deploy/same_images.py" "${pairs[@]}" || fail "a frame differs from its single-process render"
  ! "$PY" "$src/tests/deploy/same_images.py" "$tmp/frames/fly.0001.pathtrace.exr" "$tmp/frames/fly.0008.pathtrace.exr" \
    2>/dev/null || fail "frames 1 and 8 are the same image: the camera did not move"
  log "compose: frames 1-8 identical to each frame's single-process render"

  # ---- measured: the masters' tile counters over the eight frames ----
  # tiles_dropped counts results that came for a tile already committed (traced twice) or a closed
  # round; tiles_speculative the speculative copies handed out; tiles_re_leased leases handed out again
  # (expired or returned).
  "$PY" - "$tmp"/frames/fly.000?.json <<'EOF' >&2 || fail "cannot read the frames' statistics"
import json, sys
keys = ("tiles_committed", "tiles_leased", "tiles_re_leased", "tiles_speculative", "tiles_dropped")
total = dict.fromkeys(keys, 0)
for path in sys.argv[1:]:
    stats = json.load(open(path))
    for k in keys:
        total[k] += stats[k]
print(f"measured over {len(sys.argv) - 1} frames: " + ", ".join(f"{k} {v}" for k, v in total.items()))
EOF
  dc down -v -t 120 > "$tmp/compose-down.log" 2>&1 || fail "docker-compose down: $(tail -n 5 "$tmp/compose-down.log")"
  log "compose: passed"
}
