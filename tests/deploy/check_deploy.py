#!/usr/bin/python3
"""Static checks of deploy/: the Dockerfile, docker-compose.yml (validated by Debian's
`docker-compose config`: two masters with a volume each behind one network alias, scalable workers)
and the Kubernetes manifests (rendered with `kubectl kustomize` where kubectl is installed, else by
tests/deploy/k8s_render.py; parsed with python3-yaml): kinds and apiVersions, selectors, the masters'
StatefulSet and headless Service, the workers' autoscaler on epr_tiles_waiting (and the KEDA
component that replaces it), the PodDisruptionBudgets, resources and grace periods.

    check_deploy.py [--binaries EPR EPR_MASTER EPR_WORKER] [unittest arguments, e.g. Kubernetes]

With --binaries, also checks that every shared library the built programs load belongs to a Debian
package (what the runtime image installs, deploy/image-packages.sh). Run with Debian's /usr/bin/python3.
Exit 0 passed, 1 failed, 77 skipped (docker-compose or python3-yaml missing outside CI).
"""
import argparse
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import unittest

SRC = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
DEPLOY = os.path.join(SRC, "deploy")
K8S = os.path.join(DEPLOY, "k8s")
BINARIES = []

try:
    import yaml
except ImportError:  # reported by main()
    yaml = None


def read(path):
    with open(path) as f:
        return f.read()


def project_version():
    m = re.search(r"project\(\s*eprfarm\s+VERSION\s+([0-9.]+)", read(os.path.join(SRC, "CMakeLists.txt")))
    return m.group(1)


def entrypoint_variables():
    """EPR_* variables deploy/docker-entrypoint.sh reads (or epr itself, for EPR_MASTER)."""
    return set(re.findall(r"\$\{?(EPR_[A-Z_]+)", read(os.path.join(DEPLOY, "docker-entrypoint.sh"))))


def dockerfile_stages():
    sys.path.insert(0, os.path.dirname(__file__))
    from compose_hosts import dockerfile_stages as parse

    return parse(os.path.join(DEPLOY, "Dockerfile"))


IMAGE_RE = re.compile(r"^(?:\$\{EPR_REGISTRY:-eprfarm\}|eprfarm)/(epr-master|epr-worker):(.+)$")


class Dockerfile(unittest.TestCase):
    def setUp(self):
        self.text = read(os.path.join(DEPLOY, "Dockerfile"))
        self.stages = dockerfile_stages()

    def test_stages_on_debian_12(self):
        for name in ("build", "runtime", "master", "worker"):
            self.assertIn(name, self.stages, f"Dockerfile has no stage {name}")
        m = re.search(r"^ARG DEBIAN_IMAGE=(\S+)", self.text, re.M)
        self.assertIsNotNone(m, "no ARG DEBIAN_IMAGE")
        self.assertRegex(m.group(1), r"^debian:(bookworm|12)(-slim)?$", "base image is not Debian 12")
        for name in ("build", "runtime"):
            self.assertEqual(self.stages[name]["from"], "${DEBIAN_IMAGE}")
        self.assertEqual(self.stages["master"]["from"], "runtime")
        self.assertEqual(self.stages["worker"]["from"], "runtime")

    def test_build_stage_uses_the_setup_script_packages(self):
        self.assertIn("image-packages.sh build scripts/setup.sh", self.text)
        out = subprocess.run(["bash", os.path.join(DEPLOY, "image-packages.sh"), "build"], capture_output=True,
                             text=True, check=True).stdout.split()
        for p in ("cmake", "ninja-build", "libembree-dev", "libosmesa6-dev", "libgrpc++-dev"):
            self.assertIn(p, out, f"setup.sh's build list lacks {p}")
        self.assertIn("image-packages.sh runtime", self.text, "runtime packages are not derived from the binaries")

    def test_non_root_with_health_checks(self):
        runtime = self.text[self.text.index("AS runtime"):]
        m = re.search(r"^USER\s+(\S+)", runtime, re.M)
        self.assertIsNotNone(m, "the runtime stage sets no USER")
        self.assertNotIn(m.group(1).split(":")[0], ("0", "root"))
        for stage in ("master", "worker"):
            part = self.text[self.text.index(f"AS {stage}"):]
            part = part[: part.find("\nFROM ") if "\nFROM " in part else len(part)]
            self.assertRegex(part, r'HEALTHCHECK .*CMD \["epr-health", "{}"'.format(stage), f"stage {stage} has no health check")
        self.assertEqual(self.stages["runtime"]["entrypoint"], ["epr-entrypoint"])
        self.assertEqual(self.stages["master"]["cmd"], ["master"])
        self.assertEqual(self.stages["worker"]["cmd"], ["worker"])

    def test_copied_files_exist(self):
        for src in re.findall(r"^COPY (deploy/\S+|scripts/\S+)", self.text, re.M):
            if src == "deploy/prebuilt/":
                continue  # not in the tree: scripts/container_images.sh --prebuilt fills it in its context
            self.assertTrue(os.path.exists(os.path.join(SRC, src)), f"COPY {src}: no such file")

    def test_prebuilt_binaries_stage(self):
        """--build-arg BINARIES=prebuilt takes the binaries of scripts/container_images.sh's context."""
        m = re.search(r"^ARG BINARIES=(\S+)", self.text, re.M)
        self.assertIsNotNone(m, "no ARG BINARIES")
        self.assertEqual(m.group(1), "build", "by default the image compiles the project")
        self.assertEqual(self.stages["binaries"]["from"], "${BINARIES}")
        self.assertEqual(self.stages["prebuilt"]["from"], "scratch")
        script = read(os.path.join(SRC, "scripts", "container_images.sh"))
        for path in ("deploy/prebuilt/bin", "deploy/prebuilt/runtime-packages.txt", "BINARIES=prebuilt"):
            self.assertIn(path, script, f"scripts/container_images.sh does not fill {path}")
        runtime = self.text[self.text.index("AS runtime"):]
        self.assertNotIn("--from=build", runtime, "the runtime stage must copy from the stage BINARIES names")
        self.assertEqual(len(re.findall(r"--from=binaries", runtime)), 2)

    def test_image_env_is_known_to_the_entrypoint(self):
        known = entrypoint_variables()
        for name in ("master", "worker"):
            for key in self.stages[name]["env"]:
                self.assertIn(key, known, f"stage {name} sets {key}, which epr-entrypoint does not read")


