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

import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.dont_write_bytecode = True  # no __pycache__ in the source tree
from scene_renders import SceneRenderTest, main  # noqa: E402

SCENE = os.path.join(HERE, "..", "..", "..", "scenes", "crytek-sponza", "sponza.json")
WIDTH, HEIGHT, SPP, SEED = 64, 36, 4, 3
JOB = ["--width", str(WIDTH), "--height", str(HEIGHT), "--spp", str(SPP), "--seed", str(SEED), "--mode", "skip"]


class SponzaSceneTest(SceneRenderTest):
    TIMEOUT = 240

    def test_every_path_renders_the_same_lit_atrium(self):
        import numpy as np

        single = self.render_every_way(SCENE, JOB, WIDTH, HEIGHT)
        self.assertTrue(np.isfinite(single).all())
        lum = single @ np.array([0.2126, 0.7152, 0.0722])
        mean = float(lum.mean())
        self.assertGreater(mean, 0.005, "the atrium is black")
        # Sunlit patches (the floor and the far walls) stand out of the shaded colonnades.
        self.assertGreater(float(np.percentile(lum, 98)), 5 * mean, "no sunlit patch stands out")
        # The sky through the roof: the brightest pixel of the top rows' centre.
        top = lum[: HEIGHT // 6, WIDTH // 3 : 2 * WIDTH // 3]
        self.assertGreater(float(top.max()), 10 * mean, "no sky through the roof's opening")


if __name__ == "__main__":
    sys.exit(main(__doc__))
