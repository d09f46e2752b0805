#!/usr/bin/env bash
# epr-entrypoint: starts one eprfarm role with its flags taken from the environment, so that
# docker-compose.yml, the Kubernetes ConfigMap and tests/deploy/netns_cluster_test.sh configure the
# programs the same way. Installed in the images as /usr/local/bin/epr-entrypoint.
#
#   epr-entrypoint master [EXTRA FLAGS...]         exec epr-master
#   epr-entrypoint worker [EXTRA FLAGS...]         exec epr-worker
#   epr-entrypoint client COMMAND [ARGS...]        exec epr COMMAND (submit, watch, get, list, cancel, render)
#   epr-entrypoint PROGRAM [ARGS...]               anything else is run as given (e.g. bash, epr-health)
#
# Environment (unset or empty: the program's own default, except where a default is shown):
#   master  EPR_LISTEN=0.0.0.0:50051  gRPC address (JobService, WorkerService, grpc.health.v1)
#           EPR_HTTP                  HTTP monitoring address (/healthz, /readyz, dashboard, /metrics);
#                                     unset: epr-master's default 0.0.0.0:8080; set but empty: no HTTP
#           EPR_STATE_DIR=/var/lib/eprfarm  results and checkpoints (a volume)
#           EPR_MASTER_NAME           the master's name, the prefix of its job ids (default: the name
#                                     saved in the state folder, else HOSTNAME-PORT)
#           EPR_LEASE_TIMEOUT_MS  EPR_HEARTBEAT_MS  EPR_REPROJECT (cpu)  EPR_MAX_QUEUED_VERTICES
#           EPR_CHECKPOINT_INTERVAL   seconds between a job's round checkpoints, 0 or auto
#           EPR_MEMORY_BUDGET         jobs needing more master memory are refused (8G, 512M; 0: no limit)
#           EPR_MAX_TILE_LOSSES       a job fails once one tile has lost its worker this often (3; 0: never)
#           EPR_DRAIN_TIMEOUT         SIGTERM: seconds at most for the open rounds to finish and be
#                                     checkpointed before the master exits (0: at once)
#           EPR_TOKEN_FILE            the bearer token every client and worker must send (a secret)
#           EPR_TLS_CERT EPR_TLS_KEY  serve gRPC over TLS;  EPR_TLS_CLIENT_CA  require client certificates
#   worker  EPR_MASTER=masters:50051  the masters' gRPC addresses: a comma list, or a name that resolves
#                                     to several (a headless Service, a compose network alias)
#           EPR_THREADS (0 = all cores)  EPR_NAME (default HOSTNAME-PID)  EPR_MAX_BACKOFF_MS
#           EPR_CACHE_DIR=/var/cache/eprfarm  scene cache
#           EPR_TOKEN_FILE            the bearer token to send (a secret)
#           EPR_TLS=1  EPR_CA_FILE  EPR_TLS_CERT  EPR_TLS_KEY   TLS to the master
#   client  EPR_MASTER (read by epr itself), EPR_TOKEN_FILE, EPR_TLS=1, EPR_CA_FILE
#   all     EPR_LOG_LEVEL             trace, debug, info, warn, error or off
# Extra flags after the role are appended and win over the environment (CLI11 keeps the last value).
# The binaries are looked up on PATH (EPR_MASTER_BIN, EPR_WORKER_BIN, EPR_CLIENT_BIN override).
set -euo pipefail

die() {
  echo "epr-entrypoint: $*" >&2
  exit 2
}

# flag NAME VALUE: appends "--NAME VALUE" to args when VALUE is not empty.
args=()
flag() {
  if [ -n "${2:-}" ]; then args+=("--$1" "$2"); fi
}
# switch NAME VALUE: appends "--NAME" when VALUE is 1, true or yes.
switch() {
  case "${2:-}" in 1 | true | TRUE | True | yes | YES) args+=("--$1") ;; esac
}

role="${1:-}"
[ -n "$role" ] || die "usage: epr-entrypoint master|worker|client|PROGRAM [ARGS...]"
shift