class Scripts(unittest.TestCase):
    def test_shell_syntax(self):
        for path in ("deploy/docker-entrypoint.sh", "deploy/image-packages.sh", "tests/deploy/netns_cluster_test.sh",
                     "scripts/container_setup.sh", "scripts/container_images.sh", "scripts/container_test.sh",
                     "scripts/container_test_compose.sh", "scripts/container_k8s_test.sh", "scripts/container_bench.sh",
                     "scripts/container_ci.sh"):
            subprocess.run(["bash", "-n", os.path.join(SRC, path)], check=True)

    def test_health_script_compiles(self):
        with open(os.path.join(DEPLOY, "epr-health")) as f:
            compile(f.read(), "epr-health", "exec")

    def test_health_protobuf_encoding(self):
        import importlib.machinery
        import importlib.util

        loader = importlib.machinery.SourceFileLoader("epr_health", os.path.join(DEPLOY, "epr-health"))
        spec = importlib.util.spec_from_loader("epr_health", loader)
        health = importlib.util.module_from_spec(spec)
        loader.exec_module(health)
        self.assertEqual(health.encode_request(""), b"")
        self.assertEqual(health.encode_request("epr.v1.JobService"), b"\x0a\x11epr.v1.JobService")
        self.assertEqual(health.decode_status(b"\x08\x01"), 1)
        self.assertEqual(health.decode_status(b""), 0)
        self.assertEqual(health.local_target("0.0.0.0:50051", "1"), "127.0.0.1:50051")
        self.assertEqual(health.local_target("[::]:8080", "1"), "[::1]:8080")

    def test_setup_installs_what_deploy_needs(self):
        text = read(os.path.join(SRC, "scripts", "setup.sh"))
        for p in ("docker-compose", "iproute2", "python3-yaml", "python3-grpcio", "python3-openimageio"):
            self.assertRegex(text, rf"(?<![\w-]){re.escape(p)}(?![\w-])", f"scripts/setup.sh does not install {p}")

    def test_runtime_libraries_come_from_debian_packages(self):
        if not BINARIES:
            self.skipTest("no --binaries given")
        r = subprocess.run(["bash", os.path.join(DEPLOY, "image-packages.sh"), "runtime", *BINARIES],
                           capture_output=True, text=True)
        self.assertEqual(r.returncode, 0, r.stderr)
        packages = r.stdout.split()
        for p in ("libc6", "libstdc++6"):
            self.assertIn(p, packages)
        self.assertTrue(any(p.startswith("libembree") for p in packages), packages)
        self.assertTrue(any(p.startswith("libosmesa") for p in packages), packages)


def seconds(duration):
    """Compose durations ("120s", "1m30s", "2m") in seconds."""
    total, n = 0, ""
    for ch in str(duration):
        if ch.isdigit() or ch == ".":
            n += ch
        else:
            total += float(n) * {"h": 3600, "m": 60, "s": 1}[ch]
            n = ""
    return total + (float(n) if n else 0)


