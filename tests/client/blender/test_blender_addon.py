#!/usr/bin/python3
"""The Blender add-on (client/blender/eprfarm_blender) in Blender against a real epr-master and
epr-worker on loopback.

    test_blender_addon.py --blender BLENDER [--xvfb-run XVFB_RUN] --package-dir BUILD/client/python
        --epr EPR --master EPR_MASTER --worker EPR_WORKER [BlenderAddonTest | BlenderUiTest]

scenes/cornell-box.gltf is imported into Blender (make_blend.py, which also checks the add-on's
camera against Blender's glTF exporter), saved as a .blend set to the eprfarm engine with the camera
keyed to move at frame 2, and rendered as a user renders it, the add-on enabled and its package
folder set the way Preferences keep them.

BlenderAddonTest (ctest blender_addon), in `blender -b`: `-f 1`, a textured material (against `epr
render` of Blender's own glTF export), `-a` for two frames, the operator Render Frames on Farm (both
frames as one batch; with a Frame Window, the run each frame names, and Mode pt and a moving object
refused) and a master that wants a token (none given: its refusal; the panel's token
file: the frame); an unreachable master, a job the master refuses and a package folder without the
package must end the render with the reason in Blender's output, no traceback and no image.
BlenderUiTest (ctest blender_addon_ui): Blender with its UI under xvfb-run, F12 and Render Animation
(the engine then runs in a job thread), Render Frames on Farm as its button starts it (a timer
follows the batch), and Blender quitting during a render, which must cancel the farm job.

Every frame must have the render size and the pixels of `epr render` of the same glTF (same seed; the
difference of every 8 x 8 block's mean within five standard errors, estimated from two seeds), and
frame 2 (camera moved) must fail that comparison. Run with Debian's /usr/bin/python3 (numpy,
OpenImageIO).
"""

from __future__ import annotations

import argparse
import re
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import unittest

HERE = os.path.dirname(os.path.abspath(__file__))
SOURCE_DIR = os.path.abspath(os.path.join(HERE, "..", "..", ".."))
sys.path.insert(0, os.path.join(HERE, "..", "python"))
sys.dont_write_bytecode = True  # no __pycache__ in the source tree
import test_client as harness  # noqa: E402  (Farm: a master and a worker on loopback)
sys.path.insert(0, os.path.join(SOURCE_DIR, "scripts"))
from addon_cycles_compare import read_exr  # noqa: E402  (an EXR's RGB as a height x width x 3 array)

ARGS = argparse.Namespace()
GLTF = os.path.join(SOURCE_DIR, "scenes", "cornell-box.gltf")
GARDEN = os.path.join(SOURCE_DIR, "scenes", "garden")  # a glTF with a sky and a sun (garden.json)
SUN = (-0.6, 0.9, -1.0)  # garden.json's sun, towards it, y up
WIDTH, HEIGHT, SPP, SEED = 64, 48, 16, 3
BLOCK = 8  # pixels per side of the blocks whose means are compared


