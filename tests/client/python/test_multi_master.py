#!/usr/bin/python3
"""The Python client across several masters (eprfarm.Client("A,B")), against two real epr-master
processes (--name m1, m2) and an epr-worker given both addresses, on loopback.

    test_multi_master.py --package-dir BUILD/client/python --epr EPR --master EPR_MASTER --worker EPR_WORKER

Checks: a submission goes to the least loaded master; a job is found by its id through either order
of the list and fetched, equal to `epr render --single-process` of the same job (M, M' and the
path-traced estimate bit-identical); cancel reaches the master holding the job; list merges both
masters' jobs; a batch of frames spreads over both masters, each frame equal to its single-process
render with that frame's camera, and `epr list --batch` through both masters sees every frame; with
one master down, list reports it and still lists the other's jobs, whose jobs still work, and
submissions go to the master that is up. glTF scenes and the sampler through both masters:
scenes/cornell-box.gltf (and a .glb, and a scene JSON naming it) bundled as `epr submit` bundles
it and rendered equal to `epr render --single-process`; sampler="independent" equal to
`--sampler independent`, the default equal to `--sampler sobol-burley` and unlike independent; a
glTF's uris that are absolute or leave the folder refused naming the file and the element, as `epr`
refuses them. Run with Debian's /usr/bin/python3.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import tempfile
import unittest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import test_client as base  # noqa: E402  (the process helpers: Farm, Process, epr, wait_for)

# A small job whose cluster render equals the single-process one bit for bit: explicit tiles, CPU
# reprojection, constant rounds (as tests/integration/cluster's jobs).
eprfarm = grpc = None  # imported from --package-dir by base.main()

JOB = {"width": 48, "height": 40, "spp": 8, "seed": 7, "mode": "skip", "tile": 32, "reproject": "cpu",
       "round_growth": 0}
JOB_FLAGS = ["--width", "48", "--height", "40", "--spp", "8", "--seed", "7", "--mode", "skip", "--tile", "32",
             "--reproject", "cpu", "--round-growth", "0"]
LONG = {"width": 64, "height": 64, "spp": 100000, "mode": "pt"}
ANIMATION = (
    '{"builtin": "cornell", "animation": {"camera": [\n'
    '  {"frame": 1, "eye": [0, 1, 3.9], "look": [0, 1, 0]},\n'
    '  {"frame": 4, "eye": [0.4, 1.15, 3.2], "look": [0.05, 1, 0], "fov": 44}]}}\n'
)


class TwoMasters:
    """Masters m1 and m2, each with its state folder, and one worker leasing from both."""

    def __init__(self, folder: str):
        self.farms = []
        for name in ("m1", "m2"):
            os.makedirs(os.path.join(folder, name))
            self.farms.append(base.Farm(os.path.join(folder, name), ["--name", name], worker=False))
        self.addresses = [f.address for f in self.farms]
        self.list = ",".join(self.addresses)
        self.worker = base.Process(
            [base.ARGS.worker, "--master", self.list, "--threads", "2", "--cache-dir", os.path.join(folder, "cache")],
            os.path.join(folder, "worker.log"),
        )

    def logs(self) -> str:
        return "\n".join(f.logs() for f in self.farms) + f"\n--- worker.log\n{self.worker.output()[-4000:]}"

    def stop(self) -> None:
        self.worker.stop()
        for f in self.farms:
            f.stop()


class TwoMastersCase(unittest.TestCase):
    """A test with its own TwoMasters in a fresh folder (PREFIX) and a client of both."""

    PREFIX = "epr-python-multi-"
    CLIENT_TIMEOUT = None  # seconds; None: the client's default

    def setUp(self):
        # Cleanups, not tearDown: they also run when setUp fails half-way (no process outlives the test).
        self.tmp = tempfile.mkdtemp(prefix=self.PREFIX)
        self.addCleanup(shutil.rmtree, self.tmp, ignore_errors=True)
        self.masters = TwoMasters(self.tmp)
        self.addCleanup(self.masters.stop)
        extra = {} if self.CLIENT_TIMEOUT is None else {"timeout": self.CLIENT_TIMEOUT}
        import eprfarm as package  # the package of the test that runs (base.main() put it on the path)

        self.client = package.Client(self.masters.list, **extra)
        self.addCleanup(self.client.close)

    def animation_scene(self) -> str:
        """ANIMATION written to the test's folder: its path."""
        scene = os.path.join(self.tmp, "walk.json")
        with open(scene, "w") as f:
            f.write(ANIMATION)
        return scene