class Compose(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        exe = shutil.which("docker-compose")
        if not exe:
            raise unittest.SkipTest("docker-compose is not installed")
        env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "HOME": os.environ.get("HOME", "/tmp")}
        r = subprocess.run([exe, "-f", os.path.join(DEPLOY, "docker-compose.yml"), "config"], capture_output=True,
                           text=True, env=env)
        if r.returncode != 0:
            raise AssertionError("docker-compose config rejected deploy/docker-compose.yml:\n" + r.stderr)
        cls.config = yaml.safe_load(r.stdout)
        cls.raw = yaml.safe_load(read(os.path.join(DEPLOY, "docker-compose.yml")))

    def service(self, name):
        self.assertIn(name, self.config["services"], f"no service {name}")
        return self.config["services"][name]

    def masters(self):
        """The services that run epr-master (image stage master, command master)."""
        found = {n: s for n, s in self.config["services"].items()
                 if (s.get("build") or {}).get("target") == "master" and (s.get("command") or [None])[0] == "master"}
        return found

    @staticmethod
    def container_ports(svc):
        ports = []
        for p in svc.get("ports") or []:
            ports.append(int(p["target"]) if isinstance(p, dict) else int(str(p).split(":")[-1].split("/")[0]))
        return ports

    @staticmethod
    def host_ports(svc):
        ports = []
        for p in svc.get("ports") or []:
            if isinstance(p, dict):
                ports.append(int(p["published"]))
            else:
                parts = str(p).split("/")[0].split(":")
                ports.append(int(parts[-2]))
        return ports

    def test_images_are_named_consistently(self):
        version = project_version()
        for name, svc in self.config["services"].items():
            raw = self.raw["services"][name]
            image = raw.get("image") or self.raw["services"]["master1"]["image"]  # master2 merges master1's
            m = IMAGE_RE.match(image)
            self.assertIsNotNone(m, f"service {name}: image {image} is not eprfarm/epr-master|worker")
            self.assertEqual(m.group(2), f"${{EPR_TAG:-{version}}}", f"service {name}: tag is not the project version")
            target = svc.get("build", {}).get("target")
            self.assertEqual(f"epr-{target}", m.group(1), f"service {name}: image {m.group(1)} built from stage {target}")
            self.assertIn(target, dockerfile_stages(), f"service {name}: no Dockerfile stage {target}")

    def test_two_masters_each_with_its_own_state_volume_and_ports(self):
        masters = self.masters()
        self.assertGreaterEqual(len(masters), 2, f"the compose file runs {sorted(masters)} as masters")
        volumes, published = [], []
        for name, master in masters.items():
            self.assertIn(50051, self.container_ports(master), name)
            self.assertIn(8080, self.container_ports(master), name)
            published += self.host_ports(master)
            env = master["environment"]
            self.assertTrue(env["EPR_LISTEN"].endswith(":50051"), name)
            self.assertTrue(env["EPR_HTTP"].endswith(":8080"), name)
            sources = {}
            for v in master.get("volumes", []):
                if isinstance(v, dict):
                    sources[v["target"]] = v.get("source")
                elif ":" in str(v):
                    source, target = str(v).split(":")[:2]
                    sources[target] = source
            state = env["EPR_STATE_DIR"]
            self.assertIn(state, sources, f"{name}: the master's state folder is not a volume")
            self.assertIn(sources[state], self.config.get("volumes") or {}, f"{name}: the state volume is not named")
            volumes.append(sources[state])
            self.assertEqual(master["healthcheck"]["test"][:3], ["CMD", "epr-health", "master"])
            self.assertEqual(env.get("EPR_TOKEN_FILE"), "/run/secrets/epr_token", f"{name} checks no token")
            # SIGTERM drains the master: the grace period covers the drain and the checkpoints after it.
            drain = float(env.get("EPR_DRAIN_TIMEOUT") or 60)
            self.assertGreaterEqual(seconds(master.get("stop_grace_period", "10s")), drain + 30,
                                    f"{name}: stop_grace_period shorter than EPR_DRAIN_TIMEOUT + 30 s")
        self.assertEqual(len(set(volumes)), len(volumes), f"masters share a state volume: {volumes}")
        names = [m["environment"].get("EPR_MASTER_NAME") for m in masters.values()]
        self.assertEqual(len(set(names)), len(names), f"masters share a name (their job ids would clash): {names}")
        self.assertEqual(len(set(published)), len(published), f"masters publish the same host port: {published}")

    def master_alias(self):
        """The network alias every master answers to (one name resolving to all of them)."""
        aliases = None
        for name, master in self.masters().items():
            nets = master.get("networks") or {}
            mine = set()
            for net in nets.values():
                mine |= set((net or {}).get("aliases") or [])
            aliases = mine if aliases is None else aliases & mine
        self.assertTrue(aliases, "the masters share no network alias")
        return sorted(aliases)[0]

    def test_workers_and_client_reach_every_master_by_one_name(self):
        alias = self.master_alias()
        for name in ("worker", "client"):
            target = self.service(name)["environment"]["EPR_MASTER"]
            hosts = [t.rsplit(":", 1)[0] for t in target.split(",")]
            self.assertEqual(hosts, [alias], f"{name}: EPR_MASTER={target} is not the masters' alias {alias}")
            self.assertEqual(target.rsplit(":", 1)[1], "50051")
        masters = set(self.masters())
        self.assertTrue(masters <= set(self.service("worker").get("depends_on") or {}),
                        "the workers do not start after every master")

    def test_workers_scale(self):
        worker = self.service("worker")
        self.assertNotIn("container_name", worker)
        self.assertEqual(self.container_ports(worker), [], "a worker publishing ports cannot be scaled")
        for net in (worker.get("networks") or {}).values():
            self.assertFalse(net and net.get("ipv4_address"), "a worker with a fixed address cannot be scaled")
        self.assertIn("epr-health", worker["healthcheck"]["test"])
        self.assertGreaterEqual(seconds(worker.get("stop_grace_period", "10s")), 10,
                                "a worker needs a moment to give its leases back")

    def test_token_is_a_secret_read_from_a_file(self):
        secrets = self.config.get("secrets") or {}
        self.assertIn("epr_token", secrets)
        self.assertIn("file", secrets["epr_token"])
        for name, svc in self.config["services"].items():
            used = [s if isinstance(s, str) else s["source"] for s in svc.get("secrets") or []]
            for s in used:
                self.assertIn(s, secrets, f"service {name} uses an undefined secret {s}")
            if "EPR_TOKEN_FILE" in svc.get("environment", {}):
                self.assertEqual(svc["environment"]["EPR_TOKEN_FILE"], "/run/secrets/epr_token")
                self.assertIn("epr_token", used, f"service {name} reads a token it is not given")
        self.assertIn("epr_token", [s["source"] for s in self.service("worker")["secrets"]])
        for svc in self.config["services"].values():
            flat = json.dumps(svc)
            self.assertNotIn("EPR_TOKEN=", flat, "a token in the environment")
            self.assertNotIn("--token ", flat)

    def test_environment_is_understood(self):
        known = entrypoint_variables()
        for name, svc in self.config["services"].items():
            for key in svc.get("environment") or {}:
                self.assertIn(key, known, f"service {name}: {key} is read by nobody (typo?)")

    def test_master_addresses_inside_the_subnet(self):
        import ipaddress

        seen = []
        for name, master in self.masters().items():
            (net_name, net), = master["networks"].items()
            subnet = self.config["networks"][net_name]["ipam"]["config"][0]["subnet"]
            self.assertIn(ipaddress.ip_address(net["ipv4_address"]), ipaddress.ip_network(subnet), name)
            seen.append(net["ipv4_address"])
        self.assertEqual(len(set(seen)), len(seen), f"masters share an address: {seen}")


