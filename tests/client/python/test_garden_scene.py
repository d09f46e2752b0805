#!/usr/bin/python3
"""scenes/garden (a glTF with textures and cut-outs, lit only by a sky image and a sun) through every
way eprfarm renders a scene: `epr render --single-process`, `epr render` (its embedded master and
worker over gRPC) and `epr submit` to a real epr-master and epr-worker on loopback.

    test_garden_scene.py --epr EPR --master EPR_MASTER --worker EPR_WORKER

The three images must be equal bit for bit (same seed; the cluster renders what one process does),
lit (the sun and the sky light the yard) and show the sky through the fence's holes: in the band of
the fence above the wall's top, seen against the sky, there must be both wood (red above blue) and
sky (blue above red) pixels, which an opaque or a missing fence would not give. Run with Debian's
/usr/bin/python3 (numpy, OpenImageIO).
"""

import math
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.dont_write_bytecode = True  # no __pycache__ in the source tree
from scene_renders import SceneRenderTest, main  # noqa: E402

SCENE = os.path.join(HERE, "..", "..", "..", "scenes", "garden", "garden.json")
WIDTH, HEIGHT, SPP, SEED = 96, 72, 8, 5
JOB = ["--width", str(WIDTH), "--height", str(HEIGHT), "--spp", str(SPP), "--seed", str(SEED), "--mode", "skip"]
EYE, LOOK, YFOV = (0.9, 1.5, 4.2), (0.1, 0.7, -0.6), 45.0  # the glTF's camera (make_garden_gltf.py)


def project(point):
    """The pixel (column, row) where the glTF's camera sees a point (y up, square pixels)."""
    sub = [a - b for a, b in zip(point, EYE)]
    f = [a - b for a, b in zip(LOOK, EYE)]
    n = math.sqrt(sum(c * c for c in f))
    f = [c / n for c in f]
    r = [f[1] * 0 - f[2] * 1, f[2] * 0 - f[0] * 0, f[0] * 1 - f[1] * 0]  # f x (0, 1, 0)
    n = math.sqrt(sum(c * c for c in r))
    r = [c / n for c in r]
    u = [r[1] * f[2] - r[2] * f[1], r[2] * f[0] - r[0] * f[2], r[0] * f[1] - r[1] * f[0]]  # r x f
    depth = sum(a * b for a, b in zip(sub, f))
    scale = HEIGHT / 2 / math.tan(math.radians(YFOV) / 2) / depth
    x = WIDTH / 2 + scale * sum(a * b for a, b in zip(sub, r))
    y = HEIGHT / 2 - scale * sum(a * b for a, b in zip(sub, u))
    return x, y


class GardenSceneTest(SceneRenderTest):
    def test_every_path_renders_the_same_lit_garden(self):
        import numpy as np

        single = self.render_every_way(SCENE, JOB, WIDTH, HEIGHT)

        # Lit: the sunny paving is bright, every pixel finite.
        self.assertTrue(np.isfinite(single).all())
        self.assertGreater(float(single.mean()), 0.2)
        # The fence's band between 1.55 and 1.8 m, right of the wall (x 1.05 .. 1.65): the sky behind it.
        (x0, y0), (x1, y1) = project((1.05, 1.8, -0.6)), project((1.65, 1.55, -0.6))
        band = single[math.ceil(y0) : math.floor(y1), math.ceil(x0) : math.floor(x1)].reshape(-1, 3)
        self.assertGreater(len(band), 20, f"band {x0:.1f}..{x1:.1f} x {y0:.1f}..{y1:.1f}")
        sky = int(np.sum(band[:, 2] > band[:, 0] * 1.1))
        wood = int(np.sum(band[:, 0] > band[:, 2] * 1.5))
        self.assertGreater(sky, len(band) // 10, f"no sky through the fence's holes ({sky} of {len(band)} pixels)")
        self.assertGreater(wood, len(band) // 10, f"no fence in front of the sky ({wood} of {len(band)} pixels)")


if __name__ == "__main__":
    sys.exit(main(__doc__))
