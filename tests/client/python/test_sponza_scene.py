#!/usr/bin/python3
"""scenes/crytek-sponza (the paper's textured scene: 262k triangles, 49 textures, alpha-masked plants,
a sky image with negative texels, and a sun) through every way eprfarm renders a scene: `epr render
--single-process`, `epr render` (its embedded master and worker over gRPC) and `epr submit` to a real
epr-master and epr-worker on loopback.

    test_sponza_scene.py --epr EPR --master EPR_MASTER --worker EPR_WORKER

The three runs must succeed, give the same image bit for bit (same seed) and a lit one: every pixel
finite, the sun's patches far brighter than the shade, the courtyard sky seen through the roof's
opening. Run with Debian's /usr/bin/python3 (numpy, OpenImageIO).
"""

import argparse
import os
import shutil
import sys
import tempfile
import unittest

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.dont_write_bytecode = True  # no __pycache__ in the source tree
import test_client as harness  # noqa: E402  (Farm: a master and a worker on loopback)
from test_garden_scene import read_exr  # noqa: E402

SCENE = os.path.join(HERE, "..", "..", "..", "scenes", "crytek-sponza", "sponza.json")
WIDTH, HEIGHT, SPP, SEED = 64, 36, 4, 3
JOB = ["--width", str(WIDTH), "--height", str(HEIGHT), "--spp", str(SPP), "--seed", str(SEED), "--mode", "skip"]


class SponzaSceneTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="epr-sponza-")

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def render(self, name, *args):
        out = os.path.join(self.tmp, name)
        r = harness.epr(*args, "--out", out, timeout=240)
        self.assertEqual(r.returncode, 0, f"{args}:\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}")
        return read_exr(out + ".exr")

    def test_every_path_renders_the_same_lit_atrium(self):
        import numpy as np

        single = self.render("single", "render", SCENE, *JOB, "--single-process", "--threads", "2")
        embedded = self.render("embedded", "render", SCENE, *JOB, "--threads", "2")
        os.makedirs(os.path.join(self.tmp, "farm"))
        farm = harness.Farm(os.path.join(self.tmp, "farm"))
        self.addCleanup(farm.stop)
        submitted = self.render("submitted", "submit", SCENE, *JOB, "--master", farm.address, "--wait")
        self.assertEqual(single.shape, (HEIGHT, WIDTH, 3))
        self.assertTrue(np.array_equal(single, embedded), "epr render differs from epr render --single-process")
        self.assertTrue(np.array_equal(single, submitted), f"epr submit differs from epr render:\n{farm.logs()}")

        self.assertTrue(np.isfinite(single).all())
        lum = single @ np.array([0.2126, 0.7152, 0.0722])
        mean = float(lum.mean())
        self.assertGreater(mean, 0.005, "the atrium is black")
        # Sunlit patches (the floor and the far walls) stand out of the shaded colonnades.
        self.assertGreater(float(np.percentile(lum, 98)), 5 * mean, "no sunlit patch stands out")
        # The sky through the roof: the brightest pixel of the top rows' centre.
        top = lum[: HEIGHT // 6, WIDTH // 3 : 2 * WIDTH // 3]
        self.assertGreater(float(top.max()), 10 * mean, "no sky through the roof's opening")

def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--epr", required=True)
    parser.add_argument("--master", required=True)
    parser.add_argument("--worker", required=True)
    args, rest = parser.parse_known_args()
    harness.ARGS.__dict__.update(vars(args))
    program = unittest.main(argv=[sys.argv[0], *rest], exit=False, verbosity=2)
    return 0 if program.result.wasSuccessful() else 1


if __name__ == "__main__":
    sys.exit(main())