API_VERSIONS = {"Namespace": "v1", "ConfigMap": "v1", "Secret": "v1", "Service": "v1", "Deployment": "apps/v1",
                "StatefulSet": "apps/v1", "PodDisruptionBudget": "policy/v1",
                "HorizontalPodAutoscaler": "autoscaling/v2", "ScaledObject": "keda.sh/v1alpha1"}


def quantity(q):
    """Kubernetes quantities (memory: 5Gi, 512M; CPU: 2, 500m) as numbers (bytes, cores)."""
    s = str(q)
    units = {"Ki": 2**10, "Mi": 2**20, "Gi": 2**30, "Ti": 2**40, "K": 1e3, "M": 1e6, "G": 1e9, "T": 1e12, "m": 1e-3}
    for u in sorted(units, key=len, reverse=True):
        if s.endswith(u):
            return float(s[: -len(u)]) * units[u]
    return float(s)


def byte_size(v):
    """epr-master --memory-budget values (8G, 512M: powers of 1024) in bytes."""
    units = {"K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}
    return float(v[:-1]) * units[v[-1]] if v[-1] in units else float(v)


class Kubernetes(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        sys.path.insert(0, os.path.dirname(__file__))
        import k8s_render

        cls.render = k8s_render
        cls.objects = k8s_render.render(K8S)
        cls.keda = k8s_render.render(K8S, [os.path.join(K8S, "autoscaling", "keda")])
        cls.rendered_by = "kubectl kustomize" if k8s_render.kubectl() else "the plain renderer"
        print(f"\n  Kubernetes manifests rendered by {cls.rendered_by}", file=sys.stderr)

    def by_kind(self, kind, objects=None):
        return [d for d in (objects or self.objects) if d["kind"] == kind]

    def one(self, kind, name, objects=None):
        found = [d for d in self.by_kind(kind, objects) if d["metadata"]["name"] == name]
        self.assertEqual(len(found), 1, f"expected one {kind} {name}, found {len(found)}")
        return found[0]

    def names(self, kind):
        return {d["metadata"]["name"] for d in self.by_kind(kind)}

    def workloads(self, objects=None):
        return [d for d in (objects or self.objects) if d["kind"] in ("Deployment", "StatefulSet", "DaemonSet")]

    def config(self):
        config = {}
        for cm in self.by_kind("ConfigMap"):
            config.update(cm["data"])
        return config

    @staticmethod
    def selects(selector, labels):
        return all(labels.get(k) == v for k, v in selector.items())

    def test_plain_rendering_agrees_with_kubectl(self):
        if not self.render.kubectl():
            self.skipTest("kubectl is not installed: the plain renderer is all there is")
        for components in ([], [os.path.join(K8S, "autoscaling", "keda")]):
            ours = sorted((d["kind"], d["metadata"]["name"], d["metadata"].get("namespace"))
                          for d in self.render.render_plain(K8S, components))
            theirs = sorted((d["kind"], d["metadata"]["name"], d["metadata"].get("namespace"))
                            for d in self.render.render_kubectl(K8S, components))
            self.assertEqual(ours, theirs, f"components {components}")

    def test_kinds_api_versions_and_required_fields(self):
        self.assertTrue(self.objects, "no manifests")
        for d in self.objects + self.keda:
            for key in ("apiVersion", "kind", "metadata"):
                self.assertIn(key, d, f"a document without {key}")
            kind = d["kind"]
            self.assertIn(kind, API_VERSIONS, f"unexpected kind {kind}")
            self.assertEqual(d["apiVersion"], API_VERSIONS[kind], f"{kind} {d['metadata'].get('name')}")
            self.assertTrue(d["metadata"].get("name"), f"{kind} without a name")
            if kind != "Namespace":
                self.assertEqual(d["metadata"].get("namespace"), "eprfarm", f"{kind} outside eprfarm")
        for kind in ("Namespace", "ConfigMap", "Secret", "Service", "Deployment", "StatefulSet",
                     "HorizontalPodAutoscaler", "PodDisruptionBudget"):
            self.assertTrue(self.by_kind(kind), f"no {kind}")

    def test_kustomization_lists_every_manifest_file(self):
        with open(os.path.join(K8S, "kustomization.yaml")) as f:
            listed = set(yaml.safe_load(f)["resources"])
        files = {f for f in os.listdir(K8S) if f.endswith((".yaml", ".yml")) and f != "kustomization.yaml"}
        self.assertEqual(listed, files)

    def test_workloads(self):
        version = project_version()
        self.one("StatefulSet", "epr-master")
        self.one("Deployment", "epr-worker")
        for d in self.workloads():
            name = d["metadata"]["name"]
            spec, pod = d["spec"], d["spec"]["template"]["spec"]
            labels = d["spec"]["template"]["metadata"]["labels"]
            self.assertTrue(self.selects(spec["selector"]["matchLabels"], labels),
                            f"{name}: selector does not match the pod labels")
            self.assertTrue(pod["securityContext"].get("runAsNonRoot"), f"{name}: not runAsNonRoot")
            self.assertNotEqual(pod["securityContext"].get("runAsUser"), 0)
            for c in pod["containers"]:
                self.assertIn("readinessProbe", c, f"{name}/{c['name']}: no readinessProbe")
                self.assertIn("livenessProbe", c, f"{name}/{c['name']}: no livenessProbe")
                m = IMAGE_RE.match(c["image"])
                self.assertIsNotNone(m, f"{name}: image {c['image']} is not eprfarm/epr-master|worker")
                self.assertEqual(m.group(2), version, f"{name}: image tag is not the project version {version}")
                self.assertEqual(m.group(1), name, f"{name} runs image {m.group(1)}")
                self.assertIn(c.get("args", [None])[0], ("master", "worker"))
                ports = {p.get("name") for p in c.get("ports", [])} | {p["containerPort"] for p in c.get("ports", [])}
                for probe in ("readinessProbe", "livenessProbe", "startupProbe"):
                    ps = c.get(probe)
                    if not ps:
                        continue
                    kinds = [k for k in ("exec", "httpGet", "grpc", "tcpSocket") if k in ps]
                    self.assertEqual(len(kinds), 1, f"{name} {probe}: one handler expected, got {kinds}")
                    if "exec" in ps:
                        self.assertEqual(ps["exec"]["command"][0], "epr-health", f"{name} {probe}")
                    else:
                        self.assertIn(ps[kinds[0]]["port"], ports, f"{name} {probe}: not a container port")

    def test_masters_are_a_statefulset_behind_a_headless_service(self):
        master = self.one("StatefulSet", "epr-master")
        spec = master["spec"]
        self.assertGreaterEqual(spec.get("replicas", 1), 2, "one master: not a multi-master farm")
        headless = self.one("Service", spec["serviceName"])
        self.assertEqual(headless["spec"].get("clusterIP"), "None", f"{spec['serviceName']} is not headless")
        # A draining (terminating, unready) master keeps its workers until its rounds are checkpointed.
        self.assertTrue(headless["spec"].get("publishNotReadyAddresses"), "the headless Service hides draining masters")
        labels = spec["template"]["metadata"]["labels"]
        self.assertTrue(self.selects(headless["spec"]["selector"], labels), "the headless Service selects no master")
        # Every master's state folder is its own volume from the claim template, mounted where EPR_STATE_DIR says.
        templates = {t["metadata"]["name"]: t for t in spec.get("volumeClaimTemplates", [])}
        c = spec["template"]["spec"]["containers"][0]
        mounts = {m["mountPath"]: m["name"] for m in c["volumeMounts"]}
        state = self.config()["EPR_STATE_DIR"]
        self.assertIn(state, mounts, "the state folder is not mounted")
        self.assertIn(mounts[state], templates, "the state folder is not a volumeClaimTemplate")
        claim = templates[mounts[state]]["spec"]
        self.assertEqual(claim["accessModes"], ["ReadWriteOnce"])
        self.assertGreater(quantity(claim["resources"]["requests"]["storage"]), 0)
        volumes = {v["name"] for v in spec["template"]["spec"].get("volumes", [])}
        self.assertNotIn(mounts[state], volumes, "a pod volume shadows the claim template")

    def test_workers_reach_every_master_through_the_headless_service(self):
        host, port = self.config()["EPR_MASTER"].rsplit(":", 1)
        host = host.removeprefix("dns:///").split(".")[0]
        svc = self.one("Service", host)
        self.assertEqual(svc["spec"].get("clusterIP"), "None", f"EPR_MASTER names {host}, not a headless Service")
        self.assertIn(int(port), [p["port"] for p in svc["spec"]["ports"]])
        master = self.one("StatefulSet", "epr-master")
        self.assertEqual(master["spec"]["serviceName"], host)

    def test_resources_and_grace_periods(self):
        config = self.config()
        master = self.one("StatefulSet", "epr-master")["spec"]["template"]["spec"]
        res = master["containers"][0]["resources"]
        budget = byte_size(config["EPR_MEMORY_BUDGET"])
        limit = quantity(res["limits"]["memory"])
        self.assertGreaterEqual(limit, budget + 512 * 2**20, "the master's memory limit leaves no room over its budget")
        self.assertEqual(quantity(res["requests"]["memory"]), limit, "the master's memory is not guaranteed")
        self.assertIn("cpu", res["requests"])
        drain = float(config["EPR_DRAIN_TIMEOUT"])
        self.assertGreaterEqual(master["terminationGracePeriodSeconds"], drain + 60,
                                "the grace period does not cover the drain and the checkpoint writes")
        worker = self.one("Deployment", "epr-worker")
        self.assertNotIn("replicas", worker["spec"], "the autoscaler owns the workers' replicas")
        wpod = worker["spec"]["template"]["spec"]
        wc = wpod["containers"][0]
        self.assertEqual(wc["resources"]["requests"]["cpu"], wc["resources"]["limits"]["cpu"])
        threads = next(e for e in wc["env"] if e["name"] == "EPR_THREADS")
        self.assertEqual(threads["valueFrom"]["resourceFieldRef"]["resource"], "limits.cpu")
        self.assertGreaterEqual(wpod["terminationGracePeriodSeconds"], 10)

    def test_disruption_budgets_cover_masters_and_workers(self):
        pdbs = self.by_kind("PodDisruptionBudget")
        for d in self.workloads():
            labels = d["spec"]["template"]["metadata"]["labels"]
            mine = [p for p in pdbs if self.selects(p["spec"]["selector"]["matchLabels"], labels)]
            self.assertEqual(len(mine), 1, f"{d['metadata']['name']}: {len(mine)} PodDisruptionBudgets")
            spec = mine[0]["spec"]
            self.assertEqual(len({"minAvailable", "maxUnavailable"} & set(spec)), 1)
            # A budget of minAvailable = all would block every node drain.
            self.assertNotEqual(str(spec.get("maxUnavailable", 1)), "0")
        for p in pdbs:
            selected = [d for d in self.workloads()
                        if self.selects(p["spec"]["selector"]["matchLabels"], d["spec"]["template"]["metadata"]["labels"])]
            self.assertEqual(len(selected), 1, f"PodDisruptionBudget {p['metadata']['name']} selects {len(selected)}")

    def test_autoscaler_scales_workers_on_tiles_waiting(self):
        hpa = self.one("HorizontalPodAutoscaler", "epr-worker")["spec"]
        ref = hpa["scaleTargetRef"]
        self.assertEqual((ref["apiVersion"], ref["kind"]), ("apps/v1", "Deployment"))
        self.one("Deployment", ref["name"])
        self.assertLessEqual(hpa.get("minReplicas", 1), hpa["maxReplicas"])
        (metric,) = hpa["metrics"]
        self.assertEqual(metric["type"], "External")
        self.assertEqual(metric["external"]["metric"]["name"], "epr_tiles_waiting")
        self.assertEqual(metric["external"]["target"]["type"], "AverageValue")
        self.assertGreater(quantity(metric["external"]["target"]["averageValue"]), 0)
        # The series' labels come from the master pods' labels (Prometheus labelmap: dots become _).
        master_labels = self.one("StatefulSet", "epr-master")["spec"]["template"]["metadata"]["labels"]
        for k, v in metric["external"]["metric"]["selector"]["matchLabels"].items():
            self.assertIn((k, v), {(re.sub(r"[^a-zA-Z0-9_]", "_", a), b) for a, b in master_labels.items()})
        self.assertGreaterEqual(hpa["behavior"]["scaleDown"]["stabilizationWindowSeconds"], 60)

    def test_masters_export_the_metric(self):
        sources = "".join(read(os.path.join(SRC, "master", "server", f)) for f in os.listdir(
            os.path.join(SRC, "master", "server")) if f.endswith(".cpp"))
        self.assertIn('"epr_tiles_waiting"', sources, "the masters export no epr_tiles_waiting gauge")

    def test_prometheus_adapter_and_scrape_configs(self):
        auto = os.path.join(K8S, "autoscaling")
        values = yaml.safe_load(read(os.path.join(auto, "prometheus-adapter-values.yaml")))
        (rule,) = values["rules"]["external"]
        self.assertIn("epr_tiles_waiting", rule["seriesQuery"])
        self.assertEqual(rule["name"]["as"], "epr_tiles_waiting")
        self.assertEqual(rule["resources"]["overrides"]["namespace"]["resource"], "namespace")
        self.assertIn("<<.LabelMatchers>>", rule["metricsQuery"])
        scrape = yaml.safe_load(read(os.path.join(auto, "prometheus-scrape.yaml")))["scrape_configs"][0]
        self.assertEqual(scrape["metrics_path"], "/metrics")
        self.assertIn("credentials_file", scrape["authorization"], "/metrics needs the token")
        relabel = scrape["relabel_configs"]
        targets = {r.get("target_label") for r in relabel} | {"labelmap" for r in relabel if r.get("action") == "labelmap"}
        self.assertTrue({"namespace", "labelmap"} <= targets, "the series would lack namespace or pod labels")
        keep = {r["source_labels"][0]: r["regex"] for r in relabel if r.get("action") == "keep"}
        master = self.one("StatefulSet", "epr-master")["spec"]["template"]
        self.assertEqual(keep["__meta_kubernetes_pod_label_app_kubernetes_io_name"],
                         master["metadata"]["labels"]["app.kubernetes.io/name"])
        port_names = {p["name"] for p in master["spec"]["containers"][0]["ports"]}
        self.assertIn(keep["__meta_kubernetes_pod_container_port_name"], port_names)

    def test_keda_component_replaces_the_autoscaler(self):
        self.assertEqual(self.by_kind("HorizontalPodAutoscaler", self.keda), [], "two autoscalers on the workers")
        so = self.one("ScaledObject", "epr-worker", self.keda)["spec"]
        self.assertEqual(so["scaleTargetRef"]["name"], "epr-worker")
        self.one("Deployment", so["scaleTargetRef"]["name"], self.keda)
        (trigger,) = so["triggers"]
        self.assertEqual(trigger["type"], "prometheus")
        self.assertIn("epr_tiles_waiting", trigger["metadata"]["query"])
        self.assertGreater(float(trigger["metadata"]["threshold"]), 0)
        self.assertLessEqual(so.get("minReplicaCount", 0), so["maxReplicaCount"])
        rest = sorted((d["kind"], d["metadata"]["name"]) for d in self.keda if d["kind"] != "ScaledObject")
        base = sorted((d["kind"], d["metadata"]["name"]) for d in self.objects if d["kind"] != "HorizontalPodAutoscaler")
        self.assertEqual(rest, base)

    def test_references_exist(self):
        configmaps, secrets = self.names("ConfigMap"), self.names("Secret")
        for d in self.workloads():
            name, pod = d["metadata"]["name"], d["spec"]["template"]["spec"]
            volumes = {v["name"]: v for v in pod.get("volumes", [])}
            claims = {t["metadata"]["name"] for t in d["spec"].get("volumeClaimTemplates", [])}
            for c in pod["containers"]:
                for e in c.get("envFrom", []):
                    if "configMapRef" in e:
                        self.assertIn(e["configMapRef"]["name"], configmaps, f"{name}: no such ConfigMap")
                    if "secretRef" in e:
                        self.assertIn(e["secretRef"]["name"], secrets, f"{name}: no such Secret")
                for m in c.get("volumeMounts", []):
                    self.assertIn(m["name"], set(volumes) | claims, f"{name}: mounts an undeclared volume {m['name']}")
            for v in volumes.values():
                if "secret" in v:
                    secret = self.one("Secret", v["secret"]["secretName"])
                    data = {**secret.get("data", {}), **secret.get("stringData", {})}
                    for item in v["secret"].get("items", []):
                        self.assertIn(item["key"], data, f"{name}: Secret has no key {item['key']}")
                if "configMap" in v:
                    self.assertIn(v["configMap"]["name"], configmaps)
                self.assertNotIn("persistentVolumeClaim", v, f"{name}: a shared claim; masters get one each")

    def test_token_is_mounted_where_the_config_says(self):
        token_dir, token_name = os.path.split(self.config()["EPR_TOKEN_FILE"])
        for d in self.workloads():
            pod = d["spec"]["template"]["spec"]
            volumes = {v["name"]: v for v in pod["volumes"]}
            mounts = {m["mountPath"]: m["name"] for m in pod["containers"][0]["volumeMounts"]}
            self.assertIn(token_dir, mounts, f"{d['metadata']['name']}: the token folder is not mounted")
            items = volumes[mounts[token_dir]]["secret"]["items"]
            self.assertIn(token_name, [i["path"] for i in items])

    def test_services_select_pods_and_ports(self):
        pods = [(d["spec"]["template"]["metadata"]["labels"], d["spec"]["template"]["spec"]) for d in self.workloads()]
        for svc in self.by_kind("Service"):
            sel = svc["spec"]["selector"]
            matches = [spec for labels, spec in pods if self.selects(sel, labels)]
            self.assertTrue(matches, f"Service {svc['metadata']['name']} selects no pod")
            port_names = {p.get("name") for spec in matches for c in spec["containers"] for p in c.get("ports", [])}
            port_numbers = {p["containerPort"] for spec in matches for c in spec["containers"] for p in c.get("ports", [])}
            for p in svc["spec"]["ports"]:
                t = p.get("targetPort", p["port"])
                self.assertIn(t, port_names | port_numbers, f"Service port {p} targets no container port")

    def test_config_is_understood(self):
        known = entrypoint_variables() | {"XDG_CACHE_HOME"}
        for cm in self.by_kind("ConfigMap"):
            for key in cm["data"]:
                self.assertIn(key, known, f"ConfigMap key {key} is read by nobody (typo?)")
        for d in self.workloads():
            for c in d["spec"]["template"]["spec"]["containers"]:
                for e in c.get("env", []):
                    self.assertIn(e["name"], known, f"{d['metadata']['name']}: env {e['name']} is read by nobody")
                    self.assertNotIn("TOKEN", e["name"].replace("TOKEN_FILE", ""), "a token in the environment")


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--binaries", nargs="+", default=[])
    args, rest = p.parse_known_args()
    BINARIES.extend(args.binaries)
    ci = bool(os.environ.get("CI"))
    missing = [what for what, ok in (("python3-yaml", yaml is not None),
                                     ("docker-compose", shutil.which("docker-compose") is not None)) if not ok]
    if missing:
        msg = f"{', '.join(missing)} not installed (scripts/setup.sh installs them)"
        print(("FAILED: " if ci else "SKIPPED: ") + "deploy checks: " + msg, file=sys.stderr)
        return 1 if ci else 77
    result = unittest.main(argv=[sys.argv[0], "-v", *rest], exit=False).result
    return 0 if result.wasSuccessful() else 1


if __name__ == "__main__":
    sys.exit(main())
