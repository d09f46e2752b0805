"""What the scene tests (test_garden_scene.py, test_sponza_scene.py) share: a scene rendered by every way
eprfarm renders one -- `epr render --single-process`, `epr render` (its embedded master and worker over
gRPC) and `epr submit` to a real epr-master and epr-worker on loopback -- checked to be the same image
bit for bit, and the command line both tests take. Debian's /usr/bin/python3 (numpy, OpenImageIO).
"""

import argparse
import os
import shutil
import sys
import tempfile
import unittest

import test_client as harness  # Farm: a master and a worker on loopback

TILE = 16  # pixels, every render's (render_every_way)


def read_exr(path):
    import numpy as np
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(path)
    if inp is None:
        raise AssertionError(f"cannot read {path}: {oiio.geterror()}")
    spec = inp.spec()
    pixels = np.asarray(inp.read_image(format="float")).reshape(spec.height, spec.width, spec.nchannels)
    inp.close()
    return pixels[:, :, :3]


class SceneRenderTest(unittest.TestCase):
    """A folder for the run's images, and `render_every_way`."""

    TIMEOUT = 120  # seconds for one epr command

    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="epr-scene-")

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def render(self, name, *args):
        out = os.path.join(self.tmp, name)
        r = harness.epr(*args, "--out", out, timeout=self.TIMEOUT)
        self.assertEqual(r.returncode, 0, f"{args}:\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}")
        return read_exr(out + ".exr")

    def render_every_way(self, scene, job, width, height):
        """The three renders of `scene` with the flags `job`, asserted equal; returns the image."""
        import numpy as np

        # One tiling for all three: `epr render` picks its tile size for the threads it starts and
        # tapers, a submitted job keeps JobSpec's 64. Tiles decide the order in which vertex records
        # reach the reprojector, and the reprojected radiance is a float sum in that order, so two
        # tilings agree only to float rounding (an ulp in a few pixels); counts and path sums do not
        # depend on tiling at all.
        job = [*job, "--tile", str(TILE), "--taper-tiles"]
        single = self.render("single", "render", scene, *job, "--single-process", "--threads", "2")
        embedded = self.render("embedded", "render", scene, *job, "--threads", "2")
        os.makedirs(os.path.join(self.tmp, "farm"))
        farm = harness.Farm(os.path.join(self.tmp, "farm"))
        self.addCleanup(farm.stop)
        submitted = self.render("submitted", "submit", scene, *job, "--master", farm.address, "--wait")
        self.assertEqual(single.shape, (height, width, 3))
        self.assertTrue(np.array_equal(single, embedded), "epr render differs from epr render --single-process")
        self.assertTrue(np.array_equal(single, submitted), f"epr submit differs from epr render:\n{farm.logs()}")
        for part in ("counts", "pathtrace"):  # M and M', and the path-traced image, written beside it
            mine = read_exr(os.path.join(self.tmp, f"single.{part}.exr"))
            for other in ("embedded", "submitted"):
                theirs = read_exr(os.path.join(self.tmp, f"{other}.{part}.exr"))
                self.assertTrue(np.array_equal(mine, theirs), f"{other}'s {part} image differs")
        return single


def main(doc: str) -> int:
    """Runs the calling module's tests with --epr, --master and --worker taken from the command line."""
    parser = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    parser.add_argument("--epr", required=True)
    parser.add_argument("--master", required=True)
    parser.add_argument("--worker", required=True)
    args, rest = parser.parse_known_args()
    harness.ARGS.__dict__.update(vars(args))
    program = unittest.main(module="__main__", argv=[sys.argv[0], *rest], exit=False, verbosity=2)
    return 0 if program.result.wasSuccessful() else 1
