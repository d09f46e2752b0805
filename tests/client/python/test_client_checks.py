#!/usr/bin/python3
"""The Python client's checks of what it is given, and batches as a whole, against real epr-master and
epr-worker processes on loopback.

    test_client_checks.py --package-dir BUILD/client/python --epr EPR --master EPR_MASTER --worker EPR_WORKER

Checks: a job's numbers of the wrong type or out of range (common/limits.h's ranges, compared with
the header) are refused naming the argument and its range before anything is sent, and the ranges'
ends are accepted by the master; list's limit, the deadlines and a CA file that is not PEM likewise
(no gRPC output); master addresses with a port outside 1-65535; scene files outside the scene's
folder or not regular refused naming file and line; a batch whose frame 3 camera is
degenerate: the error names the batch and the frame, and the frames queued before it are cancelled;
cancel_batch on one master and across two; `pip install ./client/python` into a venv, leaving the
source tree as it was. Run with Debian's /usr/bin/python3.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tempfile
import unittest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.dont_write_bytecode = True  # no __pycache__ in the source tree
import test_client as base  # noqa: E402  (the process helpers: Farm, Process, epr, free_port)
import test_multi_master as multi  # noqa: E402  (TwoMasters)

eprfarm = grpc = None  # imported from --package-dir by base.main()

LONG = {"width": 32, "height": 32, "spp": 100000, "mode": "pt"}
# Keys at frames 1 and 5 whose eyes lie on either side of the look-at point: at frame 3 the eye is on it.
THROUGH_THE_TARGET = (
    '{"builtin": "cornell", "animation": {"camera": [\n'
    '  {"frame": 1, "eye": [0, 1, 2], "look": [0, 1, 0]},\n'
    '  {"frame": 5, "eye": [0, 1, -2]}]}}\n'
)


# common/limits.h's ranges of epr-master's own flags: no job setting, so not the client's to check.
MASTER_FLAGS = {"--window-run-wait", "--window-cut-share"}


def limits_h():
    """common/limits.h's ranges of a job's settings, (lo, hi) by the flag they name."""
    with open(os.path.join(base.SOURCE_DIR, "common", "limits.h")) as f:
        text = f.read()
    found = re.findall(r'Range<(?:int|double)> k\w+\{"([^"]+)", ([0-9.]+), ([0-9.]+)\}', text)
    return {flag: (float(lo), float(hi)) for flag, lo, hi in found if flag not in MASTER_FLAGS}


class ArgumentTest(unittest.TestCase):
    """No master needed: every check happens before anything is sent (the address is a free port)."""

    def setUp(self):
        self.client = eprfarm.Client(f"127.0.0.1:{base.free_port()}", timeout=5)
        self.addCleanup(self.client.close)

    def assert_refused(self, call, message: str):
        with self.assertRaises(eprfarm.ArgumentError) as ctx:
            call()
        self.assertEqual(str(ctx.exception), message)
        self.assertIsInstance(ctx.exception, ValueError)

    def test_job_numbers_named_with_their_range(self):
        cases = [
            ({"spp": -4}, "spp -4 must be between 1 and 1000000"),
            ({"spp": 0}, "spp 0 must be between 1 and 1000000"),
            ({"width": 2**32 + 64}, "width 4294967360 must be between 1 and 16384"),
            ({"width": 64.7}, "width must be a whole number, not 64.7"),
            ({"width": 10**9}, "width 1000000000 must be between 1 and 16384"),
            ({"height": 0}, "height 0 must be between 1 and 16384"),
            ({"height": "64"}, "height must be a whole number, not '64'"),
            ({"spp": 16, "paths_per_round": 17}, "paths_per_round 17 must be between 1 and spp (16)"),
            ({"spp": 16, "min_paths": 0}, "min_paths 0 must be between 1 and spp (16)"),
            ({"subpixels": 9}, "subpixels 9 must be between 1 and 8"),
            ({"tile": 2}, "tile 2 must be between 4 and 1024"),
            ({"max_depth": 0}, "max_depth 0 must be between 1 and 100000"),
            ({"round_growth": 17}, "round_growth 17 must be between 0 and 16"),
            ({"epsilon": float("nan")}, "epsilon nan must be between 0 and 1"),
            ({"reprojected_weight": 0}, "reprojected_weight 0 must be in (0, 1]"),
            ({"seed": -1}, "seed -1 must be between 0 and 18446744073709551615"),
            ({"priority": 2**31}, "priority 2147483648 must be between -2147483648 and 2147483647"),
            ({"time_budget": -1}, "time_budget -1 must be a positive number of seconds"),
            ({"environment": 1, "environment_strength": "2"}, "environment_strength must be a number, not '2'"),
        ]
        for options, message in cases:
            with self.subTest(**{k: repr(v) for k, v in options.items()}):
                self.assert_refused(lambda: self.client.submit("builtin:cornell", **options), message)
        # submit_frames checks the same before planning anything.
        self.assert_refused(lambda: self.client.submit_frames("builtin:cornell", "1-2", spp=-4),
                            "spp -4 must be between 1 and 1000000")  # fmt: skip

    def test_ranges_are_common_limits_h(self):
        from eprfarm import limits

        ours = {r.flag: (float(r.lo), float(r.hi)) for r in limits.JOB_RANGES}
        self.assertEqual(ours, limits_h())
        with open(os.path.join(base.SOURCE_DIR, "common", "limits.h")) as f:
            name_bytes = re.search(r"kMaxNameBytes = (\d+);", f.read())
        self.assertIsNotNone(name_bytes, "no kMaxNameBytes in common/limits.h")
        self.assertEqual(limits.MAX_NAME_BYTES, int(name_bytes.group(1)))

    def test_roulette_is_the_masters(self):
        """The client's roulette names are common/roulette.cpp's table (both read the proto's modes), and
        a job sends only the mode: each mode's numbers and the default are the master's."""
        from eprfarm import job_settings
        from eprfarm.proto import render_settings_pb2 as rs_pb

        with open(os.path.join(base.SOURCE_DIR, "common", "roulette.cpp")) as f:
            table = re.findall(r'\{"(\w+)", RussianRoulette::\w+\(', f.read())
        self.assertEqual(table, ["paper", "albedo", "off", "throughput", "reuse", "auto"])
        self.assertEqual(list(job_settings.ROULETTE), table)
        spec = self.client.job_spec("builtin:cornell")
        self.assertEqual(spec.russian_roulette.mode, rs_pb.RUSSIAN_ROULETTE_MODE_UNSPECIFIED)
        for field in ("start_depth", "termination_probability", "max_depth"):
            self.assertFalse(spec.russian_roulette.HasField(field), field)
        spec = self.client.job_spec("builtin:cornell", rr="Paper", max_depth=12)
        self.assertEqual(spec.russian_roulette.mode, rs_pb.RUSSIAN_ROULETTE_MODE_PAPER)
        self.assertFalse(spec.russian_roulette.HasField("start_depth"))
        self.assertEqual(spec.russian_roulette.max_depth, 12)
        self.assert_refused(lambda: self.client.job_spec("builtin:cornell", rr="russian"),
                            "rr 'russian' is not one of paper, albedo, off, throughput, reuse, auto")  # fmt: skip

    def test_path_budget_is_sent_as_asked(self):
        """`path_budget` reaches the job's reprojection settings (`--path-budget`); off by default."""
        self.assertFalse(self.client.job_spec("builtin:cornell").reprojection.path_budget)
        self.assertTrue(self.client.job_spec("builtin:cornell", path_budget=True).reprojection.path_budget)

    def test_list_and_watch_arguments(self):
        self.assert_refused(lambda: self.client.list(limit=-1), "limit -1 must be 0 (all jobs) or more")
        self.assert_refused(lambda: self.client.list(limit=2.5), "limit must be a whole number, not 2.5")
        self.assert_refused(lambda: list(self.client.watch("j1", min_interval_ms=-1)),
                            "min_interval_ms -1 must be between 0 and 4294967295")  # fmt: skip

    def test_deadlines(self):
        for value, shown in ((0, "0"), (-1, "-1"), (float("inf"), "inf"), (10**6, "1e+06")):
            self.assert_refused(lambda: eprfarm.Client("127.0.0.1:1", timeout=value),
                                f"timeout {shown} must be between 0.001 and 86400 seconds")  # fmt: skip
        self.assert_refused(lambda: eprfarm.Client("127.0.0.1:1", transfer_timeout=0),
                            "transfer_timeout 0 must be a positive number of seconds")  # fmt: skip
        self.assertEqual(eprfarm.Client("127.0.0.1:1", timeout=0.5).timeout, 0.5)

    def test_ca_file_that_is_not_pem(self):
        # In a process of its own, whose stderr must stay empty: gRPC would print its own lines.
        tmp = tempfile.mkdtemp(prefix="epr-python-ca-")
        self.addCleanup(shutil.rmtree, tmp, True)
        not_pem, empty = os.path.join(tmp, "ca.txt"), os.path.join(tmp, "empty.pem")
        with open(not_pem, "w") as f:
            f.write("this is no certificate\n")
        open(empty, "w").close()
        script = (
            "import sys, eprfarm\n"
            "try:\n"
            "    eprfarm.Client('127.0.0.1:1', ca_file=sys.argv[1], timeout=5).list()\n"
            "except eprfarm.EprError as e:\n"
            "    print(type(e).__name__, e)\n"
        )
        env = dict(os.environ, PYTHONPATH=os.path.abspath(base.ARGS.package_dir))
        for path, message in (
            (not_pem, f"the CA file '{not_pem}' is not a PEM file of certificates: it has no readable "
                      "'-----BEGIN CERTIFICATE-----' block"),
            (empty, f"the CA file '{empty}' is empty: it must hold PEM certificates"),
            (os.path.join(tmp, "missing.pem"), f"cannot read the CA file '{tmp}/missing.pem': No such file or directory"),
        ):  # fmt: skip
            r = subprocess.run([sys.executable, "-c", script, path], env=env, capture_output=True, text=True,
                               timeout=60)  # fmt: skip
            self.assertEqual(r.stdout.strip(), f"ArgumentError {message}", r.stderr)
            self.assertEqual(r.stderr, "")

    def test_ports_outside_1_to_65535(self):
        for master in ("localhost:65536", "127.0.0.1:70000", "h:0", "[::1]:99999", "ipv4:127.0.0.1:65537",
                       "ipv6:[::1]:65536", "localhost:50051,localhost:131072"):  # fmt: skip
            bad = master.split(",")[-1]
            port = int(bad.rpartition(":")[2])
            self.assert_refused(lambda: eprfarm.master_endpoints(master),
                                f"master: '{bad}' has port {port}, outside 1-65535")  # fmt: skip
        self.assertEqual([e.target for e in eprfarm.master_endpoints("127.0.0.1:65535,127.0.0.1:1,[::1]:80")],
                         ["127.0.0.1:65535", "127.0.0.1:1", "[::1]:80"])  # fmt: skip


class OneMasterTest(base.FarmClientTest):
    """A master without a worker: jobs stay queued until cancelled."""

    PREFIX = "epr-python-checks-"
    WORKER = False

    def scene(self, name: str, text: str) -> str:
        path = os.path.join(self.tmp, name)
        with open(path, "w") as f:
            f.write(text)
        return path

    def test_range_ends_accepted_by_the_master(self):
        # The client's ranges are not narrower than the master's: each end of each range is accepted.
        for options in (
            {"width": 16384, "height": 1, "spp": 1, "mode": "pt", "tile": 1024, "max_depth": 100000,
             "round_growth": 16, "epsilon": 1, "seed": 2**64 - 1, "priority": 2**31 - 1, "reprojected_weight": 1},
            {"width": 1, "height": 1, "spp": 1000000, "paths_per_round": 1000000, "min_paths": 1000000,
             "subpixels": 8, "tile": 4, "round_growth": 0, "epsilon": 0, "seed": 0, "priority": -(2**31)},
        ):  # fmt: skip
            job = self.client.submit("builtin:cornell", **options)
            self.assertEqual(self.client.cancel(job).state, "CANCELLED")

    def test_port_beyond_65535_is_not_wrapped(self):
        port = int(self.farm.address.rpartition(":")[2])
        with self.assertRaises(eprfarm.ArgumentError) as ctx:
            eprfarm.Client(f"127.0.0.1:{port + 65536}").list()  # not the farm's port modulo 65536
        self.assertIn(f"'127.0.0.1:{port + 65536}' has port {port + 65536}, outside 1-65535", str(ctx.exception))

    def test_degenerate_frame_refuses_the_batch_before_any_frame_is_queued(self):
        scene = self.scene("through.json", THROUGH_THE_TARGET)
        with self.assertRaises(eprfarm.RpcError) as ctx:
            self.client.submit_frames(scene, "1-5", **LONG)
        e = ctx.exception
        self.assertEqual(e.code, grpc.StatusCode.INVALID_ARGUMENT)
        batch = e.batch_id
        self.assertRegex(str(e), rf"^batch {batch}: master at \S+ refused CheckFrames: INVALID_ARGUMENT: "
                                 r"through\.json:\d+: frame 3: camera eye and look-at point coincide; "
                                 r"no frame was queued$")  # fmt: skip
        self.assertEqual(self.client.list(batch=batch), [])

    def test_cancel_batch(self):
        scene = self.scene("walk.json", multi.ANIMATION)
        batch, ids = self.client.submit_frames(scene, "1-3", **LONG)
        with self.assertRaises(eprfarm.RpcError) as ctx:
            self.client.cancel(batch)  # a batch id is not a job's
        self.assertEqual(ctx.exception.code, grpc.StatusCode.NOT_FOUND)
        cancelled = self.client.cancel_batch(batch)
        self.assertEqual(sorted((j.id, j.state) for j in cancelled), sorted((i, "CANCELLED") for i in ids))
        self.assertEqual({j.state for j in self.client.list(batch=batch)}, {"CANCELLED"})
        self.assertEqual(len(self.client.cancel_batch(batch)), 3)  # again: nothing changes
        with self.assertRaises(eprfarm.RpcError) as ctx:
            self.client.cancel_batch("b-none")
        self.assertEqual(ctx.exception.code, grpc.StatusCode.NOT_FOUND)
        self.assertIn("no master has a job of batch b-none", str(ctx.exception))
        with self.assertRaises(eprfarm.ArgumentError):
            self.client.cancel_batch("not a batch id")


class TwoMastersTest(multi.TwoMastersCase):
    PREFIX = "epr-python-checks-multi-"

    def test_cancel_batch_on_every_master(self):
        scene = self.animation_scene()
        batch, ids = self.client.submit_frames(scene, "1-4", **LONG)
        per_master = [eprfarm.Client(a) for a in self.masters.addresses]
        self.assertTrue(all(len(c.list(batch=batch)) > 0 for c in per_master), "the frames went to one master")
        cancelled = self.client.cancel_batch(batch)
        self.assertEqual(sorted(j.id for j in cancelled), sorted(ids))
        self.assertEqual({j.state for j in cancelled}, {"CANCELLED"})
        for c in per_master:
            self.assertEqual({j.state for j in c.list(batch=batch)}, {"CANCELLED"})
            c.close()


class SceneSandboxTest(unittest.TestCase):
    """Scene bundling without a master: files must stay inside the scene's folder and be regular."""

    def setUp(self):
        self.tmp = tempfile.mkdtemp(prefix="epr-python-scene-")
        self.folder = os.path.join(self.tmp, "scene")
        os.makedirs(self.folder)

    def tearDown(self):
        shutil.rmtree(self.tmp, ignore_errors=True)

    def obj(self, mtllib_line: str) -> str:
        path = os.path.join(self.folder, "m.obj")
        with open(path, "w") as f:
            f.write(f"# test\n{mtllib_line}\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
        return path

    def assert_refused(self, scene: str, *fragments: str):
        with self.assertRaises(eprfarm.SceneError) as ctx:
            eprfarm.bundle_scene(scene)
        for fragment in fragments:
            self.assertIn(fragment, str(ctx.exception))

    def test_sandbox(self):
        with open(os.path.join(self.tmp, "outside.mtl"), "w") as f:
            f.write("newmtl x\nKd 1 1 1\n")
        self.assert_refused(self.obj("mtllib ../outside.mtl"), "m.obj:2:", "mtllib '../outside.mtl' leaves the scene folder")
        self.assert_refused(self.obj("mtllib /etc/passwd"), "is an absolute path")
        os.symlink(os.path.join(self.tmp, "outside.mtl"), os.path.join(self.folder, "link.mtl"))
        self.assert_refused(self.obj("mtllib link.mtl"), "leaves the scene folder")
        self.assert_refused(self.obj("mtllib missing.mtl"), "mtllib 'missing.mtl' does not exist")
        os.mkfifo(os.path.join(self.folder, "pipe.mtl"))
        self.assert_refused(self.obj("mtllib pipe.mtl"), "is a FIFO (named pipe), not a regular file")
        self.assert_refused(os.path.join(self.folder, "nothing.obj"), "nothing.obj: does not exist")
        with open(os.path.join(self.folder, "in.mtl"), "w") as f:
            f.write("newmtl a\nmap_Kd ../outside.png\n")
        self.assert_refused(self.obj("mtllib in.mtl"), "in.mtl:2:", "texture '../outside.png' leaves the scene folder")

    def test_escaped_names_and_comments(self):
        with open(os.path.join(self.folder, "a b.mtl"), "w") as f:
            f.write("newmtl a\nKd 1 1 1\n")
        with open(os.path.join(self.folder, "c.mtl"), "w") as f:
            f.write("newmtl c\nKe 1 1 1\n")
        bundle = eprfarm.bundle_scene(self.obj("mtllib a\\ b.mtl c.mtl # d.mtl"))
        self.assertEqual([p for p, _ in bundle.files], ["a b.mtl", "c.mtl", "m.obj"])
        self.assertEqual(len(bundle.content_hash()), 64)


class PipInstallTest(unittest.TestCase):
    """`pip install ./client/python` into a venv over Debian's packages, offline."""

    def test_pip_install(self):
        tmp = tempfile.mkdtemp(prefix="epr-python-pip-")
        try:
            # A copy of what the package build reads, which the build must leave as it was.
            repo = os.path.join(tmp, "repo")
            shutil.copytree(
                os.path.join(base.SOURCE_DIR, "client", "python"),
                os.path.join(repo, "client", "python"),
                ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__"),
            )
            shutil.copytree(os.path.join(base.SOURCE_DIR, "proto"), os.path.join(repo, "proto"))
            shutil.copy(os.path.join(base.SOURCE_DIR, "CMakeLists.txt"), repo)

            def tree():
                return sorted(os.path.relpath(os.path.join(d, n), repo) for d, ds, fs in os.walk(repo) for n in ds + fs)

            before = tree()
            venv = os.path.join(tmp, "venv")
            subprocess.run([sys.executable, "-m", "venv", "--system-site-packages", venv], check=True)
            python = os.path.join(venv, "bin", "python")
            r = subprocess.run(
                [python, "-m", "pip", "install", "--no-index", "--quiet", os.path.join(repo, "client", "python")],
                capture_output=True,
                text=True,
                cwd=tmp,
            )
            self.assertEqual(r.returncode, 0, r.stdout + r.stderr)
            self.assertEqual(tree(), before, "the build wrote into the source tree")
            r = subprocess.run(
                [python, "-c", "import eprfarm, eprfarm.proto.job_service_pb2_grpc as g; "
                 "print(eprfarm.__file__); print(g.JobServiceStub.__name__)"],
                capture_output=True,
                text=True,
                cwd=tmp,
            )  # fmt: skip
            self.assertEqual(r.returncode, 0, r.stderr)
            self.assertTrue(r.stdout.startswith(venv), r.stdout)
            self.assertIn("JobServiceStub", r.stdout)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(base.main())
