#!/usr/bin/python3
"""The Python client (client/python) against a real epr-master and epr-worker on loopback.

    test_client.py --package-dir BUILD/client/python --epr EPR --master EPR_MASTER --worker EPR_WORKER

--package-dir holds the eprfarm package with its generated stubs (the build tree's copy, CMake
target eprfarm_python). Checks: a render submitted, watched and fetched through the package has the
pixels of the same job submitted with `epr` (same seed); file scenes are bundled as `epr` bundles
them (same content hash, inline and uploaded); cancel; the master's errors (INVALID_ARGUMENT,
NOT_FOUND, UNAUTHENTICATED with their reasons; UNAVAILABLE); token rules. test_client_checks.py
checks the arguments, the scene sandbox, batches as a whole and `pip install`. Run with Debian's
/usr/bin/python3 (python3-grpcio, python3-protobuf, python3-numpy, python3-openimageio).
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import unittest
from typing import List, Optional

SOURCE_DIR = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", "..", ".."))
ARGS = argparse.Namespace()

# The job both clients render: small, a few rounds, a seed other than the default.
JOB = {"width": 48, "height": 40, "spp": 8, "seed": 7, "mode": "skip"}
JOB_FLAGS = ["--width", "48", "--height", "40", "--spp", "8", "--seed", "7", "--mode", "skip"]


def wait_for(predicate, timeout: float, interval: float = 0.05):
    """predicate()'s first true value within `timeout` seconds, else None."""
    end = time.monotonic() + timeout
    while True:
        value = predicate()
        if value or time.monotonic() > end:
            return value
        time.sleep(interval)


class Process:
    """A program running in the background, its output in a log file."""

    def __init__(self, argv: List[str], log_path: str, env: Optional[dict] = None):
        self.log_path = log_path
        self._log = open(log_path, "wb")
        self.proc = subprocess.Popen(argv, stdout=self._log, stderr=subprocess.STDOUT, env=env)

    def output(self) -> str:
        with open(self.log_path, "rb") as f:
            return f.read().decode(errors="replace")

    def running(self) -> bool:
        return self.proc.poll() is None

    def stop(self) -> None:
        if self.running():
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._log.close()


class Farm:
    """epr-master on a free loopback port with a temporary --state-dir, and optionally an epr-worker."""

    def __init__(self, folder: str, master_args: List[str] = (), worker: bool = True):
        self.folder = folder
        self.master_args = list(master_args)
        self.processes: List[Process] = []
        self.master = self.start_master("127.0.0.1:0")
        if worker:
            self._start(
                [ARGS.worker, "--master", self.address, "--threads", "2", "--cache-dir", self.path("cache")],
                "worker.log",
            )

    def path(self, name: str) -> str:
        return os.path.join(self.folder, name)

    def _start(self, argv: List[str], log: str) -> Process:
        p = Process(argv, self.path(log))
        self.processes.append(p)
        return p

    def start_master(self, listen: str) -> Process:
        """Starts epr-master on `listen` (port 0: a free one) and waits until it says its port."""
        runs = sum(1 for p in self.processes if os.path.basename(p.log_path).startswith("master"))
        master = self._start(
            [ARGS.master, "--listen", listen, "--http", "127.0.0.1:0", "--state-dir", self.path("state")]
            + self.master_args,
            f"master-{runs}.log",
        )
        match = wait_for(lambda: re.search(r"epr-master listening on port ([0-9]+)", master.output()), 20)
        if not match:
            self.stop()
            raise RuntimeError(f"epr-master did not start:\n{master.output()}")
        self.address = f"127.0.0.1:{match.group(1)}"
        return master

    def kill_master(self) -> None:
        """Kills the master with SIGKILL: no goodbye to anyone."""
        self.master.proc.kill()
        self.master.proc.wait()

    def restart_master(self) -> None:
        """Kills the master and starts it again on the same port and state folder."""
        self.kill_master()
        self.master = self.start_master(self.address)

    def logs(self) -> str:
        return "\n".join(f"--- {os.path.basename(p.log_path)}\n{p.output()[-4000:]}" for p in self.processes)

    def stop(self) -> None:
        for p in reversed(self.processes):
            p.stop()