class FarmCase(unittest.TestCase):
    def run(self, result=None):
        failures = len(result.failures) + len(result.errors) if result else 0
        outcome = super().run(result)
        if result and len(result.failures) + len(result.errors) > failures:
            print(self.masters.logs(), file=sys.stderr)
        return outcome

    def single_process(self, name: str, *flags: str, scene: str = "builtin:cornell"):
        """`epr render --single-process` of JOB (with more flags, e.g. a camera): its counts and pathtrace."""
        prefix = os.path.join(self.tmp, "ref", name)
        r = base.epr("render", scene, "--single-process", *JOB_FLAGS, *flags, "--out", prefix, timeout=120)
        self.assertEqual(r.returncode, 0, r.stderr)
        out = {}
        for kind in ("counts", "pathtrace"):
            with open(f"{prefix}.{kind}.exr", "rb") as f:
                out[kind] = eprfarm.decode_exr(f.read())
        return out

    def assert_same_render(self, ours, reference, what: str):
        import numpy as np

        for kind in ("counts", "pathtrace"):
            self.assertEqual(ours[kind].shape, reference[kind].shape, what)
            self.assertTrue(np.array_equal(ours[kind], reference[kind]), f"{what}: {kind} differs")

    def wait_idle(self):
        """Until neither master has samples left to trace (the load submissions compare)."""
        idle = lambda: all(m.master_info().samples_left == 0 for m in self.client.masters())  # noqa: E731
        self.assertTrue(base.wait_for(idle, 60, 0.2), "a master stayed busy")