case "$role" in
  master)
    bin="${EPR_MASTER_BIN:-epr-master}"
    flag listen "${EPR_LISTEN:-0.0.0.0:50051}"
    flag state-dir "${EPR_STATE_DIR:-/var/lib/eprfarm}"
    flag name "${EPR_MASTER_NAME:-}"
    flag lease-timeout-ms "${EPR_LEASE_TIMEOUT_MS:-}"
    flag heartbeat-ms "${EPR_HEARTBEAT_MS:-}"
    flag reproject "${EPR_REPROJECT:-}"
    flag max-queued-vertices "${EPR_MAX_QUEUED_VERTICES:-}"
    flag checkpoint-interval "${EPR_CHECKPOINT_INTERVAL:-}"
    flag memory-budget "${EPR_MEMORY_BUDGET:-}"
    flag max-tile-losses "${EPR_MAX_TILE_LOSSES:-}"
    flag drain-timeout "${EPR_DRAIN_TIMEOUT:-}"
    flag log-level "${EPR_LOG_LEVEL:-}"
    flag token-file "${EPR_TOKEN_FILE:-}"
    flag tls-cert "${EPR_TLS_CERT:-}"
    flag tls-key "${EPR_TLS_KEY:-}"
    flag tls-client-ca "${EPR_TLS_CLIENT_CA:-}"
    # Set but empty disables HTTP monitoring, so this one is passed even when empty.
    if [ -n "${EPR_HTTP+set}" ]; then args+=(--http "$EPR_HTTP"); fi
    mkdir -p "${EPR_STATE_DIR:-/var/lib/eprfarm}"
    ;;
  worker)
    bin="${EPR_WORKER_BIN:-epr-worker}"
    flag master "${EPR_MASTER:-masters:50051}"
    flag threads "${EPR_THREADS:-}"
    flag name "${EPR_NAME:-}"
    flag cache-dir "${EPR_CACHE_DIR:-/var/cache/eprfarm}"
    flag token-file "${EPR_TOKEN_FILE:-}"
    switch tls "${EPR_TLS:-}"
    flag ca-file "${EPR_CA_FILE:-}"
    flag tls-cert "${EPR_TLS_CERT:-}"
    flag tls-key "${EPR_TLS_KEY:-}"
    flag max-backoff-ms "${EPR_MAX_BACKOFF_MS:-}"
    flag log-level "${EPR_LOG_LEVEL:-}"
    mkdir -p "${EPR_CACHE_DIR:-/var/cache/eprfarm}"
    ;;
  client)
    bin="${EPR_CLIENT_BIN:-epr}"
    [ $# -ge 1 ] || die "usage: epr-entrypoint client submit|watch|get|list|cancel|render [ARGS...]"
    command="$1"
    shift
    args=("$command")
    case "$command" in
      submit | watch | get | list | cancel)
        flag token-file "${EPR_TOKEN_FILE:-}"
        switch tls "${EPR_TLS:-}"
        flag ca-file "${EPR_CA_FILE:-}"
        ;;
    esac
    [ -z "${EPR_LOG_LEVEL:-}" ] || args=(--log-level "$EPR_LOG_LEVEL" "${args[@]}")
    ;;
  *)
    exec "$role" "$@"
    ;;
esac

if [ -n "${EPR_TOKEN_FILE:-}" ]; then
  if [ -r "$EPR_TOKEN_FILE" ]; then
    # deploy/k8s/secret.yaml ships a placeholder: refuse to run a cluster with a token everyone knows.
    if grep -q '^REPLACE-ME' "$EPR_TOKEN_FILE"; then
      die "$EPR_TOKEN_FILE holds the placeholder token of deploy/k8s/secret.yaml: set a real token"
    fi
  else
    die "EPR_TOKEN_FILE=$EPR_TOKEN_FILE is not a readable file (is the secret mounted and readable by uid $(id -u)?)"
  fi
fi
exec "$bin" "${args[@]}" "$@"