def epr(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    """Runs the C++ client to its end."""
    return subprocess.run([ARGS.epr, *args], capture_output=True, text=True, timeout=timeout)


def free_port() -> int:
    """A loopback port nothing listens on (bound, then released)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def write_textured_scene(folder: str) -> str:
    """The Cornell box OBJ with its MTL in `folder`, one material textured from tex/checker.png through
    map_Kd with texture options, plus files the scene does not name. Returns the OBJ's path."""
    import numpy as np
    import OpenImageIO as oiio

    src = os.path.join(SOURCE_DIR, "scenes", "cornell-box")
    os.makedirs(os.path.join(folder, "tex"))
    shutil.copy(os.path.join(src, "CornellBox-Original.obj"), os.path.join(folder, "box.obj"))
    with open(os.path.join(src, "CornellBox-Original.mtl")) as f:
        mtl = f.read()
    # The first material gets a texture, named with options that take words before the file name.
    mtl = re.sub(r"(newmtl [^\n]*\n)", r"\1map_Kd -s 1 1 1 -clamp on tex/checker.png # a comment\n", mtl, count=1)
    with open(os.path.join(folder, "CornellBox-Original.mtl"), "w") as f:
        f.write(mtl)
    checker = np.indices((8, 8)).sum(axis=0) % 2
    pixels = np.repeat(checker[:, :, None], 3, axis=2).astype(np.uint8) * 200 + 20
    out = oiio.ImageOutput.create(os.path.join(folder, "tex", "checker.png"))
    out.open(os.path.join(folder, "tex", "checker.png"), oiio.ImageSpec(8, 8, 3, "uint8"))
    out.write_image(pixels)
    out.close()
    with open(os.path.join(folder, "unused.png"), "wb") as f:
        f.write(b"not part of the scene")
    return os.path.join(folder, "box.obj")


class FarmClientTest(unittest.TestCase):
    """Tests sharing one Farm (with a worker unless WORKER is false) in a temporary folder named PREFIX...,
    and an eprfarm.Client of its master."""

    PREFIX = "epr-python-client-"
    WORKER = True

    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix=cls.PREFIX)
        cls.farm = Farm(cls.tmp, worker=cls.WORKER)
        cls.client = eprfarm.Client(cls.farm.address)

    @classmethod
    def tearDownClass(cls):
        cls.client.close()
        cls.farm.stop()
        shutil.rmtree(cls.tmp, ignore_errors=True)