class MultiMasterTest(FarmCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="epr-python-multi-")
        cls.masters = TwoMasters(cls.tmp)
        cls.client = eprfarm.Client(cls.masters.list)
        cls.one = [eprfarm.Client(a) for a in cls.masters.addresses]  # each master alone

    @classmethod
    def tearDownClass(cls):
        for c in [cls.client, *cls.one]:
            c.close()
        cls.masters.stop()
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def test_list_forms(self):
        self.assertEqual(self.client.targets, self.masters.addresses)
        self.assertTrue(self.client.several)
        as_list = eprfarm.Client(list(reversed(self.masters.addresses)))
        self.assertEqual(as_list.targets, list(reversed(self.masters.addresses)))
        as_list.close()
        saved = os.environ.get("EPR_MASTER")
        os.environ["EPR_MASTER"] = self.masters.list
        try:
            from_env = eprfarm.Client()
            self.assertEqual(from_env.targets, self.masters.addresses)
            self.assertEqual({m.master_info().name for m in from_env.masters()}, {"m1", "m2"})
            from_env.close()
        finally:
            if saved is None:
                del os.environ["EPR_MASTER"]
            else:
                os.environ["EPR_MASTER"] = saved
        for bad in ("a:1,,b:2", "nocolon", "a:port"):
            with self.assertRaises(ValueError):
                eprfarm.Client(bad)
        # A name with several addresses: one master each, by address, the certificate checked against the name.
        resolved = eprfarm.master_endpoints("farm:7,10.0.0.9:7", lambda host: ["10.0.0.2", "fd00::1", "10.0.0.1"])
        self.assertEqual([(e.target, e.name, e.tls_server_name) for e in resolved],
                         [("ipv4:10.0.0.1:7", "farm:7 (10.0.0.1)", "farm"),
                          ("ipv4:10.0.0.2:7", "farm:7 (10.0.0.2)", "farm"),
                          ("ipv6:[fd00::1]:7", "farm:7 (fd00::1)", "farm"),
                          ("10.0.0.9:7", "10.0.0.9:7", "")])
        self.assertEqual(len(eprfarm.master_endpoints("localhost:7,localhost:7")), 1)
        self.assertEqual(eprfarm.job_id_master("m1.j000001-beef"), "m1")
        self.assertEqual(eprfarm.job_id_master("j000001-beef"), "")

    def test_submit_find_fetch_cancel(self):
        self.wait_idle()
        busy = self.one[0].submit("builtin:cornell", name="busy", **LONG)  # m1 gets work to do
        self.assertTrue(base.wait_for(lambda: self.one[0].status(busy).state == "RUNNING", 30))
        job = self.client.submit("builtin:cornell", **JOB)
        self.assertTrue(job.startswith("m2."), job)  # the least loaded master
        self.assertEqual(self.client.cancel(busy).state, "CANCELLED")  # found on m1 by its name
        self.assertEqual(self.one[0].status(busy).state, "CANCELLED")
        with self.assertRaises(eprfarm.RpcError) as ctx:
            self.one[0].status(job)
        self.assertEqual(ctx.exception.code, grpc.StatusCode.NOT_FOUND)  # the job is on m2 alone

        reversed_client = eprfarm.Client(list(reversed(self.masters.addresses)))
        for c in (self.client, reversed_client):
            self.assertEqual(c.status(job).id, job)
            self.assertEqual(c.wait(job).state, "DONE")
        files = reversed_client.get(job, out=os.path.join(self.tmp, "py", "job"))
        self.assertEqual([f.kind for f in files][:3], ["exr", "png", "json"])
        self.assertTrue(all(os.path.getsize(f.path) == f.bytes for f in files))
        arrays = self.client.get(job, as_arrays=True)
        self.assertEqual(arrays["combined"].shape, (40, 48, 3))
        with open(files[0].path, "rb") as f:
            self.assertTrue((eprfarm.decode_exr(f.read()) == arrays["combined"]).all())
        counts = self.client.fetch_bytes(job, "counts.exr").data
        self.assertEqual(counts, self.one[1].fetch_bytes(job, "counts.exr").data)
        self.assert_same_render(arrays, self.single_process("job"), "job via both masters")
        reversed_client.close()

        # An id whose master no one answers to, and one without a master name: asked of every master.
        for unknown in ("m3.j999999-none", "j999999-none"):
            with self.assertRaises(eprfarm.RpcError) as ctx:
                self.client.status(unknown)
            self.assertEqual(ctx.exception.code, grpc.StatusCode.NOT_FOUND)
            self.assertIn(f"no master knows job {unknown}", str(ctx.exception))
            self.assertIn("m1 (", str(ctx.exception))
            self.assertIn("m2 (", str(ctx.exception))

    def test_list_merges_both_masters(self):
        on = [self.one[i].submit("builtin:cornell", name=f"list-{i}", **LONG) for i in (0, 1)]
        for i, job in enumerate(on):
            self.assertTrue(job.startswith(f"m{i + 1}."), job)
            self.assertEqual(self.client.cancel(job).state, "CANCELLED")
        jobs = self.client.list()
        self.assertEqual(jobs.failed, {})
        by_id = {j.id: j for j in jobs}
        for i, job in enumerate(on):
            self.assertEqual(by_id[job].master, self.masters.addresses[i])
        self.assertEqual({j.master for j in jobs}, set(self.masters.addresses))
        for i in (0, 1):  # every job of each master, and only those
            listed_there = {j.id for j in jobs if j.master == self.masters.addresses[i]}
            self.assertEqual(listed_there, {j.id for j in self.one[i].list()})
        times = [j.proto.submitted_unix_ms for j in jobs]
        self.assertEqual(times, sorted(times, reverse=True))
        newest = self.client.list(limit=1)
        self.assertEqual([j.id for j in newest], [jobs[0].id])
        cancelled = {j.id for j in self.client.list(states=["cancelled"])}
        self.assertTrue(set(on) <= cancelled)
        self.assertNotIn(on[0], {j.id for j in self.client.list(states=["done", "queued"])})

    def test_frames_spread_over_both_masters(self):
        scene = os.path.join(self.tmp, "walk.json")
        with open(scene, "w") as f:
            f.write(ANIMATION)
        self.wait_idle()
        batch, ids = self.client.submit_frames(scene, "1-4", **JOB)
        # Equal loads: frame 1 to the first master, then each frame to the one with less work.
        self.assertEqual([j.split(".")[0] for j in ids], ["m1", "m2", "m1", "m2"])
        jobs = sorted(self.client.list(batch=batch), key=lambda s: s.frame)
        self.assertEqual([(s.id, s.frame, s.name, s.proto.batch_frames) for s in jobs],
                         [(ids[f - 1], f, f"walk.{f:04d}", 4) for f in (1, 2, 3, 4)])
        self.assertEqual([s.master for s in jobs], [self.masters.addresses[i] for i in (0, 1, 0, 1)])
        self.assertEqual(len({s.proto.scene.content_hash for s in jobs}), 1)  # uploaded once to each
        for i in (0, 1):
            self.assertEqual({s.frame for s in self.one[i].list(batch=batch)}, {1 + i, 3 + i})
        r = base.epr("list", "--batch", batch, "--master", self.masters.list)
        self.assertEqual(r.returncode, 0, r.stderr)
        self.assertTrue(all(j in r.stdout for j in ids), r.stdout)
        for s in jobs:
            self.assertEqual(self.client.wait(s.id).state, "DONE")
            cam = s.proto.effective.camera
            vec = lambda v: f"{v.x:.9g},{v.y:.9g},{v.z:.9g}"  # noqa: E731
            reference = self.single_process(
                f"frame-{s.frame}", "--eye", vec(cam.eye), "--look", vec(cam.look), "--up", vec(cam.up),
                "--fov", f"{cam.fov_y_degrees:.9g}",
            )
            self.assert_same_render(self.client.get(s.id, as_arrays=True), reference, f"frame {s.frame}")
        self.assertAlmostEqual(jobs[3].proto.effective.camera.fov_y_degrees, 44, places=4)


