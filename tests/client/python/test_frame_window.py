#!/usr/bin/python3
"""The Python client's frame windows (submit_frames(frame_window=K, window_run=N)) against real
epr-master and epr-worker processes on loopback.

    test_frame_window.py --package-dir BUILD/client/python --epr EPR --master EPR_MASTER --worker EPR_WORKER

Checks: K and N of the wrong type or out of range, a window with mode pt or reproject exact, and
window_run without a window are refused naming the argument before anything is sent; the runs
(frames.window_runs: at most N consecutive frame numbers each, as `epr submit --frame-window` plans
them) and each frame's window_first / window_last and seed (the batch's plus the frame); every job a master queues
carries frame_window and its run (the specs sent to the master, recorded on their way), and a
window batch renders as one run on the master; with two
masters each run goes whole to one master; K = 0 sends no window. Run with Debian's /usr/bin/python3.
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
import unittest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.dont_write_bytecode = True  # no __pycache__ in the source tree
import test_client as base  # noqa: E402  (the process helpers: Farm, Process, epr, free_port)
import test_multi_master as multi  # noqa: E402  (TwoMasters, ANIMATION)

eprfarm = grpc = None  # imported from --package-dir by base.main()

# Long enough that no frame ends during a test; skip, as a window needs reprojection.
LONG = {"width": 32, "height": 32, "spp": 100000, "mode": "skip", "seed": 7}


class SentSpecs:
    """Records every JobSpec a MasterClient submits (the real call goes on), as (frame, K, first, last, seed)."""

    def __init__(self, case: unittest.TestCase):
        self.sent = []
        submit = eprfarm.MasterClient.submit_spec

        def recorded(client, spec):
            self.sent.append((spec.frame, spec.frame_window, spec.window_first, spec.window_last, spec.seed))
            return submit(client, spec)

        eprfarm.MasterClient.submit_spec = recorded
        case.addCleanup(setattr, eprfarm.MasterClient, "submit_spec", submit)


class WindowArgumentTest(unittest.TestCase):
    """No master needed: every check happens before anything is sent (the address is a free port)."""

    def setUp(self):
        self.client = eprfarm.Client(f"127.0.0.1:{base.free_port()}", timeout=5)
        self.addCleanup(self.client.close)

    def assert_refused(self, message: str, **options):
        with self.assertRaises(eprfarm.ArgumentError) as ctx:
            self.client.submit_frames("builtin:cornell", "1-4", **{**LONG, **options})
        self.assertIn(message, str(ctx.exception))

    def test_bad_windows_are_refused(self):
        self.assert_refused("frame_window 17 must be between 0 and 16", frame_window=17)
        self.assert_refused("frame_window -1 must be between 0 and 16", frame_window=-1)
        self.assert_refused("frame_window must be a whole number, not True", frame_window=True)
        self.assert_refused("frame_window must be a whole number, not '2'", frame_window="2")
        self.assert_refused("frame_window needs reprojection: mode pt", frame_window=1, mode="pt")
        self.assert_refused("frame_window needs reproject gl or cpu", frame_window=1, reproject="exact")
        self.assert_refused("window_run needs a frame_window above 0", window_run=4)
        self.assert_refused("window_run 0 must be between 1 and 64", frame_window=1, window_run=0)
        self.assert_refused("window_run 65 must be between 1 and 64", frame_window=1, window_run=65)

    def test_runs(self):
        frames = eprfarm.frames
        runs = lambda count, n: frames.window_runs(list(range(1, count + 1)), n)  # noqa: E731
        self.assertEqual(runs(48, 16), [(0, 15), (16, 31), (32, 47)])
        self.assertEqual(runs(5, 3), [(0, 2), (3, 4)])  # as client_test FrameBatchPlan plans them
        self.assertEqual(runs(3, 16), [(0, 2)])
        self.assertEqual(runs(3, 1), [(0, 0), (1, 1), (2, 2)])  # no window: a frame a run
        # A run holds consecutive frame numbers: a skipped number ends it.
        self.assertEqual(frames.run_frames([1, 2, 3, 4, 10, 11, 12], 3), [(1, 3)] * 3 + [(4, 4)] + [(10, 12)] * 3)
        self.assertEqual(frames.run_frames(frames.parse_frames("1-7x2"), 3), [(1, 1), (3, 3), (5, 5), (7, 7)])
        spec = eprfarm.MasterClient("127.0.0.1:1").job_spec("builtin:cornell", **LONG)
        self.assertEqual(frames.checked_window(2, None, spec), (2, 16))
        self.assertEqual(frames.checked_window(8, 4, spec), (8, 4))
        self.assertEqual(frames.checked_window(0, None, spec), (0, 1))


class WindowFarmTest(unittest.TestCase):
    """One master and a worker: the jobs queued carry their runs."""

    def setUp(self):
        self.tmp = tempfile.mkdtemp(prefix="epr-python-window-")
        self.farm = base.Farm(self.tmp)
        self.client = eprfarm.Client(self.farm.address)
        self.scene = os.path.join(self.tmp, "walk.json")
        with open(self.scene, "w") as f:
            f.write(multi.ANIMATION)

    def tearDown(self):
        self.client.close()
        self.farm.stop()
        shutil.rmtree(self.tmp, ignore_errors=True)

    def test_every_frame_names_its_run(self):
        specs = SentSpecs(self)
        batch, ids = self.client.submit_frames(self.scene, "1-7", frame_window=2, window_run=3, **LONG)
        # Runs of three: 1-3, 4-6, 7; each frame's seed the batch's (7) plus its number.
        runs = [(1, 3)] * 3 + [(4, 6)] * 3 + [(7, 7)]
        self.assertEqual(specs.sent, [(f, 2, *runs[f - 1], 7 + f) for f in range(1, 8)])
        jobs = sorted(self.client.list(batch=batch), key=lambda s: s.frame)
        self.assertEqual([(s.id, s.frame, s.proto.batch_frames) for s in jobs],
                         [(ids[f - 1], f, 7) for f in range(1, 8)])  # fmt: skip
        self.assertEqual(len(self.client.cancel_batch(batch)), 7)

    def test_window_batch_renders_as_one_run(self):
        batch, ids = self.client.submit_frames(self.scene, "1-3", frame_window=1,
                                               **{**LONG, "spp": 8, "width": 24, "height": 24})  # fmt: skip
        self.assertEqual([self.client.wait(j).state for j in ids], ["DONE"] * 3, self.farm.logs())
        self.assertIn(f"window run 1..3 of batch {batch} (K = 1) starting", self.farm.logs())

    def test_no_window_sends_none(self):
        specs = SentSpecs(self)
        batch, _ = self.client.submit_frames(self.scene, "1-3", **LONG)
        self.assertEqual(specs.sent, [(f, 0, 0, 0, 7) for f in (1, 2, 3)])
        self.client.cancel_batch(batch)


class WindowTwoMastersTest(multi.TwoMastersCase):
    """Two masters: each run goes whole to one of them."""

    PREFIX = "epr-python-window-multi-"

    def test_runs_go_whole_to_a_master(self):
        scene = self.animation_scene()
        batch, ids = self.client.submit_frames(scene, "1-8", frame_window=1, window_run=4, **LONG)
        # Equal loads: the first run to m1, the second to the master with less work, m2 (without a
        # window the frames would alternate, m1 m2 m1 m2 ...).
        self.assertEqual([j.split(".")[0] for j in ids], ["m1"] * 4 + ["m2"] * 4)
        for i, client in enumerate(eprfarm.Client(a) for a in self.masters.addresses):
            with client:
                self.assertEqual(sorted(s.frame for s in client.list(batch=batch)), [1 + 4 * i + f for f in range(4)])
        self.assertEqual(len(self.client.cancel_batch(batch)), 8)


if __name__ == "__main__":
    sys.exit(base.main())