class ClusterTest(FarmClientTest):
    """A master and a worker without a token."""

    def run(self, result=None):
        # On a failure, the programs' logs help more than the assertion alone.
        failures = len(result.failures) + len(result.errors) if result else 0
        outcome = super().run(result)
        if result and len(result.failures) + len(result.errors) > failures:
            print(self.farm.logs(), file=sys.stderr)
        return outcome

    def test_render_matches_epr(self):
        import numpy as np

        job = self.client.submit("builtin:cornell", **JOB)
        statuses = list(self.client.watch(job))
        last = statuses[-1]
        self.assertEqual(last.state, "DONE", last.error_message)
        self.assertTrue(last.terminal)
        self.assertTrue(all(not s.terminal for s in statuses[:-1]))
        self.assertEqual((last.width, last.height, last.target_spp, last.mode), (48, 40, 8, "skip"))
        self.assertEqual(last.proto.seed, 7)
        self.assertEqual(last.percent, 100.0)
        self.assertGreaterEqual(last.spp_min, 8)
        rounds = [s.round for s in statuses]
        self.assertEqual(rounds, sorted(rounds))
        self.assertGreater(last.round, 1)
        self.assertGreater(last.paths_traced, 0)
        percents = [s.percent for s in statuses]
        self.assertEqual(percents, sorted(percents))

        files = self.client.get(job, out=os.path.join(self.tmp, "py", "cornell"))
        self.assertEqual(
            [f.kind for f in files],
            ["exr", "png", "json", "pathtrace.exr", "counts.exr", "reprojection.exr", "samples.exr", "samples.png"],
        )
        for f in files:
            self.assertEqual(os.path.getsize(f.path), f.bytes, f.path)
            self.assertEqual((f.round, f.partial), (last.round, False))
        self.assertEqual([n for n in os.listdir(os.path.join(self.tmp, "py")) if ".part-" in n], [])
        arrays = self.client.get(job, as_arrays=True)
        self.assertEqual(sorted(arrays), ["combined", "counts", "pathtrace", "reprojection", "samples"])
        self.assertEqual(arrays["combined"].shape, (40, 48, 3))
        self.assertEqual(arrays["counts"].shape, (40, 48, 2))
        self.assertEqual(arrays["combined"].dtype, np.float32)
        self.assertTrue(np.isfinite(arrays["combined"]).all())
        self.assertGreater(float(arrays["combined"].mean()), 0.01)  # the box is lit
        self.assertTrue((arrays["counts"][:, :, 0] >= 1).all())  # every pixel traced a path (min_paths 1)
        with open(files[0].path, "rb") as f:
            self.assertTrue(np.array_equal(eprfarm.decode_exr(f.read()), arrays["combined"]))

        # The same job through the C++ client: the same pixels, counts and PNG.
        prefix = os.path.join(self.tmp, "cpp", "cornell")
        r = epr("submit", "builtin:cornell", *JOB_FLAGS, "--master", self.farm.address, "--wait", "--out", prefix)
        self.assertEqual(r.returncode, 0, r.stderr)
        for f in files:
            with open(prefix + f.path[len(os.path.join(self.tmp, "py", "cornell")) :], "rb") as cpp:
                theirs = cpp.read()
            if f.kind.endswith("exr"):
                ours = arrays[{"exr": "combined"}.get(f.kind, f.kind.split(".")[0])]
                self.assertTrue(np.array_equal(eprfarm.decode_exr(theirs), ours), f.kind)
            elif f.kind.endswith("png"):
                with open(f.path, "rb") as mine:
                    self.assertEqual(mine.read(), theirs, f.kind)

    def test_frames_match_epr(self):
        folder = os.path.join(self.tmp, "frames")
        os.makedirs(folder, exist_ok=True)
        scene = os.path.join(folder, "walk.json")
        with open(scene, "w") as f:
            f.write(
                '{"builtin": "cornell", "animation": {"camera": [\n'
                '  {"frame": 1, "eye": [0, 1, 3.9]},\n'
                '  {"frame": 3, "eye": [0.4, 1.2, 3.5], "look": [0.2, 1, 0], "fov": 50}]}}\n'
            )
        batch, ids = self.client.submit_frames(scene, "1-3", **JOB)
        self.assertEqual(len(ids), 3)
        jobs = sorted(self.client.list(batch=batch), key=lambda s: s.frame)
        self.assertEqual([(s.batch_id, s.frame, s.name) for s in jobs],
                         [(batch, f, f"walk.{f:04d}") for f in (1, 2, 3)])
        self.assertEqual(len({s.proto.scene.content_hash for s in jobs}), 1)
        self.assertEqual(len(self.client.list(batch="b-none")), 0)
        # The same frames through the C++ client, which evaluates the cameras itself: the same cameras,
        # and the same pixels.
        r = epr("submit", scene, *JOB_FLAGS, "--frames", "1-3", "--master", self.farm.address)
        self.assertEqual(r.returncode, 0, r.stderr)
        theirs = sorted(self.client.list(batch=r.stdout.strip()), key=lambda s: s.frame)
        self.assertEqual(len(theirs), 3)
        for ours, cpp in zip(jobs, theirs):
            self.assertEqual(ours.proto.effective.camera, cpp.proto.effective.camera, ours.frame)
        half = jobs[1].proto.effective.camera.eye
        self.assertAlmostEqual(half.x, 0.2, places=6)
        for ours, cpp in zip(jobs, theirs):
            for job in (ours.id, cpp.id):
                self.assertEqual(list(self.client.watch(job))[-1].state, "DONE")
            a = self.client.get(ours.id, as_arrays=True)
            b = self.client.get(cpp.id, as_arrays=True)
            self.assertTrue((a["counts"] == b["counts"]).all(), ours.frame)
            self.assertTrue((a["pathtrace"] == b["pathtrace"]).all(), ours.frame)
        with self.assertRaises(ValueError):
            self.client.submit_frames(scene, "3-1", **JOB)
        with self.assertRaises(ValueError):
            self.client.submit_frames(scene, "1-2", eye=(0, 1, 3), **JOB)

    def test_sky_image_bundled_as_epr_does(self):
        # A scene JSON's "environment" image travels in the bundle, as `epr submit` sends it.
        scene = os.path.join(SOURCE_DIR, "scenes", "sky", "courtyard.json")
        bundle = eprfarm.bundle_scene(scene)
        self.assertEqual([p for p, _ in bundle.files],
                         ["courtyard.json", "courtyard.mtl", "courtyard.obj", "sky.exr"])
        r = epr("submit", scene, "--width", "16", "--height", "16", "--spp", "1", "--master", self.farm.address)
        self.assertEqual(r.returncode, 0, r.stderr)
        status = self.client.cancel(r.stdout.strip())
        self.assertEqual(status.proto.scene.content_hash, bundle.content_hash())

    def test_environment_and_sun_as_epr_sends_them(self):
        # A sky image with a built-in scene travels beside a generated scene JSON, and a sun goes in the
        # JobSpec: the same bundle, the same lighting and the same pixels as `epr submit --env --sun`.
        sky = os.path.join(SOURCE_DIR, "scenes", "sky", "sky.exr")
        sun = (0.3, 1, 0.4, 5, 2)
        job = self.client.submit("builtin:cornell", environment=sky, sun=sun, **JOB)
        r = epr("submit", "builtin:cornell", *JOB_FLAGS, "--env", sky, "--sun", "0.3,1,0.4,5,2",
                "--master", self.farm.address)
        self.assertEqual(r.returncode, 0, r.stderr)
        theirs = r.stdout.strip()
        strong = self.client.submit("builtin:cornell", environment=sky, environment_strength=3, sun=sun, **JOB)
        plain = self.client.submit("builtin:cornell", **JOB)
        for j in (job, theirs, strong, plain):
            self.assertEqual(list(self.client.watch(j))[-1].state, "DONE")
        ours_status, their_status = self.client.status(job), self.client.status(theirs)
        self.assertEqual(ours_status.proto.scene.content_hash, their_status.proto.scene.content_hash)
        self.assertEqual(ours_status.proto.effective.sun, their_status.proto.effective.sun)
        self.assertEqual(ours_status.proto.effective.environment, their_status.proto.effective.environment)
        self.assertEqual(ours_status.proto.effective.environment.image, "sky.exr")
        self.assertEqual(self.client.status(strong).proto.effective.environment.strength, 3)
        a, b = self.client.get(job, as_arrays=True), self.client.get(theirs, as_arrays=True)
        self.assertTrue((a["pathtrace"] == b["pathtrace"]).all() and (a["counts"] == b["counts"]).all())
        brighter = self.client.get(strong, as_arrays=True)["pathtrace"].mean()
        unlit = self.client.get(plain, as_arrays=True)["pathtrace"].mean()
        self.assertGreater(float(brighter), float(a["pathtrace"].mean()))  # the sky x 3
        self.assertGreater(float(a["pathtrace"].mean()), float(unlit))  # the sun and the sky add light

        # A constant colour, as --env R,G,B: bit for bit.
        grey = self.client.submit("builtin:cornell", environment=(0.5, 0.25, 1), **JOB)
        r = epr("submit", "builtin:cornell", *JOB_FLAGS, "--env", "0.5,0.25,1", "--master", self.farm.address)
        self.assertEqual(r.returncode, 0, r.stderr)
        for j in (grey, r.stdout.strip()):
            self.assertEqual(list(self.client.watch(j))[-1].state, "DONE")
        a, b = self.client.get(grey, as_arrays=True), self.client.get(r.stdout.strip(), as_arrays=True)
        self.assertTrue((a["pathtrace"] == b["pathtrace"]).all() and (a["counts"] == b["counts"]).all())

        # A file scene's sky must lie in the scene's folder; malformed values are refused with a reason.
        courtyard = os.path.join(SOURCE_DIR, "scenes", "sky", "courtyard.json")
        bundle, rel = eprfarm.bundle_scene_with_image(courtyard, sky)
        self.assertEqual(rel, "sky.exr")
        self.assertEqual(bundle.content_hash(), eprfarm.bundle_scene(courtyard).content_hash())
        scene = write_textured_scene(os.path.join(self.tmp, "sky-outside"))
        with self.assertRaisesRegex(eprfarm.SceneError, "lies outside the scene's folder"):
            self.client.submit(scene, environment=sky, **JOB)
        with self.assertRaisesRegex(eprfarm.SceneError, "does not exist"):
            self.client.submit("builtin:cornell", environment=os.path.join(self.tmp, "none.exr"), **JOB)
        with self.assertRaisesRegex(ValueError, "a colour"):
            self.client.submit("builtin:cornell", environment=(1, 2), **JOB)
        with self.assertRaisesRegex(ValueError, "direction towards the sun"):
            self.client.submit("builtin:cornell", sun=(0, 1), **JOB)
        with self.assertRaisesRegex(eprfarm.RpcError, "strength"):
            self.client.submit("builtin:cornell", environment=1, environment_strength=-1, **JOB)
        with self.assertRaisesRegex(eprfarm.RpcError, "sun direction"):
            self.client.submit("builtin:cornell", sun=(0, 0, 0), **JOB)

    def test_scene_files_bundled_as_epr_does(self):
        scene = write_textured_scene(os.path.join(self.tmp, "textured"))
        bundle = eprfarm.bundle_scene(scene)
        self.assertEqual(bundle.entry_path, "box.obj")
        self.assertEqual([p for p, _ in bundle.files], ["CornellBox-Original.mtl", "box.obj", "tex/checker.png"])

        def submitted_hash(job: str) -> str:
            status = self.client.cancel(job)  # the bundle is what matters here, not the render
            return status.proto.scene.content_hash

        inline = submitted_hash(self.client.submit(scene, width=16, height=16, spp=1))
        r = epr("submit", scene, "--width", "16", "--height", "16", "--spp", "1", "--master", self.farm.address)
        self.assertEqual(r.returncode, 0, r.stderr)
        theirs = submitted_hash(r.stdout.strip())
        self.assertEqual(inline, theirs)
        self.assertEqual(inline, bundle.content_hash())

        # Over the inline limit the scene goes through UploadScene first and the job names its hash.
        uploader = eprfarm.Client(self.farm.address)
        uploader.inline_scene_limit = 0
        progress = []
        uploader.upload_progress = lambda sent, total: progress.append((sent, total))
        spec = uploader.job_spec(scene, width=16, height=16, spp=1)
        self.assertEqual(spec.scene.WhichOneof("source"), "uploaded_hash")
        self.assertEqual(spec.scene.uploaded_hash, theirs)
        self.assertEqual(progress[-1], (bundle.total_bytes, bundle.total_bytes))
        self.assertEqual(submitted_hash(uploader.submit_spec(spec)), theirs)
        uploader.close()

        # A scene JSON naming the OBJ (with comments, which the loader ignores) brings its files along.
        with open(os.path.join(self.tmp, "textured", "scene.json"), "w") as f:
            f.write('// the textured box\n{ "obj": "box.obj", /* the OBJ */ "camera": {"fov": 40} }\n')
        json_scene = os.path.join(self.tmp, "textured", "scene.json")
        self.assertEqual(
            [p for p, _ in eprfarm.bundle_scene(json_scene).files],
            ["CornellBox-Original.mtl", "box.obj", "scene.json", "tex/checker.png"],
        )
        ours = submitted_hash(self.client.submit(json_scene, width=16, height=16, spp=1))
        r = epr("submit", json_scene, "--width", "16", "--height", "16", "--spp", "1", "--master", self.farm.address)
        self.assertEqual(r.returncode, 0, r.stderr)
        self.assertEqual(ours, submitted_hash(r.stdout.strip()))

    def test_cancel(self):
        job = self.client.submit("builtin:cornell", width=64, height=64, spp=100000, mode="pt", name="long")
        # Watch until a round has committed; leaving the loop early cancels the stream.
        for status in self.client.watch(job):
            if status.round >= 1:
                break
        self.assertEqual(status.state, "RUNNING")
        self.assertEqual(status.name, "long")
        with self.assertRaises(eprfarm.JobError) as ctx:
            self.client.get(job)
        self.assertEqual(ctx.exception.state, "RUNNING")
        self.assertIn("partial=True", str(ctx.exception))
        preview = self.client.fetch_bytes(job, "exr", partial=True)
        self.assertTrue(preview.partial)
        self.assertEqual(preview.media_type, "image/x-exr")

        after = self.client.cancel(job)
        self.assertEqual(after.state, "CANCELLED")
        self.assertTrue(after.terminal)
        self.assertEqual(self.client.status(job).state, "CANCELLED")
        self.assertEqual([s.state for s in self.client.watch(job)], ["CANCELLED"])
        self.assertIn(job, [j.id for j in self.client.list(states=["cancelled"])])
        self.assertNotIn(job, [j.id for j in self.client.list(states=["done", "running"])])
        # The last committed round stays fetchable, marked partial.
        arrays = self.client.get(job, as_arrays=True)
        self.assertEqual(arrays["combined"].shape, (64, 64, 3))
        self.assertNotIn("reprojection", arrays)  # PT produces no reprojection results
        files = self.client.get(job, out=os.path.join(self.tmp, "cancelled", "long"))
        self.assertTrue(all(f.partial for f in files))
        self.assertEqual(self.client.cancel(job).state, "CANCELLED")  # cancelling again changes nothing

    def test_script_without_close_exits(self):
        # A script that watches a job and leaves its client to the interpreter's exit must end (a
        # channel whose connectivity was watched could hang the exit in its finalizer).
        script = (
            "import sys, eprfarm\n"
            f"c = eprfarm.Client({self.farm.address!r})\n"
            "job = c.submit('builtin:cornell', width=16, height=16, spp=2)\n"
            "sys.exit(0 if c.wait(job).state == 'DONE' else 3)\n"
        )
        env = dict(os.environ, PYTHONPATH=os.path.abspath(ARGS.package_dir))
        r = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=120)
        self.assertEqual(r.returncode, 0, r.stderr)

    def test_master_errors(self):
        # A spec the client's checks would refuse (test_client_checks.py), sent as it is.
        spec = self.client.job_spec("builtin:cornell")
        spec.target_spp = 0
        with self.assertRaises(eprfarm.RpcError) as ctx:
            self.client.submit_spec(spec)
        e = ctx.exception
        self.assertEqual(e.code, grpc.StatusCode.INVALID_ARGUMENT)
        self.assertEqual(e.reason, "--spp 0 must be between 1 and 1000000")
        self.assertIn("refused SubmitJob: INVALID_ARGUMENT: --spp 0", str(e))
        self.assertFalse(e.unreachable)

        for w in (0.0, 1.5):
            spec = self.client.job_spec("builtin:cornell", width=8, height=8, spp=1)
            spec.reprojection.reprojected_weight = w
            with self.assertRaises(eprfarm.RpcError) as ctx:
                self.client.submit_spec(spec)
            self.assertEqual(ctx.exception.code, grpc.StatusCode.INVALID_ARGUMENT)
            self.assertIn("--reprojected-weight %g must be in (0, 1]" % w, ctx.exception.reason)
        spec = self.client.job_spec("builtin:cornell", reprojected_weight=0.75)
        self.assertEqual(spec.reprojection.reprojected_weight, 0.75)

        with self.assertRaises(eprfarm.RpcError) as ctx:
            self.client.submit("builtin:nosuchscene", width=8, height=8, spp=1)
        self.assertEqual(ctx.exception.code, grpc.StatusCode.INVALID_ARGUMENT)
        self.assertIn("nosuchscene", ctx.exception.reason)

        for call in (self.client.status, self.client.cancel, lambda j: list(self.client.watch(j))):
            with self.assertRaises(eprfarm.RpcError) as ctx:
                call("j999999-none")
            self.assertEqual(ctx.exception.code, grpc.StatusCode.NOT_FOUND)
            self.assertIn("j999999-none", ctx.exception.reason)

        down = eprfarm.Client(f"127.0.0.1:{free_port()}", timeout=5)
        for call in (lambda: down.status("x"), lambda: list(down.watch("x"))):
            with self.assertRaises(eprfarm.RpcError) as ctx:
                call()
            self.assertEqual(ctx.exception.code, grpc.StatusCode.UNAVAILABLE)
            self.assertTrue(ctx.exception.unreachable)
            self.assertIn("cannot reach master at 127.0.0.1:", str(ctx.exception))
        down.close()

        with self.assertRaises(ValueError):
            self.client.submit("builtin:cornell", eye=(0, 1, 3))  # a camera needs all four parts
        with self.assertRaises(ValueError):
            self.client.submit("builtin:cornell", mode="fast")