def block_means(image):
    h, w, c = image.shape
    return image.reshape(h // BLOCK, BLOCK, w // BLOCK, BLOCK, c).mean(axis=(1, 3))


class BlenderCase(unittest.TestCase):
    """A farm, the test's .blend and `epr render`'s images of the same glTF."""

    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="epr-blender-addon-")
        cls.farm = harness.Farm(cls.tmp)
        # Blender finds the add-on in its user scripts folder, as after "Install add-on".
        addons = os.path.join(cls.tmp, "scripts", "addons")
        os.makedirs(addons)
        addon = os.path.join(SOURCE_DIR, "client", "blender", "eprfarm_blender")
        os.symlink(addon, os.path.join(addons, "eprfarm_blender"))
        cls.env = dict(
            os.environ,
            BLENDER_USER_SCRIPTS=os.path.join(cls.tmp, "scripts"),
            BLENDER_USER_CONFIG=os.path.join(cls.tmp, "config"),
        )
        cls.blend = os.path.join(cls.tmp, "box.blend")
        made = cls.blender(
            "--factory-startup",
            "--python",
            os.path.join(HERE, "make_blend.py"),
            "--",
            "--addon-dir",
            os.path.join(SOURCE_DIR, "client", "blender"),
            "--package-dir",
            ARGS.package_dir,
            "--gltf",
            GLTF,
            "--master",
            cls.farm.address,
            "--width",
            str(WIDTH),
            "--height",
            str(HEIGHT),
            "--spp",
            str(SPP),
            "--seed",
            str(SEED),
            "--mode",
            "pt",
            "--move-camera-at",
            "2",
            "--blend",
            cls.blend,
        )
        if made.returncode != 0 or not os.path.exists(cls.blend):
            cls.farm.stop()
            output = f"{made.stdout[-6000:]}\n{made.stderr[-3000:]}"
            raise RuntimeError(f"make_blend.py failed ({made.returncode}):\n{output}")
        # The same glTF through `epr render`, with the job's seed and with another (the noise).
        cls.reference = cls.epr_render(SEED)
        cls.other_seed = cls.epr_render(SEED + 1)

    @classmethod
    def tearDownClass(cls):
        cls.farm.stop()
        shutil.rmtree(cls.tmp, ignore_errors=True)

    @classmethod
    def blender(cls, *args: str) -> subprocess.CompletedProcess:
        try:
            return subprocess.run(
                [ARGS.blender, "-b", *args],
                capture_output=True,
                text=True,
                timeout=120,
                env=cls.env,
                stdin=subprocess.DEVNULL,
            )
        except FileNotFoundError:
            raise RuntimeError(
                f"cannot run Blender ({ARGS.blender}): scripts/setup.sh installs Debian's blender"
            ) from None

    @classmethod
    def epr_render(cls, seed: int, scene: str = GLTF):
        out = os.path.join(os.path.dirname(scene) if scene != GLTF else cls.tmp, f"epr-seed{seed}")
        r = harness.epr(
            "render", scene, "--width", str(WIDTH), "--height", str(HEIGHT), "--spp", str(SPP),
            "--mode", "pt", "--seed", str(seed), "--out", out,
        )  # fmt: skip
        if r.returncode != 0:
            raise RuntimeError(f"epr render failed:\n{r.stdout}\n{r.stderr}")
        return read_exr(out + ".exr")

    def render_blend(
        self, out: str, *frame_args: str, master=None, python=None, exit_code=False
    ) -> subprocess.CompletedProcess:
        """`blender -b` of the test's .blend with the add-on enabled (as Preferences keep it) and its
        package folder set; `python` runs after the file is loaded; `frame_args`: -f 1, -a, ...;
        exit_code: `--python-exit-code 1` (a script's uncaught exception ends Blender with status 1)."""
        enable = (
            "import addon_utils, bpy; addon_utils.enable('eprfarm_blender', default_set=True); "
            f"bpy.context.preferences.addons['eprfarm_blender'].preferences.package_path = {ARGS.package_dir!r}"
        )
        after = f"import bpy; bpy.context.scene.eprfarm.master = {(master or self.farm.address)!r}\n" + (python or "")
        first = ["--python-exit-code", "1"] if exit_code else []
        return self.blender(*first, "--python-expr", enable, self.blend, "-o", out, "--python-expr", after, *frame_args)

    def assert_within_noise(self, image, what: str, reference=None, other_seed=None):
        """`image` against `epr render`'s `reference` (default: scenes/cornell-box.gltf's), block by
        block, within five standard errors estimated from `other_seed` (the same with another seed)."""
        import numpy as np

        if reference is None:
            reference, other_seed = self.reference, self.other_seed
        ours, ref = block_means(image), block_means(reference)
        # The standard error of a block mean's difference between two renders: the per-pixel
        # difference of two seeds, averaged over the block.
        h, w, c = reference.shape
        d = (reference - other_seed).reshape(h // BLOCK, BLOCK, w // BLOCK, BLOCK, c)
        se = d.std(axis=(1, 3)) / BLOCK
        excess = np.abs(ours - ref) - (5 * se + 1e-4)
        worst = np.unravel_index(np.argmax(excess), excess.shape)
        self.assertLessEqual(
            excess.max(),
            0.0,
            f"{what}: block {worst[:2]} channel {worst[2]}: {ours[worst]:.5f} against epr render's {ref[worst]:.5f} "
            f"(5 standard errors: {5 * se[worst]:.5f})",
        )
        se_mean = float(d.std()) / np.sqrt(d.size)
        self.assertAlmostEqual(float(image.mean()), float(reference.mean()), delta=5 * se_mean)



class BlenderAddonTest(BlenderCase):
    """`blender -b`: the render engine on the command line, the batch operator, errors."""

    def test_frame_matches_epr_render(self):
        out = os.path.join(self.tmp, "still", "box_####")
        r = self.render_blend(out, "-f", "1")
        path = out.replace("####", "0001") + ".exr"
        self.assertTrue(os.path.exists(path), f"no frame written:\n{r.stdout[-6000:]}\n{r.stderr[-2000:]}")
        self.assertNotIn("Traceback", r.stdout + r.stderr)
        self.assertRegex(r.stdout, r"eprfarm: frame 1: job \S+ done, 16\.0 spp")
        image = read_exr(path)
        self.assertEqual(image.shape, (HEIGHT, WIDTH, 3))
        self.assert_within_noise(image, "frame 1 of -f 1")

    def test_textured_material(self):
        # A plane on the back wall with a generated colour-grid texture (the exporter writes it as a
        # PNG beside the glTF, which travels in the job's bundle): the add-on's frame against
        # `epr render` of Blender's own glTF export of the same scene, camera included.
        folder = os.path.join(self.tmp, "textured")
        os.makedirs(folder)
        still, exported = os.path.join(folder, "still.exr"), os.path.join(folder, "scene.gltf")
        r = self.render_blend(
            os.path.join(folder, "frames", "box_####"),
            python=(
                "image = bpy.data.images.new('grid', 64, 64)\n"
                "image.generated_type = 'COLOR_GRID'\n"
                "bpy.ops.mesh.primitive_plane_add(size=0.8, location=(0, 1.0, 1.2), rotation=(1.5708, 0, 0))\n"
                "material = bpy.data.materials.new('grid')\n"
                "material.use_nodes = True\n"
                "nodes = material.node_tree.nodes\n"
                "texture = nodes.new('ShaderNodeTexImage')\n"
                "texture.image = image\n"
                "bsdf = nodes['Principled BSDF']\n"
                "material.node_tree.links.new(texture.outputs['Color'], bsdf.inputs['Base Color'])\n"
                "bsdf.inputs['Roughness'].default_value = 1.0\n"
                "bpy.context.active_object.data.materials.append(material)\n"
                "bpy.ops.render.render()\n"
                f"bpy.data.images['Render Result'].save_render({still!r})\n"
                f"bpy.ops.export_scene.gltf(filepath={exported!r}, export_format='GLTF_SEPARATE',\n"
                "                          export_cameras=True)\n"
            ),
        )
        log = f"{r.stdout[-6000:]}\n{r.stderr[-2000:]}"
        self.assertRegex(r.stdout, r"eprfarm: frame 1: job \S+ done, 16\.0 spp", log)
        self.assertNotIn("Traceback", r.stdout + r.stderr, log)
        self.assertIn("grid.png", os.listdir(folder), log)
        image = read_exr(still)
        self.assertEqual(image.shape, (HEIGHT, WIDTH, 3))
        reference, other_seed = self.epr_render(SEED, exported), self.epr_render(SEED + 1, exported)
        self.assert_within_noise(image, "textured plane", reference, other_seed)
        with self.assertRaises(AssertionError):  # the plane is there: not the bare box
            self.assert_within_noise(image, "textured plane against the bare box")

    def test_world_and_sun(self):
        # scenes/garden's glTF imported, lit as garden.json lights it but set up in Blender: a World
        # with its sky image (an Environment Texture turned 30 degrees by a Mapping node) and a Sun
        # lamp; a point lamp is warned about. Against `epr render` of the JSON with the sky turned as
        # much, from F12's render and from Render Frames on Farm; the unturned sky, and a sun from the
        # mirrored side, must fail the comparison.
        import json

        garden = os.path.join(self.tmp, "garden")
        variants = {"turned": (30, SUN), "unturned": (0, SUN), "mirrored": (30, (-SUN[0], SUN[1], -SUN[2]))}
        for name, (rotation, sun) in variants.items():
            shutil.copytree(GARDEN, os.path.join(garden, name))
            with open(os.path.join(GARDEN, "garden.json")) as f:
                doc = json.loads("\n".join(line for line in f if not line.lstrip().startswith("//")))
            doc["environment"]["rotation_deg"], doc["sun"]["direction"] = rotation, list(sun)
            with open(os.path.join(garden, name, "garden.json"), "w") as f:
                json.dump(doc, f)
        still = os.path.join(garden, "still.exr")
        r = self.render_blend(
            os.path.join(garden, "frames", "garden_####"),
            python=(
                "import math, numpy\n"
                "from mathutils import Vector\n"
                "numpy.bool = bool\n"
                "for o in list(bpy.data.objects):\n"
                "    bpy.data.objects.remove(o, do_unlink=True)\n"
                f"bpy.ops.import_scene.gltf(filepath={os.path.join(GARDEN, 'garden.gltf')!r})\n"
                "scene = bpy.context.scene\n"
                "scene.render.engine = 'EPRFARM'  # (the importer sets Eevee)\n"
                "scene.camera = next(o for o in scene.objects if o.type == 'CAMERA')\n"
                "world = scene.world = bpy.data.worlds.new('yard sky')\n"
                "world.use_nodes = True\n"
                "nodes, links = world.node_tree.nodes, world.node_tree.links\n"
                "sky = nodes.new('ShaderNodeTexEnvironment')\n"
                f"sky.image = bpy.data.images.load({os.path.join(GARDEN, 'sky.exr')!r})\n"
                "mapping = nodes.new('ShaderNodeMapping')\n"
                "mapping.inputs['Rotation'].default_value = (0, 0, math.radians(30))\n"
                "links.new(nodes.new('ShaderNodeTexCoord').outputs['Generated'], mapping.inputs['Vector'])\n"
                "links.new(mapping.outputs['Vector'], sky.inputs['Vector'])\n"
                "links.new(sky.outputs['Color'], nodes['Background'].inputs['Color'])\n"
                "lamp = bpy.data.lights.new('noon', 'SUN')\n"
                "lamp.energy, lamp.angle = 3.0, math.radians(0.53)\n"
                "sun = bpy.data.objects.new('noon', lamp)\n"
                "scene.collection.objects.link(sun)\n"
                f"sun.rotation_euler = Vector({(SUN[0], -SUN[2], SUN[1])!r}).to_track_quat('Z', 'Y').to_euler()\n"
                "bpy.ops.object.light_add(type='SPOT')\n"  # dark: its radius is warned about
                "bpy.context.object.data.energy = 0\n"
                "bpy.ops.render.render()\n"
                f"bpy.data.images['Render Result'].save_render({still!r})\n"
                "scene.frame_start = scene.frame_end = 1\n"
                "print('operator:', sorted(bpy.ops.eprfarm.render_frames()), flush=True)\n"
                "from eprfarm_blender import export\n"
                "world.node_tree.links.remove(nodes['Background'].inputs['Color'].links[0])\n"
                "nodes['Background'].inputs['Color'].default_value = (0.2, 0.3, 0.5, 1)\n"
                "nodes['Background'].inputs['Strength'].default_value = 2\n"
                "lighting, _ = export.farm_lighting(scene, bpy.context.evaluated_depsgraph_get(), '.')\n"
                "print('constant world:', lighting['environment'], flush=True)\n"
                "links.new(nodes.new('ShaderNodeTexSky').outputs['Color'], nodes['Background'].inputs['Color'])\n"
                "scene.collection.objects.link(bpy.data.objects.new('dusk', bpy.data.lights.new('dusk', 'SUN')))\n"
                "lighting, warned = export.farm_lighting(scene, bpy.context.evaluated_depsgraph_get(), '.')\n"
                "print('sky texture:', sorted(lighting), *warned, sep='\\n', flush=True)\n"
            ),
        )
        log = f"{r.stdout[-6000:]}\n{r.stderr[-2000:]}"
        self.assertRegex(r.stdout, r"eprfarm: frame 1: job \S+ done, 16\.0 spp", log)
        self.assertNotIn("Traceback", r.stdout + r.stderr, log)
        self.assertIn("Warning: eprfarm: Spot lamp 'Spot': its radius is ignored (a point: hard shadows)", log)
        self.assertRegex(r.stdout, r"constant world: \{'color': \[0\.2\d*, 0\.3\d*, 0\.5\], 'strength': 2\.0\}", log)
        self.assertIn("sky texture:\n['lights', 'sun']\n", r.stdout, log)  # what the farm cannot model: named
        self.assertIn(
            "the world 'yard sky' is not exported: the Background colour comes from a Sky Texture node", r.stdout, log
        )
        image = read_exr(still)
        self.assertEqual(image.shape, (HEIGHT, WIDTH, 3))

        def reference(name, seed):
            return self.epr_render(seed, os.path.join(garden, name, "garden.json"))

        turned = reference("turned", SEED), reference("turned", SEED + 1)
        self.assert_within_noise(image, "the garden with its World and Sun", *turned)
        self.assertIn("operator: ['FINISHED']", r.stdout, log)  # Render Frames on Farm: the batch's export
        batch = read_exr(os.path.join(garden, "frames", "garden_0001.exr"))
        self.assert_within_noise(batch, "the garden's frame of Render Frames on Farm", *turned)
        for name in ("unturned", "mirrored"):
            with self.assertRaises(AssertionError, msg=name):
                self.assert_within_noise(
                    image, f"against the {name} sky and sun", reference(name, SEED), reference(name, SEED + 1)
                )

    def test_two_frames(self):
        out = os.path.join(self.tmp, "anim", "box_####")
        r = self.render_blend(out, "-s", "1", "-e", "2", "-a")
        paths = [out.replace("####", f"{f:04d}") + ".exr" for f in (1, 2)]
        written = sorted(os.listdir(os.path.dirname(out))) if os.path.isdir(os.path.dirname(out)) else []
        self.assertEqual(written, ["box_0001.exr", "box_0002.exr"], f"{r.stdout[-6000:]}\n{r.stderr[-2000:]}")
        self.assertEqual(len(set(re.findall(r"eprfarm: frame ([12]): job (\S+) done", r.stdout))), 2, r.stdout[-6000:])
        first, second = (read_exr(p) for p in paths)
        self.assertEqual(first.shape, (HEIGHT, WIDTH, 3))
        self.assertEqual(second.shape, (HEIGHT, WIDTH, 3))
        self.assert_within_noise(first, "frame 1 of -a")
        # Frame 2 sees the box from elsewhere: the same comparison must fail.
        with self.assertRaises(AssertionError):
            self.assert_within_noise(second, "frame 2 of -a")

    def test_batch_operator(self):
        # Render Frames on Farm: both frames queued as one batch, saved at the output path as they
        # finish and loaded as one image sequence. The inline limit is lowered so that the scene
        # goes by UploadScene: the two frames' exports are the same file (only the camera moves), so
        # it is uploaded once. (The UI test's batch sends it inline.)
        out = os.path.join(self.tmp, "batch", "box_####")
        r = self.render_blend(
            out,
            python=(
                "from eprfarm_blender import settings\n"
                "eprfarm = settings.import_client()\n"
                "eprfarm.MasterClient.inline_scene_limit = 1000\n"
                "uploads = []\n"
                "upload = eprfarm.Client.upload_scene\n"
                "def counted(client, bundle):\n"
                "    uploads.append(bundle.total_bytes)\n"
                "    return upload(client, bundle)\n"
                "eprfarm.Client.upload_scene = counted\n"
                "result = bpy.ops.eprfarm.render_frames()\n"
                "print('uploads:', len(uploads), 'bytes over the limit:', all(b > 1000 for b in uploads))\n"
                "image = bpy.data.images['eprfarm box']\n"
                "print('operator:', sorted(result), image.source, bpy.path.abspath(image.filepath))\n"
            ),
        )
        paths = [out.replace("####", f"{f:04d}") + ".exr" for f in (1, 2)]
        log = f"{r.stdout[-6000:]}\n{r.stderr[-2000:]}"
        self.assertIn(f"operator: ['FINISHED'] SEQUENCE {paths[0]}", r.stdout, log)
        self.assertIn("uploads: 1 bytes over the limit: True", r.stdout, log)
        self.assertRegex(r.stdout, r"eprfarm: batch (\S+): 2 frames queued")
        self.assertRegex(r.stdout, r"eprfarm: batch \S+: 2/2 frames done, 100%")
        self.assertNotIn("Traceback", r.stdout + r.stderr)
        first, second = (read_exr(p) for p in paths)
        self.assertEqual(first.shape, (HEIGHT, WIDTH, 3))
        self.assertEqual(second.shape, (HEIGHT, WIDTH, 3))
        self.assert_within_noise(first, "frame 1 of the batch")
        with self.assertRaises(AssertionError):
            self.assert_within_noise(second, "frame 2 of the batch")
        # The batch's jobs on the master: one per frame, in the batch.
        import eprfarm

        with eprfarm.Client(self.farm.address) as client:
            batch = re.search(r"eprfarm: batch (\S+): 2 frames queued", r.stdout).group(1)
            jobs = client.list(batch=batch)
        self.assertEqual(
            sorted((j.frame, j.state, j.name) for j in jobs), [(1, "DONE", "box.0001"), (2, "DONE", "box.0002")]
        )

    def test_batch_operator_errors(self):
        # Render Frames on Farm from a script: an unreachable master, a port beyond 65535 (not taken
        # modulo 65536: that is the farm's port) and an output folder that cannot be made (a file is
        # in the way: the frames are cancelled) are reported in words; the script's call raises them as
        # RuntimeError, whose traceback is the script's alone, and --python-exit-code 1 makes that
        # Blender's status.
        dead, port = harness.free_port(), int(self.farm.address.rpartition(":")[2])
        blocked = os.path.join(self.tmp, "operator-errors", "a-file")
        os.makedirs(os.path.dirname(blocked))
        open(blocked, "w").close()
        r = self.render_blend(
            os.path.join(blocked, "frames", "box_####"),
            exit_code=True,
            python=(
                "def run(master):\n"
                "    bpy.context.scene.eprfarm.master = master\n"
                "    try:\n"
                "        print('operator:', sorted(bpy.ops.eprfarm.render_frames()), flush=True)\n"
                "    except RuntimeError as e:\n"
                "        print('operator raised:', e, flush=True)\n"
                f"run('127.0.0.1:{dead}')\n"
                f"run('127.0.0.1:{port + 65536}')\n"
                f"run({self.farm.address!r})\n"
                "print('--- uncaught', flush=True)\n"
                f"bpy.context.scene.eprfarm.master = '127.0.0.1:{dead}'\n"
                "bpy.ops.eprfarm.render_frames()\n"
                "print('after', 'the call', flush=True)\n"
            ),
        )
        log = f"{r.stdout[-6000:]}\n{r.stderr[-2000:]}"
        self.assertEqual(r.returncode, 1, log)
        self.assertIn(f"operator raised: Error: eprfarm: cannot reach master at 127.0.0.1:{dead}", r.stdout, log)
        self.assertIn(
            f"operator raised: Error: eprfarm: master: '127.0.0.1:{port + 65536}' has port {port + 65536}, "
            "outside 1-65535", r.stdout, log
        )  # fmt: skip
        self.assertRegex(
            r.stdout, r"operator raised: Error: eprfarm: batch \S+: frame 1: cannot save \S+a-file/frames/box_0001\.exr: "
            r"Not a directory; its frames that had not ended were cancelled", log
        )  # fmt: skip
        self.assertNotIn("operator: ['FINISHED']", r.stdout, log)
        self.assertNotIn("after the call", r.stdout, log)
        before, uncaught = r.stdout.split("--- uncaught", 1)
        self.assertNotIn("Traceback", before, log)
        self.assertIn("RuntimeError: Error: eprfarm: cannot reach master", uncaught, log)
        self.assertNotIn("eprfarm_blender", uncaught, log)  # no frame of the add-on's in the traceback
        import eprfarm

        with eprfarm.Client(self.farm.address) as client:
            batch = re.search(r"eprfarm: batch (\S+): frame 1: cannot save", r.stdout).group(1)
            self.assertLessEqual({j.state for j in client.list(batch=batch)}, {"DONE", "CANCELLED"}, log)

    def test_batch_operator_frame_window(self):
        # Frame Window 1: every frame's job names the window and its run (frames 1-2, one run) and has
        # the seed plus its frame, as the specs sent show; the batch ends. Refused, with the reason and nothing left running: Mode pt
        # (nothing to reproject), and a mesh that moves between the frames (not a still scene).
        out = os.path.join(self.tmp, "window", "box_####")
        r = self.render_blend(
            out,
            python=(
                "from eprfarm_blender import settings\n"
                "eprfarm = settings.import_client()\n"
                "submit = eprfarm.Client.submit_spec\n"
                "def recorded(client, spec):\n"
                "    print('sent:', spec.frame, spec.frame_window, spec.window_first, spec.window_last, spec.seed, flush=True)\n"
                "    return submit(client, spec)\n"
                "eprfarm.Client.submit_spec = recorded\n"
                "s = bpy.context.scene.eprfarm\n"
                "s.frame_window, s.mode = 1, 'skip'\n"
                "print('operator:', sorted(bpy.ops.eprfarm.render_frames()), flush=True)\n"
                "def refused(what):\n"
                "    try:\n"
                "        print(what, sorted(bpy.ops.eprfarm.render_frames()), flush=True)\n"
                "    except RuntimeError as e:\n"
                "        print(what, 'raised:', e, flush=True)\n"
                "s.mode = 'pt'\n"
                "refused('pt:')\n"
                "s.mode = 'skip'\n"
                "bpy.ops.mesh.primitive_cube_add(size=0.2, location=(0, 0.5, 0.5))\n"
                "cube = bpy.context.active_object\n"
                "cube.keyframe_insert('location', frame=1)\n"
                "cube.location.x += 0.3\n"
                "cube.keyframe_insert('location', frame=2)\n"
                "refused('moving:')\n"
            ),
        )
        log = f"{r.stdout[-6000:]}\n{r.stderr[-2000:]}"
        self.assertIn("operator: ['FINISHED']", r.stdout, log)
        self.assertRegex(r.stdout, r"eprfarm: batch \S+: 2/2 frames done, 100%", log)
        self.assertEqual(re.findall(r"sent: (.*)", r.stdout)[:2], [f"1 1 1 2 {SEED + 1}", f"2 1 1 2 {SEED + 2}"], log)
        self.assertEqual(len(re.findall(r"sent: ", r.stdout)), 3, log)  # the moving scene's frame 1, then refused
        self.assertIn("pt: raised: Error: eprfarm: frame_window needs reprojection: mode pt", r.stdout, log)
        self.assertRegex(
            r.stdout, r"moving: raised: Error: eprfarm: batch (\S+): frame 2: the scene is not the same as at frame 1 "
            r"\(objects, materials or lights move\): a frame window needs a still scene; set Frame Window to 0; "
            r"its frames that had not ended were cancelled", log
        )  # fmt: skip
        self.assertNotIn("Traceback", r.stdout + r.stderr)
        import eprfarm

        with eprfarm.Client(self.farm.address) as client:
            batch = re.search(r"moving: raised: Error: eprfarm: batch (\S+):", r.stdout).group(1)
            self.assertLessEqual({j.state for j in client.list(batch=batch)}, {"DONE", "CANCELLED"}, log)

    def test_errors(self):
        # Three renders in one Blender: an unreachable master; then the right master, but no emitter
        # left and a point lamp, which the add-on does not export: the master refuses the scene and
        # says why, and the add-on warned about the lamp; then a package folder without the eprfarm
        # package. (A script's render call raises the error the engine reported as a RuntimeError.)
        nowhere = os.path.join(self.tmp, "no-package")
        os.makedirs(nowhere, exist_ok=True)
        port = harness.free_port()
        out = os.path.join(self.tmp, "errors", "box_####")
        r = self.render_blend(
            out,
            master=f"127.0.0.1:{port}",
            python=(
                "def render():\n"
                "    try:\n"
                "        bpy.ops.render.render(write_still=True)\n"
                "    except RuntimeError as e:\n"
                "        print('render raised:', e, flush=True)\n"
                "render()\n"
                "print('--- refused', flush=True)\n"
                f"bpy.context.scene.eprfarm.master = {self.farm.address!r}\n"
                "bpy.data.materials['light'].node_tree.nodes['Principled BSDF'].inputs['Emission Strength']"
                ".default_value = 0\n"
                "bpy.ops.object.light_add(type='SPOT')\n"  # a dark lamp: warned about, and no light
                "bpy.context.object.data.energy = 0\n"
                "render()\n"
                "print('--- package', flush=True)\n"
                f"bpy.context.preferences.addons['eprfarm_blender'].preferences.package_path = {nowhere!r}\n"
                "render()\n"
            ),
        )
        self.assertIn("--- refused", r.stdout, f"{r.stdout[-6000:]}\n{r.stderr[-2000:]}")
        self.assertIn("--- package", r.stdout, f"{r.stdout[-6000:]}\n{r.stderr[-2000:]}")
        unreachable, rest = r.stdout.split("--- refused")
        refused, package = rest.split("--- package")
        self.assertIn(f"Error: eprfarm: cannot reach master at 127.0.0.1:{port}", unreachable)
        self.assertIn(f"render raised: Error: eprfarm: cannot reach master at 127.0.0.1:{port}", unreachable)
        self.assertIn("Warning: eprfarm: Spot lamp 'Spot': its radius is ignored (a point: hard shadows)", refused)
        self.assertRegex(
            refused, r"Error: eprfarm: master at \S+ refused SubmitJob: INVALID_ARGUMENT: scene\.json has no light"
        )
        self.assertIn(
            f"Error: eprfarm: the eprfarm package folder '{nowhere}' (add-on preferences) has no eprfarm package",
            package,
        )
        self.assertNotIn("Traceback", r.stdout + r.stderr)
        self.assertFalse(os.path.exists(os.path.dirname(out)), "an image was written for a failed render")
    def test_token(self):
        # A farm whose master wants a token (its worker has it): without one the master's refusal
        # is shown; with the token file of the panel the frame renders.
        token = "blender-token_for.tests"
        folder = os.path.join(self.tmp, "token")
        os.makedirs(folder)
        token_file = os.path.join(folder, "token")
        with open(token_file, "w") as f:
            f.write(token + "\n")
        os.environ["EPR_TOKEN"] = token  # the master's and the worker's, not Blender's (self.env)
        try:
            farm = harness.Farm(folder)
        finally:
            del os.environ["EPR_TOKEN"]
        self.addCleanup(farm.stop)
        out = os.path.join(folder, "frames", "box_####")
        still = os.path.join(folder, "still.exr")
        r = self.render_blend(
            out,
            master=farm.address,
            python=(
                "try:\n"
                "    bpy.ops.render.render(write_still=True)\n"
                "except RuntimeError as e:\n"
                "    print('render raised:', e, flush=True)\n"
                "print('--- with token', flush=True)\n"
                f"bpy.context.scene.eprfarm.token_file = {token_file!r}\n"
                "bpy.ops.render.render()\n"
                f"bpy.data.images['Render Result'].save_render({still!r})\n"
            ),
        )
        log = f"{r.stdout[-6000:]}\n{r.stderr[-2000:]}"
        self.assertIn("--- with token", r.stdout, log)
        without, with_token = r.stdout.split("--- with token")
        self.assertIn(f"Error: eprfarm: master at {farm.address} refused SubmitJob: UNAUTHENTICATED", without, log)
        # What to do, in the words of the add-on's panel, not the package's arguments.
        self.assertIn("(set the master's token in Render Properties > eprfarm: Token, or Token File)", without, log)
        self.assertNotIn("token=", without, log)
        self.assertRegex(with_token, r"eprfarm: frame 1: job \S+ done, 16\.0 spp", log)
        self.assertNotIn("Traceback", r.stdout + r.stderr)
        self.assertFalse(os.path.exists(os.path.dirname(out)), "an image was written for a refused job")
        self.assert_within_noise(read_exr(still), "frame 1 with a token")


class BlenderUiTest(BlenderCase):
    """Blender with its UI under xvfb-run: F12 and Render Animation run the engine in a job thread."""

    def test_f12_and_render_animation(self):
        still = os.path.join(self.tmp, "ui", "still.exr")
        frames = os.path.join(self.tmp, "ui", "anim_####")
        batch_frames = os.path.join(self.tmp, "ui", "batch_####")
        os.makedirs(os.path.dirname(still))
        enable = (
            "import addon_utils, bpy; addon_utils.enable('eprfarm_blender', default_set=True); "
            f"bpy.context.preferences.addons['eprfarm_blender'].preferences.package_path = {ARGS.package_dir!r}"
        )
        try:
            # A session of its own: should Blender not quit, the whole group (xvfb-run, Xvfb, Blender) is
            # killed and the test fails with Blender's output; killing xvfb-run alone leaves Blender
            # running, holding the pipes.
            p = subprocess.Popen(
                [ARGS.xvfb_run, "-a", "-s", "-screen 0 1280x1024x24", ARGS.blender, "--factory-startup",
                 "--python-expr", enable, self.blend, "--python", os.path.join(HERE, "ui_render.py"),
                 "--", "--still", still, "--frames", frames, "--batch", batch_frames],
                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=self.env, stdin=subprocess.DEVNULL,
                start_new_session=True,
            )  # fmt: skip
        except FileNotFoundError:
            self.fail(f"cannot run {ARGS.xvfb_run}: scripts/setup.sh installs Debian's xvfb")
        try:
            stdout, stderr = p.communicate(timeout=270)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            stdout, stderr = p.communicate()
            self.fail(f"Blender did not quit within 270 s:\n{stdout[-6000:]}\n{stderr[-3000:]}")
        r = subprocess.CompletedProcess(p.args, p.returncode, stdout, stderr)
        log = f"{r.stdout[-6000:]}\n{r.stderr[-3000:]}"
        self.assertIn("ui_render: animation finished", r.stdout, log)
        quit_while = re.search(r"ui_render: quitting while (\S+) runs", r.stdout)
        self.assertIsNotNone(quit_while, log)
        self.assertIn("ui_render: invoke: {'FINISHED'}", r.stdout, log)  # the batch operator
        self.assertIn("ui_render: batch finished", r.stdout, log)
        self.assertRegex(r.stdout, r"eprfarm: batch \S+: 2/2 frames done, 100%", log)
        # Blender quit during the long render: the render stopped and cancelled its farm job.
        import eprfarm

        long_job = quit_while.group(1)
        self.assertIn(f"eprfarm: frame 1: job {long_job} cancelled", r.stdout, log)
        with eprfarm.Client(self.farm.address) as client:
            self.assertEqual(client.status(long_job).state, "CANCELLED")
        self.assertNotIn("Traceback", r.stdout + r.stderr, log)
        # F12, the animation's frame 1, the long F12
        self.assertEqual(len(re.findall(r"eprfarm: frame 1: job \S+ at", r.stdout)), 3, log)
        self.assertEqual(len(re.findall(r"eprfarm: frame 2: job \S+ at", r.stdout)), 1, log)
        image = read_exr(still)
        self.assertEqual(image.shape, (HEIGHT, WIDTH, 3))
        self.assert_within_noise(image, "F12")
        first, second = (read_exr(frames.replace("####", f"{f:04d}") + ".exr") for f in (1, 2))
        self.assert_within_noise(first, "frame 1 of Render Animation")
        with self.assertRaises(AssertionError):
            self.assert_within_noise(second, "frame 2 of Render Animation")
        first, second = (read_exr(batch_frames.replace("####", f"{f:04d}") + ".exr") for f in (1, 2))
        self.assert_within_noise(first, "frame 1 of Render Frames on Farm")
        with self.assertRaises(AssertionError):
            self.assert_within_noise(second, "frame 2 of Render Frames on Farm")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--blender", required=True, help="the blender program (Debian's)")
    parser.add_argument("--xvfb-run", default="xvfb-run", help="Debian's xvfb-run, for BlenderUiTest")
    parser.add_argument("--package-dir", required=True, help="folder holding the eprfarm package with its stubs")
    parser.add_argument("--epr", required=True)
    parser.add_argument("--master", required=True)
    parser.add_argument("--worker", required=True)
    args, rest = parser.parse_known_args()
    args.package_dir = os.path.abspath(args.package_dir)
    ARGS.__dict__.update(vars(args))
    harness.ARGS.__dict__.update(vars(args))
    sys.path.insert(0, args.package_dir)
    program = unittest.main(argv=[sys.argv[0], *rest], exit=False, verbosity=2)
    return 0 if program.result.wasSuccessful() else 1


if __name__ == "__main__":
    sys.exit(main())