class MasterDownTest(TwoMastersCase, FarmCase):
    """One master stopped: list reports it and lists the other's jobs, which still work."""

    PREFIX = "epr-python-multi-down-"
    CLIENT_TIMEOUT = 5

    def test_one_master_down(self):
        small = {"width": 16, "height": 16, "spp": 2, "mode": "pt"}
        jobs = []
        for address in self.masters.addresses:
            with eprfarm.Client(address) as one:
                jobs.append(one.submit("builtin:cornell", **small))
        for job in jobs:
            self.assertEqual(self.client.wait(job).state, "DONE")
        self.masters.farms[0].kill_master()

        with self.assertLogs("eprfarm", "WARNING") as logs:
            listed = self.client.list()
        self.assertEqual([j.id for j in listed], [jobs[1]])
        self.assertEqual(list(listed.failed), [self.masters.addresses[0]])
        self.assertTrue(listed.failed[self.masters.addresses[0]].unreachable)
        # Named by address, or as "name (address)" once the client has learnt the name.
        away = self.masters.addresses[0]
        self.assertTrue(any("did not answer" in line and (f"master {away} " in line or f"({away}) did not" in line)
                            for line in logs.output), logs.output)
        # The other master's job is found by its name and fetched.
        self.assertEqual(self.client.status(jobs[1]).state, "DONE")
        self.assertEqual(self.client.get(jobs[1], as_arrays=True)["combined"].shape, (16, 16, 3))
        # The stopped master's job: not found elsewhere, and the error says where it may be.
        with self.assertRaises(eprfarm.RpcError) as ctx:
            self.client.status(jobs[0])
        self.assertTrue(ctx.exception.unreachable)
        self.assertIn(f"may be on {self.masters.addresses[0]}", str(ctx.exception))
        # New work goes to the master that is up, batches too.
        with self.assertLogs("eprfarm", "WARNING"):
            job = self.client.submit("builtin:cornell", **small)
        self.assertTrue(job.startswith("m2."), job)
        with self.assertLogs("eprfarm", "WARNING"):
            _, ids = self.client.submit_frames("builtin:cornell", "1-2", **small)
        self.assertEqual([j.split(".")[0] for j in ids], ["m2", "m2"])
        self.assertEqual(self.client.wait(job).state, "DONE")

        self.masters.farms[1].kill_master()
        with self.assertRaises(eprfarm.RpcError) as ctx, self.assertLogs("eprfarm", "WARNING"):
            self.client.list()
        self.assertTrue(ctx.exception.unreachable)