class TokenTest(unittest.TestCase):
    """A master that requires a bearer token (--token-file)."""

    TOKEN = "s3cret-token_for.tests"

    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="epr-python-token-")
        cls.token_file = os.path.join(cls.tmp, "token")
        with open(cls.token_file, "w") as f:
            f.write(cls.TOKEN + "\n")
        os.chmod(cls.token_file, 0o600)
        cls.farm = Farm(cls.tmp, ["--token-file", cls.token_file], worker=False)

    @classmethod
    def tearDownClass(cls):
        cls.farm.stop()
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def setUp(self):
        self.saved_env = os.environ.pop("EPR_TOKEN", None)

    def tearDown(self):
        os.environ.pop("EPR_TOKEN", None)
        if self.saved_env is not None:
            os.environ["EPR_TOKEN"] = self.saved_env

    def assert_unauthenticated(self, client):
        with self.assertRaises(eprfarm.RpcError) as ctx:
            client.list()
        e = ctx.exception
        self.assertEqual(e.code, grpc.StatusCode.UNAUTHENTICATED)
        self.assertTrue(e.reason, "the master gives a reason")
        self.assertIn("UNAUTHENTICATED", str(e))
        self.assertIn("token", str(e))
        return e

    def test_wrong_or_missing_token(self):
        self.assert_unauthenticated(eprfarm.Client(self.farm.address, token="wrong-token"))
        self.assert_unauthenticated(eprfarm.Client(self.farm.address))
        os.environ["EPR_TOKEN"] = "also-wrong"
        self.assert_unauthenticated(eprfarm.Client(self.farm.address))

    def test_right_token(self):
        for client in (
            eprfarm.Client(self.farm.address, token_file=self.token_file),
            eprfarm.Client(self.farm.address, token=self.TOKEN),
        ):
            job = client.submit("builtin:cornell", width=8, height=8, spp=1)
            self.assertIn(job, [j.id for j in client.list()])
            self.assertEqual(client.cancel(job).state, "CANCELLED")
            client.close()
        os.environ["EPR_TOKEN"] = self.TOKEN
        self.assertIsInstance(eprfarm.Client(self.farm.address).list(), list)

    def test_token_rules(self):
        bad = os.path.join(self.tmp, "bad-token")
        for content, message in (("two words\n", "printable ASCII"), ("\n \n", "is empty")):
            with open(bad, "w") as f:
                f.write(content)
            with self.assertRaises(eprfarm.TokenError) as ctx:
                eprfarm.Client(self.farm.address, token_file=bad)
            self.assertIn(message, str(ctx.exception))
            self.assertIn(bad, str(ctx.exception))
        with self.assertRaises(eprfarm.TokenError):
            eprfarm.Client(self.farm.address, token_file=os.path.join(self.tmp, "missing"))
        with self.assertRaises(ValueError):
            eprfarm.Client(self.farm.address, token="has space")
        os.environ["EPR_TOKEN"] = "a b"
        with self.assertRaises(eprfarm.TokenError) as ctx:
            eprfarm.Client(self.farm.address)
        self.assertIn("$EPR_TOKEN", str(ctx.exception))


