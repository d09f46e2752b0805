#!/usr/bin/python3
"""Static checks of deploy/: the Dockerfile, docker-compose.yml (validated by Debian's
`docker-compose config`) and the Kubernetes manifests (parsed with python3-yaml).

    check_deploy.py [--binaries EPR EPR_MASTER EPR_WORKER]

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
            self.assertTrue(os.path.exists(os.path.join(SRC, src)), f"COPY {src}: no such file")

    def test_image_env_is_known_to_the_entrypoint(self):
        known = entrypoint_variables()
        for name in ("master", "worker"):
            for key in self.stages[name]["env"]:
                self.assertIn(key, known, f"stage {name} sets {key}, which epr-entrypoint does not read")


class Scripts(unittest.TestCase):
    def test_shell_syntax(self):
        for path in ("deploy/docker-entrypoint.sh", "deploy/image-packages.sh", "tests/deploy/netns_cluster_test.sh"):
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

    @staticmethod
    def container_ports(svc):
        ports = []
        for p in svc.get("ports") or []:
            ports.append(int(p["target"]) if isinstance(p, dict) else int(str(p).split(":")[-1].split("/")[0]))
        return ports

    def test_images_are_named_consistently(self):
        version = project_version()
        for name, svc in self.raw["services"].items():
            m = IMAGE_RE.match(svc.get("image", ""))
            self.assertIsNotNone(m, f"service {name}: image {svc.get('image')} is not eprfarm/epr-master|worker")
            self.assertEqual(m.group(2), f"${{EPR_TAG:-{version}}}", f"service {name}: tag is not the project version")
            target = svc.get("build", {}).get("target")
            self.assertEqual(f"epr-{target}", m.group(1), f"service {name}: image {m.group(1)} built from stage {target}")
            self.assertIn(target, dockerfile_stages(), f"service {name}: no Dockerfile stage {target}")

    def test_master_publishes_grpc_and_http_and_keeps_state_in_a_named_volume(self):
        master = self.service("master")
        self.assertIn(50051, self.container_ports(master))
        self.assertIn(8080, self.container_ports(master))
        env = master["environment"]
        self.assertTrue(env["EPR_LISTEN"].endswith(":50051"))
        self.assertTrue(env["EPR_HTTP"].endswith(":8080"))
        mounts = [v for v in master.get("volumes", []) if isinstance(v, dict) or ":" in str(v)]
        sources = {}
        for v in mounts:
            if isinstance(v, dict):
                sources[v["target"]] = v.get("source")
            else:
                source, target = str(v).split(":")[:2]
                sources[target] = source
        state = env["EPR_STATE_DIR"]
        self.assertIn(state, sources, "the master's state folder is not a volume")
        self.assertIn(sources[state], self.config.get("volumes") or {}, "the state volume is not a named volume")
        self.assertEqual(master["healthcheck"]["test"][:3], ["CMD", "epr-health", "master"])
        self.assertEqual(env.get("EPR_TOKEN_FILE"), "/run/secrets/epr_token", "the master checks no token")

    def test_workers_scale(self):
        worker = self.service("worker")
        self.assertNotIn("container_name", worker)
        self.assertEqual(self.container_ports(worker), [], "a worker publishing ports cannot be scaled")
        for net in (worker.get("networks") or {}).values():
            self.assertFalse(net and net.get("ipv4_address"), "a worker with a fixed address cannot be scaled")
        self.assertEqual(worker["environment"]["EPR_MASTER"], "master:50051")
        self.assertIn("epr-health", worker["healthcheck"]["test"])

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

    def test_master_address_inside_the_subnet(self):
        import ipaddress

        master = self.service("master")
        (net_name, net), = master["networks"].items()
        subnet = self.config["networks"][net_name]["ipam"]["config"][0]["subnet"]
        self.assertIn(ipaddress.ip_address(net["ipv4_address"]), ipaddress.ip_network(subnet))


class Kubernetes(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.docs = []  # (file, document)
        for f in sorted(os.listdir(K8S)):
            if f.endswith((".yaml", ".yml")):
                with open(os.path.join(K8S, f)) as fh:
                    for doc in yaml.safe_load_all(fh):
                        if doc is not None:
                            cls.docs.append((f, doc))
        cls.objects = [(f, d) for f, d in cls.docs if d.get("kind") != "Kustomization"]

    def by_kind(self, kind):
        return [d for _, d in self.objects if d["kind"] == kind]

    def names(self, kind):
        return {d["metadata"]["name"] for d in self.by_kind(kind)}

    def workloads(self):
        return [d for _, d in self.objects if d["kind"] in ("Deployment", "StatefulSet", "DaemonSet")]

    def test_required_fields(self):
        self.assertTrue(self.objects, "no manifests")
        for f, d in self.objects:
            for key in ("apiVersion", "kind", "metadata"):
                self.assertIn(key, d, f"{f}: a document without {key}")
            self.assertTrue(d["metadata"].get("name"), f"{f}: {d['kind']} without a name")
            if d["kind"] != "Namespace":
                self.assertEqual(d["metadata"].get("namespace"), "eprfarm", f"{f}: {d['kind']} outside eprfarm")
        for kind in ("Namespace", "ConfigMap", "Secret", "PersistentVolumeClaim", "Service", "Deployment"):
            self.assertTrue(self.by_kind(kind), f"no {kind}")

    def test_kustomization_lists_every_file(self):
        kust = [d for _, d in self.docs if d.get("kind") == "Kustomization"]
        self.assertEqual(len(kust), 1)
        files = {f for f, _ in self.objects}
        self.assertEqual(set(kust[0]["resources"]), files)

    def test_workloads(self):
        version = project_version()
        deployments = {d["metadata"]["name"]: d for d in self.by_kind("Deployment")}
        self.assertIn("epr-master", deployments)
        self.assertIn("epr-worker", deployments)
        self.assertEqual(deployments["epr-master"]["spec"]["replicas"], 1)
        self.assertEqual(deployments["epr-master"]["spec"]["strategy"]["type"], "Recreate")
        for d in self.workloads():
            name = d["metadata"]["name"]
            spec, pod = d["spec"], d["spec"]["template"]["spec"]
            labels = d["spec"]["template"]["metadata"]["labels"]
            for k, v in spec["selector"]["matchLabels"].items():
                self.assertEqual(labels.get(k), v, f"{name}: selector does not match the pod labels")
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
                    spec = c.get(probe)
                    if not spec:
                        continue
                    kinds = [k for k in ("exec", "httpGet", "grpc", "tcpSocket") if k in spec]
                    self.assertEqual(len(kinds), 1, f"{name} {probe}: one handler expected, got {kinds}")
                    if "exec" in spec:
                        self.assertEqual(spec["exec"]["command"][0], "epr-health", f"{name} {probe}")
                    else:
                        port = spec[kinds[0]]["port"]
                        self.assertIn(port, ports, f"{name} {probe}: port {port} is not a container port")

    def test_references_exist(self):
        configmaps, secrets, pvcs = self.names("ConfigMap"), self.names("Secret"), self.names("PersistentVolumeClaim")
        for d in self.workloads():
            name, pod = d["metadata"]["name"], d["spec"]["template"]["spec"]
            volumes = {v["name"]: v for v in pod.get("volumes", [])}
            for c in pod["containers"]:
                for e in c.get("envFrom", []):
                    if "configMapRef" in e:
                        self.assertIn(e["configMapRef"]["name"], configmaps, f"{name}: no such ConfigMap")
                    if "secretRef" in e:
                        self.assertIn(e["secretRef"]["name"], secrets, f"{name}: no such Secret")
                for m in c.get("volumeMounts", []):
                    self.assertIn(m["name"], volumes, f"{name}: mounts an undeclared volume {m['name']}")
            for v in volumes.values():
                if "secret" in v:
                    secret = next(s for s in self.by_kind("Secret") if s["metadata"]["name"] == v["secret"]["secretName"])
                    data = {**secret.get("data", {}), **secret.get("stringData", {})}
                    for item in v["secret"].get("items", []):
                        self.assertIn(item["key"], data, f"{name}: Secret has no key {item['key']}")
                    self.assertIn(v["secret"]["secretName"], secrets)
                if "configMap" in v:
                    self.assertIn(v["configMap"]["name"], configmaps)
                if "persistentVolumeClaim" in v:
                    self.assertIn(v["persistentVolumeClaim"]["claimName"], pvcs)

    def test_master_state_is_persistent_and_token_is_mounted_where_the_config_says(self):
        config = {}
        for cm in self.by_kind("ConfigMap"):
            config.update(cm["data"])
        master = next(d for d in self.by_kind("Deployment") if d["metadata"]["name"] == "epr-master")
        pod = master["spec"]["template"]["spec"]
        c = pod["containers"][0]
        volumes = {v["name"]: v for v in pod["volumes"]}
        mounts = {m["mountPath"]: m["name"] for m in c["volumeMounts"]}
        self.assertIn(config["EPR_STATE_DIR"], mounts, "the state folder is not mounted")
        self.assertIn("persistentVolumeClaim", volumes[mounts[config["EPR_STATE_DIR"]]])
        token_dir, token_name = os.path.split(config["EPR_TOKEN_FILE"])
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
            matches = [spec for labels, spec in pods if all(labels.get(k) == v for k, v in sel.items())]
            self.assertTrue(matches, f"Service {svc['metadata']['name']} selects no pod")
            port_names = {p.get("name") for spec in matches for c in spec["containers"] for p in c.get("ports", [])}
            port_numbers = {p["containerPort"] for spec in matches for c in spec["containers"] for p in c.get("ports", [])}
            for p in svc["spec"]["ports"]:
                t = p.get("targetPort", p["port"])
                self.assertIn(t, port_names | port_numbers, f"Service port {p} targets no container port")

    def test_config_is_understood_and_points_at_the_service(self):
        known = entrypoint_variables() | {"XDG_CACHE_HOME"}
        config = {}
        for cm in self.by_kind("ConfigMap"):
            for key in cm["data"]:
                self.assertIn(key, known, f"ConfigMap key {key} is read by nobody (typo?)")
            config.update(cm["data"])
        host, port = config["EPR_MASTER"].rsplit(":", 1)
        svc = next((s for s in self.by_kind("Service") if s["metadata"]["name"] == host), None)
        self.assertIsNotNone(svc, f"EPR_MASTER={config['EPR_MASTER']} names no Service")
        self.assertIn(int(port), [p["port"] for p in svc["spec"]["ports"]])
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