class SecureMastersTest(unittest.TestCase):
    """Two masters over TLS with one token: the client's token and CA apply to both."""

    TOKEN = "multi-master-token"

    def setUp(self):
        self.tmp = tempfile.mkdtemp(prefix="epr-python-multi-tls-")
        cert, key, token = (os.path.join(self.tmp, n) for n in ("cert.pem", "key.pem", "token"))
        base.subprocess.run(
            ["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", key, "-out", cert, "-days", "1",
             "-subj", "/CN=localhost", "-addext", "subjectAltName=DNS:localhost,IP:127.0.0.1"],
            check=True,
            capture_output=True,
        )
        with open(token, "w") as f:
            f.write(self.TOKEN + "\n")
        os.chmod(token, 0o600)
        self.cert = cert
        self.farms = []
        for name in ("s1", "s2"):
            os.makedirs(os.path.join(self.tmp, name))
            args = ["--name", name, "--tls-cert", cert, "--tls-key", key, "--token-file", token]
            self.farms.append(base.Farm(os.path.join(self.tmp, name), args, worker=False))
        self.list = ",".join(f.address for f in self.farms)

    def tearDown(self):
        for f in self.farms:
            f.stop()
        shutil.rmtree(self.tmp, ignore_errors=True)

    def test_token_and_tls_on_every_master(self):
        with eprfarm.Client(self.list, token=self.TOKEN, ca_file=self.cert) as c:
            self.assertEqual(sorted(m.master_info().name for m in c.masters()), ["s1", "s2"])
            first = c.submit("builtin:cornell", width=8, height=8, spp=1000, mode="pt")
            second = c.submit("builtin:cornell", width=8, height=8, spp=1000, mode="pt")
            # No worker: the first job's samples stay queued, so the second goes to the other master.
            self.assertEqual(sorted(j.split(".")[0] for j in (first, second)), ["s1", "s2"])
            self.assertEqual({j.id for j in c.list()}, {first, second})
            for job in (first, second):
                self.assertEqual(c.cancel(job).state, "CANCELLED")
        with eprfarm.Client(self.list, token="wrong", ca_file=self.cert) as c:
            with self.assertRaises(eprfarm.RpcError) as ctx, self.assertLogs("eprfarm", "WARNING"):
                c.list()
            self.assertEqual(ctx.exception.code, grpc.StatusCode.UNAUTHENTICATED)
        with eprfarm.Client(self.list, token=self.TOKEN, timeout=5) as c:  # plain text to TLS masters
            with self.assertRaises(eprfarm.RpcError) as ctx, self.assertLogs("eprfarm", "WARNING"):
                c.submit("builtin:cornell", width=8, height=8, spp=1)
            self.assertTrue(ctx.exception.unreachable)


def write_glb(gltf: str, out: str) -> None:
    """`gltf` (one buffer in a .bin file) as a self-contained .glb: the buffer becomes its BIN chunk."""
    with open(gltf) as f:
        doc = json.load(f)
    with open(os.path.join(os.path.dirname(gltf), doc["buffers"][0].pop("uri")), "rb") as f:
        binary = f.read()
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    binary += b"\0" * (-len(binary) % 4)
    le32 = lambda v: v.to_bytes(4, "little")  # noqa: E731
    total = 12 + 8 + len(text) + 8 + len(binary)
    with open(out, "wb") as f:
        f.write(b"glTF" + le32(2) + le32(total) + le32(len(text)) + b"JSON" + text + le32(len(binary)) + b"BIN\0" + binary)