class TlsTest(unittest.TestCase):
    """A master serving gRPC over TLS (--tls-cert, --tls-key) with a test certificate made by openssl."""

    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="epr-python-tls-")
        cls.cert = os.path.join(cls.tmp, "cert.pem")
        key = os.path.join(cls.tmp, "key.pem")
        subprocess.run(
            ["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", key, "-out", cls.cert, "-days", "1",
             "-subj", "/CN=localhost", "-addext", "subjectAltName=DNS:localhost,IP:127.0.0.1"],
            check=True,
            capture_output=True,
        )
        cls.farm = Farm(cls.tmp, ["--tls-cert", cls.cert, "--tls-key", key], worker=False)

    @classmethod
    def tearDownClass(cls):
        cls.farm.stop()
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def test_tls(self):
        trusted = eprfarm.Client(self.farm.address, ca_file=self.cert)  # ca_file implies tls
        job = trusted.submit("builtin:cornell", width=8, height=8, spp=1)
        self.assertEqual(trusted.cancel(job).state, "CANCELLED")
        trusted.close()
        # Plain text to a TLS master, and TLS trusting only the system's roots, which do not know the
        # test certificate: no connection.
        for client in (eprfarm.Client(self.farm.address, timeout=5), eprfarm.Client(self.farm.address, tls=True)):
            with self.assertRaises(eprfarm.RpcError) as ctx:
                client.list()
            self.assertTrue(ctx.exception.unreachable, ctx.exception)
            client.close()
        with self.assertRaises(ValueError):
            eprfarm.Client(self.farm.address, ca_file=os.path.join(self.tmp, "missing.pem"))


