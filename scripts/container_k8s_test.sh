#!/usr/bin/env bash
# What `podman kube play` (podman 4.3) can run of deploy/k8s, with the images of
# scripts/container_images.sh.
#
#   scripts/container_k8s_test.sh --epr BIN
#
# kube play takes Pods, Deployments, ConfigMaps, Secrets and PersistentVolumeClaims; it has no
# Namespace, Service, StatefulSet, HorizontalPodAutoscaler or PodDisruptionBudget (those are checked by
# schema: tests/deploy/check_deploy.py). From the rendered kustomization (tests/deploy/k8s_render.py)
# this script plays:
#   - the ConfigMap epr-config as it is, but EPR_TOKEN_FILE=/run/secrets/token: podman 4.3 ignores a
#     secret volume's items[].path and names the file after the key;
#   - the Secret epr-token with a token made for the run (the manifest's placeholder is refused by the
#     entrypoint), as a podman secret holding the Secret's YAML, which is where kube play looks;
#   - every secret volume with `optional: false` (without it podman 4.3.1 panics: nil pointer
#     dereference in kube.VolumeFromSecret);
#   - the StatefulSet's pod template as a Pod named epr-masters (the headless Service's name, which the
#     workers' EPR_MASTER=epr-masters:50051 names: the pod's name resolves on the podman network), its
#     volume claim template as the PersistentVolumeClaim state-epr-master-0;
#   - the worker Deployment with 2 replicas (the autoscaler sets them in a cluster).
# podman 4.3 makes each emptyDir a named volume of the volume's name (tmp, cache), shared by every pod
# that names it: good enough here, not what Kubernetes does.
# Checked: both workers register with the master; the liveness probes, which kube play turns into
# health checks, pass, fail while the process is stopped (SIGSTOP from the host) and pass again after
# SIGCONT; the startup (gRPC health) and readiness (/readyz; epr-health worker --ready) probes, which
# podman 4.3 does not run, are run by hand in the containers; a job submitted with epr in the master
# pod equals `epr render --single-process` bit for bit (counts.exr, pathtrace.exr).
# Exit 0 passed, 1 failed.
set -uo pipefail

here="$(cd "$(dirname "$0")" && pwd)"
src="$(cd "$here/.." && pwd)"
PY=/usr/bin/python3
EPR_BIN=""
[ "${1:-}" = --epr ] && [ -x "${2:-}" ] && EPR_BIN="$2" || { echo "usage: $0 --epr BIN" >&2; exit 2; }
tmp="$(mktemp -d /tmp/epr-k8s-play.XXXXXX)"
net="eprk8s$$"
log() { echo "[kube play $(date +%T)] $*" >&2; }
fail() {
  echo "FAILED: kube play test: $*" >&2
  for c in epr-masters-master epr-worker-pod-0-worker epr-worker-pod-1-worker; do
    podman logs "$c" > "$tmp/$c.log" 2>&1 && { echo "---- $c (all in $tmp/$c.log)" >&2; tail -n 20 "$tmp/$c.log" >&2; }
  done
  exit 1
}
cleanup() {
  [ -f "$tmp/play.yaml" ] && podman kube down "$tmp/play.yaml" >/dev/null 2>&1
  podman volume rm -f state-epr-master-0 tmp cache epr-token >/dev/null 2>&1
  podman secret rm epr-token >/dev/null 2>&1
  podman network rm -f "$net" >/dev/null 2>&1
}
trap cleanup EXIT
for n in epr-masters epr-worker-pod-0 epr-worker-pod-1; do
  ! podman pod exists "$n" || fail "a pod $n exists already (podman kube down, or podman pod rm -f $n)"
done
! podman secret inspect epr-token >/dev/null 2>&1 || fail "a podman secret epr-token exists already"

head -c 32 /dev/urandom | base64 > "$tmp/token"
"$PY" - "$src" "$tmp" <<'EOF' || fail "cannot render deploy/k8s"
import base64, sys, yaml
src, tmp = sys.argv[1:]
sys.path.insert(0, f"{src}/tests/deploy")
import k8s_render
objs = k8s_render.render(f"{src}/deploy/k8s")
token = open(f"{tmp}/token").read().strip()
def secret_volumes_required(pod_spec):
    for v in pod_spec.get("volumes", []):
        if "secret" in v:
            v["secret"]["optional"] = False