class GltfAndSamplerTest(FarmCase):
    """glTF scenes and the sampler, submitted through the client over both masters (farm.py)."""

    GLTF = os.path.join(base.SOURCE_DIR, "scenes", "cornell-box.gltf")

    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="epr-python-gltf-")
        cls.masters = TwoMasters(cls.tmp)
        cls.client = eprfarm.Client(cls.masters.list)

    @classmethod
    def tearDownClass(cls):
        cls.client.close()
        cls.masters.stop()
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def render(self, scene: str, **options):
        job = self.client.submit(scene, **JOB, **options)
        status = self.client.wait(job)
        self.assertEqual(status.state, "DONE", status.error_message)
        return self.client.get(job, as_arrays=True)

    def epr_hash(self, scene: str) -> str:
        """The content hash of `scene` as `epr submit` bundles it (the job cancelled at once)."""
        r = base.epr("submit", scene, "--width", "16", "--height", "16", "--spp", "1", "--master",
                     self.masters.addresses[0])
        self.assertEqual(r.returncode, 0, r.stderr)
        return self.client.cancel(r.stdout.strip()).proto.scene.content_hash

    def test_gltf_renders_as_epr_renders_it(self):
        bundle = eprfarm.bundle_scene(self.GLTF)
        self.assertEqual(bundle.entry_path, "cornell-box.gltf")
        self.assertEqual([p for p, _ in bundle.files], ["cornell-box.bin", "cornell-box.gltf"])
        self.assertEqual(bundle.content_hash(), self.epr_hash(self.GLTF))
        self.assert_same_render(self.render(self.GLTF), self.single_process("gltf", scene=self.GLTF), "glTF")

        # A .glb is one file; a scene JSON naming the glTF brings the glTF's files along.
        folder = os.path.join(self.tmp, "glb")
        os.makedirs(folder)
        glb = os.path.join(folder, "box.glb")
        write_glb(self.GLTF, glb)
        with open(os.path.join(folder, "unused.bin"), "wb") as f:
            f.write(b"not part of the scene")
        self.assertEqual([p for p, _ in eprfarm.bundle_scene(glb).files], ["box.glb"])
        self.assertEqual(eprfarm.bundle_scene(glb).content_hash(), self.epr_hash(glb))
        for name in ("cornell-box.gltf", "cornell-box.bin"):
            shutil.copy(os.path.join(base.SOURCE_DIR, "scenes", name), os.path.join(self.tmp, "glb", name))
        scene_json = os.path.join(folder, "scene.json")
        with open(scene_json, "w") as f:
            f.write('// the glTF box\n{ "obj": "cornell-box.gltf", "camera": {"fov": 40} }\n')
        bundle = eprfarm.bundle_scene(scene_json)
        self.assertEqual([p for p, _ in bundle.files], ["cornell-box.bin", "cornell-box.gltf", "scene.json"])
        self.assertEqual(bundle.content_hash(), self.epr_hash(scene_json))

    def test_sampler(self):
        import numpy as np

        independent = self.render("builtin:cornell", sampler="independent")
        self.assert_same_render(independent, self.single_process("independent", "--sampler", "independent"),
                                "sampler independent")
        default = self.render("builtin:cornell")
        self.assert_same_render(default, self.single_process("sobol", "--sampler", "sobol-burley"), "default sampler")
        self.assertFalse(np.array_equal(default["pathtrace"], independent["pathtrace"]),
                         "the default sampler renders as independent does")
        with self.assertRaises(ValueError) as ctx:
            self.client.submit("builtin:cornell", sampler="halton", **JOB)
        self.assertIn("sampler 'halton' is not one of sobol-burley, independent", str(ctx.exception))

    def test_gltf_refusals(self):
        folder = os.path.join(self.tmp, "refusals", "scene")
        os.makedirs(os.path.join(folder, "sub"))
        with open(os.path.join(folder, "..", "outside.bin"), "wb") as f:
            f.write(b"\0" * 64)
        os.symlink(os.path.join(folder, "..", "outside.bin"), os.path.join(folder, "link.bin"))

        def gltf(name: str, buffers=(), images=()) -> str:
            path = os.path.join(folder, name)
            doc = {"asset": {"version": "2.0"}, "buffers": [{"uri": u, "byteLength": 64} for u in buffers],
                   "images": [{"uri": u} for u in images]}
            with open(path, "w") as f:
                json.dump(doc, f)
            return path

        def refused(scene: str, *parts: str, epr_too: bool = True) -> None:
            with self.assertRaises(ValueError) as ctx:
                eprfarm.bundle_scene(scene)
            self.assertIsInstance(ctx.exception, eprfarm.SceneError)
            for part in parts:
                self.assertIn(part, str(ctx.exception))
            if epr_too:  # `epr submit` refuses it with the same words, before it connects
                r = base.epr("submit", scene, "--master", self.masters.addresses[0])
                self.assertNotEqual(r.returncode, 0)
                self.assertIn(parts[-1], r.stderr)

        absolute = os.path.join(folder, "..", "outside.bin")
        refused(gltf("abs.gltf", [absolute]), "abs.gltf: buffers[0]: ",
                f"buffers[0]: uri '{absolute}' is an absolute path; scene files must name files inside the scene folder")
        refused(gltf("up.gltf", ["data:application/octet-stream;base64,AAAA", "../outside.bin"]), "up.gltf: ",
                "buffers[1]: uri '../outside.bin' leaves the scene folder")
        refused(gltf("sub/image.gltf", images=["../../outside.bin"]), "image.gltf: ",
                "images[0]: uri '../../outside.bin' leaves the scene folder")
        refused(gltf("pct.gltf", ["%2E%2E/outside.bin"]), "pct.gltf: ", "buffers[0]: uri '../outside.bin' leaves")
        refused(gltf("link.gltf", ["link.bin"]), "link.gltf: ", "buffers[0]: uri 'link.bin' leaves the scene folder")
        refused(gltf("missing.gltf", ["missing.bin"]), "missing.gltf: ", "buffers[0]: uri 'missing.bin' does not exist")
        refused(gltf("abs-image.gltf", images=["/etc/hostname"]), "abs-image.gltf: ",
                "images[0]: uri '/etc/hostname' is an absolute path", epr_too=False)
        # In a scene JSON the glTF is named; in a .glb the uris of its JSON chunk are checked as well.
        with open(os.path.join(folder, "scene.json"), "w") as f:
            f.write('{"obj": "up.gltf"}')
        refused(os.path.join(folder, "scene.json"), "up.gltf: ", "buffers[1]: uri '../outside.bin' leaves")
        with open(os.path.join(folder, "out.json"), "w") as f:
            f.write('{"obj": "../x.gltf"}')
        refused(os.path.join(folder, "out.json"), "out.json", "obj '../x.gltf' leaves the scene folder", epr_too=False)
        with open(os.path.join(folder, "up.glb"), "wb") as f:
            text = json.dumps({"asset": {"version": "2.0"}, "buffers": [{"uri": "../outside.bin", "byteLength": 64}]})
            text = text.encode() + b" " * (-len(text) % 4)
            f.write(b"glTF" + (2).to_bytes(4, "little") + (20 + len(text)).to_bytes(4, "little")
                    + len(text).to_bytes(4, "little") + b"JSON" + text)
        refused(os.path.join(folder, "up.glb"), "up.glb: ", "buffers[0]: uri '../outside.bin' leaves the scene folder")
        # data: URIs stay in the glTF; an image file that is not there is the master's to name.
        inline = gltf("inline.gltf", ["data:application/octet-stream;base64,AAAA"], ["gone.png"])
        self.assertEqual([p for p, _ in eprfarm.bundle_scene(inline).files], ["inline.gltf"])


if __name__ == "__main__":
    sys.exit(base.main())