class MasterRestartTest(unittest.TestCase):
    """A watch outlives a restart of its master: the job resumes from the state folder, the watch
    reconnects and follows it to its end."""

    def setUp(self):
        self.tmp = tempfile.mkdtemp(prefix="epr-python-restart-")
        self.farm = Farm(self.tmp)

    def tearDown(self):
        self.farm.stop()
        shutil.rmtree(self.tmp, ignore_errors=True)

    def test_watch_reconnects(self):
        client = eprfarm.Client(self.farm.address, watch_reconnect_timeout=30)
        job = client.submit("builtin:cornell", width=32, height=32, spp=100000, mode="pt")
        statuses = []
        restarted = cancelled = False
        with self.assertLogs("eprfarm", "WARNING") as logs:
            for status in client.watch(job):
                statuses.append(status)
                if not restarted and status.round >= 1:
                    self.farm.restart_master()
                    restarted = True
                elif restarted and not cancelled:
                    # The new master resumed the job; only it can answer the cancel and report the end.
                    self.assertEqual(client.cancel(job).state, "CANCELLED")
                    cancelled = True
        self.assertTrue(restarted and cancelled)
        self.assertTrue(any(f"lost the watch of job {job}" in line for line in logs.output), logs.output)
        self.assertEqual(statuses[-1].state, "CANCELLED")
        self.assertEqual({s.id for s in statuses}, {job})
        client.close()

    def test_calls_after_master_restart(self):
        import numpy as np

        client = eprfarm.Client(self.farm.address)
        job = client.submit("builtin:cornell", width=16, height=16, spp=2, mode="pt")
        self.assertEqual(client.wait(job).state, "DONE")
        before = eprfarm.decode_exr(client.fetch_bytes(job, "exr").data)
        self.farm.kill_master()
        with self.assertRaises(eprfarm.RpcError) as ctx:
            client.status(job)
        self.assertTrue(ctx.exception.unreachable)
        # The master back on its port and state folder: the same client reaches it again once the
        # channel's reconnection backoff has passed, and the job is DONE with the same image (if the
        # master was killed before the job's end was checkpointed, it runs its last rounds again).
        self.farm.master = self.farm.start_master(self.farm.address)

        def answers() -> bool:
            try:
                return bool(client.status(job))
            except eprfarm.RpcError as e:
                self.assertTrue(e.unreachable, e)
                return False

        self.assertTrue(wait_for(answers, 20, 0.2))
        self.assertEqual(client.wait(job).state, "DONE")
        after = eprfarm.decode_exr(client.fetch_bytes(job, "exr").data)
        self.assertTrue(np.array_equal(before, after))
        client.close()


def main() -> int:
    """Runs the tests of the script started (this file, or a test file using its helpers): the flags they
    all take (--package-dir, --epr, --master, --worker) go to ARGS, the rest to unittest; eprfarm and grpc
    are imported from the package folder into this module and the script's."""
    global eprfarm, grpc
    script = sys.modules["__main__"]
    parser = argparse.ArgumentParser(description=script.__doc__.split("\n\n")[0])
    parser.add_argument("--package-dir", required=True, help="folder holding the eprfarm package with its stubs")
    parser.add_argument("--epr", required=True)
    parser.add_argument("--master", required=True)
    parser.add_argument("--worker", required=True)
    args, rest = parser.parse_known_args()
    ARGS.__dict__.update(vars(args))
    sys.path.insert(0, os.path.abspath(args.package_dir))
    import grpc
    import eprfarm

    script.eprfarm, script.grpc = eprfarm, grpc
    program = unittest.main(module=script, argv=[sys.argv[0], *rest], exit=False, verbosity=2)
    return 0 if program.result.wasSuccessful() else 1


if __name__ == "__main__":
    sys.exit(main())