play = []
for o in objs:
    kind = o["kind"]
    if kind == "ConfigMap":
        o["data"]["EPR_TOKEN_FILE"] = "/run/secrets/token"
        play.append(o)
    elif kind == "Secret":
        o.pop("stringData", None)
        o["data"] = {"token": base64.b64encode(token.encode()).decode()}
        yaml.safe_dump(o, open(f"{tmp}/secret.yaml", "w"))
    elif kind == "StatefulSet":
        t = o["spec"]["template"]
        secret_volumes_required(t["spec"])
        (claim,) = o["spec"]["volumeClaimTemplates"]
        name = f"{claim['metadata']['name']}-{o['metadata']['name']}-0"
        play.append({"apiVersion": "v1", "kind": "PersistentVolumeClaim", "metadata": {"name": name},
                     "spec": claim["spec"]})
        t["spec"].setdefault("volumes", []).append({"name": claim["metadata"]["name"],
                                                    "persistentVolumeClaim": {"claimName": name}})
        play.append({"apiVersion": "v1", "kind": "Pod",
                     "metadata": {"name": o["spec"]["serviceName"], "labels": t["metadata"].get("labels", {})},
                     "spec": t["spec"]})
    elif kind == "Deployment":
        secret_volumes_required(o["spec"]["template"]["spec"])
        o["spec"]["replicas"] = 2
        play.append(o)
yaml.safe_dump_all(play, open(f"{tmp}/play.yaml", "w"))
EOF
podman secret create epr-token "$tmp/secret.yaml" >/dev/null || fail "podman secret create"
podman network create "$net" >/dev/null || fail "podman network create"
podman kube play --network "$net" "$tmp/play.yaml" > "$tmp/play.log" 2>&1 || fail "podman kube play: $(tail -n 5 "$tmp/play.log")"
m=epr-masters-master
w0=epr-worker-pod-0-worker
w1=epr-worker-pod-1-worker

wait_for() { # SECONDS WHAT COMMAND...
  local deadline=$((SECONDS + $1)) what="$2"
  shift 2
  until "$@" >/dev/null 2>&1; do [ "$SECONDS" -lt "$deadline" ] || fail "$what: not within $((deadline - SECONDS)) s"; sleep 0.5; done
}
registered() { [ "$(podman logs "$m" 2>&1 | grep -c 'worker .* registered')" -ge 2 ]; }
wait_for 120 "both worker pods registering with the master pod" registered
log "the master pod runs; both worker pods registered with it as epr-masters:50051"

# Liveness (kube play's health checks): healthy, unhealthy while stopped, healthy again.
for c in "$m" "$w0"; do
  podman healthcheck run "$c" >/dev/null || fail "$c: liveness probe fails on a running container"
  pid="$(podman inspect "$c" --format '{{.State.Pid}}')"
  kill -STOP "$pid"
  podman healthcheck run "$c" >/dev/null 2>&1 && { kill -CONT "$pid"; fail "$c: liveness probe passes while the process is stopped"; }
  kill -CONT "$pid"
  wait_for 60 "$c: liveness after SIGCONT" podman healthcheck run "$c"
done
log "liveness probes: pass, fail while the process is stopped, pass again"
# Startup and readiness probes, by hand: what the kubelet would run.
podman exec "$m" epr-health grpc 127.0.0.1:50051 >/dev/null || fail "the master's startup probe (gRPC health)"
podman exec "$m" epr-health http http://127.0.0.1:8080/readyz >/dev/null || fail "the master's readiness probe (/readyz)"
podman exec "$w0" epr-health worker --ready >/dev/null || fail "the worker's readiness probe"
log "startup and readiness probes pass (run by hand)"

job=(builtin:cornell --width 64 --height 64 --spp 16 --paths-per-round 4 --tile 32 --mode skip --min-paths 1 --seed 11)
podman exec "$m" epr --log-level warn submit "${job[@]}" --master localhost:50051 --token-file /run/secrets/token \
  --wait --out /tmp/job > "$tmp/submit.log" 2>&1 || fail "epr submit in the master pod: $(tail -n 3 "$tmp/submit.log")"
for f in counts pathtrace; do podman cp "$m:/tmp/job.$f.exr" "$tmp/job.$f.exr" || fail "podman cp job.$f.exr"; done
"$EPR_BIN" render "${job[@]}" --single-process --out "$tmp/ref" > "$tmp/ref.log" 2>&1 || fail "epr render --single-process"
"$PY" "$src/tests/deploy/same_images.py" "$tmp/job.counts.exr" "$tmp/ref.counts.exr" \
  "$tmp/job.pathtrace.exr" "$tmp/ref.pathtrace.exr" || fail "the pods' job differs from epr render --single-process"
log "a job in the pods equals epr render --single-process"
log "PASSED"
rm -rf "$tmp"
